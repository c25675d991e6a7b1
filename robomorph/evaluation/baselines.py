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
- ``accel_arx`` (opt-in): an ARX model in acceleration form, ``y[t+1] = 2 y[t] - y[t-1] + W x[t]``
  with ``x[t]`` the inputs, their last change, the outputs' last step and a constant: a double
  integrator whose acceleration is linear in the torque, fitted on each window's own context
  with its ridge chosen on the context's last quarter. Unlike ``arx`` it cannot drift away from
  smooth motion: with ``W = 0`` it is ``constant_velocity``.
- ``accel_arx_train`` (opt-in): the same structure fitted once over the training recordings,
  its constant re-estimated on each context's last samples (what offsets and gravity add there).
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

# The kinematic bars live with the predictors that stack them (the context backtest): one code, not a copy.
from robomorph.inference.kinematics import KINEMATIC, constant_acceleration, constant_velocity, hold  # noqa: F401

BASELINES = ("hold", "constant_velocity", "constant_acceleration", "arx", "arx_train", "nominal_physics")
# Competitors run only when named (--baselines): each window costs a fit of its own.
OPT_IN = ("identified_physics", "identified_physics_springs", "accel_arx", "accel_arx_train")
# Not a competitor (it reads the parameters the model never sees) but the ceiling of
# physics itself: each robot's own parameters, from the same estimated state. Opt-in.
CEILINGS = ("true_physics",)
# An ARX simulation whose outputs leave this band around the context is called diverged
# and replaced by ``hold``: one exploding trajectory would otherwise swamp every mean.
_ARX_BLOWUP = 1e3


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
    the training data; a simulation leaving the context's band is held, as for ``arx``
    (``band="training"``: the training outputs' band instead, for free runs from a context of a
    few samples, whose own band says nothing).
    """

    na: int = 2
    nb: int = 2
    ridge: float = 1e-8
    band: str = "context"
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
        bounds = _Bounds()
        for u, y in blocks:
            u, y = u.astype(np.float64), y.astype(np.float64)
            bounds.add(y)
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
        self._band = bounds.band()
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
        pred, self.diverged = _held_if_diverged(y_all[:, tc:] * ys + ym, u_ctx, y_ctx.astype(np.float64), u_query,
                                                self._band if self.band == "training" else None)
        return pred


class _Bounds:
    """The per-channel range of training outputs seen block by block."""

    def __init__(self) -> None:
        self.low = self.high = None

    def add(self, y: np.ndarray) -> None:
        low, high = y.min((0, 1)), y.max((0, 1))
        self.low = low if self.low is None else np.minimum(self.low, low)
        self.high = high if self.high is None else np.maximum(self.high, high)

    def band(self) -> tuple[np.ndarray, float]:
        """``(centre (n_y,), half-width)``: the band a free run is judged against."""
        return (self.low + self.high) / 2, float(((self.high - self.low) / 2).max())


def _accel_design(u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Regressors (B, T - 2, R) and targets (B, T - 2, n_y) of the acceleration form: row ``t``
    (``t = 1 .. T - 2``) predicts ``y[t+1] - 2 y[t] + y[t-1]`` from ``u[t]`` (applied from the
    state at ``t``, so it moves ``y[t+1]``), ``u[t] - u[t-1]``, ``y[t] - y[t-1]`` and 1."""
    v = y[:, 1:-1] - y[:, :-2]
    x = np.concatenate([u[:, 1:-1], u[:, 1:-1] - u[:, :-2], v, np.ones(v.shape[:2] + (1,))], axis=-1)
    return x, y[:, 2:] - 2 * y[:, 1:-1] + y[:, :-2]


def _ridge(x: np.ndarray, a: np.ndarray, ridge: float) -> np.ndarray:
    """Per-window ridge solutions (B, R, n_y) of ``a ~ x W``, columns scaled by their std."""
    scale = x.std(1) + 1e-12  # (B, R)
    scale[:, -1] = 1.0  # the constant
    xn = x / scale[:, None]
    gram = np.einsum("btr,bts->brs", xn, xn)
    reg = ridge * np.trace(gram, axis1=1, axis2=2)[:, None, None] / gram.shape[1] * np.eye(gram.shape[1])
    return np.linalg.solve(gram + reg, np.einsum("btr,btn->brn", xn, a)) / scale[:, :, None]


def _accel_rollout(w: np.ndarray, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
    """Free simulation (B, H, n_y) of the acceleration form with per-window weights ``w`` (B, R, n_y)."""
    u = np.concatenate([u_ctx[:, -2:], u_query], axis=1)  # u[c-2], u[c-1], u[c], ...
    y_prev, y_last = y_ctx[:, -2], y_ctx[:, -1]
    ones = np.ones((len(u), 1))
    out = np.empty(y_ctx.shape[:1] + u_query.shape[1:2] + y_ctx.shape[2:])
    for k in range(u_query.shape[1]):
        x = np.concatenate([u[:, k + 1], u[:, k + 1] - u[:, k], y_last - y_prev, ones], axis=1)
        y_prev, y_last = y_last, 2 * y_last - y_prev + np.einsum("br,brn->bn", x, w)
        out[:, k] = y_last
    return out


def _held_if_diverged(pred: np.ndarray, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray,
                      band: tuple[np.ndarray, float] | None = None) -> tuple[np.ndarray, int]:
    """``pred`` with each window that left the context's band (as :class:`ARX` judges it; ``band``:
    ``(centre, half-width)`` of the training outputs instead) held instead, and their count."""
    if band is None:
        centre = y_ctx.mean(1, keepdims=True)
        span = np.abs(y_ctx - centre).max((1, 2)) + 1e-9
    else:
        centre, span = np.asarray(band[0])[None, None], band[1] + 1e-9
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(pred).all((1, 2)) | (np.abs(pred - centre).max((1, 2)) > _ARX_BLOWUP * span)
    pred[bad] = hold(u_ctx, y_ctx, u_query)[bad]
    return pred, int(bad.sum())


@dataclass
class AccelARX:
    """The acceleration-form ARX of ``accel_arx``, fitted on each window's own context.

    The ridge is chosen per window among ``ridges``: each is fitted on the context's first
    ``1 - holdout`` share and scored by simulating the rest freely; the best is refitted on the
    whole context. A simulation leaving the context's band is held and counted, as for ``arx``.
    """

    ridges: tuple[float, ...] = (1e-4, 1e-2, 1e-1, 1.0)
    holdout: float = 0.25
    diverged: int = field(default=0, init=False)

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
        u_ctx, y_ctx, u_query = (np.asarray(a, dtype=np.float64) for a in (u_ctx, y_ctx, u_query))
        c = u_ctx.shape[1]
        split = int(round(c * (1 - self.holdout)))
        n_reg = 2 * u_ctx.shape[-1] + y_ctx.shape[-1] + 1
        if split - 2 < n_reg or c - split < 2:
            raise ValueError(f"accel_arx needs a context of at least {int(np.ceil((n_reg + 4) / (1 - self.holdout)))} "
                             f"steps for {n_reg} coefficients per output, got {c}")
        x_fit, a_fit = _accel_design(u_ctx[:, :split], y_ctx[:, :split])
        errors = []
        for ridge in self.ridges:
            pred = _accel_rollout(_ridge(x_fit, a_fit, ridge), u_ctx[:, :split], y_ctx[:, :split], u_ctx[:, split:])
            with np.errstate(over="ignore", invalid="ignore"):
                err = np.sqrt(((pred - y_ctx[:, split:]) ** 2).mean((1, 2)))
            errors.append(np.where(np.isfinite(err), err, np.inf))
        best = np.asarray(self.ridges)[np.argmin(np.stack(errors), axis=0)]  # (B,)
        x, a = _accel_design(u_ctx, y_ctx)
        w = np.stack([_ridge(x[b:b + 1], a[b:b + 1], r)[0] for b, r in enumerate(best)])
        with np.errstate(over="ignore", invalid="ignore"):
            pred = _accel_rollout(w, u_ctx, y_ctx, u_query)
        pred, self.diverged = _held_if_diverged(pred, u_ctx, y_ctx, u_query)
        return pred


@dataclass
class TrainedAccelARX:
    """The acceleration-form ARX of ``accel_arx_train``: one fit over training trajectories (the
    normal equations accumulated block by block, as :class:`TrainedARX`), then on each window
    its constant moved by the mean residual of the context's last ``bias_steps`` rows."""

    ridge: float = 1e-6
    bias_steps: int = 50
    band: str = "context"  # or "training", as TrainedARX
    diverged: int = field(default=0, init=False)
    trajectories: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self._w: np.ndarray | None = None

    def fit(self, blocks) -> "TrainedAccelARX":
        """Least squares over ``blocks``: an iterable of ``(u (B, T, n_u), y (B, T, n_y))``."""
        gram = rhs = scale = None
        bounds = _Bounds()
        for u, y in blocks:
            bounds.add(np.asarray(y, np.float64))
            x, a = _accel_design(np.asarray(u, np.float64), np.asarray(y, np.float64))
            x, a = x.reshape(-1, x.shape[-1]), a.reshape(-1, a.shape[-1])
            if gram is None:
                scale = x.std(0) + 1e-12
                scale[-1] = 1.0
                gram, rhs = np.zeros((len(scale), len(scale))), np.zeros((len(scale), a.shape[-1]))
            xn = x / scale
            gram += xn.T @ xn
            rhs += xn.T @ a
            self.trajectories += len(u)
        if gram is None:
            raise ValueError("accel_arx_train needs at least one training trajectory")
        gram[np.diag_indices_from(gram)] += self.ridge * np.trace(gram) / len(gram)
        self._w = np.linalg.solve(gram, rhs) / scale[:, None]  # (R, n_y)
        self._band = bounds.band()
        return self

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray) -> np.ndarray:
        if self._w is None:
            raise ValueError("fit accel_arx_train on training data before predicting")
        u_ctx, y_ctx, u_query = (np.asarray(a, dtype=np.float64) for a in (u_ctx, y_ctx, u_query))
        if u_ctx.shape[1] < 3:
            raise ValueError("accel_arx_train needs a context of at least 3 steps")
        x, a = _accel_design(u_ctx, y_ctx)
        w = np.repeat(self._w[None], len(u_ctx), axis=0)
        w[:, -1] += (a - x @ self._w)[:, -self.bias_steps:].mean(1)  # the constant row
        with np.errstate(over="ignore", invalid="ignore"):
            pred = _accel_rollout(w, u_ctx, y_ctx, u_query)
        pred, self.diverged = _held_if_diverged(pred, u_ctx, y_ctx, u_query,
                                                self._band if self.band == "training" else None)
        return pred
