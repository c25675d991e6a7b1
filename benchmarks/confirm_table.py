"""Markdown tables from the CSVs of ``benchmarks/horizon_ablation.py`` (the README's ablation
and formulation tables): one row per variant and scoring point, beside hold and the catalogue
physics of the same formulation.

    python benchmarks/confirm_table.py results/benchmarks/confirm60_total.csv \\
        results/benchmarks/confirm60_command.csv > results/benchmarks/confirm60.md
    python benchmarks/confirm_table.py results/benchmarks/confirm60_total.csv \\
        results/benchmarks/confirm60_command.csv --plot results/benchmarks/confirm60_curves.png

``--plot`` draws the per-step joint RMS curves (``<csv stem>_curves.csv`` beside each CSV)
of every predictor on a log scale, one panel per CSV.
"""

from __future__ import annotations

import argparse
import csv

STEPS = ("0", "15", "60", "300", "799")
HEAD = ("inputs", "predictor", "2-core min", "steps", "first step", "0.25 s", "1 s", "5 s", "13.3 s",
        "R² (800)", "FIT (800)", "±1σ / ±2σ coverage", "below hold everywhere (start / random offsets)",
        "below physics from 0.5 s")


def _cells(r: dict, name: str, prefix: str = "model") -> list[str]:
    if prefix == "hold":  # the hold columns of a model row: hold's own errors, nothing else
        return [r["inputs"], name, "", "", *(r[f"hold_mrad_{t}"] for t in STEPS), *[""] * 5]
    cover = f"{r['cover1sigma']} / {r['cover2sigma']}" if r.get("cover1sigma") else ""
    below = f"{r['below_hold_everywhere']} / {r['random_below_hold_everywhere']}" if r.get("below_hold_everywhere") else ""
    return [r["inputs"], name, r["budget_2core_min"], r["steps"], *(r[f"model_mrad_{t}"] for t in STEPS),
            r["r2_800"], r["fit_800"], cover, below, r.get("below_physics_from_0.5s", "")]


def table(paths: list[str]) -> str:
    lines = ["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
    for path in paths:
        with open(path) as f:
            rows = list(csv.DictReader(f))
        models = [r for r in rows if not r["variant"].startswith("nominal_physics")]
        for r in rows:
            if r["variant"].startswith("nominal_physics"):
                lines.append("| " + " | ".join(_cells(r, "catalogue physics")) + " |")
        if models:
            lines.append("| " + " | ".join(_cells(models[-1], "hold", "hold")) + " |")
        # Runs on another training store name its size (horizon_ablation's train_robots column).
        lines += ["| " + " | ".join(_cells(r, f"`{r['variant']}`" + (f", {r['train_robots']} robots"
                                                                      if r.get("train_robots") else ""))) + " |"
                  for r in models]
    return "\n".join(lines) + "\n\nJoint-angle RMS over robots and joints [mrad] at each query step (context 200, " \
        "windows from the trajectory start); R² and FIT: approach 1, mean over the 14 outputs.\n"


def plot(paths: list[str], out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(paths), figsize=(6.5 * len(paths), 4.2), sharey=True, squeeze=False)
    for ax, path in zip(axes[0], paths):
        with open(path.replace(".csv", "_curves.csv")) as f:
            rows = list(csv.DictReader(f))
        t = [int(r["step"]) / 60 for r in rows]  # 60 Hz
        for name in rows[0]:
            if name != "step":
                ax.plot(t, [float(r[name]) for r in rows], label=name.replace("nominal_physics", "catalogue physics"))
        ax.set(yscale="log", xlabel="time into the prediction [s]", title=path.split("/")[-1].replace(".csv", ""))
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    axes[0][0].set_ylabel("joint-angle RMS error [mrad]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("csv", nargs="+")
    p.add_argument("--plot", help="also draw the per-step curves into this PNG")
    args = p.parse_args()
    print(table(args.csv), end="")
    if args.plot:
        plot(args.csv, args.plot)


if __name__ == "__main__":
    main()
