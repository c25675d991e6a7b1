"""Joint velocity from sampled positions: what the recordings do not hold, estimated where needed.

Shared by the physics baselines (:mod:`robomorph.evaluation.physics`), identification and the
hybrid model's backbone: each needs the velocity at a context sample to start a simulation.
"""

from __future__ import annotations

import numpy as np


def estimate_velocity(q: np.ndarray, dt: float, points: int = 6) -> np.ndarray:
    """Velocity at the last sample from a cubic fitted to the last ``points`` samples.

    Args:
        q: (B, T, n) positions sampled every ``dt``; T >= 2.

    Returns:
        (B, n) velocity estimates (a backward difference when T < 4).
    """
    t = q.shape[1]
    if t < 2:
        raise ValueError("velocity estimation needs at least 2 context samples")
    k = min(points, t)
    deg = min(3, k - 1)
    times = (np.arange(k) - (k - 1)) * dt  # the last sample at time 0
    basis = np.vander(times, deg + 1, increasing=True)  # columns 1, t, t^2, ...
    coef, *_ = np.linalg.lstsq(basis, q[:, -k:].transpose(1, 0, 2).reshape(k, -1), rcond=None)
    return coef[1].reshape(q.shape[0], q.shape[2])  # d/dt at t = 0


def velocity_weights(t: int, points: int = 6) -> np.ndarray:
    """The linear filter :func:`estimate_velocity` applies, per sample step instead of per second.

    The fit is linear in the samples, so its slope at the last sample is a fixed weighting of the
    last ``k = min(points, t)`` samples: ``v = weights @ q[-k:]`` in units of the samples per step
    (divide by ``dt`` for a rate). Any affine change of units commutes with it, which is why a
    model can extrapolate its normalized outputs with it. ``points=2`` is the last backward
    difference, the ``constant_velocity`` baseline's velocity.

    Returns:
        (k,) weights, the last one for the last sample.
    """
    if t < 2:
        raise ValueError("velocity estimation needs at least 2 context samples")
    if points < 2:
        raise ValueError(f"velocity estimation needs at least 2 points, got {points}")
    k = min(points, t)
    deg = min(3, k - 1)
    basis = np.vander(np.arange(k, dtype=np.float64) - (k - 1), deg + 1, increasing=True)
    return np.linalg.pinv(basis)[1]  # the slope row of the least-squares solve
