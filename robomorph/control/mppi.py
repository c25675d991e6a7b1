"""Model-predictive path integral control (MPPI) over whole torque sequences.

Why not ``pytorch-mppi``: its dynamics interface is one step at a time,
``F(state, action) -> next state``, called ``horizon`` times per plan. RoboMorph's
predictors map a whole torque sequence to a whole output sequence in one call (the
transformer decodes the horizon at once; a physics predictor runs one threaded
``mujoco.rollout`` over all candidates), and the in-context model has no state vector to
step at all. Planning here is therefore a function of ``(K, H, n_u)`` candidate torques to
``(K, H, n_y)`` predicted outputs, and the update is MPPI's (Williams et al. 2017):

1. ``K`` candidates ``U + eps``: the mean plan plus smooth noise (Gaussian knots every
   ``knot`` frames, linearly interpolated), clipped to the torque limits; the first
   candidate is the mean plan itself;
2. each is scored by :func:`tracking_cost` on its predicted outputs;
3. the plan moves to the cost-weighted mean, weights ``exp(-(c - c_min) / lambda)`` with
   ``lambda = temperature * (median(c) - c_min)`` (scale-free: the same setting works for any
   predictor and task);
4. the first ``replan`` frames are applied and the plan shifts by as many (warm start).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MPPIConfig:
    """Settings of the planner (defaults: the settings behind the documented results).

    Attributes:
        samples: candidate torque sequences per plan (K).
        horizon: frames planned ahead (H).
        replan: frames applied from each plan before the next one.
        knot: frames between the noise's knots (smoothness of the exploration).
        noise: exploration std per joint as a fraction of the joint's torque limit.
        temperature: MPPI's lambda relative to the spread of the costs (smaller: greedier).
        w_pos: weight of the EE position error [1/m^2].
        w_rot: weight of the orientation error (1 - <q, q_ref>^2).
        w_vel: weight of the joint speeds [s^2/rad^2] (damps the motion).
        w_posture: weight of the joints' distance from the start pose [1/rad^2] (the
            redundant degree of freedom, as OSC's null-space term).
        w_limit: weight of a joint's intrusion into the ``limit_margin`` band inside its
            limits [1/rad^2] (a soft barrier: the world ends an episode at a joint limit).
        limit_margin: width of that band [rad].
    """

    samples: int = 128
    horizon: int = 20
    replan: int = 1
    knot: int = 10
    noise: float = 0.005
    temperature: float = 0.05
    w_pos: float = 1e4
    w_rot: float = 30.0
    w_vel: float = 1e-2
    w_posture: float = 1e-2
    w_limit: float = 1e6
    limit_margin: float = 0.15

    def __post_init__(self):
        for name in ("samples", "horizon", "replan", "knot"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"mpc.{name} must be >= 1, got {getattr(self, name)}")
        if self.replan > self.horizon:
            raise ValueError(f"mpc.replan ({self.replan}) must not exceed mpc.horizon ({self.horizon})")
        for name in ("noise", "temperature"):
            if not 0 < getattr(self, name) < np.inf:
                raise ValueError(f"mpc.{name} must be finite and > 0, got {getattr(self, name)}")
        for name in ("w_pos", "w_rot", "w_vel", "w_posture", "w_limit", "limit_margin"):
            if not 0 <= getattr(self, name) < np.inf:
                raise ValueError(f"mpc.{name} must be finite and >= 0, got {getattr(self, name)}")


@dataclass
class Goal:
    """What the plan is scored against over its horizon.

    Attributes:
        pos: (H, 3) reference EE positions at plan steps 1..H.
        quat: (4,) reference orientation, X Y Z W (the order of ``y``).
        q_now: (n,) measured joints now (for the first speed).
        posture: (n,) the joints' rest pose.
        dt: frame period [s].
        joint_range: (n, 2) the joints' limits [rad] (None: no barrier).
    """

    pos: np.ndarray
    quat: np.ndarray
    q_now: np.ndarray
    posture: np.ndarray
    dt: float
    joint_range: np.ndarray | None = None


def tracking_cost(y: np.ndarray, goal: Goal, cfg: MPPIConfig) -> np.ndarray:
    """(K,) cost of predicted outputs ``y`` (K, H, 7 + n): EE x y z, quaternion X Y Z W, joints."""
    pos_err = y[:, :, :3] - goal.pos[None]
    cost = cfg.w_pos * np.einsum("khi,khi->k", pos_err, pos_err)
    dot = y[:, :, 3:7] @ goal.quat
    cost += cfg.w_rot * np.sum(1.0 - dot ** 2, axis=1)
    q = y[:, :, 7:]
    speed = np.diff(q, axis=1, prepend=np.broadcast_to(goal.q_now, (len(q), 1, q.shape[2]))) / goal.dt
    cost += cfg.w_vel * np.einsum("khj,khj->k", speed, speed)
    off = q - goal.posture
    cost += cfg.w_posture * np.einsum("khj,khj->k", off, off)
    if goal.joint_range is not None and cfg.w_limit:
        lo, hi = goal.joint_range[:, 0] + cfg.limit_margin, goal.joint_range[:, 1] - cfg.limit_margin
        intrusion = np.maximum(lo - q, 0.0) + np.maximum(q - hi, 0.0)
        cost += cfg.w_limit * np.einsum("khj,khj->k", intrusion, intrusion)
    return cost


class MPPI:
    """One controller's planner (its random stream and its warm-started plan).

    Args:
        cfg: settings.
        limits: (n,) torque limits [N m]; every candidate is clipped to them.
        rng: the planner's random stream (a seeded episode gives the same plans).
    """

    def __init__(self, cfg: MPPIConfig, limits: np.ndarray, rng: np.random.Generator):
        self.cfg, self.rng = cfg, rng
        self.limits = np.asarray(limits, dtype=np.float64)
        self.sigma = cfg.noise * self.limits
        self.plan_: np.ndarray = np.zeros((cfg.horizon, len(self.limits)))
        h = np.arange(cfg.horizon) / cfg.knot
        self._i0 = np.floor(h).astype(int)
        self._w = (h - self._i0)[None, :, None]
        self._knots = self._i0[-1] + 2

    def reset(self, torque: np.ndarray) -> None:
        """Starts from holding ``torque`` over the horizon (the warm-up's last command)."""
        self.plan_[:] = np.clip(torque, -self.limits, self.limits)

    def candidates(self) -> tuple[np.ndarray, np.ndarray]:
        """(K, H, n) clipped candidates and the noise they carry (row 0: the plan itself)."""
        cfg = self.cfg
        knots = self.rng.standard_normal((cfg.samples, self._knots, len(self.limits))) * self.sigma
        eps = knots[:, self._i0] * (1.0 - self._w) + knots[:, self._i0 + 1] * self._w
        eps[0] = 0.0
        cand = np.clip(self.plan_[None] + eps, -self.limits, self.limits)
        return cand, cand - self.plan_[None]

    def step(self, predict: Callable[[np.ndarray], np.ndarray], goal: Goal) -> np.ndarray:
        """Re-plans and returns the ``(replan, n)`` torques to apply now.

        Args:
            predict: ``(K, H, n) torques -> (K, H, 7 + n)`` predicted outputs at plan steps 1..H.
            goal: the horizon's reference.
        """
        cand, eps = self.candidates()
        y = np.asarray(predict(cand), dtype=np.float64)
        cost = tracking_cost(y, goal, self.cfg)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        best = float(np.min(cost))
        if not np.isfinite(best):  # every prediction diverged: keep the plan
            weights = np.eye(1, len(cost))[0]
        else:
            finite = cost[np.isfinite(cost)]
            lam = max(self.cfg.temperature * (float(np.median(finite)) - best), 1e-12)
            weights = np.exp(-(cost - best) / lam)
            weights /= weights.sum()
        self.plan_ = np.clip(self.plan_ + np.einsum("k,khj->hj", weights, eps), -self.limits, self.limits)
        r = self.cfg.replan
        out = self.plan_[:r].copy()
        self.plan_ = np.concatenate([self.plan_[r:], np.repeat(self.plan_[-1:], r, axis=0)])
        return out
