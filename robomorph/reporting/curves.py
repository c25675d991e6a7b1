"""The training curves of the report: read from each run's CSV log, drawn in one figure.

Losses are drawn on a log axis when every value is positive and on a linear one otherwise:
a Gaussian negative log-likelihood goes below zero as the model learns, and a log axis
would silently drop exactly those points.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from robomorph.core.names import CURVES

__all__ = ["curves_figure", "plot_curves", "read_curves"]


def read_curves(path: Path) -> tuple[dict[str, tuple[list[float], list[float]]], list[str]]:
    """The (steps, values) of each of :data:`CURVES` in a Lightning CSVLogger file.

    Rows are sparse (each row holds the keys logged at that moment), so a point is kept
    only where both ``step`` and the value are present and finite.

    Returns:
        The curves found, and notes on what is missing or unreadable.
    """
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        rows, header = list(reader), set(reader.fieldnames or ())
    if "step" not in header:
        return {}, [f"{path.name} has no 'step' column; no curves"]
    curves, notes, bad = {}, [], 0
    for key in CURVES:
        if key not in header:
            notes.append(f"{path.name} has no '{key}' column")
            continue
        steps, values = [], []
        for row in rows:
            try:
                step, value = float(row["step"] or "nan"), float(row[key] or "nan")
            except (TypeError, ValueError):
                bad += 1
                continue
            if math.isfinite(step) and math.isfinite(value):
                steps.append(step)
                values.append(value)
        if steps:
            curves[key] = (steps, values)
        else:
            notes.append(f"{path.name}: '{key}' has no values yet")
    if bad:
        notes.append(f"{path.name}: skipped {bad} non-numeric cells")
    return curves, notes


def _scale(values: list[float]) -> str:
    """``log`` for losses that are all positive; ``linear`` as soon as one is not (a Gaussian
    NLL goes negative, and a log axis would silently drop those points)."""
    return "log" if values and min(values) > 0 else "linear"


def curves_figure(runs: list):
    """A matplotlib Figure with a panel per curve in :data:`CURVES` and a line per run (each
    run has ``name`` and ``curves`` as read by :func:`read_curves`), every logged point
    drawn; None without curves."""
    if not any(run.curves for run in runs):
        return None
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0 * len(CURVES), 4.0), layout="constrained")
    axes = fig.subplots(1, len(CURVES))
    colours = colormaps["tab10"]
    for ax, key in zip(axes, CURVES):
        for i, run in enumerate(runs):
            if key in run.curves:
                steps, values = run.curves[key]
                ax.plot(steps, values, color=colours(i % 10), label=run.name, lw=1.4,
                        marker="." if len(steps) < 30 else None)
        if key.endswith("loss"):
            ax.set_yscale(_scale([v for run in runs for v in run.curves.get(key, ((), ()))[1]]))
        elif ax.has_data() and ax.get_ylim()[0] < -1.0 < ax.get_ylim()[1]:
            # Early R² can be hugely negative; clipping keeps the useful range readable.
            ax.set_ylim(bottom=-1.0)
        # Whose: the network's decoder, which a hybrid's physics modes need not read (the page's caption says).
        ax.set(title=f"decoder {key} ({ax.get_yscale()} scale)" if key.endswith("loss") else f"decoder {key}",
               xlabel="step")
        ax.grid(alpha=0.3)
    handles, labels = [], []
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    fig.legend(handles, labels, loc="outside right upper", fontsize="small")
    return fig


def plot_curves(runs: list) -> bytes | None:
    """:func:`curves_figure` as PNG bytes; None without curves."""
    fig = curves_figure(runs)
    if fig is None:
        return None
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()
