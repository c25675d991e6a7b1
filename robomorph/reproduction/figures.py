"""The paper's context and horizon figure: ``context_horizon.png``, ``.json`` and ``.csv``.

Top row: a fixed context (the training one) and shorter predicted horizons, as in the
paper's "different prediction horizons with the same test context" figure. Bottom row:
a fixed predicted window and the last ``c`` context steps only. Left R², right FIT;
solid lines approach 1, dashed approach 2; the hold baseline for reference.
"""

from __future__ import annotations

import csv
import io
import os

from robomorph.core.atomic import write_json, write_text

SWEEPS = (("horizon", "horizon", "prediction horizon [steps] (context fixed)"),
          ("context", "context_len", "context length [steps] (predicted window fixed)"))
METRICS = ("r2", "fit", "r2_a2", "fit_a2")


def sweep_rows(sweeps: dict[str, list[dict]]) -> list[dict]:
    """Long format: one row per sweep, x value and source, with the four scores."""
    rows = []
    for sweep, key, _ in SWEEPS:
        for point in sweeps.get(sweep, []):
            for source, scores in point.items():
                if isinstance(scores, dict):
                    rows.append({"sweep": sweep, "x": point[key], "source": source,
                                 **{m: scores.get(m, float("nan")) for m in METRICS}})
    return rows


def write_context_figure(out: str, sweeps: dict[str, list[dict]], meta: dict, info: dict) -> dict:
    """Writes ``context_horizon.png/.json/.csv`` into ``out``; returns the JSON content.

    Args:
        sweeps: the ``sweeps`` entry of an evaluation's ``metrics.json`` (both sweeps).
        meta: that evaluation's ``meta`` (training window, store, checkpoint).
        info: provenance (scale, command, date, machine, budgets).
    """
    if not sweeps.get("horizon") or not sweeps.get("context"):
        raise ValueError("the context figure needs both sweeps: evaluate with sweep_horizon_spec and sweep_context_spec")
    rows = sweep_rows(sweeps)
    doc = {"info": info, "meta": {k: meta.get(k) for k in ("ckpt", "data", "context_len", "horizon", "n", "normalization")},
           "sweeps": sweeps}
    write_json(os.path.join(out, "context_horizon.json"), doc)
    table = io.StringIO()
    w = csv.DictWriter(table, fieldnames=["sweep", "x", "source", *METRICS])
    w.writeheader()
    w.writerows(rows)
    write_text(os.path.join(out, "context_horizon.csv"), table.getvalue())
    _plot(os.path.join(out, "context_horizon.png"), sweeps, meta, info)
    return doc


def _plot(path: str, sweeps: dict[str, list[dict]], meta: dict, info: dict) -> str:
    from robomorph.evaluation.plots import _STYLE, _plt  # noqa: PLC0415  (matplotlib only when drawing)

    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), squeeze=False)
    for r, (sweep, key, label) in enumerate(SWEEPS):
        points = sweeps[sweep]
        x = [p[key] for p in points]
        sources = [s for s in points[0] if isinstance(points[0][s], dict)]
        trained = meta.get("horizon") if sweep == "horizon" else meta.get("context_len")
        for c, (metric, name, floor, top) in enumerate((("r2", "R²", -1.0, 1.0), ("fit", "FIT [%]", -100.0, 100.0))):
            ax = axes[r][c]
            for src in sources:
                style = dict(_STYLE.get(src, {}))
                for suffix, ls, tag in (("", style.pop("ls", "-"), "approach 1"), ("_a2", "--", "approach 2")):
                    values = [max(p[src].get(metric + suffix, float("nan")), floor) for p in points]
                    ax.plot(x, values, marker="o", ms=3, ls=ls, label=f"{src}, {tag}", **style)
            if trained:
                ax.axvline(trained, color="0.6", lw=0.8, ls=":")
            ax.set(xlabel=label, ylabel=f"mean {name}", ylim=(floor - 0.05 * (top - floor), top + 0.05 * (top - floor)))
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    leak = ("\nnormalization paper_window (the paper's protocol): predictions use the query outputs' statistics"
            if info.get("normalization") == "paper_window" else "")
    fig.suptitle(f"context and horizon (scale {info['scale']}; {meta.get('n')} test trajectories, trained with context "
                 f"{meta.get('context_len')} + horizon {meta.get('horizon')}; scores below the floor drawn on it){leak}",
                 fontsize=9, color="firebrick" if leak else "black")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
