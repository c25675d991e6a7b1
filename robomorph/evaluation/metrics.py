"""The paper's per-channel metrics on arrays shaped (..., T, C), numpy or torch alike.

Each function reduces over the time axis and returns one value per channel (shape
(..., C)):  RMSE;  NRMSE = RMSE / std(y);  R^2 = 1 - SSE / SST;
FIT = 100 (1 - ||y - yhat|| / ||y - mean(y)||).

A flat channel (std(y) below ``eps``) has no defined R^2, FIT or NRMSE. Rather than a
silent NaN or inf, its score is the perfect value when the prediction is exact (RMSE
below ``eps``) and 0 otherwise for R^2 and FIT; NRMSE divides by ``eps`` instead of 0.
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.core.names import FIT, NRMSE, R2, RMSE
from robomorph.evaluation.fit_bands import FIT_BANDS, fit_band  # noqa: F401  (re-exported)

EPS = 1e-8


def _xp(y):
    return torch if isinstance(y, torch.Tensor) else np


def _parts(y, yhat):
    xp = _xp(y)
    if y.shape != yhat.shape:
        raise ValueError(f"y and yhat shapes differ: {tuple(y.shape)} vs {tuple(yhat.shape)}")
    err = y - yhat
    sse = (err**2).sum(-2)
    centred = y - y.mean(-2, keepdims=True) if xp is np else y - y.mean(-2, keepdim=True)
    sst = (centred**2).sum(-2)
    return xp, sse, sst, y.shape[-2]


def rmse(y, yhat):
    """Root mean squared error per channel."""
    xp, sse, _, t = _parts(y, yhat)
    return xp.sqrt(sse / t)


def nrmse(y, yhat, eps: float = EPS):
    """RMSE divided by the standard deviation of y, per channel."""
    xp, sse, sst, t = _parts(y, yhat)
    std = xp.sqrt(sst / t)
    return xp.sqrt(sse / t) / (xp.clip(std, eps, None) if xp is np else std.clamp_min(eps))


def _flat_safe(xp, score, sse, sst, t, eps, perfect):
    flat = sst / t < eps**2
    exact = sse / t < eps**2
    fallback = xp.where(exact, xp.ones_like(score) * perfect, xp.zeros_like(score))
    return xp.where(flat, fallback, score)


def r2(y, yhat, eps: float = EPS):
    """Coefficient of determination per channel."""
    xp, sse, sst, t = _parts(y, yhat)
    safe = xp.where(sst > 0, sst, xp.ones_like(sst))
    return _flat_safe(xp, 1 - sse / safe, sse, sst, t, eps, 1.0)


def fit_index(y, yhat, eps: float = EPS):
    """FIT = 100 (1 - ||y - yhat|| / ||y - mean y||) per channel."""
    xp, sse, sst, t = _parts(y, yhat)
    safe = xp.where(sst > 0, sst, xp.ones_like(sst))
    return _flat_safe(xp, 100 * (1 - xp.sqrt(sse) / xp.sqrt(safe)), sse, sst, t, eps, 100.0)


METRICS = {R2: r2, RMSE: rmse, NRMSE: nrmse, FIT: fit_index}  # in the order of names.METRICS


def approach1_mean(y, yhat, name: str = "r2"):
    """The paper's approach 1, reduced to one number: metric per trajectory and channel,
    mean over channels, then mean over trajectories. y, yhat: (N, T, C)."""
    return METRICS[name](y, yhat).mean(-1).mean(-1)


def approach1(y, yhat, names: list[str]) -> dict:
    """The paper's first evaluation approach, every metric.

    Each metric per trajectory and channel over time; reported per channel as mean and
    std over trajectories, and overall as the mean over channels of each trajectory,
    then mean and std over trajectories. y, yhat: (N, T, C) numpy arrays.

    Returns:
        ``{"channels": {name: {metric: {"mean", "std"}}}, "mean": {metric: {"mean", "std"}}}``
    """
    _check_names(y, names)
    values = {m: np.asarray(f(y, yhat), dtype=np.float64) for m, f in METRICS.items()}  # (N, C)
    channels = {name: {m: {"mean": float(v[:, i].mean()), "std": float(v[:, i].std())} for m, v in values.items()}
                for i, name in enumerate(names)}
    mean = {m: {"mean": float(v.mean(-1).mean()), "std": float(v.mean(-1).std())} for m, v in values.items()}
    return {"channels": channels, "mean": mean}


def approach2(y, yhat, names: list[str]) -> dict:
    """The paper's second approach: each channel's trajectories concatenated in time,
    then one value per channel (and their mean over channels).

    Returns:
        ``{"channels": {name: {metric: value}}, "mean": {metric: value}}``
    """
    _check_names(y, names)
    flat_y, flat_hat = y.reshape(1, -1, y.shape[-1]), yhat.reshape(1, -1, yhat.shape[-1])
    values = {m: np.asarray(f(flat_y, flat_hat), dtype=np.float64)[0] for m, f in METRICS.items()}  # (C,)
    return {"channels": {name: {m: float(v[i]) for m, v in values.items()} for i, name in enumerate(names)},
            "mean": {m: float(v.mean()) for m, v in values.items()}}


def _check_names(y, names: list[str]) -> None:
    if y.ndim != 3 or y.shape[-1] != len(names):
        raise ValueError(f"expected y shaped (N, T, {len(names)}) for channels {names}, got {tuple(y.shape)}")
