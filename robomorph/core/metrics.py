"""The paper's per-channel scores on arrays shaped (..., T, C), numpy or torch alike.

Each function reduces over the time axis and returns one value per channel (shape
(..., C)):  RMSE;  NRMSE = RMSE / std(y);  R^2 = 1 - SSE / SST;
FIT = 100 (1 - ||y - yhat|| / ||y - mean(y)||).

A flat channel (std(y) below ``eps``) has no defined R^2, FIT or NRMSE. Rather than a
silent NaN or inf, its score is the perfect value when the prediction is exact (RMSE
below ``eps``) and 0 otherwise for R^2 and FIT; NRMSE divides by ``eps`` instead of 0.

Training logs them on tensors and evaluation reports them on arrays, so they live below
both; torch is never imported here (a tensor argument means it is loaded already).
"""

from __future__ import annotations

import sys

import numpy as np

EPS = 1e-8


def _xp(y):
    torch = sys.modules.get("torch")
    return torch if torch is not None and isinstance(y, torch.Tensor) else np


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


METRICS = {"r2": r2, "rmse": rmse, "nrmse": nrmse, "fit": fit_index}
