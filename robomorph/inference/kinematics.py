"""Kinematic extrapolation: predictions that read nothing but the context's last outputs.

On real arms, whose joint angles are smooth and finely measured, these are the bars a dynamics model must clear
at short horizons (``docs/guide/real-robots.md``). The evaluation's baselines of the same names
(:mod:`robomorph.evaluation.baselines`) and the context backtest's candidates (:mod:`robomorph.inference.stacking`)
are these functions, never a copy.

Each takes ``u_ctx (B, Tc, n_u)``, ``y_ctx (B, Tc, n_y)`` and ``u_query (B, H, n_u)`` (whose length alone is read) and
returns ``(B, H, n_y)`` in float64. Channels are extrapolated one by one, quaternion channels included (over a short
horizon their norm drifts by the square of the step's rotation).
"""

from __future__ import annotations

import numpy as np


def hold(u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """The last context output, held for every query step."""
    return np.repeat(np.asarray(y_ctx, dtype=np.float64)[:, -1:], u_query.shape[1], axis=1)


def constant_velocity(u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """Each output continued along its last step: ``y[c-1] + k (y[c-1] - y[c-2])`` at query step ``k``."""
    y = np.asarray(y_ctx, dtype=np.float64)
    if y.shape[1] < 2:
        raise ValueError("constant_velocity needs a context of at least 2 steps")
    k = np.arange(1, u_query.shape[1] + 1)[None, :, None]  # (1, H, 1)
    return y[:, -1:] + k * (y[:, -1:] - y[:, -2:-1])


def constant_acceleration(u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """Each output continued along the parabola through its last three samples:
    ``y[c-1] + k v + k (k + 1) / 2 a``, with ``v`` and ``a`` the last backward differences."""
    y = np.asarray(y_ctx, dtype=np.float64)
    if y.shape[1] < 3:
        raise ValueError("constant_acceleration needs a context of at least 3 steps")
    k = np.arange(1, u_query.shape[1] + 1)[None, :, None]
    v = y[:, -1:] - y[:, -2:-1]
    a = v - (y[:, -2:-1] - y[:, -3:-2])
    return y[:, -1:] + k * v + k * (k + 1) / 2 * a


# By name, in the order reports list them.
KINEMATIC = {"hold": hold, "constant_velocity": constant_velocity, "constant_acceleration": constant_acceleration}
