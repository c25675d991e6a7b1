"""The end-effector references a controller tracks: circle, spiral and reach (point to point).

Every episode opens with a warm-up under the catalogue OSC controller along the task's own
path (the circle's or the spiral's; the reach task warms up on a circle), which records the
first context. From frame ``warmup`` on the model-predictive controller takes over:

- ``circle`` and ``spiral`` keep following the path drawn by :mod:`robomorph.sim.paths`
  (the generator's own circles and spirals, so a model has seen motions like these);
- ``reach`` leaves the circle where it stands at the switch, moves 10-20 cm in a random
  direction along a quintic (rest to rest) in ``move`` seconds and holds the target, so
  the tail measures how well the controller settles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robomorph.sim.paths import PATHS, CircleConfig, SpiralConfig

TASKS = ("circle", "spiral", "reach")


@dataclass(frozen=True)
class Reference:
    """A reference of ``T`` frames (frame k at time k dt).

    Attributes:
        pos, vel, acc: (T, 3) desired EE position [m], velocity and acceleration.
        quat: (4,) the EE orientation to hold (MuJoCo order w x y z; the start pose's).
        warmup: frames under the warm-up controller; the tracking phase is ``warmup..T-1``.
    """

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    quat: np.ndarray
    warmup: int

    @property
    def steps(self) -> int:
        return len(self.pos)


def _quintic(start: np.ndarray, delta: np.ndarray, steps: int, dt: float, move: float):
    """Rest-to-rest move from ``start`` by ``delta`` in ``move`` s, then held: (pos, vel, acc) (T, 3)."""
    t = np.arange(steps) * dt
    s = np.clip(t / move, 0.0, 1.0)
    h = s ** 3 * (10 - 15 * s + 6 * s ** 2)
    hd = np.where(t < move, 30 * s ** 2 * (1 - s) ** 2 / move, 0.0)
    hdd = np.where(t < move, 60 * s * (1 - s) * (1 - 2 * s) / move ** 2, 0.0)
    return start + h[:, None] * delta, hd[:, None] * delta, hdd[:, None] * delta


def draw_reference(task: str, rng: np.random.Generator, start_pos: np.ndarray, start_quat: np.ndarray,
                   warmup: int, steps: int, dt: float, move: float = 1.5) -> Reference:
    """Draws the reference of one episode from the EE start pose.

    Args:
        task: one of :data:`TASKS`.
        rng: the episode's random stream.
        start_pos, start_quat: EE position (3,) and orientation (4,) w x y z at rest at the start.
        warmup: frames of the warm-up.
        steps: frames in all (warm-up included).
        dt: frame period [s].
        move: duration of the reach move [s].
    """
    if task not in TASKS:
        raise ValueError(f"unknown control task {task!r}; choose from {', '.join(TASKS)}")
    if not 0 < warmup < steps:
        raise ValueError(f"the warm-up ({warmup} frames) must be shorter than the episode ({steps})")
    path = "spiral" if task == "spiral" else "circle"
    cfg = SpiralConfig() if path == "spiral" else CircleConfig()
    pos, vel, acc = PATHS[path](rng, np.asarray(start_pos, dtype=np.float64), steps, dt, cfg)
    if task == "reach":
        direction = rng.standard_normal(3)
        delta = direction / np.linalg.norm(direction) * rng.uniform(0.10, 0.20)
        tail = _quintic(pos[warmup], delta, steps - warmup, dt, move)
        for out, part in zip((pos, vel, acc), tail):
            out[warmup:] = part
    return Reference(pos, vel, acc, np.asarray(start_quat, dtype=np.float64).copy(), int(warmup))


def reachable(model, ref: Reference, q0, joint_margin: float = 0.15, tol: float = 1e-3,
              min_singular: float = 0.05, every: int = 5) -> bool:
    """Whether the arm can follow ``ref`` kinematically, well inside its joint limits.

    Follows the reference (every ``every`` frames, holding ``ref.quat``) from ``q0`` by damped
    least squares on the catalogue kinematics (link geometry is not randomized, so they are
    every robot's), and asks at each point for a residual below ``tol`` [m], every joint
    ``joint_margin`` [rad] inside its limits, and the smallest singular value of the position
    Jacobian above ``min_singular`` [m/rad] (away from the stretched-out singularity). A
    reference that fails would measure the arm's workspace, not the controller: an episode
    redraws it, as the generator redraws a rejected trajectory.
    """
    import mujoco  # noqa: PLC0415

    data = mujoco.MjData(model)
    nj = len(q0)
    lo, hi = model.jnt_range[:nj, 0] + joint_margin, model.jnt_range[:nj, 1] - joint_margin
    site = model.site("ee").id
    jac = np.zeros((6, model.nv))
    err, quat, conj, qerr = np.zeros(6), np.zeros(4), np.zeros(4), np.zeros(4)
    q = np.array(q0, dtype=np.float64)
    for f in range(0, ref.steps, every):
        for _ in range(20):
            data.qpos[:nj] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            err[:3] = ref.pos[f] - data.site_xpos[site]
            mujoco.mju_mat2Quat(quat, data.site_xmat[site])
            mujoco.mju_negQuat(conj, quat)
            mujoco.mju_mulQuat(qerr, ref.quat, conj)
            mujoco.mju_quat2Vel(err[3:], qerr, 1.0)
            mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site)
            if np.linalg.norm(err[:3]) < tol / 4 and np.linalg.norm(err[3:]) < 1e-3:
                break
            j = jac[:, :nj]
            q += j.T @ np.linalg.solve(j @ j.T + 1e-4 * np.eye(6), err)
        if np.linalg.norm(err[:3]) > tol or np.any(q < lo) or np.any(q > hi):
            return False
        if np.linalg.svd(jac[:3, :nj], compute_uv=False)[-1] < min_singular:
            return False
    return True
