"""The figures ``robomorph.evaluate`` writes: samples (with the model's ±σ bands when it
gives a standard deviation), error growth in physical units, R^2 spread, sweeps.

Every function takes arrays in physical units (predictions keyed by source: ``model``
and the baselines) and writes one PNG, returning its path.
"""

from __future__ import annotations

import os

import numpy as np

from robomorph.core import metrics
from robomorph.core.atomic import save_figure
from robomorph.data.units import channel_label, literal
from robomorph.evaluation import horizons

_STYLE = {"model": dict(color="C0", lw=1.4), "hold": dict(color="C7", ls=":"),
          "arx": dict(color="C2", ls="--", lw=1.0), "arx_train": dict(color="C1", ls="--", lw=1.0),
          "nominal_physics": dict(color="C3", ls="-.", lw=1.0),
          "identified_physics": dict(color="C5", ls="-.", lw=1.0),
          "identified_physics_springs": dict(color="C6", ls="-.", lw=1.0),
          "true_physics": dict(color="C4", ls=(0, (1, 1)), lw=1.0)}


def _plt():
    import matplotlib  # noqa: PLC0415  (plotting is optional at import time)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _grid(n: int) -> tuple[int, int]:
    cols = min(4, n)
    return (n + cols - 1) // cols, cols


def plot_samples(path: str, y_ctx: np.ndarray, y_true: np.ndarray, preds: dict[str, np.ndarray],
                 names: list[str], dt: float, index: int, std: np.ndarray | None = None) -> str:
    """Context, truth and every source's prediction of trajectory ``index``, all channels.

    With ``std`` (the model's predicted standard deviation, same shape as its prediction)
    the model's ±1σ and ±2σ bands are shaded around its mean.
    """
    plt = _plt()
    rows, cols = _grid(len(names))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.2 * rows), sharex=True, squeeze=False)
    tc, th = y_ctx.shape[1], y_true.shape[1]
    t_ctx, t_q = np.arange(tc) * dt, (tc + np.arange(th)) * dt
    for i, (ax, name) in enumerate(zip(axes.flat, names)):
        ax.axvspan(0, tc * dt, color="0.92", lw=0)
        ax.plot(t_ctx, y_ctx[index, :, i], color="k", lw=1.0)
        ax.plot(t_q, y_true[index, :, i], color="k", lw=1.0, label="truth")
        if std is not None and "model" in preds:
            mean, sd = preds["model"][index, :, i], std[index, :, i]
            for k, alpha in ((2, 0.12), (1, 0.25)):
                ax.fill_between(t_q, mean - k * sd, mean + k * sd, color=_STYLE["model"]["color"], alpha=alpha, lw=0,
                                label=f"model ±{k}σ")
        for src, y in preds.items():
            ax.plot(t_q, y[index, :, i], label=literal(src), **_STYLE.get(src, {}))
        ax.set_title(literal(name), fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.supxlabel("time [s] (grey: context)", fontsize=9)
    fig.suptitle(f"trajectory {index}", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return path


def plot_error_growth(path: str, y_true: np.ndarray, preds: dict[str, np.ndarray], dt: float,
                      names: list[str], steps: list[int] = (), y_units: list[str] | None = None) -> str:
    """RMS error over trajectories against time into the horizon, in physical units, log-log.

    One panel per quantity of :func:`robomorph.evaluation.horizons.groups_for` (for the
    Panda: joints [mrad], end-effector position [mm] and orientation [mrad]); dotted
    vertical lines mark the reported ``steps``.
    """
    plt = _plt()
    groups = horizons.groups_for(names, y_units)
    cols = min(3, len(groups))
    rows = (len(groups) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    t = np.arange(1, y_true.shape[1] + 1) * dt
    for ax, g in zip(axes.flat, groups):
        for src, y in preds.items():
            ax.plot(t, np.maximum(horizons.error_curve(y_true, y, g), 1e-12), label=literal(src), **_STYLE.get(src, {}))
        for k in steps:
            ax.axvline(k * dt, color="0.6", ls=":", lw=0.8)
        # Log time too: the first second, what a controller uses, would be a sliver otherwise.
        ax.set(xlabel="time into the horizon [s]", ylabel=f"RMS error [{literal(g.unit)}]" if g.unit else "RMS error",
               xscale="log", yscale="log", title=literal(g.label))
        ax.grid(alpha=0.3, which="both")
    for ax in list(axes.flat)[len(groups):]:
        ax.axis("off")
    fig.suptitle("error growth over the prediction horizon (RMS over trajectories)", fontsize=10)
    if len(preds) > 8:  # a legend that long hides the curves: beside the panels instead
        axes.flat[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        fig.tight_layout()
        save_figure(fig, path, dpi=100, bbox_inches="tight")
    else:
        axes.flat[0].legend(fontsize=8)
        fig.tight_layout()
        save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path


def plot_r2_distribution(path: str, y_true: np.ndarray, preds: dict[str, np.ndarray], names: list[str]) -> str:
    """Per-channel spread of per-trajectory R^2 (approach 1) for every source, clipped at -1."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(7.0, 0.8 * len(names) * max(1, len(preds)) / 2), 4))
    width = 0.8 / len(preds)
    for k, (src, y) in enumerate(preds.items()):
        r2 = np.clip(np.asarray(metrics.r2(y_true, y)), -1.0, 1.0)  # (N, C)
        pos = np.arange(len(names)) + (k - (len(preds) - 1) / 2) * width
        box = ax.boxplot(r2, positions=pos, widths=width * 0.9, showfliers=False, patch_artist=True)
        color = _STYLE.get(src, {}).get("color", f"C{k}")
        for b in box["boxes"]:
            b.set(facecolor=color, alpha=0.5)
        ax.plot([], [], color=color, lw=6, alpha=0.5, label=literal(src))
    ax.set_xticks(np.arange(len(names)), [literal(n) for n in names], rotation=45, fontsize=8)
    ax.set(ylabel="R² per trajectory (clipped at -1)", ylim=(-1.05, 1.05), title="R² distribution per channel")
    ax.axhline(0, color="0.5", lw=0.6)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path


def plot_sweep(path: str, rows: list[dict], key: str) -> str:
    """Mean R^2 and FIT, approaches 1 and 2, against ``key`` (``horizon`` or ``context_len``).

    R^2 is drawn from -1 and FIT from -100 up: far worse values (a baseline that drifts
    away) sit on the floor instead of squashing every other curve into a line.
    """
    plt = _plt()
    x = [r[key] for r in rows]
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.4))
    sources = [s for s in rows[0] if isinstance(rows[0][s], dict)]
    panels = (("r2", "mean R² (approach 1)", -1.0), ("fit", "mean FIT % (approach 1)", -100.0),
              ("r2_a2", "R² (approach 2)", -1.0), ("fit_a2", "FIT % (approach 2)", -100.0))
    for ax, (metric, label, floor) in zip(axes, panels):
        for src in sources:
            values = np.maximum([r[src].get(metric, np.nan) for r in rows], floor)
            ax.plot(x, values, marker="o", ms=3, label=literal(src), **_STYLE.get(src, {}))
        top = 1.0 if metric.startswith("r2") else 100.0
        ax.set(xlabel="prediction horizon [steps]" if key == "horizon" else "context length [steps]",
               ylabel=label, ylim=(floor - 0.05 * (top - floor), top + 0.05 * (top - floor)))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path


def write_all(out: str, y_ctx: np.ndarray, y_true: np.ndarray, preds: dict[str, np.ndarray],
              names: list[str], dt: float, samples: int, seed: int = 0, std: np.ndarray | None = None,
              steps: list[int] = (), y_units: list[str] | None = None) -> list[str]:
    """The standard set: ``samples`` sample trajectories, error growth, R^2 distribution."""
    rng = np.random.default_rng(seed)
    picks = sorted(rng.choice(len(y_true), size=min(samples, len(y_true)), replace=False).tolist())
    # Panel titles carry the store's units ("q1 [rad]") where it records them.
    labels = [channel_label(n, u) for n, u in zip(names, y_units)] if y_units else names
    paths = [plot_samples(os.path.join(out, f"sample_{i}.png"), y_ctx, y_true, preds, labels, dt, i, std) for i in picks]
    paths.append(plot_error_growth(os.path.join(out, "error_growth.png"), y_true, preds, dt, names, steps, y_units))
    paths.append(plot_r2_distribution(os.path.join(out, "r2_distribution.png"), y_true, preds, labels))
    return paths
