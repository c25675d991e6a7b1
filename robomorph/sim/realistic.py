"""The engine of realistic attempts: Python at every physics step, as a real arm's 1 kHz loop.

Friction as a state-dependent passive force, latency, a payload, a feedback controller
updated every physics step and logging at the physics rate all need the state between two
recorded frames. ``mujoco.rollout`` applies a fixed control sequence and cannot compute a
force from the state it reaches, so an attempt with any of these terms
(:attr:`RealismConfig.steps_in_python`) runs here, through
:func:`robomorph.sim.closed_loop.simulate_substeps`, whatever its task.

The controller's gravity compensation (``gravity_compensation: nominal_model``) is the
catalogue robot's g(q) plus the payload only when the payload is configured
(:class:`Compensation`); with ``true_model`` the arm's own actuators compensate the randomized
robot and its payload, as before. The compensation is evaluated at every physics step (a real
arm's loop runs at 1 kHz); frame-rate commands (open-loop torques, OSC) are held over the
frame's substeps. Controllers see the true state (the sensor errors of
:func:`robomorph.sim.realism.sense` are the log's, not the loop's).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.sim import osc, realism
from robomorph.sim.closed_loop import simulate_substeps
from robomorph.sim.realism import Realization


class Flange:
    """Adds a point-mass payload to the flange body of model copies (absolute, never compounding).

    The body's inertia about the combined centre of mass follows the parallel-axis theorem,
    re-diagonalized into MuJoCo's principal frame (``body_inertia``, ``body_iquat``).
    """

    def __init__(self, model: mujoco.MjModel):
        self.body = int(model.site_bodyid[model.site("ee").id])
        b = self.body
        self.nominal = (float(model.body_mass[b]), model.body_ipos[b].copy(), model.body_inertia[b].copy(),
                        model.body_iquat[b].copy())

    def apply(self, model: mujoco.MjModel, mass: float, com: np.ndarray, base: tuple | None = None) -> None:
        """Sets the flange body to ``base`` (default: its nominal values) plus the payload."""
        b = self.body
        m0, c0, i0, q0 = base or self.nominal
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, q0)
        rot = rot.reshape(3, 3)
        inertia = rot @ np.diag(i0) @ rot.T
        total = m0 + mass
        if mass <= 0 or total <= 0:
            model.body_mass[b], model.body_ipos[b], model.body_inertia[b], model.body_iquat[b] = m0, c0, i0, q0
            return
        c = (m0 * c0 + mass * np.asarray(com)) / total
        for m, p in ((m0, c0), (mass, com)):
            r = np.asarray(p) - c
            inertia = inertia + m * (r @ r * np.eye(3) - np.outer(r, r))
        eig, vec = np.linalg.eigh(inertia)
        if np.linalg.det(vec) < 0:
            vec[:, 0] = -vec[:, 0]
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, vec.ravel())
        model.body_mass[b], model.body_ipos[b], model.body_inertia[b], model.body_iquat[b] = total, c, eig, quat

    def current(self, model: mujoco.MjModel) -> tuple:
        """The flange body's values in ``model`` (to add a payload on top of a randomized body)."""
        b = self.body
        return (float(model.body_mass[b]), model.body_ipos[b].copy(), model.body_inertia[b].copy(),
                self.nominal[3].copy())



class Compensation:
    """g(q) of the catalogue robot with the configured payload: what the arm's controller adds.

    Gravity alone is the recursive Newton-Euler bias at zero velocity; it needs only the
    kinematics and the centres of mass (not a whole forward pass), so it is cheap enough
    to evaluate at every physics step.
    """

    def __init__(self, arm, substeps: int, dt: float):
        self.model = arm.build_model(substeps, dt, gravity_compensation=False)
        self.data = mujoco.MjData(self.model)
        self.flange = Flange(self.model)
        self.nj = arm.n_joint
        self._out = np.zeros(self.model.nv)

    def configure(self, mass: float, com: np.ndarray) -> None:
        """Sets the payload the controller knows (mass 0: none)."""
        self.flange.apply(self.model, mass, com)

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        d = self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        mujoco.mj_rne(self.model, d, 0, self._out)  # qvel stays 0: the bias is gravity alone
        return self._out[: self.nj].copy()


@dataclass
class Result:
    """A realistic attempt's physics: every physics step's sensor rows and logged command."""

    sens: np.ndarray  # (T * substeps, nsensordata)
    command: np.ndarray  # (T * substeps, n): the torque sent, less the gravity compensation
    target: np.ndarray | None = None
    kp: float = float("nan")


class _Held:
    """A frame-rate command (open-loop torque or OSC), held over the frame's substeps, plus the
    gravity compensation, evaluated at every physics step as a real arm's 1 kHz loop does."""

    def __init__(self, frame_command, substeps: int, comp, limits: np.ndarray, log: np.ndarray):
        self.frame_command, self.substeps, self.comp, self.limits, self.log = frame_command, substeps, comp, limits, log
        self._cmd = np.zeros(len(limits))

    def __call__(self, data: mujoco.MjData, k: int) -> np.ndarray:
        n = len(self.limits)
        if k % self.substeps == 0:
            self._cmd = np.array(self.frame_command(data, k // self.substeps), dtype=np.float64)
        g = self.comp(data.qpos[:n]) if self.comp is not None else 0.0
        u = np.clip(self._cmd + g, -self.limits, self.limits)
        self.log[k] = u - g
        return u


class _Feedback:
    """A joint PD on the reference, with compensation, at every physics step."""

    def __init__(self, q_ref: np.ndarray, qd_ref: np.ndarray, real: Realization, comp, limits: np.ndarray,
                 log: np.ndarray):
        self.q_ref, self.qd_ref, self.kp, self.kd = q_ref, qd_ref, real.kp, real.kd
        self.comp, self.limits, self.log = comp, limits, log

    def __call__(self, data: mujoco.MjData, k: int) -> np.ndarray:
        n = len(self.limits)
        q, qd = data.qpos[:n], data.qvel[:n]
        g = self.comp(q) if self.comp is not None else 0.0
        u = np.clip(self.kp * (self.q_ref[k] - q) + self.kd * (self.qd_ref[k] - qd) + g, -self.limits, self.limits)
        self.log[k] = u - g
        return u


def simulate(recipe, model: mujoco.MjModel, data: mujoco.MjData, d, real: Realization,
             comp: Compensation | None) -> Result:
    """Simulates attempt ``d`` (an :class:`robomorph.sim.episode.Draw`) on the randomized ``model``
    (payload already added) with ``real``'s latency, friction and controller."""
    r, arm = recipe, recipe.arm
    n, limits, total = arm.n_joint, arm.limits, recipe.steps * recipe.substeps
    if comp is not None:
        comp.configure(real.payload_mass if real.payload_configured else 0.0, real.payload_com)
    log = np.empty((total, n))
    target, kp = None, float("nan")
    if real.reference is not None:
        h = r.dt / r.substeps
        q_ref, qd_ref = realism.reference(real, d.qpos0, np.arange(total) * h, r.realism.feedback.ramp)
        controller = _Feedback(q_ref, qd_ref, real, comp, limits, log)
    elif d.ctrl is not None:
        signal = d.ctrl
        controller = _Held(lambda data, t: signal[t], r.substeps, comp, limits, log)
    else:
        path_cfg = r.circle if d.task == "circle" else r.spiral
        pos0, quat0 = osc.start_pose(model, data, d.qpos0)
        pos, vel, acc = osc.PATHS[d.task](d.rng, pos0, r.steps, r.dt, path_cfg)
        kp = r.osc.draw_kp(d.rng)
        ctrl = osc.OSCController(model, pos, vel, acc, quat0, d.qpos0, kp, r.osc, torque_limits=limits)
        controller, target = _Held(ctrl, r.substeps, comp, limits, log), pos
    friction = r.realism.friction
    passive = realism.Friction(real, friction.smoothing_velocity) if friction.active else None
    idle = comp(np.asarray(d.qpos0)) if comp is not None else None
    sens, _ = simulate_substeps(model, data, d.qpos0, r.steps, r.substeps, controller, real.latency, idle, passive)
    return Result(sens, log, target, kp)
