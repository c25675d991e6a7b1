"""The registry of robot arms (domains): the Panda, the arms robosuite ships, and the user's own.

Every arm is a torque-driven domain with the same construction as :mod:`robomorph.sim.panda`:
a floor, an end-effector site ``ee`` (at the flange, where robosuite mounts grippers, for
the robosuite arms; at the Panda's TCP for the Panda), one torque motor per joint clamped
to the manufacturer's torque limit, gravity compensation of the current model routed
through the actuators (``gravcomp`` on every body, ``actuatorgravcomp`` on every joint,
switched off with ``gravity_compensation: none``) and the same sensor layout: for ``n``
joints ``sensordata`` holds EE position (3), EE quaternion w x y z (4), q (n), the joint
torque (n), the contact count (1) and the motors' own force (n).

The robosuite arms are read at run time from the installed ``robosuite`` wheel (MIT code,
installed ``--no-deps`` by the ``arms`` extra; its Python is never imported), then edited
with ``mujoco.MjSpec``: its motors, sensors and visual-only meshes are dropped (the
explicit ``<inertial>`` elements carry the masses, so the dynamics do not change), and
the pieces above are added. Joints without limits (Kinova's continuous joints) get
+-2 pi, so the joint-limit filter and the randomizer have a range to work with.

Torque limits are the ``ctrlrange`` values of robosuite's ``robot.xml``; their sources, as
the XML comments give them, are in :data:`ARMS` (``torque_source``); a test checks that
they still match the installed XML.

A user's own arms (``robomorph arms add NAME --urdf robot.urdf``, :mod:`robomorph.sim.user_arms`)
live in a user folder, never in the installed package: ``$ROBOMORPH_ARMS``, else
``$XDG_DATA_HOME/robomorph/arms``, else ``~/.local/share/robomorph/arms``, one folder per arm
holding ``arm.json`` and its model (``model.urdf`` or ``model.xml``: kinematics, inertials,
joint limits, damping and friction, without geometry). :data:`ARMS` finds them beside the shipped ones, so everything that
asks the registry (generate, the physics baselines, identified physics, the hybrid,
``Predictor.from_arm``) works on them alike; their domain is built as a robosuite arm's is.
"""

from __future__ import annotations

import copy
import functools
import importlib.util
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.sim import panda

DEFAULT_ROBOT = "panda"
ROBOSUITE_VERSION = "1.5.2"


class AssetsMissingError(panda.AssetsMissingError):
    """An arm's MJCF is not installed (the ``arms`` extra)."""


class UnknownRobotError(RoboMorphError, ValueError):
    """A robot name the registry does not hold."""


@dataclass(frozen=True)
class SensorLayout:
    """Slices of ``sensordata`` for an arm with ``n`` joints (the order the sensors are added in)."""

    n: int

    @classmethod
    def of_width(cls, nsensordata: int) -> "SensorLayout":
        """The layout of sensor rows ``nsensordata`` wide (8 + 3 n)."""
        n, rest = divmod(int(nsensordata) - 8, 3)
        if rest or n < 1:
            raise ValueError(f"{nsensordata} sensor values is not a RoboMorph arm layout (8 + 3 n)")
        return cls(n)

    @property
    def ee_pos(self) -> slice:
        return slice(0, 3)

    @property
    def ee_quat(self) -> slice:  # MuJoCo order w, x, y, z
        return slice(3, 7)

    @property
    def qpos(self) -> slice:
        return slice(7, 7 + self.n)

    @property
    def tau(self) -> slice:
        return slice(7 + self.n, 7 + 2 * self.n)

    @property
    def contacts(self) -> int:
        return 7 + 2 * self.n

    @property
    def cmd(self) -> slice:
        return slice(8 + 2 * self.n, 8 + 3 * self.n)


@dataclass(frozen=True)
class Arm:
    """One registered arm.

    Attributes:
        name: registry key (``--robot``), also the stores' ``domain``.
        title: the arm's name for people.
        joint_names: the MJCF joints driven, base to flange.
        torque_limits: (n,) motor limits [N m].
        torque_source: where the limits come from.
        home: (n,) centre of the initial poses (robosuite's ``init_qpos``); ``None``: the
            middle of the joint ranges (the Panda's scheme, kept as it was).
        folder: robosuite's ``models/assets/robots/<folder>`` (``None`` for the Panda).
        hand: the body the EE site is put on.
        model_file: a user arm's ``model.xml`` (``None`` for the shipped arms).
        digest: the SHA-256 of a user arm's model, so a cached model never outlives its file.
    """

    name: str
    title: str
    joint_names: tuple[str, ...]
    torque_limits: tuple[float, ...]
    torque_source: str
    home: tuple[float, ...] | None = None
    folder: str | None = None
    hand: str = "right_hand"
    model_file: str | None = None
    digest: str | None = None

    def __post_init__(self):
        if len(self.torque_limits) != len(self.joint_names) or (
                self.home is not None and len(self.home) != len(self.joint_names)):
            raise ValueError(f"arm {self.name}: joint_names, torque_limits and home must have one value per joint")

    @property
    def n_joint(self) -> int:
        return len(self.joint_names)

    @property
    def limits(self) -> np.ndarray:
        """(n,) torque limits as an array (the Panda's is :data:`panda.TORQUE_LIMITS` itself)."""
        return panda.TORQUE_LIMITS if self.name == "panda" else np.asarray(self.torque_limits)

    @property
    def joint_gain(self) -> np.ndarray:
        """(n,) how much larger this arm's joints are than the Panda's of the same role.

        Per joint, the smaller of two ratios to the Panda's joint of the same role (the
        wrist is the last three joints): the torque limits, and the effective inertia
        at the centre of the initial poses (the diagonal of the joint-space mass matrix
        plus the middle of the default armature range, 0.1 kg m^2). A signal scaled by it
        accelerates the arm about as the paper's signal does the Panda, without asking for
        more of its motors. Ones for the Panda, whose recipes are unchanged.
        """
        return np.ones(self.n_joint) if self.name == "panda" else _joint_gain(self).copy()

    @property
    def layout(self) -> SensorLayout:
        return SensorLayout(self.n_joint)

    @property
    def u_names(self) -> tuple[str, ...]:
        return tuple(f"tau{i}" for i in range(self.n_joint))

    @property
    def u_cmd_names(self) -> tuple[str, ...]:
        return tuple(f"cmd{i}" for i in range(self.n_joint))

    @property
    def y_names(self) -> tuple[str, ...]:
        return panda.Y_NAMES[:7] + tuple(f"q{i}" for i in range(self.n_joint))

    def build_model(self, substeps: int = 8, dt: float = 1 / 60,
                    gravity_compensation: bool = True) -> mujoco.MjModel:
        """Compiles the arm's domain (a fresh model, safe to modify); see :func:`panda.build_model`."""
        if self.name == "panda":
            return panda.build_model(substeps, dt, gravity_compensation)
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        return copy.deepcopy(_compiled(self, float(dt) / substeps, bool(gravity_compensation)))

    def link_bodies(self, model: mujoco.MjModel) -> tuple[str, ...]:
        """The randomized bodies: for the Panda its links and hand; otherwise the body each joint turns."""
        if self.name == "panda":
            return panda.LINK_BODIES
        return tuple(model.body(model.jnt_bodyid[model.joint(j).id]).name for j in self.joint_names)


_UR = "Universal Robots, max joint torques (universal-robots.com/articles/ur-articles/max-joint-torques)"
SHIPPED: dict[str, Arm] = {a.name: a for a in (
    Arm("panda", "Franka Emika Panda", tuple(f"panda_joint{i}" for i in range(1, 8)),
        tuple(panda.TORQUE_LIMITS), "Franka Control Interface documentation (dm-robotics-panda model)",
        hand="hand"),
    Arm("ur5e", "Universal Robots UR5e", ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                          "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"),
        (150.0, 150.0, 150.0, 28.0, 28.0, 28.0), _UR,
        home=(-0.470, -1.735, 2.480, -2.275, -1.590, -1.991), folder="ur5e"),
    Arm("iiwa", "KUKA LBR iiwa 7", tuple(f"joint_{i}" for i in range(1, 8)),
        (176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0), "KUKA LBR iiwa brochure (kuka_lbr_iiwa_brochure_en.pdf)",
        home=(0.0, 0.3, 0.0, -1.2, 0.0, 0.9, 0.0), folder="iiwa"),
    Arm("kinova3", "Kinova Gen3 (7 DOF)", tuple(f"Actuator{i}" for i in range(1, 8)),
        (32.0, 32.0, 32.0, 32.0, 32.0, 13.0, 13.0), "Kinova Gen3 user guide, actuator datasheet (p. 24)",
        home=(0.0, 0.650, 0.0, 1.890, 0.0, 0.600, -np.pi / 2), folder="kinova3"),
    Arm("xarm7", "UFACTORY xArm7", tuple(f"joint{i}" for i in range(1, 8)),
        (80.0,) * 7, "robosuite 1.5.2 robot.xml ('physical limits of the actuator', no datasheet named)",
        home=(0.0, 0.0, 0.0, 0.39 * np.pi, 0.0, 0.39 * np.pi, 0.0), folder="xarm7"),
    Arm("sawyer", "Rethink Sawyer", tuple(f"right_j{i}" for i in range(7)),
        (80.0, 80.0, 40.0, 40.0, 9.0, 9.0, 9.0), "robosuite 1.5.2 robot.xml (Rethink Sawyer specifications)",
        home=(0.0, -1.18, 0.0, 2.18, 0.0, 0.57, -1.57), folder="sawyer"),
    Arm("jaco", "Kinova Jaco 2 (7 DOF, j2s7s300)", tuple(f"j2s7s300_joint_{i}" for i in range(1, 8)),
        (30.5, 30.5, 30.5, 30.5, 30.5, 6.8, 6.8), "Kinova Jaco actuator spec sheet (KA-58 / KA-75+)",
        home=(3.192, 3.680, 0.0, 1.170, 0.050, 3.760, 3.142), folder="jaco"),
)}


USER_ARMS_ENV = "ROBOMORPH_ARMS"


def user_folder() -> str:
    """The folder of the user's own arms (see the module docstring); it may not exist yet."""
    if os.environ.get(USER_ARMS_ENV):
        return os.path.abspath(os.path.expanduser(os.environ[USER_ARMS_ENV]))
    data = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return os.path.join(os.path.abspath(data), "robomorph", "arms")


def _user_names() -> list[str]:
    folder = user_folder()
    if not os.path.isdir(folder):
        return []
    return sorted(n for n in os.listdir(folder) if n not in SHIPPED and os.path.isfile(os.path.join(folder, n, "arm.json")))


@functools.lru_cache(maxsize=64)
def read_user_arm(path: str, mtime_ns: int) -> Arm:  # mtime in the key: a re-added arm is read anew
    with open(path, encoding="utf-8") as f:
        rec = json.load(f)
    return Arm(rec["name"], rec["title"], tuple(rec["joint_names"]), tuple(float(v) for v in rec["torque_limits"]),
               rec["torque_source"], None if rec.get("home") is None else tuple(rec["home"]), hand=rec["hand"],
               model_file=os.path.join(os.path.dirname(path), rec["model"]), digest=rec["digest"])


def user_arm(name: str) -> Arm | None:
    """The user's arm ``name`` from the user folder, or None."""
    if name in SHIPPED or not isinstance(name, str) or not name or os.sep in name or name.startswith("."):
        return None
    path = os.path.join(user_folder(), name, "arm.json")
    try:
        return read_user_arm(path, os.stat(path).st_mtime_ns)
    except FileNotFoundError:
        return None
    except (ValueError, KeyError, TypeError) as exc:  # a hand-edited or half-copied arm.json
        raise UnknownRobotError(f"the user arm {name!r} ({path}) is damaged ({type(exc).__name__}: {exc}); remove it with "
                                f"`robomorph arms remove {name}` and add it again") from None


class _Registry(Mapping):
    """The shipped arms, then the user's own (read from the user folder at each look-up, so an
    arm added or removed by another process is seen)."""

    def __getitem__(self, name: str) -> Arm:
        arm = SHIPPED.get(name) or user_arm(name)
        if arm is None:
            raise KeyError(name)
        return arm

    def __iter__(self) -> Iterator[str]:
        yield from SHIPPED
        yield from _user_names()

    def __len__(self) -> int:
        return len(SHIPPED) + len(_user_names())


ARMS: Mapping[str, Arm] = _Registry()


_ARMATURE_MID = 0.1  # kg m^2: the middle of RandomizationConfig.armature's default range


def centre_pose(arm: Arm, joint_range: np.ndarray) -> np.ndarray:
    """(n,) the centre of an arm's initial poses: its home pose moved HOME_MARGIN inside the
    limits, or the middle of the ranges (the Panda)."""
    lo, hi = np.asarray(joint_range).T
    if arm.home is None:
        return (lo + hi) / 2
    return np.clip(arm.home, lo + HOME_MARGIN, hi - HOME_MARGIN)


HOME_MARGIN = 0.5  # rad


def _inertia(arm: Arm) -> np.ndarray:
    """Diagonal of the nominal joint-space mass matrix at :func:`centre_pose`, plus armature."""
    model = arm.build_model(gravity_compensation=False)
    data = mujoco.MjData(model)
    data.qpos[:] = centre_pose(arm, model.jnt_range[:arm.n_joint])
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return np.diag(full) + _ARMATURE_MID


@functools.lru_cache(maxsize=None)
def _joint_gain(arm: Arm) -> np.ndarray:
    n = arm.n_joint
    # Role of each joint in the Panda: the first n - 3 joints from the base, the last 3 the wrist.
    role = np.array([i if i < n - 3 else i + 7 - n for i in range(n)])
    torque = arm.limits / panda.TORQUE_LIMITS[role]
    inertia = _inertia(arm) / _inertia(ARMS["panda"])[role]
    return np.minimum(torque, inertia)


def names() -> list[str]:
    """The registered robots, Panda first, the user's own after the shipped ones."""
    return list(ARMS)


def get(name: str) -> Arm:
    """The arm registered as ``name``."""
    try:
        return ARMS[name]
    except KeyError:
        raise UnknownRobotError(f"unknown robot {name!r}; choose from {names()} (or add your own: "
                                "robomorph arms add NAME --urdf robot.urdf)") from None


def of_store(attrs: dict) -> Arm | None:
    """The arm a store was simulated with (its ``domain``), or None for other stores."""
    return ARMS.get(str(attrs.get("domain")))


def robosuite_xml(folder: str) -> str:
    """Path of robosuite's ``robot.xml`` for ``folder``, without importing robosuite."""
    spec = importlib.util.find_spec("robosuite")
    if spec is None or not spec.submodule_search_locations:
        raise AssetsMissingError(
            "this arm's model comes from robosuite, which is not installed: run `make install` or "
            f"`pip install --no-deps robosuite=={ROBOSUITE_VERSION}`")
    path = os.path.join(spec.submodule_search_locations[0], "models", "assets", "robots", folder, "robot.xml")
    if not os.path.isfile(path):
        raise AssetsMissingError(f"{path} not found (robosuite=={ROBOSUITE_VERSION} expected)")
    return path


def _strip(spec: mujoco.MjSpec) -> None:
    """Drops what the domain replaces (motors, sensors) or never uses (visual meshes)."""
    for item in list(spec.sensors) + list(spec.actuators):
        spec.delete(item)
    # Visual geoms neither collide nor carry mass (every body has an explicit <inertial>);
    # their meshes are most of the compile time and memory of a model copy.
    for geom in list(spec.geoms):
        if geom.contype == 0 and geom.conaffinity == 0:
            spec.delete(geom)
    used = {g.meshname for g in spec.geoms}
    for mesh in list(spec.meshes):
        if mesh.name not in used:
            spec.delete(mesh)


def _add_sensors(spec: mujoco.MjSpec, joints: list) -> None:
    """The sensors in :class:`SensorLayout` order."""
    st, ot = mujoco.mjtSensor, mujoco.mjtObj
    spec.add_sensor(name="ee_pos", type=st.mjSENS_FRAMEPOS, objtype=ot.mjOBJ_SITE, objname="ee")
    spec.add_sensor(name="ee_quat", type=st.mjSENS_FRAMEQUAT, objtype=ot.mjOBJ_SITE, objname="ee")
    for i, joint in enumerate(joints):
        spec.add_sensor(name=f"q{i}", type=st.mjSENS_JOINTPOS, objtype=ot.mjOBJ_JOINT, objname=joint.name)
    for i, joint in enumerate(joints):
        spec.add_sensor(name=f"tau{i}", type=st.mjSENS_JOINTACTFRC, objtype=ot.mjOBJ_JOINT, objname=joint.name)
    # Every active contact (self and floor), as the Panda's `contact data="found"` sensor.
    contacts = spec.add_sensor(name="contacts", type=st.mjSENS_CONTACT)
    contacts.intprm[:3] = [1, 0, 1]
    for i in range(len(joints)):
        spec.add_sensor(name=f"cmd{i}", type=st.mjSENS_ACTUATORFRC, objtype=ot.mjOBJ_ACTUATOR, objname=f"motor{i}")


def _exclude_base(spec: mujoco.MjSpec, first_joint) -> None:
    """Excludes contacts between the first link and the fixed base it turns in.

    MuJoCo filters parent-child contacts except when the parent is welded to the world
    (so that arms can touch the floor); the first link's collision geometry overlaps its
    base housing in some of robosuite's arms (Sawyer), which would reject every trajectory.
    """
    first = first_joint.parent
    fixed = []
    body = first.parent
    while body is not None and body.name != "world":
        fixed.append(body)
        body = body.parent
    for base in fixed:
        spec.add_exclude(bodyname1=base.name, bodyname2=first.name)


def build_spec(arm: Arm, timestep: float, gravity_compensation: bool) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(arm.model_file or robosuite_xml(arm.folder))
    if arm.model_file:  # a user's arm: joints it does not drive (a gripper's) are welded where they stand at zero
        for joint in [j for j in spec.joints if j.name not in arm.joint_names]:
            spec.delete(joint)
    spec.modelname = f"robomorph_{arm.name}"
    _strip(spec)
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_light(pos=[0, 0, 3], dir=[0, 0, -1])
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1],
                            rgba=[0.8, 0.8, 0.8, 1])
    on, limited = mujoco.mjtLimited.mjLIMITED_TRUE, mujoco.mjtLimited.mjLIMITED_TRUE
    joints = [spec.joint(name) for name in arm.joint_names]
    for i, (joint, limit) in enumerate(zip(joints, arm.torque_limits)):
        if joint.limited == mujoco.mjtLimited.mjLIMITED_FALSE or not np.any(joint.range):
            joint.range = [-2 * np.pi, 2 * np.pi]  # continuous joints: see the module docstring
        joint.limited = limited
        joint.actgravcomp = bool(gravity_compensation)
        joint.actfrclimited = on
        joint.actfrcrange = [-limit, limit]
        joint.damping = abs(joint.damping)
        spec.add_actuator(name=f"motor{i}", target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                          ctrllimited=on, ctrlrange=[-limit, limit])
    for site in [s for s in spec.sites if s.name == "ee"]:
        spec.delete(site)  # robosuite's xArm7 marks its flange "ee" already: one site, ours
    spec.body(arm.hand).add_site(name="ee", size=[0.01, 0.01, 0.01])
    _exclude_base(spec, joints[0])
    for body in spec.bodies:
        body.gravcomp = 1.0 if gravity_compensation else 0.0
    _add_sensors(spec, joints)
    return spec


@functools.lru_cache(maxsize=16)
def _compiled(arm: Arm, timestep: float, gravity_compensation: bool) -> mujoco.MjModel:
    model = build_spec(arm, timestep, gravity_compensation).compile()
    if model.nq != arm.n_joint or model.nv != arm.n_joint or model.nu != arm.n_joint:
        raise RuntimeError(f"{arm.name}: expected {arm.n_joint} joints and motors, got nq={model.nq}, "
                           f"nv={model.nv}, nu={model.nu}")
    return model
