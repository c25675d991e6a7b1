"""The torque-driven Franka Panda domain.

The arm comes from the MJCF and meshes shipped by ``dm-robotics-panda`` (Gaz et al. 2019
inertias); this module adds a floor, a rigid hand with the gripper held, an end-effector
site, seven torque motors with the real limits, and the sensors that make ``y``.

Gravity: every body has ``gravcomp=1`` and every joint ``actuatorgravcomp``, so MuJoCo
computes g(q) from the *current* (randomized) model and routes it through the actuators.
The result is the paper's construction (gravity compensation from the randomized masses,
added to the torque signal) evaluated at every physics step, and the ``jointactuatorfrc``
sensors report the full torque applied at each joint (signal + g(q), clamped to the
limits), which is what is recorded as ``u``. The ``actuatorfrc`` sensors report the motors'
own force, the command without the gravcomp, which is recorded as ``u_cmd``. With
``gravity_compensation: none`` the gravcomp is switched off and ``u`` is the signal alone.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.errors import RoboMorphError

N_JOINT = 7
TORQUE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
# A comfortable pose used as the spring reference default and by tests.
HOME_QPOS = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
LINK_BODIES = tuple(f"panda_link{i}" for i in range(1, 8)) + ("hand",)

U_NAMES = tuple(f"tau{i}" for i in range(N_JOINT))
# The command: what the arm's user asked for, before the gravity compensation it adds.
U_CMD_NAMES = tuple(f"cmd{i}" for i in range(N_JOINT))
Y_NAMES = ("ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw") + tuple(
    f"q{i}" for i in range(N_JOINT)
)

# Layout of ``sensordata`` (fixed by the order the sensors are added in _build_mjcf).
SENS_EE_POS = slice(0, 3)
SENS_EE_QUAT = slice(3, 7)  # MuJoCo order w, x, y, z
SENS_QPOS = slice(7, 14)
SENS_TAU = slice(14, 21)
SENS_CONTACTS = 21
SENS_CMD = slice(22, 29)  # motor forces: the clamped command, without actuator gravcomp


class AssetsMissingError(RoboMorphError, RuntimeError):
    """The Panda meshes are not installed."""


def assets_dir() -> str:
    """Directory holding ``panda.xml`` and its meshes (from ``dm-robotics-panda``)."""
    try:
        import dm_robotics.panda as dp  # noqa: PLC0415  (optional, assets only)
    except ImportError as exc:
        raise AssetsMissingError(
            "The Franka Panda assets are missing: run `make install` or "
            "`pip install --no-deps dm-robotics-panda==0.4.8`."
        ) from exc
    path = os.path.join(os.path.dirname(dp.__file__), "assets", "panda")
    if not os.path.isfile(os.path.join(path, "panda.xml")):
        raise AssetsMissingError(f"panda.xml not found under {path}")
    return path


def _build_mjcf(timestep: float, gravity_compensation: bool):
    # dm_control is used to build and name the MJCF only; it must not probe for OpenGL.
    os.environ.setdefault("MUJOCO_GL", "disable")
    from dm_control import mjcf  # noqa: PLC0415  (heavy import, only when building)

    root_dir = assets_dir()
    root = mjcf.from_path(os.path.join(root_dir, "panda.xml"))
    root.model = "robomorph_panda"
    for sensor in list(root.sensor.all_children()):
        sensor.remove()  # the asset's site torque sensors are not part of y
    root.option.timestep = timestep
    root.option.integrator = "implicitfast"
    root.worldbody.add("light", pos=[0, 0, 3], dir=[0, 0, -1])
    root.worldbody.add(
        "geom", name="floor", type="plane", size=[2, 2, 0.1], rgba=[0.8, 0.8, 0.8, 1]
    )

    joints = [root.find("joint", f"panda_joint{i}") for i in range(1, N_JOINT + 1)]
    for joint, limit in zip(joints, TORQUE_LIMITS):
        joint.actuatorgravcomp = "true" if gravity_compensation else "false"
        joint.actuatorfrcrange = [-limit, limit]
        # The asset ships a negative damping on joint 6, which is non-physical.
        joint.damping = abs(joint.damping)
        root.actuator.add(
            "motor", name=f"motor{joint.name[-1]}", joint=joint,
            ctrllimited="true", ctrlrange=[-limit, limit],
        )

    with open(os.path.join(root_dir, "hand.obj"), "rb") as f:
        hand_mesh = root.asset.add("mesh", name="hand", file=mjcf.Asset(f.read(), ".obj"))
    hand = root.find("body", "panda_link8").add("body", name="hand", euler=[0, 0, -np.pi / 4])
    hand.add("inertial", pos=[-0.01, 0, 0.03], mass=0.73, diaginertia=[1e-3, 2.5e-3, 1.7e-3])
    hand.add("geom", name="hand", type="mesh", mesh=hand_mesh)
    # The closed fingers (gripper held) as one collision box, so a fingertip touching the
    # floor or the arm counts as a contact; the TCP sits between the fingertips.
    hand.add("geom", name="fingers", type="box", pos=[0, 0, 0.0834], size=[0.012, 0.03, 0.025],
             mass=0.03, rgba=[0.9, 0.9, 0.9, 1])
    hand.add("site", name="ee", pos=[0, 0, 0.1034], size=[0.01])

    for body in root.find_all("body"):
        body.gravcomp = 1.0 if gravity_compensation else 0.0

    root.sensor.add("framepos", name="ee_pos", objtype="site", objname="ee")
    root.sensor.add("framequat", name="ee_quat", objtype="site", objname="ee")
    for joint in joints:
        root.sensor.add("jointpos", name=f"q{joint.name[-1]}", joint=joint)
    for joint in joints:
        root.sensor.add("jointactuatorfrc", name=f"tau{joint.name[-1]}", joint=joint)
    # Counts every active contact (self and floor): any contact invalidates a rollout.
    root.sensor.add("contact", name="contacts", data="found")
    # The motors' own force is the command alone: MuJoCo adds the actuator gravcomp to
    # the joint (jointactuatorfrc above) but not to the actuator (actuatorfrc).
    for motor in root.actuator.all_children():
        root.sensor.add("actuatorfrc", name=f"cmd{motor.name[-1]}", actuator=motor)
    return root


@functools.lru_cache(maxsize=8)
def compiled_xml(timestep: float, gravity_compensation: bool):
    root = _build_mjcf(timestep, gravity_compensation)
    return root.to_xml_string(), root.get_assets()


def build_model(substeps: int = 8, dt: float = 1 / 60, gravity_compensation: bool = True) -> mujoco.MjModel:
    """Compiles the Panda domain.

    Args:
        substeps: physics steps per recorded sample.
        dt: recorded sample time in seconds (the paper's 60 Hz by default).
        gravity_compensation: route g(q) of the current model through the actuators.

    Returns:
        A fresh ``MjModel`` (safe to modify: each call compiles a new one).
    """
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    xml, assets = compiled_xml(float(dt) / substeps, bool(gravity_compensation))
    return mujoco.MjModel.from_xml_string(xml, assets=assets)


@dataclass(frozen=True)
class PandaIndex:
    """Ids and limits read off a compiled model (the same for every randomized copy)."""

    body_ids: np.ndarray  # (8,) link1..link7 + hand
    joint_range: np.ndarray  # (7, 2)
    ee_site: int

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "PandaIndex":
        body_ids = np.array([model.body(name).id for name in LINK_BODIES])
        return cls(
            body_ids=body_ids,
            joint_range=model.jnt_range[:N_JOINT].copy(),
            ee_site=model.site("ee").id,
        )
