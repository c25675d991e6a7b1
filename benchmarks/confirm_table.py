"""Markdown tables from the CSVs of ``benchmarks/horizon_ablation.py`` (the README's ablation
and formulation tables): one row per variant and scoring point, beside hold and the catalogue
physics of the same formulation.

    python benchmarks/confirm_table.py results/benchmarks/confirm60_total.csv \\
        results/benchmarks/confirm60_command.csv --out results/benchmarks/confirm60.md
    python benchmarks/confirm_table.py results/benchmarks/confirm60_total.csv \\
        results/benchmarks/confirm60_command.csv --plot results/benchmarks/confirm60_curves.png

``--out`` writes the table as a Markdown result file: its provenance line, the table, and
the provenance of every CSV's rows (command, commit, date, machine). ``--plot`` draws
the per-step joint RMS curves (``<csv stem>_curves.csv`` beside each CSV)
of every predictor on a log scale, one panel per CSV.
"""

from __future__ import annotations

import argparse
import sys

from common import check_outputs

from robomorph.core.errors import run_command
from robomorph.core.results import ResultsError, markdown_table, read_provenance, read_rows, write_markdown

HEAD = ("inputs", "predictor", "2-core min", "steps")
TAIL = ("R²", "FIT", "±1σ / ±2σ coverage", "below hold everywhere (start / random offsets)", "below physics from 0.5 s")


def _steps(row: dict) -> list[int]:
    """The 1-based steps of a CSV's ``model_mrad_step<k>`` columns (step k: k dt after the context)."""
    return sorted(int(c[len("model_mrad_step"):]) for c in row if c.startswith("model_mrad_step"))


def _cells(r: dict, name: str, steps: list[int], prefix: str = "model") -> list[str]:
    if prefix == "hold":  # the hold columns of a model row: hold's own errors, nothing else
        return [r["inputs"], name, "", "", *(r[f"hold_mrad_step{k}"] for k in steps), *[""] * 5]
    cover = f"{r['cover1sigma']} / {r['cover2sigma']}" if r.get("cover1sigma") else ""
    below = f"{r['below_hold_everywhere']} / {r['random_below_hold_everywhere']}" if r.get("below_hold_everywhere") else ""
    return [r["inputs"], name, r["budget_2core_min"], r["steps"], *(r[f"model_mrad_step{k}"] for k in steps),
            r["r2"], r["fit"], cover, below, r.get("below_physics_from_0.5s", "")]


def _rows(path: str) -> list[dict]:
    rows = read_rows(path)
    if rows and not _steps(rows[0]):
        raise ResultsError(f"{path} has no model_mrad_step<k> columns: it was written by an older "
                           "benchmarks/horizon_ablation.py (0-based steps); regenerate it")
    return rows


def table(paths: list[str]) -> str:
    cells, steps = [], None
    for path in paths:
        rows = _rows(path)
        if steps is not None and rows and _steps(rows[0]) != steps:
            raise ResultsError(f"{path} reports other steps ({_steps(rows[0])}) than {paths[0]} ({steps})")
        steps = _steps(rows[0]) if rows else steps
        models = [r for r in rows if not r["variant"].startswith("nominal_physics")]
        cells += [_cells(r, "catalogue physics", steps) for r in rows if r["variant"].startswith("nominal_physics")]
        if models:
            cells.append(_cells(models[-1], "hold", steps, "hold"))
        # Runs on another training store name its size (horizon_ablation's train_robots column).
        cells += [_cells(r, f"`{r['variant']}`" + (f", {r['train_robots']} robots" if r.get("train_robots") else ""),
                         steps) for r in models]
    steps = steps or []
    return markdown_table([*HEAD, *(f"step {k}" for k in steps), *TAIL], cells) + \
        "\n\nJoint-angle RMS over robots and joints [mrad] at each query step (step k is k dt after the last " \
        "context sample; windows from the trajectory start); R² and FIT: approach 1, mean over the outputs.\n"


def sources(paths: list[str]) -> str:
    """Where each CSV's rows came from (its provenance blocks)."""
    lines = ["Rows from:"]
    for path in paths:
        lines += [f"- `{path}`: `{b.get('command')}` at commit `{b.get('commit')}` on {b.get('date')} "
                  f"({b.get('machine')})" for b in read_provenance(path)] or [f"- `{path}`: no provenance recorded"]
    return "\n".join(lines) + "\n"


def plot(paths: list[str], out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(paths), figsize=(6.5 * len(paths), 4.2), sharey=True, squeeze=False)
    for ax, path in zip(axes[0], paths):
        rows = read_rows(path.replace(".csv", "_curves.csv"))
        t = [int(r["step"]) / 60 for r in rows]  # 60 Hz; step k is k dt after the context
        for name in rows[0]:
            if name != "step":
                ax.plot(t, [float(r[name]) for r in rows], label=name.replace("nominal_physics", "catalogue physics"))
        ax.set(yscale="log", xlabel="time into the prediction [s]", title=path.split("/")[-1].replace(".csv", ""))
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    axes[0][0].set_ylabel("joint-angle RMS error [mrad]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("csv", nargs="+")
    p.add_argument("--out", help="write the table to this Markdown file (with provenance) instead of printing it")
    p.add_argument("--plot", help="also draw the per-step curves into this PNG")
    args = p.parse_args(argv)
    check_outputs(out__md=args.out)
    try:
        text = table(args.csv)
        if args.out:
            write_markdown(args.out, text + "\n" + sources(args.csv))
        else:
            print(text, end="")
    except ResultsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    if args.plot:
        plot(args.csv, args.plot)


if __name__ == "__main__":
    sys.exit(run_command(main))
