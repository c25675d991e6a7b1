"""``python -m robomorph.inspect``: summarize a RoboMorph dataset and plot a few trajectories.

The summary names the store's channels with their ranges, the generation counts and
rejections, the parameter ranges and the extra arrays. Channel statistics are computed
chunk by chunk over at most ``SAMPLE_ROWS`` trajectories (whole chunks spread evenly over
the store, so the same store always gives the same figures and a 10k-trajectory store is
summarized in about a second); the summary says when it sampled.

``--plot out.png`` writes two images: ``out.png`` with one panel per input and output
channel showing ``--plot-trajectories`` trajectories over time, and ``out_params.png`` with a
histogram of every physical parameter over all trajectories (not written when the store
has no parameters, e.g. one made by ``robomorph.ingest``).
"""

from __future__ import annotations

import json
import math
import os
import warnings

import numpy as np
from matplotlib.figure import Figure

from robomorph.core.atomic import save_figure
from robomorph.core.errors import UsageError
from robomorph.data.store import Dataset, StoreDamagedError
from robomorph.data.units import channel_label, channel_units, literal

SAMPLE_ROWS = 256
# Attributes the summary shows in its own sections; the rest are listed as they are.
_SHOWN = {"schema", "u_names", "y_names", "param_names", "dt", "status", "n", "capacity", "steps",
          "domain", "task", "requested", "attempted", "kept", "rejected", "config"}


def _sample_blocks(n: int, chunk: int, limit: int = SAMPLE_ROWS) -> list[slice]:
    """Row blocks of at most ``limit`` rows in all, chunk-aligned and spread over ``n`` rows."""
    if n <= limit:
        return [slice(s, min(s + chunk, n)) for s in range(0, n, chunk)]
    size = min(chunk, limit)
    starts = np.linspace(0, (n - size) // chunk, math.ceil(limit / size)).round().astype(int) * chunk
    blocks, left = [], limit
    for s in np.unique(starts):
        take = min(size, n - s, left)
        blocks.append(slice(int(s), int(s) + take))
        left -= take
    return blocks


def channel_stats(dataset: Dataset, name: str, blocks: list[slice]) -> np.ndarray:
    """Per-channel ``[min, mean, std, max, non-finite count]`` of a (N, T, C) array.

    Args:
        dataset: the open store.
        name: ``u`` or ``y`` (any array with channels last).
        blocks: the row blocks to read, one at a time so memory stays at one chunk.

    Returns:
        Array of shape (C, 5); NaN statistics for a channel with no finite value.
    """
    width = dataset.group[name].shape[-1]
    lo, hi = np.full(width, np.inf), np.full(width, -np.inf)
    total, sq, count, bad = (np.zeros(width) for _ in range(4))
    for rows in blocks:
        x = dataset.read(name, rows).astype(np.float64).reshape(-1, width)
        ok = np.isfinite(x)
        bad += (~ok).sum(0)
        count += ok.sum(0)
        lo = np.minimum(lo, np.where(ok, x, np.inf).min(0, initial=np.inf))
        hi = np.maximum(hi, np.where(ok, x, -np.inf).max(0, initial=-np.inf))
        x = np.where(ok, x, 0.0)
        total += x.sum(0)
        sq += (x * x).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        std = np.sqrt(np.maximum(sq / count - mean**2, 0.0))
    empty = count == 0
    lo[empty], hi[empty] = np.nan, np.nan
    return np.stack([lo, mean, std, hi, bad], axis=1)


def _table(names: list[str], stats: np.ndarray, cols: tuple[str, ...]) -> list[str]:
    width = max([len(n) for n in names] + [4])
    lines = ["  " + " " * width + "".join(f"{c:>12}" for c in cols)]
    for name, row in zip(names, stats):
        line = f"  {name:<{width}}" + "".join(f"{v:>12.4g}" for v in row[: len(cols)])
        if len(row) > len(cols) and row[len(cols)]:
            line += f"   ({int(row[len(cols)])} non-finite)"
        lines.append(line)
    return lines


def _counts(a: dict) -> list[str]:
    req, att, kept = a.get("requested"), a.get("attempted"), a.get("kept")
    rate = f"{kept / att:.1%}" if isinstance(kept, int) and isinstance(att, int) and att > 0 else "n/a"
    lines = [f"counts:    requested {req}, attempted {att}, kept {kept} (kept rate {rate})"]
    reasons = a.get("rejected") or {}
    rejected = {k: v for k, v in reasons.items() if v}
    if not rejected:
        lines.append("rejected:  none")
    else:
        lines.append(f"rejected:  {sum(rejected.values())} in all")
    for reason, count in sorted(rejected.items(), key=lambda kv: (-kv[1], kv[0])):
        share = f" ({count / att:.1%} of attempts)" if isinstance(att, int) and att > 0 else ""
        lines.append(f"  {reason:<24}{count:>10}{share}")
    idle = sorted(k for k, v in reasons.items() if not v)
    if idle:  # filters that ran but never fired are worth seeing too
        lines.append(f"  no rejections for: {', '.join(idle)}")
    return lines


def _short(value, limit: int = 100) -> str:
    text = json.dumps(value, default=str) if isinstance(value, (dict, list)) else repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _channels(ds: Dataset, sample: int) -> list[str]:
    if ds.n == 0:
        return ["channels:  no valid rows yet"]
    blocks = _sample_blocks(ds.n, ds.chunk, sample)
    used = sum(b.stop - b.start for b in blocks)
    how = "all" if used == ds.n else f"sampled: {used} of {ds.n}, whole chunks spread evenly"
    lines = []
    arrays = [("inputs (total torque)", "u", ds.u_names), ("outputs", "y", ds.y_names)]
    if ds.has_inputs("command"):
        arrays.insert(1, ("inputs (command)", "u_cmd", ds.input_names("command")))
    for kind, name, names in arrays:
        lines.append(f"{kind} {name} over {used} trajectories ({how}):")
        lines += _table(names, channel_stats(ds, name, blocks), ("min", "mean", "std", "max"))
    return lines


def _params(ds: Dataset) -> list[str]:
    if not ds.param_names:
        return ["params:    none (P=0)"]
    if ds.n == 0:
        return [f"params:    {len(ds.param_names)} names, no valid rows yet"]
    p = ds.read("params").astype(np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns stay NaN
        stats = np.stack([np.nanmin(p, 0), np.nanmean(p, 0), np.nanmax(p, 0), (~np.isfinite(p)).sum(0)], 1)
    return [f"params over all {ds.n} trajectories:"] + _table(ds.param_names, stats, ("min", "mean", "max"))


def _unless_damaged(lines, what: str) -> list[str]:
    """``lines()``, or one line saying a damaged chunk (listed above them) stopped the reading."""
    try:
        return lines()
    except StoreDamagedError:
        return [f"{what + ':':<10} not read: a chunk they need is damaged (see 'damaged' above)"]


def summarize(dataset: Dataset, sample: int = SAMPLE_ROWS) -> str:
    """A human-readable summary of a store (see the module docstring).

    Args:
        dataset: a store opened with :func:`robomorph.data.store.open_store`.
        sample: at most this many trajectories feed the channel statistics.

    Returns:
        The summary as multi-line text.
    """
    ds, a = dataset, dataset.attrs
    n_u, n_y, P, T = len(ds.u_names), len(ds.y_names), len(ds.param_names), ds.steps
    lines = [
        f"store:     {ds.path}",
        f"status:    {a.get('status')} ({ds.n} of {a.get('capacity', ds.n)} trajectories valid)",
        f"domain:    {a.get('domain')}    task: {a.get('task')}",
        f"shape:     N={ds.n}  T={T}  n_u={n_u}  n_y={n_y}  P={P}",
        f"time:      dt={ds.dt:g} s, {T * ds.dt:g} s per trajectory ({T} samples)",
        *_counts(a),
        *[f"damaged:   '{name}' chunk {key} (trajectories {first}..{last}) {problem}"
          for name, key, first, last, problem in ds.damaged_chunks()],
        *_unless_damaged(lambda: _channels(ds, sample), "channels"),
        *_unless_damaged(lambda: _params(ds), "params"),
        "extra arrays:" if set(ds.arrays) - {"u", "y", "params"} else "extra arrays: none",
    ]
    for name in ds.arrays:
        if name not in ("u", "y", "params"):
            arr = ds.group[name]
            lines.append(f"  {name:<20}{str(arr.dtype):<10}{tuple(arr.shape)}")
    if "config" in a:
        lines.append(f"config:    {_short(a['config'], 300)}")
    lines += [f"{k + ':':<16} {_short(a[k])}" for k in sorted(a) if k not in _SHOWN]
    return "\n".join(lines)


def _grid(fig: Figure, n_u: int, n_y: int, ncols: int) -> list:
    """Axes for u channels then y channels, each group starting on a new row."""
    rows_u, rows_y = math.ceil(n_u / ncols), math.ceil(n_y / ncols)
    grid = fig.add_gridspec(rows_u + rows_y, ncols)
    axes = []
    for offset, count in ((0, n_u), (rows_u, n_y)):
        for j in range(count):
            axes.append(fig.add_subplot(grid[offset + j // ncols, j % ncols]))
    return axes


def _plot_trajectories(ds: Dataset, path: str, idx: np.ndarray) -> None:
    attrs = ds.attrs
    names = [f"{kind}: {channel_label(n, unit)}" for kind, chans in (("u", ds.u_names), ("y", ds.y_names))
             for n, unit in zip(chans, channel_units(attrs, kind))]
    ncols = min(4, max(len(ds.u_names), len(ds.y_names)))
    rows = math.ceil(len(ds.u_names) / ncols) + math.ceil(len(ds.y_names) / ncols)
    fig = Figure(figsize=(4.2 * ncols, 2.3 * rows + 0.8), layout="constrained")
    data = np.concatenate([ds.read("u", idx), ds.read("y", idx)], axis=2)  # (k, T, n_u + n_y)
    t = np.arange(ds.steps) * ds.dt
    for c, ax in enumerate(_grid(fig, len(ds.u_names), len(ds.y_names), ncols)):
        for k, row in enumerate(idx):
            ax.plot(t, data[k, :, c], lw=0.9, color=f"C{k % 10}", label=f"trajectory {row}")
        ax.set_title(literal(names[c]), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    handles, labels = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper right", ncols=min(len(idx), 6), fontsize=8)
    fig.suptitle(literal(f"{ds.attrs.get('domain')} / {ds.attrs.get('task')}: {len(idx)} of {ds.n} trajectories"),
                 fontsize=11, x=0.02, ha="left")
    fig.supxlabel("time [s]", fontsize=9)
    save_figure(fig, path, dpi=100)


def _plot_params(ds: Dataset, path: str) -> None:
    P = len(ds.param_names)
    ncols = min(P, 6)
    rows = math.ceil(P / ncols)
    fig = Figure(figsize=(2.7 * ncols, 1.9 * rows + 0.6), layout="constrained")
    params = ds.read("params")
    bins = int(np.clip(np.sqrt(ds.n), 5, 40))
    for j, name in enumerate(ds.param_names):
        ax = fig.add_subplot(rows, ncols, j + 1)
        values = params[:, j][np.isfinite(params[:, j])]
        ax.hist(values, bins=bins, color="C0")
        ax.set_title(literal(name), fontsize=8)
        ax.tick_params(labelsize=6)
    fig.suptitle(literal(f"{ds.attrs.get('domain')}: parameters over {ds.n} trajectories"), fontsize=11)
    save_figure(fig, path, dpi=100)


def params_plot_path(path: str) -> str:
    """Where :func:`plot` writes the parameter histograms: ``out.png`` -> ``out_params.png``."""
    root, ext = os.path.splitext(path)
    return f"{root}_params{ext or '.png'}"


def plot(dataset: Dataset, path: str, n_traj: int = 3, seed: int = 0, params: bool = True) -> list[str]:
    """Plots trajectories to ``path`` and parameter histograms to :func:`params_plot_path`.

    Args:
        dataset: the open store.
        path: image for the trajectories (format from the extension, PNG by default).
        n_traj: how many trajectories to draw, chosen at random without replacement.
        seed: seed of that choice, so the same call draws the same trajectories.
        params: draw the histograms too (a Panda's 67 panels take seconds to draw: a caller
            plotting several stores of one randomization draws them once).

    Returns:
        The paths written (the histogram image only when the store has parameters).
    """
    if dataset.n == 0:
        raise UsageError(f"{dataset.path} has no valid trajectories to plot")
    if n_traj < 1:
        raise UsageError(f"--plot-trajectories must be >= 1, got {n_traj}")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(dataset.n, size=min(n_traj, dataset.n), replace=False))
    _plot_trajectories(dataset, path, idx)
    written = [path]
    if params and dataset.param_names:
        _plot_params(dataset, params_plot_path(path))
        written.append(params_plot_path(path))
    return written
