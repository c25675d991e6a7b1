"""The paper's two evaluation approaches over the per-channel scores of
:mod:`robomorph.core.metrics`, on (N, T, C) numpy arrays.

Approach 1 also records what a mean over per-trajectory scores hides: a channel that barely moves in a
window (a joint at rest, a quaternion component near its extreme) has an R² and FIT that compare the error
with the channel's noise, and one such window of FIT −1000 rules a mean. Such a window is *quiet*
(:func:`quiet_windows`); approach 1 counts them per channel and gives medians over the windows where the
channel moves, beside the paper's means, which keep every window.
"""

from __future__ import annotations

import numpy as np

from robomorph.core.metrics import METRICS


def approach1_mean(y, yhat, name: str = "r2"):
    """The paper's approach 1, reduced to one number: metric per trajectory and channel,
    mean over channels, then mean over trajectories. y, yhat: (N, T, C)."""
    return METRICS[name](y, yhat).mean(-1).mean(-1)


# A channel is quiet in a window when its standard deviation over the window is within this many times
# its measurement noise's: its motion is no larger than its noise.
QUIET_RATIO = 2.0


def noise_std(y) -> np.ndarray:
    """Each window's measurement noise per channel, (N, T, C) -> (N, C): white noise of std s has second
    differences of std sqrt(6) s, and a motion sampled finely adds little to them. Zero below 3 steps."""
    y = np.asarray(y, dtype=np.float64)
    if y.shape[1] < 3:
        return np.zeros((y.shape[0], y.shape[2]))
    return np.sqrt((np.diff(y, n=2, axis=1) ** 2).mean(1) / 6)


def quiet_windows(y) -> np.ndarray:
    """(N, C) True where a channel's std over the window is within :data:`QUIET_RATIO` times its noise
    (:func:`noise_std`), a flat channel included: its R² and FIT in that window say little of a model."""
    y = np.asarray(y, dtype=np.float64)
    if y.shape[1] < 3:
        return np.zeros((y.shape[0], y.shape[2]), dtype=bool)
    return y.std(1) <= QUIET_RATIO * noise_std(y)


def _median(values: np.ndarray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else None


def approach1(y, yhat, names: list[str]) -> dict:
    """The paper's first evaluation approach, every metric.

    Each metric per trajectory and channel over time; reported per channel as mean and
    std over trajectories, and overall as the mean over channels of each trajectory,
    then mean and std over trajectories (the paper's). Beside them, ``median``: per channel
    over the windows where it moves, overall over the windows of the mean over their moving
    channels (None where there is none), and ``quiet``: per channel, the windows where it
    does not (:func:`quiet_windows`). y, yhat: (N, T, C) numpy arrays.

    Returns:
        ``{"channels": {name: {metric: {"mean", "std", "median"}}}, "mean": {metric: {"mean", "std", "median"}},
        "quiet": {"windows": N, "ratio": QUIET_RATIO, "channels": {name: count}}}``
    """
    _check_names(y, names)
    values = {m: np.asarray(f(y, yhat), dtype=np.float64) for m, f in METRICS.items()}  # (N, C)
    quiet = quiet_windows(y)  # (N, C)
    moving = {m: np.where(quiet, np.nan, v) for m, v in values.items()}
    channels = {name: {m: {"mean": float(v[:, i].mean()), "std": float(v[:, i].std()),
                           "median": _median(moving[m][:, i])} for m, v in values.items()}
                for i, name in enumerate(names)}
    per_window = {m: np.array([row[np.isfinite(row)].mean() if np.isfinite(row).any() else np.nan for row in v])
                  for m, v in moving.items()}  # (N,): each window's mean over its moving channels
    mean = {m: {"mean": float(v.mean(-1).mean()), "std": float(v.mean(-1).std()), "median": _median(per_window[m])}
            for m, v in values.items()}
    return {"channels": channels, "mean": mean,
            "quiet": {"windows": int(y.shape[0]), "ratio": QUIET_RATIO,
                      "channels": {name: int(quiet[:, i].sum()) for i, name in enumerate(names)}}}


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
