"""Operational space control (OSC) of the Panda end effector: the circle and spiral tasks.

Control law (Khatib's OSC; the paper's equation with the task inertia made explicit):

    u = J^T F + N^T tau0 + c(q, qd) + tau_f,
    F = Lambda (xdd_d - Jdot qd + Kp (x_d - x) + Kd (xd_d - xd)),
    Lambda = (J M^-1 J^T)^-1 (eigenvalues capped),   N^T = I - J^T Lambda J M^-1,

over the 6-D task (EE position and orientation; the orientation target is the initial
one). The gains act on unit-mass error dynamics (``kd = 2 sqrt(kp)`` is critical
damping): the paper's ``Kp`` is ``Lambda Kp`` here. ``C_ee xd_d`` of the paper is
taken exactly: ``c`` is the joint-space Coriolis/centrifugal torque and ``-Jdot qd`` the
velocity-product acceleration of the EE, which together give
``J^T (Lambda J M^-1 c - Lambda Jdot qd) + N^T c``. ``tau0`` is a joint PD toward the
initial pose, weighted by M and projected into the null space, which keeps the
redundant seventh degree of freedom from drifting. ``tau_f`` feeds forward the model's
joint damping and dry friction (see :class:`OSCConfig`). g(q) is not added: the Panda
domain routes gravity compensation through the actuators (see :mod:`robomorph.sim.panda`).

The paths it tracks are drawn in :mod:`robomorph.sim.paths`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from robomorph.core.config import check_range
from robomorph.core.names import OSC_TASKS
from robomorph.sim.closed_loop import reset_to, simulate_closed_loop
from robomorph.sim.panda import TORQUE_LIMITS
from robomorph.sim.paths import PATHS, CircleConfig, SpiralConfig, positive


@dataclass(frozen=True)
class OSCConfig:
    """Gains of the operational space controller.

    Attributes:
        kp: translational stiffness [1/s^2] (paper's code: 10).
        kd: translational damping [1/s]; ``None`` means critical, ``2 sqrt(kp)``.
        kp_range: if set, kp is drawn U(lo, hi) per trajectory (paper's option: (1, 5)).
        kp_rot: rotational stiffness [1/s^2] holding the initial EE orientation.
        kd_rot: rotational damping; ``None`` means ``2 sqrt(kp_rot)``.
        kp_null: null-space posture stiffness toward the initial joints [1/s^2].
        kd_null: null-space damping; ``None`` means ``2 sqrt(kp_null)``.
        coriolis: compensate Coriolis/centrifugal terms (the paper's ``C_ee``).
        joint_friction: feed forward the model's joint damping and dry friction along
            the joint velocity that realizes the reference velocity (below). The
            Panda's dry friction (0.15-1.2 N m) otherwise holds the arm until the error
            is large: with kp = 10 the nominal robot tracks a circle to 6-8 cm RMS.
        friction_velocity: joint speed [rad/s] over which the dry-friction feedforward
            changes sign (a tanh), so a joint reversing direction gets no torque step.
        reference_gain: the friction feedforward follows the reference velocity
            ``xd_d + reference_gain * (x_d - x)`` [1/s] (Slotine and Li), so friction is
            also cancelled while an error is being corrected. The wrist's rotational
            task inertia is tiny, so a feedback term stable at 60 Hz alone cannot
            break its 1.2 N m stiction: orientation errors would reach 0.2 rad.
        max_task_inertia: cap on the eigenvalues of Lambda [kg, or kg m^2 for
            rotations]. Near a singular pose (the arm stretched out) one eigenvalue of
            ``J M^-1 J^T`` goes to zero; capping its inverse keeps the force along that
            direction bounded instead of saturating every motor. Away from singularities
            nothing changes (the nominal Panda's largest eigenvalue is about 18 kg).
    """

    kp: float = 10.0
    kd: float | None = None
    kp_range: tuple[float, float] | None = None
    kp_rot: float = 10.0
    kd_rot: float | None = None
    kp_null: float = 10.0
    kd_null: float | None = None
    coriolis: bool = True
    joint_friction: bool = True
    friction_velocity: float = 0.02
    reference_gain: float = 10.0
    max_task_inertia: float = 100.0

    def __post_init__(self):
        positive("osc", kp=self.kp, kd=self.kd, kp_rot=self.kp_rot, kd_rot=self.kd_rot,
                  friction_velocity=self.friction_velocity, max_task_inertia=self.max_task_inertia)
        for name in ("kp_null", "kd_null", "reference_gain"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ValueError(f"osc.{name} must be >= 0, got {value}")
        if self.kp_range is not None:
            check_range("osc.kp_range", self.kp_range)
            positive("osc", kp_range_low=self.kp_range[0])

    def draw_kp(self, rng: np.random.Generator) -> float:
        """The translational stiffness of one trajectory."""
        return float(rng.uniform(*self.kp_range)) if self.kp_range is not None else self.kp

    def gains(self, kp: float) -> tuple[np.ndarray, np.ndarray]:
        """(6,) stiffness and damping vectors of the task (position, then rotation)."""
        kd = self.kd if self.kd is not None else 2 * np.sqrt(kp)
        kd_rot = self.kd_rot if self.kd_rot is not None else 2 * np.sqrt(self.kp_rot)
        return np.repeat([kp, self.kp_rot], 3), np.repeat([kd, kd_rot], 3)

    @property
    def null_gains(self) -> tuple[float, float]:
        kd = self.kd_null if self.kd_null is not None else 2 * np.sqrt(self.kp_null)
        return self.kp_null, kd


class OSCController:
    """Tracks a Cartesian path with the EE site, holding its orientation (controller protocol).

    Buffers are allocated once; a call costs about 30 us on one core.
    """

    def __init__(self, model: mujoco.MjModel, path_pos: np.ndarray, path_vel: np.ndarray,
                 path_acc: np.ndarray, quat_target: np.ndarray, qpos0: np.ndarray, kp: float,
                 cfg: OSCConfig, extra_torque: Callable[[np.ndarray], np.ndarray] | None = None,
                 torque_limits: np.ndarray | None = None):
        """Prepares the controller.

        Args:
            model: the simulated model (torque motors on every degree of freedom).
            path_pos, path_vel, path_acc: (T, 3) desired EE trajectory.
            quat_target: (4,) EE orientation to hold, MuJoCo order w x y z.
            qpos0: (nv,) posture the null-space term pulls toward.
            kp: translational stiffness of this trajectory (see :meth:`OSCConfig.draw_kp`).
            cfg: the other gains.
            extra_torque: optional ``qpos -> (nu,)`` torque added to the command, e.g.
                gravity compensation from a nominal model when the simulator has none.
            torque_limits: (nv,) motor limits the command is clipped to (default: the Panda's).
        """
        nv = model.nv
        self.limits = TORQUE_LIMITS if torque_limits is None else np.asarray(torque_limits, dtype=np.float64)
        if model.nu != nv or nv != len(self.limits):
            raise ValueError(f"OSC drives one motor per joint ({len(self.limits)} limits), got nu={model.nu}, nv={nv}")
        if not path_pos.shape == path_vel.shape == path_acc.shape or path_pos.shape[1:] != (3,):
            raise ValueError("path_pos, path_vel and path_acc must all be (T, 3)")
        self.model, self.site = model, model.site("ee").id
        self.body = int(model.site_bodyid[self.site])
        self.kp6, self.kd6 = cfg.gains(kp)
        self.kp_null, self.kd_null = cfg.null_gains
        self.cfg, self.min_eig, self.extra_torque = cfg, 1.0 / cfg.max_task_inertia, extra_torque
        steps = len(path_pos)
        self.path_pos = np.array(path_pos, dtype=np.float64)
        self.path_vel = np.zeros((steps, 6))  # 6-D task velocity (rotational part zero)
        self.path_vel[:, :3] = path_vel
        # xdd_d + Kd xd_d per frame, so a call adds only the state-dependent terms.
        self.feedforward = np.zeros((steps, 6))
        self.feedforward[:, :3] = path_acc + self.kd6[:3] * path_vel
        self.quat_target = np.array(quat_target, dtype=np.float64)
        self.qpos0 = np.array(qpos0[:nv], dtype=np.float64)

        self._jac, self._jdot, self._jminv = np.zeros((6, nv)), np.zeros((6, nv)), np.zeros((6, nv))
        self._lam_inv = np.zeros((6, 6))  # J M^-1 J^T
        # Column 0: task acceleration, column 1: reference velocity; Lambda is applied
        # to both at once.
        self._rhs = np.zeros((6, 2))
        self._err = np.zeros(6)
        self._quat, self._qconj, self._qerr = np.zeros(4), np.zeros(4), np.zeros(4)
        self._posture, self._tau0, self._bias = np.zeros(nv), np.zeros(nv), np.zeros(nv)
        self._qd_ref, self._u = np.zeros(nv), np.zeros(nv)

    def _orientation_error(self, data: mujoco.MjData) -> None:
        # Rotation vector of q_target * conj(q) (world frame, shortest way round), the
        # frame the rotational Jacobian is expressed in.
        mujoco.mju_mat2Quat(self._quat, data.site_xmat[self.site])
        mujoco.mju_negQuat(self._qconj, self._quat)
        mujoco.mju_mulQuat(self._qerr, self.quat_target, self._qconj)
        mujoco.mju_quat2Vel(self._err[3:], self._qerr, 1.0)

    def _velocity_terms(self, data: mujoco.MjData, accel: np.ndarray) -> None:
        """Subtracts Jdot qd from the task acceleration and puts c(q, qd) in ``_bias``."""
        m, qvel = self.model, data.qvel
        mujoco.mj_jacDot(m, data, self._jdot[:3], self._jdot[3:], data.site_xpos[self.site], self.body)
        accel -= self._jdot @ qvel
        # RNE without acceleration is C qd + g; with gravity switched off for the call it
        # is C qd alone, whatever the model's gravity compensation does.
        flags = m.opt.disableflags
        m.opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_GRAVITY
        try:
            mujoco.mj_rne(m, data, 0, self._bias)
        finally:
            m.opt.disableflags = flags

    def _friction_terms(self, lam_vel: np.ndarray) -> None:
        """Adds damping and dry friction along the reference joint velocity to ``_bias``."""
        m, qd = self.model, self._qd_ref
        # J-bar v_r = M^-1 J^T Lambda v_r: the joint velocity the dynamically consistent
        # inverse picks for the reference velocity (no null-space motion). The model's
        # values are read at each call, so a randomized copy is compensated as it is.
        np.matmul(self._jminv.T, lam_vel, out=qd)
        self._bias += m.dof_damping * qd
        self._bias += m.dof_frictionloss * np.tanh(qd / self.cfg.friction_velocity)

    def _apply_task_inertia(self, rhs: np.ndarray) -> np.ndarray:
        """Lambda @ rhs, with Lambda's eigenvalues capped at ``max_task_inertia``."""
        eig, vec = np.linalg.eigh(self._lam_inv)
        np.maximum(eig, self.min_eig, out=eig)
        return vec @ ((vec.T @ rhs) / eig[:, None])

    def __call__(self, data: mujoco.MjData, t: int) -> np.ndarray:
        """The torque command of frame ``t`` (expects the frame-start state computed)."""
        m, qvel, jac, jminv = self.model, data.qvel, self._jac, self._jminv
        mujoco.mj_jacSite(m, data, jac[:3], jac[3:], self.site)
        mujoco.mj_solveM(m, data, jminv, jac)  # rows of J M^-1, as M is symmetric
        np.matmul(jminv, jac.T, out=self._lam_inv)

        err, accel = self._err, self._rhs[:, 0]
        np.subtract(self.path_pos[t], data.site_xpos[self.site], out=err[:3])
        self._orientation_error(data)
        accel[:] = self.feedforward[t] + self.kp6 * err - self.kd6 * (jac @ qvel)
        np.multiply(err, self.cfg.reference_gain, out=self._rhs[:, 1])
        self._rhs[:, 1] += self.path_vel[t]

        # Null-space posture PD, M-weighted so its gains mean the same on every joint.
        np.multiply(self.qpos0 - data.qpos[: m.nv], self.kp_null, out=self._posture)
        self._posture -= self.kd_null * qvel
        mujoco.mj_mulM(m, data, self._tau0, self._posture)
        accel -= jminv @ self._tau0
        self._bias[:] = 0.0
        if self.cfg.coriolis:
            self._velocity_terms(data, accel)

        lam = self._apply_task_inertia(self._rhs)  # (6, 2): F and Lambda xd_d
        if self.cfg.joint_friction:
            self._friction_terms(lam[:, 1])
        u = self._u
        np.matmul(jac.T, lam[:, 0], out=u)
        u += self._tau0
        u += self._bias
        if self.extra_torque is not None:
            u += self.extra_torque(data.qpos[: m.nv])
        np.clip(u, -self.limits, self.limits, out=u)
        return u


def start_pose(model: mujoco.MjModel, data: mujoco.MjData,
               qpos0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """EE position (3,) and quaternion (4,) w x y z at rest in ``qpos0`` (resets ``data``)."""
    reset_to(model, data, qpos0)
    site = model.site("ee").id
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    return data.site_xpos[site].copy(), quat


def simulate_osc(model: mujoco.MjModel, data: mujoco.MjData, qpos0: np.ndarray, task: str,
                 rng: np.random.Generator, steps: int, substeps: int, dt: float,
                 osc_cfg: OSCConfig, path_cfg: CircleConfig | SpiralConfig,
                 extra_torque: Callable[[np.ndarray], np.ndarray] | None = None,
                 torque_limits: np.ndarray | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Draws a path from the EE start pose and tracks it with OSC at one update per frame.

    Args:
        model, data: the (randomized) model and scratch data.
        qpos0: (7,) initial joints (at rest); also the null-space posture.
        task: ``"circle"`` or ``"spiral"``.
        rng: the trajectory's random stream (path first, then kp).
        steps: frames T.
        substeps: physics steps per frame.
        dt: frame period [s].
        osc_cfg: controller gains.
        path_cfg: the task's path ranges.
        extra_torque, torque_limits: see :class:`OSCController`.

    Returns:
        sens (T, nsensordata) sensor data, target (T, 3) desired EE positions, kp used.
    """
    if task not in PATHS:
        raise ValueError(f"unknown OSC task {task!r}; choose from {list(OSC_TASKS)}")
    expected = CircleConfig if task == "circle" else SpiralConfig
    if not isinstance(path_cfg, expected):
        raise TypeError(f"task {task!r} needs a {expected.__name__}, got {type(path_cfg).__name__}")
    pos0, quat0 = start_pose(model, data, qpos0)
    pos, vel, acc = PATHS[task](rng, pos0, steps, dt, path_cfg)
    kp = osc_cfg.draw_kp(rng)
    ctrl = OSCController(model, pos, vel, acc, quat0, qpos0, kp, osc_cfg, extra_torque, torque_limits)
    return simulate_closed_loop(model, data, qpos0, steps, substeps, ctrl), pos, kp
