"""The paper's Tables 1 and 2 from evaluation results: markdown, LaTeX and JSON.

Each writer takes the ``metrics.json`` contents of :func:`robomorph.evaluation.evaluator.evaluate`
and an ``info`` dict (scale, command, date, machine, budgets) for the header, and writes
``<name>.md``, ``<name>.tex`` and ``<name>.json`` into the output folder.
"""

from __future__ import annotations

import math
import os

from robomorph.core.atomic import write_json, write_text
from robomorph.core.normalizations import leaks_query_statistics, normalization_label
from robomorph.core.results import markdown_table
from robomorph.evaluation.fit_bands import FIT_BANDS, LATEX_COLORS, fit_band
from robomorph.reproduction.improved import DESCRIPTION, IMPROVED

TABLE1_COLUMNS = ("r2", "r2_std", "rmse", "rmse_std")
TABLE1_HEADS = ("R²", "σ(R²)", "RMSE", "σ(RMSE)")
REGIME_TITLES = {"zero_shot": "Zero-shot", "finetune": "FT spiral", "scratch": "Scratch"}
# The paper's symbols for the Panda outputs (EE position, EE quaternion, joints).
_TEX_NAMES = {"ee_x": "$x$", "ee_y": "$y$", "ee_z": "$z$", "ee_qx": "$X$", "ee_qy": "$Y$", "ee_qz": "$Z$",
              "ee_qw": "$W$", **{f"q{i}": f"$q_{i}$" for i in range(10)}}


_INPUTS_TEXT = {"total": "total joint torque, the paper's input",
                "command": "the command, without the gravity compensation the arm adds"}


def header_markdown(info: dict, with_normalization: bool = True) -> str:
    """The provenance line every table starts with (naming its input formulation), ending with
    its normalization (flagged in bold when it leaks the query outputs' statistics, as the
    paper's protocol does)."""
    budgets = ", ".join(f"{k} {v}" for k, v in info["budgets"].items() if v is not None)
    elapsed = f" ({info['elapsed_min']} min into the command)" if info.get("elapsed_min") is not None else ""
    inputs = info.get("inputs", "total")  # absent in tables written before the option: total
    line = (f"Scale `{info['scale']}`; inputs `{inputs}` ({_INPUTS_TEXT[inputs]}); command `{info['command']}`; "
            f"{info['date']}{elapsed}; machine: {info['machine']}; budgets: {budgets}.")
    if not with_normalization:
        return line
    norm = info.get("normalization")  # absent in tables written before the option: train_stats
    label = normalization_label(norm)
    return f"{line} **⚠ {label}**" if leaks_query_statistics(norm) else f"{line} {label}"


def _layers(n: int) -> str:
    return f"{n} Layer{'s' if n != 1 else ''}"


def _row_label(row: dict) -> str:
    """``4``, or ``4 (improved)`` for the improved model's rows (rows written before it: the paper's)."""
    return f"{row['n_layer']} (improved)" if row.get("model") == IMPROVED else str(row["n_layer"])


def table1_rows(results: dict[int, dict[str, dict]], model: str = "paper") -> list[dict]:
    """One row per (depth, test store): approach-1 mean and std over trajectories of R² and RMSE.

    Args:
        results: ``{n_layer: {test name: metrics.json content}}``.
        model: ``paper`` (the paper's architecture) or ``improved`` (Table 1's extra row:
            :mod:`robomorph.reproduction.improved`).
    """
    rows = []
    for depth, tests in results.items():
        for test, res in tests.items():
            m = res["approach1"]["mean"]
            hold = res.get("baselines", {}).get("hold")
            rows.append({"n_layer": depth, "model": model, "test": test, "r2": m["r2"]["mean"], "r2_std": m["r2"]["std"],
                         "rmse": m["rmse"]["mean"], "rmse_std": m["rmse"]["std"], "n": res["meta"]["n"],
                         "hold_r2": hold["approach1"]["mean"]["r2"]["mean"] if hold else None})
    return rows


def write_table1(out: str, rows: list[dict], info: dict) -> dict:
    """Writes ``table1.md``, ``table1.tex`` and ``table1.json``; returns the JSON content."""
    doc = {"info": info, "columns": list(TABLE1_COLUMNS), "rows": rows}
    lines = ["# Table 1: impact of the number of layers (in-distribution multi-sine, approach 1)", "",
             header_markdown(info), "",
             markdown_table(["Layers", "Test", *TABLE1_HEADS],
                            [[_row_label(r), r["test"], f"{r['r2']:.3f}", f"{r['r2_std']:.3f}", f"{r['rmse']:.4f}",
                              f"{r['rmse_std']:.4f}"] for r in rows])]
    lines += ["", "R² and RMSE: per trajectory and channel over the horizon, averaged over channels; mean and "
              "standard deviation (σ) over the test trajectories (the paper's first evaluation approach)."]
    holds = [f"{r['test']} {r['hold_r2']:.3f}" for r in rows if r["n_layer"] == rows[0]["n_layer"] and r["hold_r2"] is not None]
    if holds:
        lines.append("For scale: the hold baseline (last context output held) scores R² " + ", ".join(holds) + ".")
    if any(r.get("model") == IMPROVED for r in rows):
        extra = info.get(IMPROVED)
        lines.append(f"Rows marked *improved*: {DESCRIPTION}, same training store, depth and steps as the paper's "
                     "rows; leak-free." + (f" Added by `{extra['command']}` on {extra['date']}." if extra else ""))
    lines += _partial_notes(info)
    write_text(os.path.join(out, "table1.md"), "\n".join(lines) + "\n")
    write_text(os.path.join(out, "table1.tex"), table1_tex(rows, info))
    write_json(os.path.join(out, "table1.json"), doc)
    return doc


def _partial_notes(info: dict) -> list[str]:
    """What a table written before its command finished, or collected from evaluations, lacks."""
    notes = []
    if info.get("pending"):
        notes.append(f"The *{info['pending']}* rows are not here yet: the command was still training them when "
                     "this table was written. Re-run it to add them (finished runs and evaluations are kept).")
    collected = info.get("collected")
    if collected:
        lacking = f" Runs not scored there, so not in this table: {', '.join(collected['missing'])}." \
            if collected["missing"] else ""
        notes.append(f"Collected from the evaluations of the command above by `{collected['command']}` on "
                     f"{collected['date']} (nothing trained or scored again).{lacking}")
    return notes


def table1_tex(rows: list[dict], info: dict) -> str:
    """The paper's tabular: a block per depth, rows test0..test2, columns R², σ, RMSE, σ."""
    lines = [f"% {header_markdown(info)}", r"\begin{table}[!b]", r"\centering", r"\scriptsize",
             r"\begin{tabular}{c|cccc}"]
    for block in dict.fromkeys(_row_label(r) for r in rows):
        first = next(r for r in rows if _row_label(r) == block)
        title = _layers(first["n_layer"]) + (", improved model" if first.get("model") == IMPROVED else "")
        lines += [r"  \hline", rf"\multicolumn{{5}}{{c}}{{\textbf{{{title}}}}} \\", r"  \hline",
                  r"\textbf{TestA} & $R^2$ & $\sigma_{R^2}$ & RMSE & $\sigma_{RMSE}$ \\", r"  \hline"]
        lines += [rf"\textbf{{{r['test']}}} & {r['r2']:.3f} & {r['r2_std']:.3f} & {r['rmse']:.4f} & {r['rmse_std']:.4f} \\"
                  for r in rows if _row_label(r) == block]
    lines += [r"  \hline", r"\end{tabular}",
              rf"\caption{{Impact of the number of layers on prediction accuracies (scale {info['scale']}).}}",
              r"\label{tab:layer_comp}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def table2_data(results: dict[str, dict]) -> dict:
    """Per-channel and mean R² and FIT of each regime: approach 2 in the cells, approach 1 beside.

    The paper scores its OSC tasks, Table 2 included, with the second evaluation approach
    (each channel's test trajectories concatenated): an OSC path leaves some channels of
    some robots nearly flat, and per-trajectory R² on those (approach 1) runs to large
    negative values that swamp the mean. Approach 1 stays in the JSON (``r2_a1``, ``fit_a1``).

    Args:
        results: ``{regime: metrics.json content}`` in column order.
    """
    first = next(iter(results.values()))
    names = list(first["approach2"]["channels"])
    rows = {}
    for ch in [*names, "mean"]:
        rows[ch] = {}
        for regime, res in results.items():
            a1 = res["approach1"]["mean"] if ch == "mean" else res["approach1"]["channels"][ch]
            a2 = res["approach2"]["mean"] if ch == "mean" else res["approach2"]["channels"][ch]
            fit = a2["fit"]
            rows[ch][regime] = {"r2": a2["r2"], "fit": fit, "r2_a1": a1["r2"]["mean"], "fit_a1": a1["fit"]["mean"],
                                "band": fit_band(fit), "mark": FIT_BANDS[fit_band(fit)].mark}
    # Every regime is scored on the same test store, so the hold baseline is the same for all.
    hold = first.get("baselines", {}).get("hold")
    return {"regimes": list(results), "channels": names, "rows": rows, "approach": 2,
            "hold": hold["approach2"]["mean"] if hold else None}


def write_table2(out: str, data: dict, titles: dict[str, str], info: dict) -> dict:
    """Writes ``table2.md``, ``table2.tex`` and ``table2.json``; returns the JSON content.

    Args:
        titles: column title of each regime, e.g. ``{"finetune": "FT spiral (2000 steps)"}``.
    """
    doc = {"info": info, "titles": titles, **data}
    regimes = data["regimes"]
    head = ["Channel"] + [f"{titles[g]} {m}" for g in regimes for m in ("R²", "FIT")]
    lines = ["# Table 2: zero-shot, fine-tuning and training from scratch on the spiral task (approach 2)", "",
             header_markdown(info), "",
             markdown_table(head, [["**mean**" if ch == "mean" else ch,
                                    *(v for g in regimes for v in (f"{cells[g]['r2']:.3f}",
                                                                   f"{cells[g]['mark']} {cells[g]['fit']:.2f}"))]
                                   for ch, cells in data["rows"].items()])]
    legend = ", ".join(f"{b.mark} {b.label}" for b in FIT_BANDS)
    mean = data["rows"]["mean"]
    a1 = "; ".join(f"{titles[g]} R² {mean[g]['r2_a1']:.3g}, FIT {mean[g]['fit_a1']:.3g}" for g in regimes)
    lines += ["", "Per channel: R² and FIT of the spiral test trajectories concatenated channel by channel (the "
              "paper's second evaluation approach, which it uses for OSC tasks); **mean** is the mean over channels. "
              f"FIT colours (the paper's Table 3): {legend}.",
              f"Approach 1 (per trajectory, then mean; dominated by nearly flat channels of OSC paths): {a1}."]
    if data.get("hold"):
        lines.append(f"For scale: the hold baseline (last context output held) scores R² {data['hold']['r2']:.3f}, "
                     f"FIT {data['hold']['fit']:.2f} (approach 2 mean).")
    lines += _partial_notes(info)
    write_text(os.path.join(out, "table2.md"), "\n".join(lines) + "\n")
    write_text(os.path.join(out, "table2.tex"), table2_tex(data, titles, info))
    write_json(os.path.join(out, "table2.json"), doc)
    return doc


def table2_tex(data: dict, titles: dict[str, str], info: dict) -> str:
    """The paper's tabular: both cells of a regime coloured by its FIT band (``\\cellcolor``)."""
    regimes = data["regimes"]
    pre = "\n".join(f"% {line}" for line in LATEX_COLORS.splitlines())
    lines = [f"% {header_markdown(info)}", r"% needs \usepackage{colortbl} and the paper's colours:", pre,
             r"\begin{table}[t!]", r"\tiny", r"\centering", r"\begin{tabular}{c|" + "|".join("cc" for _ in regimes) + "}",
             r"  \hline",
             "& " + " & ".join(_multicol(titles[g], i < len(regimes) - 1) for i, g in enumerate(regimes)) + r" \\",
             r"  \hline", "& " + " & ".join(r"$R^2$ & $Fit\,Index$" for _ in regimes) + r" \\", r"  \hline"]
    for ch, cells in data["rows"].items():
        if ch == "mean":
            lines.append(r"  \hline")
        parts = []
        for g in regimes:
            color = FIT_BANDS[cells[g]["band"]].latex
            parts += [rf"\cellcolor{{{color}}}{_num(cells[g]['r2'], 3)}", rf"\cellcolor{{{color}}}{_num(cells[g]['fit'], 2)}"]
        label = "mean" if ch == "mean" else _TEX_NAMES.get(ch, ch.replace("_", r"\_"))
        lines.append(f"{label} & " + " & ".join(parts) + r" \\")
    lines += [r"  \hline", r"\end{tabular}",
              rf"\caption{{Comparison between zero-shot, fine-tuning on the spiral, and training from scratch "
              rf"(second evaluation approach; scale {info['scale']}).}}", r"\label{tab:comparison}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def _multicol(title: str, vline: bool) -> str:
    return rf"\multicolumn{{2}}{{c}}{{{title}}}" + (r" \vline" if vline else "")


def _num(v: float, digits: int) -> str:
    return f"{v:.{digits}f}" if math.isfinite(v) else "--"

