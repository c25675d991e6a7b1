"""The paper's two evaluation approaches over the per-channel scores of
:mod:`robomorph.core.metrics`, on (N, T, C) numpy arrays."""

from __future__ import annotations

import numpy as np

from robomorph.core.metrics import METRICS


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
