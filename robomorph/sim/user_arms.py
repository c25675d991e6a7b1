"""The user's own arms: a URDF (or an MJCF) registered in the user folder the registry reads.

``robomorph arms add NAME --urdf robot.urdf`` checks the description, then keeps it in
``<user folder>/NAME/`` (see :func:`robomorph.sim.arms.user_folder`) beside ``arm.json``
(joints, torque limits, end-effector body, source and its SHA-256); MuJoCo's URDF importer
compiles it each time the arm is built (its ``<inertial>`` elements, joint limits, ``effort``
limits, and ``<dynamics>`` damping and friction). The kept model has no geometry at all:
meshes are optional (a URDF whose mesh files are elsewhere still imports), and collisions play
no part in the dynamics. A URDF is kept as it is, less its ``<visual>`` and ``<collision>``
elements (``model.urdf``, every number as written); an MJCF is compiled with its meshes, every
body's inertia written explicitly, and saved without geometry (``model.xml``, the numbers of
the compiled model in full precision). Joints that are not driven (a gripper's fingers, joints
above ``--base-link``) are welded where they stand at zero.

Ill-posed inertials are refused with the link's name: a link turned by a joint without mass, a
negative or non-finite mass, an inertia matrix that is not positive definite or breaks the
triangle inequality (no rigid body has it; MuJoCo would reject or silently fix it).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import shutil
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.atomic import atomic_folder
from robomorph.core.errors import MissingInputError, OutputExistsError, RoboMorphError
from robomorph.core.names import check_plain_name
from robomorph.sim import arms

MODEL_FILES, RECORD_FILE = {"urdf": "model.urdf", "mjcf": "model.xml"}, "arm.json"
_MOVABLE = ("revolute", "continuous", "prismatic", "floating", "planar")
_DRIVABLE = ("revolute", "continuous")  # the domain's joints are hinges (angles in rad)


class ArmDescriptionError(RoboMorphError, ValueError):
    """A URDF or MJCF that cannot become a registered arm (the message says why and what to do)."""


@dataclass(frozen=True)
class ArmRequest:
    """What ``arms add`` was asked: the description and the choices it leaves open.

    Attributes:
        name: the registry name (``--robot NAME``, ``--arm NAME``).
        path: the URDF or MJCF file.
        fmt: ``urdf`` or ``mjcf``.
        base_link, ee_link: the chain's ends (default: the root, and the one deepest leaf).
        joints: the driven joints (default: the movable joints from base to end effector).
        torque_limits: per driven joint [N m] (default: the description's effort limits).
        title: the arm's name for people (default: the description's robot name).
    """

    name: str
    path: str
    fmt: str
    base_link: str | None = None
    ee_link: str | None = None
    joints: tuple[str, ...] | None = None
    torque_limits: tuple[float, ...] | None = None
    title: str | None = None

    def __post_init__(self):
        check_plain_name(self.name, "NAME")
        if self.name in arms.SHIPPED:
            raise ArmDescriptionError(f"{self.name!r} is a shipped arm: choose another name for yours")
        if self.fmt not in ("urdf", "mjcf"):
            raise ArmDescriptionError(f"unknown description format {self.fmt!r}: give --urdf or --mjcf")
        if not os.path.isfile(self.path):
            raise MissingInputError(f"{self.fmt.upper()} file not found: {self.path}")
        if self.torque_limits is not None and not all(np.isfinite(v) and v > 0 for v in self.torque_limits):
            raise ArmDescriptionError(f"--torque-limits must be positive numbers of N m, got {list(self.torque_limits)}")


# --- URDF -------------------------------------------------------------------------------------

def _check_inertial(link: ET.Element, moved: bool, path: str) -> None:
    """Refuses a link's ill-posed inertial, naming the link (see the module docstring)."""
    name = link.get("name")
    inertial = link.find("inertial")
    mass = 0.0
    if inertial is not None and inertial.find("mass") is not None:
        mass = float(inertial.find("mass").get("value", "nan"))
    if not np.isfinite(mass) or mass < 0:
        raise ArmDescriptionError(f"link {name!r} in {path} has mass {mass}: a mass is a finite number >= 0 kg")
    if mass == 0:
        if moved:
            raise ArmDescriptionError(f"link {name!r} in {path} is turned by a joint but has no mass (no <inertial> or "
                                      "mass 0): give it its <inertial> (mass, origin and inertia), e.g. from CAD")
        return
    el = inertial.find("inertia")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    i = {k: float(el.get(k, "0")) if el is not None else 0.0 for k in keys}
    tensor = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]], [i["ixz"], i["iyz"], i["izz"]]])
    if not np.all(np.isfinite(tensor)):
        raise ArmDescriptionError(f"link {name!r} in {path}: its inertia holds a non-finite value")
    eig = np.linalg.eigvalsh(tensor)
    if eig[0] <= 0:
        raise ArmDescriptionError(f"link {name!r} in {path}: its inertia matrix is not positive definite (principal "
                                  f"moments {', '.join(f'{v:.4g}' for v in eig)} kg m^2); check ixx..izz and their signs")
    if eig[0] + eig[1] < eig[2] * (1 - 1e-9):
        raise ArmDescriptionError(f"link {name!r} in {path}: its principal moments {', '.join(f'{v:.4g}' for v in eig)} "
                                  "kg m^2 break the triangle inequality (A + B >= C) that every rigid body obeys")


class _Tree:
    """A URDF's links and joints, with the chain a request picks."""

    def __init__(self, root: ET.Element, path: str):
        self.path = path
        self.links = {link.get("name"): link for link in root.findall("link")}
        self.joints = {j.get("name"): j for j in root.findall("joint")}
        self.parent_joint = {}  # child link -> joint
        for name, j in self.joints.items():
            ends = [j.find(tag).get("link") if j.find(tag) is not None else None for tag in ("parent", "child")]
            missing = [tag for tag, link in zip(("parent", "child"), ends) if link not in self.links]
            if missing:
                raise ArmDescriptionError(f"joint {name!r} in {path}: its <{missing[0]} link=...> names no link of the "
                                          "URDF; a joint connects two of its links")
            self.parent_joint[ends[1]] = j
        roots = [name for name in self.links if name not in self.parent_joint]
        if len(roots) != 1:
            raise ArmDescriptionError(f"{path}: a robot has one root link, found {len(roots)} ({', '.join(roots)})")
        self.root = roots[0]

    def movable(self, joint: ET.Element) -> bool:
        return joint.get("type") in _MOVABLE

    def path_up(self, link: str) -> list[ET.Element]:
        """The joints from ``link`` up to the root, nearest first."""
        out = []
        while link in self.parent_joint:
            j = self.parent_joint[link]
            out.append(j)
            link = j.find("parent").get("link")
        return out

    def default_ee(self) -> str:
        leaves = [n for n in self.links if not any(j.find("parent").get("link") == n for j in self.joints.values())]
        depth = {n: sum(self.movable(j) for j in self.path_up(n)) for n in leaves}
        best = max(depth.values())
        deepest = [n for n in leaves if depth[n] == best]
        if len(deepest) != 1:
            raise ArmDescriptionError(f"{self.path}: {len(deepest)} links end the longest chains ({', '.join(deepest)}): "
                                      "name the end effector with --ee-link")
        return deepest[0]

    def chain(self, base: str, ee: str) -> list[str]:
        """The movable joints from ``base`` to ``ee``, base first."""
        for link in (base, ee):
            if link not in self.links:
                raise ArmDescriptionError(f"{self.path} has no link {link!r}; its links: {', '.join(self.links)}")
        joints, link = [], ee
        while link != base:
            if link not in self.parent_joint:
                raise ArmDescriptionError(f"{self.path}: link {ee!r} does not hang below {base!r}; check --base-link "
                                          "and --ee-link")
            j = self.parent_joint[link]
            joints.append(j)
            link = j.find("parent").get("link")
        return [j.get("name") for j in reversed(joints) if self.movable(j)]


def _urdf_spec(req: ArmRequest) -> tuple[mujoco.MjSpec, list[str], str, list[float] | None, str, str]:
    """``(spec, driven joints, ee body, effort limits or None, robot name, model text)`` of a URDF."""
    try:
        root = ET.parse(req.path).getroot()
    except ET.ParseError as exc:
        raise ArmDescriptionError(f"cannot read {req.path} as XML: {exc}") from exc
    if root.tag != "robot":
        raise ArmDescriptionError(f"{req.path} is not a URDF (its root element is <{root.tag}>, not <robot>); "
                                  "an MJCF goes with --mjcf")
    tree = _Tree(root, req.path)
    base, ee = req.base_link or tree.root, req.ee_link or tree.default_ee()
    driven = list(req.joints) if req.joints else tree.chain(base, ee)
    for name in driven:
        j = tree.joints.get(name)
        if j is None:
            raise ArmDescriptionError(f"{req.path} has no joint {name!r}; its joints: {', '.join(tree.joints)}")
        if j.get("type") not in _DRIVABLE:
            raise ArmDescriptionError(f"joint {name!r} in {req.path} is {j.get('type')}: the driven joints must be "
                                      "revolute or continuous (leave it out of --joints to weld it)")
    if not driven:
        raise ArmDescriptionError(f"{req.path}: no movable joint between {base!r} and {ee!r}")
    moved = {tree.joints[n].find("child").get("link") for n in driven}
    for name, link in tree.links.items():
        try:
            _check_inertial(link, name in moved, req.path)
        except ValueError as exc:
            if isinstance(exc, ArmDescriptionError):
                raise
            raise ArmDescriptionError(f"link {name!r} in {req.path}: unreadable <inertial> ({exc})") from exc
        for tag in ("visual", "collision"):  # no geometry: meshes need not be found, nothing collides
            for el in link.findall(tag):
                link.remove(el)
    efforts = []
    for name in driven:
        limit = tree.joints[name].find("limit")
        efforts.append(float(limit.get("effort", "0")) if limit is not None else 0.0)
    ext = root.find("mujoco")
    if ext is None:
        ext = ET.SubElement(root, "mujoco")
    compiler = ext.find("compiler") if ext.find("compiler") is not None else ET.SubElement(ext, "compiler")
    # Every link stays a body (fusestatic off): the EE site goes on the --ee-link's own frame.
    compiler.set("fusestatic", "false")
    compiler.set("discardvisual", "true")
    text = ET.tostring(root, encoding="unicode")
    try:
        spec = mujoco.MjSpec.from_string(text)
    except ValueError as exc:
        raise ArmDescriptionError(f"MuJoCo cannot read {req.path}: {str(exc).strip().splitlines()[0]}") from exc
    return spec, driven, ee, efforts if all(e > 0 for e in efforts) else None, root.get("name") or req.name, text


# --- MJCF -------------------------------------------------------------------------------------

def _mjcf_spec(req: ArmRequest) -> tuple[mujoco.MjSpec, list[str], str, list[float] | None, str, None]:
    try:
        spec = mujoco.MjSpec.from_file(req.path)
        model = spec.compile()
    except ValueError as exc:
        raise ArmDescriptionError(f"MuJoCo cannot compile {req.path}: {str(exc).strip().splitlines()[0]}") from exc
    hinges = [model.joint(j).name for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    driven = list(req.joints) if req.joints else hinges
    missing = [j for j in driven if j not in hinges]
    if missing:
        raise ArmDescriptionError(f"{req.path} has no hinge joint {', '.join(map(repr, missing))}; its hinges: "
                                  f"{', '.join(hinges)}")
    if not driven:
        raise ArmDescriptionError(f"{req.path} has no hinge joint to drive")
    ee = req.ee_link or model.body(model.jnt_bodyid[model.joint(driven[-1]).id]).name
    if ee not in [model.body(b).name for b in range(model.nbody)]:
        raise ArmDescriptionError(f"{req.path} has no body {ee!r} for --ee-link")
    _bake_inertials(spec, model)
    return spec, driven, ee, _mjcf_limits(model, driven), spec.modelname or req.name, None


def _mjcf_limits(model: mujoco.MjModel, driven: list[str]) -> list[float] | None:
    """Per driven joint: its actuator's control range (a motor on the joint), else its force limit."""
    limits = []
    for name in driven:
        j = model.joint(name).id
        acts = [a for a in range(model.nu) if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_trnid[a, 0] == j and model.actuator_ctrllimited[a]]
        if acts:
            a = acts[0]
            limits.append(float(np.max(np.abs(model.actuator_ctrlrange[a])) * abs(model.actuator_gear[a, 0])))
        elif model.jnt_actfrclimited[j]:
            limits.append(float(np.max(np.abs(model.jnt_actfrcrange[j]))))
        else:
            return None
    return limits


def _bake_inertials(spec: mujoco.MjSpec, model: mujoco.MjModel) -> None:
    """Writes every body's compiled inertia into the spec, so its geometry can go."""
    for body in spec.bodies:
        if body.name == "world":
            continue
        b = model.body(body.name)
        body.explicitinertial = True
        body.mass = float(b.mass[0])
        body.ipos, body.iquat, body.inertia = b.ipos.copy(), b.iquat.copy(), b.inertia.copy()
        body.fullinertia = [np.nan] * 6


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _full_precision(xml: str, model: mujoco.MjModel) -> str:
    """MuJoCo's XML writer keeps six digits: the compiled model's own numbers (frames, inertias,
    joint axes, ranges and dynamics) are written back in full, so the saved arm is the compiled one."""
    root = ET.fromstring(xml)
    in_frame = {child for frame in root.iter("frame") for child in frame.iter("body")}
    for el in root.iter("body"):
        b = model.body(el.get("name"))
        if el not in in_frame:  # the compiled pose is relative to the parent body, not to a <frame> between them
            for alt in ("euler", "axisangle", "xyaxes", "zaxis"):
                el.attrib.pop(alt, None)
            el.set("pos", _numbers(b.pos))
            el.set("quat", _numbers(b.quat))
        inertial = el.find("inertial")
        if inertial is not None:
            inertial.attrib.clear()
            inertial.attrib.update({"pos": _numbers(b.ipos), "quat": _numbers(b.iquat), "mass": _numbers(b.mass),
                                    "diaginertia": _numbers(b.inertia)})
    for el in root.iter("joint"):
        j = model.joint(el.get("name"))
        dof = model.jnt_dofadr[j.id]
        el.attrib.update({"pos": _numbers(j.pos), "axis": _numbers(j.axis), "range": _numbers(j.range),
                          "damping": _numbers(model.dof_damping[dof]), "frictionloss": _numbers(model.dof_frictionloss[dof]),
                          "armature": _numbers(model.dof_armature[dof]), "stiffness": _numbers(j.stiffness),
                          "springref": _numbers(model.qpos_spring[model.jnt_qposadr[j.id]]),
                          "ref": _numbers(model.qpos0[model.jnt_qposadr[j.id]])})
    return ET.tostring(root, encoding="unicode")


# --- both -------------------------------------------------------------------------------------

def _finish(spec: mujoco.MjSpec, driven: list[str], req: ArmRequest) -> mujoco.MjModel:
    """Welds the joints that are not driven, drops geometry, motors and sensors; the compiled
    model must then hold exactly the driven joints, each turning a body with a positive inertia."""
    for j in list(spec.joints):
        if j.name not in driven:
            spec.delete(j)
    for item in [*spec.geoms, *spec.sites, *spec.actuators, *spec.sensors, *spec.tendons, *spec.equalities]:
        spec.delete(item)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    try:
        model = spec.compile()
    except ValueError as exc:
        raise ArmDescriptionError(f"MuJoCo cannot compile {req.path} as an arm: {str(exc).strip().splitlines()[0]}") from exc
    if model.nq != len(driven) or model.nv != len(driven):
        raise ArmDescriptionError(f"{req.path}: expected {len(driven)} driven joints, the model has nq={model.nq}; "
                                  "name them with --joints")
    for j in driven:
        b = model.jnt_bodyid[model.joint(j).id]
        if not (model.body_mass[b] > 0 and np.all(model.body_inertia[b] > 0)):
            raise ArmDescriptionError(f"body {model.body(b).name!r} (turned by joint {j!r}) in {req.path} has mass "
                                      f"{model.body_mass[b]:.4g} kg and principal inertia {model.body_inertia[b]}: "
                                      "a moving link needs a positive mass and inertia")
    return model


def describe(req: ArmRequest) -> tuple[str, dict]:
    """``(model XML, arm record)`` of a request, checked; nothing is written.

    Raises:
        ArmDescriptionError: an ill-posed description (the message names the link or joint).
    """
    spec, driven, ee, limits, title, text = (_urdf_spec if req.fmt == "urdf" else _mjcf_spec)(req)
    if req.torque_limits is not None:
        if len(req.torque_limits) != len(driven):
            raise ArmDescriptionError(f"--torque-limits gives {len(req.torque_limits)} values for {len(driven)} joints "
                                      f"({', '.join(driven)})")
        limits, source = list(req.torque_limits), "robomorph arms add --torque-limits"
    elif limits is None:
        raise ArmDescriptionError(f"{req.path} gives no torque limit for every driven joint ({', '.join(driven)}): "
                                  "add effort=\"...\" to their <limit> or pass --torque-limits N1,N2,... (N m)")
    else:
        source = f"{os.path.basename(req.path)} ({'<limit effort>' if req.fmt == 'urdf' else 'actuator ctrlrange'})"
    model = _finish(spec, driven, req)
    xml = text if text is not None else _full_precision(spec.to_xml(), model)
    with open(req.path, "rb") as f:
        source_digest = hashlib.sha256(f.read()).hexdigest()
    record = {"name": req.name, "title": req.title or title, "joint_names": driven, "torque_limits": limits,
              "torque_source": source, "home": None, "hand": ee, "model": MODEL_FILES[req.fmt],
              "digest": hashlib.sha256(xml.encode()).hexdigest(), "format": req.fmt,
              "source": os.path.abspath(req.path), "source_sha256": source_digest,
              "base_link": req.base_link, "added": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    return xml, record


def add(req: ArmRequest, overwrite: bool = False) -> arms.Arm:
    """Registers the arm of ``req`` in the user folder and returns it as the registry sees it.

    The arm's folder appears whole or not at all (written beside, then renamed); the domain
    is compiled from it before it is kept.

    Raises:
        ArmDescriptionError: an ill-posed description.
        OutputExistsError: a user arm of that name exists (without ``overwrite``).
    """
    xml, record = describe(req)
    folder = arms.user_folder()
    target = os.path.join(folder, req.name)
    if os.path.exists(target) and not overwrite:
        raise OutputExistsError(f"a user arm {req.name!r} exists ({target}): pass --overwrite to replace it, or "
                                f"`robomorph arms remove {req.name}` first")
    # The one atomic folder writer: the arm is built in a hidden folder beside its place and swapped in
    # whole once its domain builds; a failure leaves the earlier arm (or none) as it was.
    with atomic_folder(target) as staging:
        with open(os.path.join(staging, MODEL_FILES[req.fmt]), "w", encoding="utf-8") as f:
            f.write(xml)
        with open(os.path.join(staging, RECORD_FILE), "w", encoding="utf-8") as f:
            json.dump(record, f, indent=1)
        arm = arms.read_user_arm(os.path.join(staging, RECORD_FILE), 0)
        arm.build_model(gravity_compensation=False)  # the domain must build before the arm is kept
    return arms.get(req.name)


def remove(name: str) -> str:
    """Removes the user arm ``name``; returns its folder. Shipped arms are refused."""
    if name in arms.SHIPPED:
        raise ArmDescriptionError(f"{name!r} is a shipped arm: only your own arms can be removed")
    check_plain_name(name, "NAME")
    target = os.path.join(arms.user_folder(), name)
    if not os.path.isfile(os.path.join(target, RECORD_FILE)):
        raise MissingInputError(f"no user arm {name!r} in {arms.user_folder()}; `robomorph arms list` shows them")
    shutil.rmtree(target)
    return target


def listing() -> list[dict]:
    """One row per registered arm: name, joints, whether shipped, its title and source."""
    rows = []
    for name in arms.names():
        try:
            arm = arms.get(name)
        except arms.UnknownRobotError as exc:  # listed, not fatal: the line says how to repair it
            rows.append({"name": name, "joints": 0, "kind": "damaged", "title": str(exc), "source": ""})
            continue
        user = arm.model_file is not None
        source = ""
        if user:
            with open(os.path.join(os.path.dirname(arm.model_file), RECORD_FILE), encoding="utf-8") as f:
                source = json.load(f).get("source", "")
        rows.append({"name": name, "joints": arm.n_joint, "kind": "user" if user else "shipped", "title": arm.title,
                     "source": source})
    return rows
