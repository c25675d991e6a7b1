"""Errors by horizon in physical units, and the calibration of a predicted standard deviation.

A model predictive controller asks "how far off is the prediction 0.25 s from now, in
millimetres?", not "what is the R² over 800 steps?". These functions answer that from
arrays shaped (N, H, n_y) (trajectories, query steps, channels), numpy only.

Step convention: step ``k`` (1-based) is the ``k``-th predicted sample, ``k * dt`` after
the last context sample (row ``c + k - 1`` of the trajectory when the context is rows
``0 .. c-1``): the first predicted step is step 1, the end of an 800-step horizon is
step 800, and 0.25 s at dt = 1/60 s is step 15.

Quantities (``Group``): the channels are grouped by what they measure.

- Panda layout (``q0 .. q6``, ``ee_x ee_y ee_z``, ``ee_qx ee_qy ee_qz ee_qw``):
  ``joints`` [mrad], RMS over trajectories and joints of the joint-angle error;
  ``ee_pos`` [mm], RMS over trajectories of the Euclidean distance between the
  predicted and the true end-effector position; ``ee_rot`` [mrad], RMS over trajectories
  of the rotation angle between the predicted and the true orientation (q and -q are
  the same rotation, so the angle is sign-invariant; the predicted quaternion is
  normalized first, since a network's output need not have unit norm).
- Any other channel: one quantity per channel, the RMS over trajectories in the store's
  own units (``y_units`` from the store attributes when it records them).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from robomorph.core.errors import RoboMorphError

DEFAULT_HORIZONS = "1,0.25s,1s,5s,end"
SIGMAS = (1, 2)
# The share of a Gaussian inside ±1σ and ±2σ.
IDEAL = {s: math.erf(s / math.sqrt(2)) for s in SIGMAS}
_POS = ("ee_x", "ee_y", "ee_z")
_QUAT = ("ee_qx", "ee_qy", "ee_qz", "ee_qw")
_JOINT = re.compile(r"q\d+$")


class HorizonError(RoboMorphError, ValueError):
    """A ``--horizons`` specification that cannot be read or lies outside the horizon."""


@dataclass(frozen=True)
class Group:
    """One reported quantity: which channels, how their error is combined, and its unit.

    Attributes:
        name: key in ``metrics.json`` (``joints``, ``ee_pos``, ``ee_rot`` or a channel name).
        channels: indices into the ``y`` channels.
        kind: ``rms`` (mean square over the channels), ``distance`` (Euclidean norm over
            the channels) or ``rotation`` (angle between quaternions).
        unit: the unit of the reported values; scale: factor from the store's units to it.
    """

    name: str
    channels: tuple[int, ...]
    kind: str
    unit: str
    scale: float = 1.0

    @property
    def label(self) -> str:
        return f"{self.name} [{self.unit}]" if self.unit else self.name


def groups_for(y_names: list[str], y_units: list[str] | None = None) -> list[Group]:
    """The quantities reported for a store with channels ``y_names`` (see the module doc)."""
    index = {n: i for i, n in enumerate(y_names)}
    groups = []
    joints = tuple(i for i, n in enumerate(y_names) if _JOINT.match(n))
    if joints:
        groups.append(Group("joints", joints, "rms", "mrad", 1e3))
    if all(n in index for n in _POS):
        groups.append(Group("ee_pos", tuple(index[n] for n in _POS), "distance", "mm", 1e3))
    if all(n in index for n in _QUAT):
        groups.append(Group("ee_rot", tuple(index[n] for n in _QUAT), "rotation", "mrad", 1e3))
    used = {i for g in groups for i in g.channels}
    for i, n in enumerate(y_names):
        if i not in used:
            unit = str(y_units[i]) if y_units is not None and i < len(y_units) else ""
            groups.append(Group(n, (i,), "rms", unit))
    return groups


def quaternion_angle(q_true: np.ndarray, q_pred: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] between two quaternion arrays (..., 4), either sign, either order of parts.

    ``4 atan2(|a - b|, |a + b|)`` with ``b`` flipped onto ``a``'s hemisphere: the angle
    between unit 4-vectors doubled, accurate for tiny and large angles alike (an
    ``arccos`` of the dot product loses half its digits near zero).
    """
    a = q_true / np.maximum(np.linalg.norm(q_true, axis=-1, keepdims=True), 1e-12)
    b = q_pred / np.maximum(np.linalg.norm(q_pred, axis=-1, keepdims=True), 1e-12)
    b = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    return 4.0 * np.arctan2(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))


def squared_error(y: np.ndarray, yhat: np.ndarray, group: Group) -> np.ndarray:
    """(N, H) squared error of ``group`` per trajectory and step, in the store's units."""
    idx = list(group.channels)
    err = yhat[..., idx] - y[..., idx]
    if group.kind == "rms":
        return (err**2).mean(-1)
    if group.kind == "distance":
        return (err**2).sum(-1)
    if group.kind == "rotation":
        return quaternion_angle(y[..., idx], yhat[..., idx]) ** 2
    raise ValueError(f"unknown group kind {group.kind!r}")


def error_curve(y: np.ndarray, yhat: np.ndarray, group: Group) -> np.ndarray:
    """(H,) RMS over trajectories at every step, in ``group.unit``."""
    return np.sqrt(squared_error(y, yhat, group).mean(0)) * group.scale


def parse_horizons(spec: str | None, horizon: int, dt: float) -> list[int]:
    """Reads ``--horizons`` into sorted, distinct 1-based steps within ``[1, horizon]``.

    Items, comma-separated: an integer is a step (``1`` = the first predicted step), a
    number with ``s`` is seconds (rounded to the nearest step, at least 1), ``end`` is the
    last step. ``None`` or empty means :data:`DEFAULT_HORIZONS`, whose items beyond a
    short horizon are dropped; items given explicitly must fit.

    Raises:
        HorizonError: an unreadable item, or an explicit one beyond the horizon.
    """
    explicit = bool(spec and spec.strip())
    steps = set()
    for item in (spec if explicit else DEFAULT_HORIZONS).split(","):
        item = item.strip().lower()
        try:
            if item == "end":
                k = horizon
            elif item.endswith("s"):
                seconds = float(item[:-1])
                if not 0 < seconds < float("inf"):  # 0s is no step, as 0 is none; a tiny time is the first
                    raise HorizonError(f"--horizons item {item!r}: seconds must be finite and > 0 (0.25s is "
                                       "0.25 s after the last context sample)")
                k = max(1, int(round(seconds / dt)))
            else:
                k = int(item)
        except HorizonError:
            raise
        except ValueError:
            raise HorizonError(f"--horizons items are steps (15), seconds (0.25s) or 'end', got {item!r}") from None
        if not 1 <= k <= horizon:
            if explicit:
                raise HorizonError(f"--horizons item {item!r} is step {k}, outside the evaluated horizon of "
                                   f"{horizon} steps ({horizon * dt:.3g} s): pass a shorter one or a longer --horizon")
            continue
        steps.add(k)
    return sorted(steps)


def coverage(y: np.ndarray, mean: np.ndarray, std: np.ndarray, steps: list[int],
             channels: tuple[int, ...] | None = None) -> dict[str, list[float]]:
    """Fraction of true values inside ``mean ± k std`` at each step, over trajectories and channels.

    Returns:
        ``{"1sigma": [...], "2sigma": [...]}``, one fraction per step of ``steps`` (1-based).
    """
    idx = [k - 1 for k in steps]
    cols = list(range(y.shape[-1])) if channels is None else list(channels)
    z = np.abs(y[:, idx][..., cols] - mean[:, idx][..., cols]) / np.maximum(std[:, idx][..., cols], 1e-300)
    return {f"{s}sigma": (z <= s).mean(axis=(0, 2)).tolist() for s in SIGMAS}


def coverage_miss(y: np.ndarray, mean: np.ndarray, std: np.ndarray,
                  channels: tuple[int, ...] | None = None) -> dict[str, float]:
    """Mean absolute distance of the ±1σ / ±2σ coverage from its Gaussian ideal over all steps.

    Returns:
        ``{"1sigma": ..., "2sigma": ...}`` in fractions (0.05: five percentage points off on average).
    """
    cover = coverage(y, mean, std, list(range(1, y.shape[1] + 1)), channels)
    return {f"{s}sigma": float(np.abs(np.asarray(cover[f"{s}sigma"]) - IDEAL[s]).mean()) for s in SIGMAS}


def spread_skill(y: np.ndarray, mean: np.ndarray, std: np.ndarray, steps) -> list[float | None]:
    """At each 1-based step of ``steps``, how well the spread orders the windows by their errors: the
    rank correlation across windows between ``std`` and ``|y - mean|`` (each (N, H, n_y)), the median
    over the channels (1: the larger spread always has the larger error; 0: no better than one spread
    for all windows; None where every channel's spread, or error, is the same in every window).

    A calibration scales every window's spread at a step alike, so it cannot raise a low skill: the
    windows whose spread was too small for their errors stay so and show as heavy tails, and then
    no scale puts both ±1σ and ±2σ near a Gaussian's shares (the power of ``robomorph calibrate``'s
    ``power`` method helps only as far as the spread's ranking is right)."""
    def ranks(a: np.ndarray) -> np.ndarray:
        return np.argsort(np.argsort(a, axis=0), axis=0).astype(np.float64)

    out = []
    for s in steps:
        e, sd = np.abs(np.asarray(y)[:, s - 1] - np.asarray(mean)[:, s - 1]), np.asarray(std)[:, s - 1]
        re, rs = ranks(e), ranks(sd)
        re, rs = re - re.mean(0), rs - rs.mean(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = (re * rs).sum(0) / np.sqrt((re ** 2).sum(0) * (rs ** 2).sum(0))
        # A channel whose spread (or error) is the same in every window says nothing: left out.
        corr = corr[np.isfinite(corr) & (sd.std(0) > 0) & (e.std(0) > 0)]
        out.append(float(np.median(corr)) if len(corr) else None)  # None: JSON's "no figure" (NaN is not JSON)
    return out


def gaussian_nll(y: np.ndarray, mean: np.ndarray, std: np.ndarray, channels: tuple[int, ...] | None = None) -> float:
    """Mean Gaussian negative log-likelihood per value [nats] of ``y`` under ``N(mean, std²)``.

    It depends on the units of the channels (a std in metres against one in millimetres), so
    compare it only between predictions of the same windows.
    """
    cols = list(range(y.shape[-1])) if channels is None else list(channels)
    s = np.maximum(std[..., cols], 1e-300)
    z = (y[..., cols] - mean[..., cols]) / s
    return float(np.mean(0.5 * np.log(2 * np.pi) + np.log(s) + 0.5 * z**2))


def horizon_report(y: np.ndarray, preds: dict[str, np.ndarray], y_names: list[str], dt: float,
                   steps: list[int], std: np.ndarray | None = None, y_units: list[str] | None = None) -> dict:
    """The ``horizons`` entry of ``metrics.json``: RMS errors per source, quantity and step.

    Args:
        y: (N, H, n_y) true outputs; preds: source name -> (N, H, n_y) predictions.
        steps: 1-based steps (:func:`parse_horizons`).
        std: (N, H, n_y) the model's predicted standard deviation, when it gives one; then
            ``calibration`` holds its ±1σ / ±2σ coverage per step (all channels, and per quantity),
            and ``skill`` how well it ranks the trajectories by their errors (:func:`spread_skill`).

    With ``model`` among ``preds``, ``below`` says for every other source and quantity over
    which share of all H steps the model's error is below that source's (:func:`below`).
    """
    groups = groups_for(y_names, y_units)
    idx = [k - 1 for k in steps]
    out = {"steps": list(steps), "seconds": [k * dt for k in steps], "horizon": int(y.shape[1]),
           "quantities": {g.name: {"unit": g.unit, "channels": [y_names[i] for i in g.channels], "kind": g.kind}
                          for g in groups},
           "rms": {src: {g.name: error_curve(y, p, g)[idx].tolist() for g in groups} for src, p in preds.items()}}
    if "model" in preds and len(preds) > 1:
        out["below"] = {src: {g.name: below(y, preds["model"], p, g) for g in groups}
                        for src, p in preds.items() if src != "model"}
    if std is not None:
        out["calibration"] = {"all": coverage(y, preds["model"], std, steps),
                              **{g.name: coverage(y, preds["model"], std, steps, g.channels) for g in groups}}
        out["skill"] = {"all": spread_skill(y, preds["model"], std, steps),
                        **{g.name: spread_skill(y[..., list(g.channels)], preds["model"][..., list(g.channels)],
                                                std[..., list(g.channels)], steps) for g in groups}}
    return out


def below(y: np.ndarray, model: np.ndarray, other: np.ndarray, group: Group) -> dict:
    """Where over the whole horizon the model's RMS error is below that of another source.

    Returns:
        ``fraction``: of all steps; ``first_not_below``: the first 1-based step where it is
        not (None when it is below at every step).
    """
    is_below = error_curve(y, model, group) < error_curve(y, other, group)
    worse = np.flatnonzero(~is_below)
    return {"fraction": float(is_below.mean()), "first_not_below": int(worse[0]) + 1 if len(worse) else None}


def _percent(fraction: float) -> str:
    """A share in percent that reads 100 only when it is all of the steps (799 of 800 is 99.9)."""
    text = f"{100 * fraction:.0f}"
    return f"{100 * fraction:.1f}" if text in ("0", "100") and 0 < fraction < 1 else text


def horizon_markdown(h: dict, sources: tuple[str, ...] | None = None) -> str:
    """A markdown table (rows: quantity and source; columns: steps) of a :func:`horizon_report`,
    then the coverage of the model's ±1σ/±2σ bands and the shares of steps below each baseline."""
    from robomorph.core.results import markdown_table  # noqa: PLC0415

    names = [s for s in (sources or tuple(h["rms"])) if s in h["rms"]]
    cols = [f"step {k} ({t:.3g} s)" for k, t in zip(h["steps"], h["seconds"])]
    rows = []
    for q, info in h["quantities"].items():
        label = f"{q} [{info['unit']}]" if info["unit"] else q
        rows += [[label, src, *(f"{v:.4g}" for v in h["rms"][src][q])] for src in names]
    cal = h.get("calibration") or {}
    # All outputs, then the joints alone where there are others (goals are stated for the joints).
    parts = [("all", "")] + ([("joints", ", joints")] if "joints" in cal and len(h["quantities"]) > 1 else [])
    for part, suffix in parts if "all" in cal else []:
        rows += [[f"inside ±{s}σ [%]{suffix}", "model", *(f"{100 * v:.1f}" for v in cal[part][f"{s}sigma"])]
                 for s in SIGMAS]
    if h.get("skill"):  # metrics.json files written before it have none
        rows.append(["std-error rank corr.", "model", *("" if v is None else f"{v:.2f}" for v in h["skill"]["all"])])
    lines = [markdown_table(["quantity", "source", *cols], rows, align=["left", "left", *["right"] * len(cols)])]
    for src, by_q in h.get("below", {}).items():
        if src not in names:
            continue
        parts = [f"{q} {_percent(b['fraction'])} %" + (f" (first step not below: {b['first_not_below']})"
                                                       if b["first_not_below"] else "") for q, b in by_q.items()]
        lines += ["", f"Share of the {h.get('horizon', '')} predicted steps where the model's RMS error is below "
                  f"{src}'s: " + "; ".join(parts)]
    return "\n".join(lines) + "\n"
