"""Validity filters: which simulated trajectories a dataset keeps, and why others go.

Each check runs on sensor data at any rate (every physics step for open-loop rollouts,
every control step for OSC), so a short collision is seen whenever it was sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robomorph.sim import panda
from robomorph.sim.arms import SensorLayout

REASONS = ("nan", "contact", "joint_limit", "saturation", "quaternion_jump")


@dataclass(frozen=True)
class FilterConfig:
    """Thresholds of the discard filters (the paper's code values by default)."""

    joint_margin: float = 0.05  # rad from a joint limit
    torque_margin: float = 1.0  # N m from a torque limit
    quat_jump: float = 0.1  # largest per-sample change of any quaternion component
    max_abs_state: float = 1e3  # beyond this a state is treated as diverged

    def __post_init__(self):
        for name in ("joint_margin", "torque_margin", "quat_jump", "max_abs_state"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"filters.{name} must be >= 0, got {getattr(self, name)}")


def continuous_quaternion(quat: np.ndarray) -> np.ndarray:
    """Flips signs so consecutive unit quaternions never point to opposite hemispheres.

    ``q`` and ``-q`` are the same rotation; the sign a simulator reports may flip from one
    sample to the next, which a learner would see as a jump of size 2. The first sample
    keeps the sign it was given (the component order is not known here, so no scalar
    part can be singled out), then each sample keeps the sign closest to its predecessor.

    Args:
        quat: (..., T, 4) quaternions in any component order.
    """
    q = np.array(quat, dtype=np.float64, copy=True)
    dots = np.sum(q[..., 1:, :] * q[..., :-1, :], axis=-1)
    # The sign of sample t is the product of the flips up to t: a cumulative parity.
    # (the first sample's zero is shaped from q, not dots: one sample has no dots at all)
    flips = np.concatenate([np.zeros(q.shape[:-2] + (1,)), (dots < 0).astype(np.float64)], axis=-1)
    sign = np.where(np.cumsum(flips, axis=-1) % 2 == 1, -1.0, 1.0)
    return q * sign[..., None]


def check(sens: np.ndarray, joint_range: np.ndarray, cfg: FilterConfig,
          torque_limits: np.ndarray = panda.TORQUE_LIMITS) -> str | None:
    """Returns the first reason to reject a trajectory, or ``None`` if it is valid.

    Args:
        sens: (S, nsensordata) sensor data of an arm with n joints (layout of
            :class:`robomorph.sim.arms.SensorLayout`).
        joint_range: (n, 2) joint limits of the simulated model.
        cfg: thresholds.
        torque_limits: (n,) actuator limits in N m (the Panda's by default).
    """
    lay = SensorLayout(len(joint_range))
    if not np.all(np.isfinite(sens)) or np.abs(sens).max() > cfg.max_abs_state:
        return "nan"
    if sens[:, lay.contacts].max() > 0:
        return "contact"
    q = sens[:, lay.qpos]
    lo, hi = joint_range[:, 0] + cfg.joint_margin, joint_range[:, 1] - cfg.joint_margin
    if np.any(q < lo) or np.any(q > hi):
        return "joint_limit"
    if np.any(np.abs(sens[:, lay.tau]) > torque_limits - cfg.torque_margin):
        return "saturation"
    quat = continuous_quaternion(sens[:, lay.ee_quat])
    if len(quat) > 1 and np.abs(np.diff(quat, axis=0)).max() > cfg.quat_jump:
        return "quaternion_jump"
    return None


def to_outputs(sens: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turns an arm's sensor data into the dataset's (u, y), with a continuous quaternion.

    Args:
        sens: (..., T, nsensordata), 8 + 3 n values for n joints.

    Returns:
        u (..., T, n) joint torques; y (..., T, 7 + n) EE xyz, EE quaternion XYZW, q0..q{n-1}.
    """
    lay = SensorLayout.of_width(sens.shape[-1])
    quat_wxyz = continuous_quaternion(sens[..., lay.ee_quat])
    quat_xyzw = quat_wxyz[..., [1, 2, 3, 0]]
    y = np.concatenate([sens[..., lay.ee_pos], quat_xyzw, sens[..., lay.qpos]], axis=-1)
    return sens[..., lay.tau].astype(np.float32), y.astype(np.float32)


def to_command(sens: np.ndarray, added: np.ndarray | None = None) -> np.ndarray:
    """The command (``u_cmd``): the motors' force less any compensation added to it.

    Args:
        sens: (..., T, nsensordata).
        added: (..., T, n) torque the controller added to the command before the motors
            (the catalogue robot's g(q) in ``nominal_model`` mode), or None.

    Returns:
        (..., T, n) float32; with the arm's own gravcomp (or none), ``u = u_cmd + g``.
    """
    cmd = sens[..., SensorLayout.of_width(sens.shape[-1]).cmd]
    return (cmd if added is None else cmd - added).astype(np.float32)
