"""Baselines every evaluation reports beside the meta-model, so users see what it adds.

Each baseline predicts ``y_query (B, H, n_y)`` from the same information the meta-model
gets: the context ``u_ctx (B, Tc, n_u)``, ``y_ctx (B, Tc, n_y)`` and the query inputs
``u_query (B, H, n_u)``. None of them sees ``y_query``.

- ``hold``: the last context output held over the horizon.
- ``constant_velocity``: each output extrapolated along the velocity of the last two context
  samples. On real logs, where joint angles are smooth and measured finely, this is the bar
  at short horizons: a predictor that loses to it there is no use to a controller.
- ``constant_acceleration``: the same with the acceleration of the last three samples too
  (a parabola); better than ``constant_velocity`` over a few steps, worse beyond.
- ``arx``: a linear ARX model fitted by least squares on each trajectory's own context,
  then simulated freely over the horizon (its own outputs fed back).
- ``arx_train``: one linear ARX model fitted by least squares over the model's *training*
  data (the usual system-identification baseline), started from each context's last
  samples and simulated freely over the horizon.
- ``nominal_physics``: the catalogue Panda (no randomization) simulated in MuJoCo from
  the state at the end of the context, driven by the recorded torques.
- ``identified_physics`` (opt-in): the physical parameters a context reveals (a mass per
  link; damping, armature and friction loss per joint) fitted to each window's context,
  within the randomization ranges, then that robot simulated like ``nominal_physics``
  (:mod:`robomorph.evaluation.identified`). Each window is a fit of seconds, so it runs only
  when named.
- ``identified_physics_springs`` (opt-in): the same fit with the joints' springs (their
  stiffness) fitted too, as the command hybrid's regression fits them: the engineer's
  baseline given the same parameters as the hybrid. Slower (one more column per joint).
- ``true_physics`` (opt-in): ``nominal_physics`` with each robot's *true* stored parameters, which
  no predictor gets: how far the dynamics themselves stay predictable from the estimated
  state. Driven by the total torque, tiny state errors grow tenfold about every 57 steps
  (g(q) is paid at the recorded state); driven by the command on an arm compensating its
  own gravity, they do not grow (``benchmarks/predictability.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BASELINES = ("hold", "constant_velocity", "constant_acceleration", "arx", "arx_train", "nominal_physics")
# Competitors run only when named (--baselines): each window costs a fit of its own.
OPT_IN = ("identified_physics", "identified_physics_springs")
# Not a competitor (it reads the parameters the model never sees) but the ceiling of
# physics itself: each robot's own parameters, from the same estimated state. Opt-in.
CEILINGS = ("true_physics",)
# An ARX simulation whose outputs leave this band around the context is called diverged
# and replaced by ``hold``: one exploding trajectory would otherwise swamp every mean.
_ARX_BLOWUP = 1e3


def hold(u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """The last context output, held for every query step."""
    return np.repeat(y_ctx[:, -1:], u_query.shape[1], axis=1)


def constant_velocity(u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """Each output continued along its last step: ``y[c-1] + k (y[c-1] - y[c-2])`` at query step ``k``.

    The outputs are extrapolated channel by channel, quaternion channels included (over a
    short horizon their norm drifts by the square of the step's rotation).
    """
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


# The baselines that read nothing but the context's last outputs, by name.
KINEMATIC = {"hold": hold, "constant_velocity": constant_velocity, "constant_acceleration": constant_acceleration}


@dataclass
class ARX:
    """MIMO ARX ``y[t] = sum_i A_i y[t-i] + sum_j B_j u[t-j] + c``, one fit per trajectory.

    The inputs act with one step of delay (``j >= 1``): row ``t`` of a store is the state
    at the start of frame ``t`` and ``u[t]`` is applied from there, so it cannot move
    ``y[t]``. Regressors are scaled per trajectory for a well-conditioned fit; ``ridge``
    is a small Tikhonov term relative to the regressors' energy.

    Attributes:
        na: output lags; nb: input lags; ridge: relative regularization.
        diverged: trajectories of the last call whose simulation blew up (held instead).
    """

    na: int = 2
    nb: int = 2
    ridge: float = 1e-8
    diverged: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.na < 1 or self.nb < 1:
            raise ValueError(f"ARX orders must be >= 1, got na={self.na}, nb={self.nb}")

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
        lag = max(self.na, self.nb)
        n_reg = self.na * y_ctx.shape[-1] + self.nb * u_ctx.shape[-1] + 1
        if u_ctx.shape[1] - lag < n_reg:
            raise ValueError(f"ARX({self.na},{self.nb}) has {n_reg} coefficients per output but the context "
                             f"gives only {u_ctx.shape[1] - lag} equations: use a longer context or lower orders")
        out = np.empty(y_ctx.shape[:1] + u_query.shape[1:2] + y_ctx.shape[2:])
        self.diverged = 0
        for b in range(len(u_ctx)):
            out[b] = self._one(u_ctx[b].astype(np.float64), y_ctx[b].astype(np.float64),
                               u_query[b].astype(np.float64))
        return out

    def _one(self, u: np.ndarray, y: np.ndarray, uq: np.ndarray) -> np.ndarray:
        # Per-trajectory scaling from the context only.
        ym, ys = y.mean(0), np.maximum(y.std(0), 1e-9)
        um, us = u.mean(0), np.maximum(u.std(0), 1e-9)
        yn, un, uqn = (y - ym) / ys, (u - um) / us, (uq - um) / us
        lag, t = max(self.na, self.nb), len(y)
        rows = [self._regressor(yn, un, k) for k in range(lag, t)]
        phi, target = np.stack(rows), yn[lag:]
        gram = phi.T @ phi
        gram[np.diag_indices_from(gram)] += self.ridge * np.trace(gram) / len(gram)
        theta = np.linalg.solve(gram, phi.T @ target)  # (n_reg, n_y)
        y_all = np.concatenate([yn, np.empty((len(uqn), yn.shape[1]))])
        u_all = np.concatenate([un, uqn])
        for k in range(t, t + len(uqn)):
            y_all[k] = self._regressor(y_all, u_all, k) @ theta
        pred = y_all[t:] * ys + ym
        span = np.abs(y - ym).max() + 1e-9
        if not np.isfinite(pred).all() or np.abs(pred - ym).max() > _ARX_BLOWUP * span:
            self.diverged += 1
            return np.repeat(y[-1:], len(uq), axis=0)
        return pred

    def _regressor(self, y: np.ndarray, u: np.ndarray, k: int) -> np.ndarray:
        return np.concatenate([y[k - self.na:k][::-1].ravel(), u[k - self.nb:k][::-1].ravel(), [1.0]])


def _lagged(y: np.ndarray, u: np.ndarray, na: int, nb: int) -> np.ndarray:
    """Regressors of every step ``k >= max(na, nb)`` of a batch: (B, T - lag, n_reg), the same
    layout as :meth:`ARX._regressor` (newest lag first, then the constant)."""
    lag, t = max(na, nb), y.shape[1]
    parts = [y[:, lag - i:t - i] for i in range(1, na + 1)] + [u[:, lag - j:t - j] for j in range(1, nb + 1)]
    return np.concatenate(parts + [np.ones(y.shape[:1] + (t - lag, 1))], axis=-1)


@dataclass
class TrainedARX:
    """One MIMO ARX model (same structure as :class:`ARX`) fitted over training trajectories.

    Fit once with :meth:`fit` (any number of calls accumulate the normal equations, so a
    large store is read in blocks), then predict like every baseline. Scaling comes from
    the training data; a simulation leaving the context's band is held, as for ``arx``.
    """

    na: int = 2
    nb: int = 2
    ridge: float = 1e-8
    diverged: int = field(default=0, init=False)
    trajectories: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.na < 1 or self.nb < 1:
            raise ValueError(f"ARX orders must be >= 1, got na={self.na}, nb={self.nb}")
        self._theta: np.ndarray | None = None

    def fit(self, blocks) -> "TrainedARX":
        """Least squares over ``blocks``: an iterable of ``(u (B, T, n_u), y (B, T, n_y))``.

        Two passes are avoided by scaling with the first block's statistics (the scaling only
        conditions the solve; the fitted predictor does not depend on it beyond rounding).
        """
        gram = rhs = None
        for u, y in blocks:
            u, y = u.astype(np.float64), y.astype(np.float64)
            if gram is None:
                self._scale = (y.mean((0, 1)), np.maximum(y.std((0, 1)), 1e-9),
                               u.mean((0, 1)), np.maximum(u.std((0, 1)), 1e-9))
                n_reg = self.na * y.shape[-1] + self.nb * u.shape[-1] + 1
                gram, rhs = np.zeros((n_reg, n_reg)), np.zeros((n_reg, y.shape[-1]))
            yn, un = self._normalize(u, y)
            phi = _lagged(yn, un, self.na, self.nb).reshape(-1, gram.shape[0])
            gram += phi.T @ phi
            rhs += phi.T @ yn[:, max(self.na, self.nb):].reshape(-1, yn.shape[-1])
            self.trajectories += len(u)
        if gram is None:
            raise ValueError("arx_train needs at least one training trajectory")
        gram[np.diag_indices_from(gram)] += self.ridge * np.trace(gram) / len(gram)
        self._theta = np.linalg.solve(gram, rhs)  # (n_reg, n_y)
        return self

    def _normalize(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ym, ys, um, us = self._scale
        return (y - ym) / ys, (u - um) / us

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
        if self._theta is None:
            raise ValueError("fit the ARX model on training data before predicting")
        lag = max(self.na, self.nb)
        if u_ctx.shape[1] < lag:
            raise ValueError(f"ARX({self.na},{self.nb}) needs a context of at least {lag} steps")
        y_c, u_all = self._normalize(np.concatenate([u_ctx, u_query], 1).astype(np.float64), y_ctx.astype(np.float64))
        tc, h = y_c.shape[1], u_query.shape[1]
        y_all = np.concatenate([y_c, np.zeros((len(y_c), h, y_c.shape[2]))], axis=1)
        for k in range(tc, tc + h):  # free simulation: the model's own outputs fed back
            reg = _lagged(y_all[:, k - lag:k + 1], u_all[:, k - lag:k + 1], self.na, self.nb)[:, 0]
            y_all[:, k] = reg @ self._theta
        ym, ys, _, _ = self._scale
        pred = y_all[:, tc:] * ys + ym
        # Same divergence rule as ARX: outside the context's band -> hold, and counted.
        y64 = y_ctx.astype(np.float64)
        centre = y64.mean(1, keepdims=True)
        span = np.abs(y64 - centre).max((1, 2)) + 1e-9
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(pred).all((1, 2)) | (np.abs(pred - centre).max((1, 2)) > _ARX_BLOWUP * span)
        pred[bad] = hold(u_ctx, y64, u_query)[bad]
        self.diverged = int(bad.sum())
        return pred


