"""Table 1 under both normalizations beside the paper's figures: ``table1_protocols.md/.json``.

    python -m robomorph.reproduce compare --scale small
    # reads results/paper/small/table1.json (train_stats) and
    #       results/paper/small_paper_window/table1.json (paper_window),
    # writes results/paper/small_paper_window/table1_protocols.md and .json

The paper z-scored each window over context and query (README, section 9). The two
runs compared here train the same models on the same stores with the same budgets and differ
only in that normalization, so the difference between their columns is what the paper's
protocol alone adds to the scores. The paper's own figures (deeper models, far more data, a
GPU) stand in a third column; depths are matched by rank (our shallowest with its 10 layers).
"""

from __future__ import annotations

import json
import os

from robomorph.core.atomic import write_json, write_text
from robomorph.core.errors import RoboMorphError
from robomorph.core.names import NORMALIZATIONS
from robomorph.core.normalizations import leaks_query_statistics, normalization_label
from robomorph.core.results import markdown_table
from robomorph.reproduction.tables import header_markdown

# The paper's Table 1 (tab:layer_comp in paper/robomorph.tex): layers -> test -> (R², σ(R²), RMSE, σ(RMSE)).
PAPER_TABLE1 = {
    10: {"test0": (0.682, 0.343, 0.0530, 0.0236), "test1": (0.750, 0.292, 0.0465, 0.0218),
         "test2": (0.755, 0.293, 0.0458, 0.0212)},
    12: {"test0": (0.713, 0.287, 0.0521, 0.0242), "test1": (0.787, 0.219, 0.0454, 0.0219),
         "test2": (0.793, 0.212, 0.0448, 0.0213)},
    16: {"test0": (0.700, 0.303, 0.0531, 0.0258), "test1": (0.761, 0.262, 0.0468, 0.0239),
         "test2": (0.767, 0.255, 0.0462, 0.0234)},
}
PROTOCOLS = NORMALIZATIONS  # the comparison's two columns: train_stats, then paper_window
FILE = "table1_protocols"


class ComparisonError(RoboMorphError, ValueError):
    """The two Table 1 results cannot be compared (missing, wrong protocol, other rows)."""


def read_table1(folder: str, expected: str, scale: str | None = None) -> dict:
    """``<folder>/table1.json``, checked to have been produced under normalization ``expected``."""
    path = os.path.join(folder, "table1.json")
    if not os.path.isfile(path):
        how = (f" --scale {scale}" if scale else "") + ("" if expected == "train_stats" else " --normalization paper_window")
        raise ComparisonError(f"{path} not found: run `python -m robomorph.reproduce table1{how} --out {folder}` first "
                              "(both protocols at the same scale)")
    with open(path) as f:
        doc = json.load(f)
    # Tables written before the option existed were all train_stats.
    found = doc.get("info", {}).get("normalization") or "train_stats"
    if found != expected:
        raise ComparisonError(f"{path} was produced with normalization {found!r}, expected {expected!r}: "
                              "pass the train_stats folder as --leak-free and the paper_window one as --out")
    return doc


def compare_rows(leak_free: dict, paper_window: dict) -> list[dict]:
    """One row per (depth, test store): R² and RMSE of both protocols and of the paper.

    Raises:
        ComparisonError: the two tables differ in scale, depths or test stores.
    """
    # The paper's architecture only: the leak-free table's extra rows (the improved model) have no
    # paper_window counterpart.
    a = {(r["n_layer"], r["test"]): r for r in leak_free["rows"] if r.get("model", "paper") == "paper"}
    b = {(r["n_layer"], r["test"]): r for r in paper_window["rows"] if r.get("model", "paper") == "paper"}
    scales = (leak_free["info"].get("scale"), paper_window["info"].get("scale"))
    if set(a) != set(b) or scales[0] != scales[1]:
        raise ComparisonError(f"the two Table 1 results differ (scales {scales[0]} / {scales[1]}, rows "
                              f"{sorted(a)} / {sorted(b)}): run both with the same --scale and budgets")
    depths = sorted({d for d, _ in a})
    rank = {d: sorted(PAPER_TABLE1)[i] if len(depths) == len(PAPER_TABLE1) else None for i, d in enumerate(depths)}
    rows = []
    for depth, test in a:
        paper = PAPER_TABLE1.get(rank[depth], {}).get(test)
        row = {"n_layer": depth, "paper_n_layer": rank[depth] if paper else None, "test": test}
        for name, src in zip(PROTOCOLS, (a, b)):
            row[name] = {"r2": src[depth, test]["r2"], "rmse": src[depth, test]["rmse"]}
        row["paper"] = {"r2": paper[0], "rmse": paper[2]} if paper else None
        rows.append(row)
    return rows


def summary(rows: list[dict]) -> dict:
    """Mean R² and RMSE of each column over all rows, and the share of the R² gap between
    ``train_stats`` and the paper that ``paper_window`` closes (None without the paper's column)."""
    def mean(col: str, metric: str) -> float | None:
        vals = [r[col][metric] for r in rows if r.get(col)]
        return sum(vals) / len(vals) if vals and len(vals) == len(rows) else None

    out = {col: {m: mean(col, m) for m in ("r2", "rmse")} for col in (*PROTOCOLS, "paper")}
    ts, pw, pa = out["train_stats"]["r2"], out["paper_window"]["r2"], out["paper"]["r2"]
    out["gap_closed"] = (pw - ts) / (pa - ts) if pa is not None and pa != ts else None
    return out


def _cell(v: float | None, digits: int) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def _rows(doc: dict) -> list[list[str]]:
    """One row per depth and test store, then the mean over all of them."""
    s, rows = doc["summary"], []
    for r in doc["rows"]:
        p = r["paper"] or {}
        rows.append([f"{r['n_layer']} / {r['paper_n_layer'] or '–'}", r["test"], _cell(r["train_stats"]["r2"], 3),
                     _cell(r["paper_window"]["r2"], 3), _cell(p.get("r2"), 3), _cell(r["train_stats"]["rmse"], 4),
                     _cell(r["paper_window"]["rmse"], 4), _cell(p.get("rmse"), 4)])
    rows.append(["**mean**", "all", *(_cell(s[k][m], d) for m, d in (("r2", 3), ("rmse", 4))
                                      for k in ("train_stats", "paper_window", "paper"))])
    return rows


def markdown(doc: dict) -> str:
    """The side-by-side table with both runs' provenance and what the columns mean."""
    s = doc["summary"]
    lines = ["# Table 1 under both normalizations, beside the paper (approach 1)", "",
             f"- train_stats: {header_markdown(doc['train_stats_info'], False)}",
             f"- paper_window: {header_markdown(doc['paper_window_info'], False)}", "",
             f"{normalization_label('train_stats')}", "",
             f"**⚠ {normalization_label('paper_window')}**", "",
             markdown_table(["Layers (ours / paper)", "Test", "R² train_stats", "R² paper_window", "R² paper",
                             "RMSE train_stats", "RMSE paper_window", "RMSE paper"], _rows(doc))]
    lines += ["", "R² and RMSE: approach 1 (per trajectory and channel over the horizon, averaged over channels, "
              "then over test trajectories). Both of our columns train the same models on the same stores with the "
              "same budgets; only the normalization differs. The paper's column is its Table 1 (10 / 12 / 16 "
              "layers, d_model 192, millions of trajectories, a GPU), matched to our depths by rank."]
    if s["gap_closed"] is not None:
        lines.append(f"The paper's normalization alone moves the mean R² from {s['train_stats']['r2']:.3f} to "
                     f"{s['paper_window']['r2']:.3f}: {100 * s['gap_closed']:.0f} % of the distance to the paper's "
                     f"{s['paper']['r2']:.3f}.")
    return "\n".join(lines) + "\n"


def compare(leak_free_dir: str, paper_window_dir: str, out: str | None = None, scale: str | None = None) -> dict:
    """Writes ``table1_protocols.md`` and ``.json`` into ``out`` (default ``paper_window_dir``).

    Raises:
        ComparisonError: a ``table1.json`` is missing, of the other protocol, or of other rows.
    """
    ts, pw = read_table1(leak_free_dir, "train_stats", scale), read_table1(paper_window_dir, "paper_window", scale)
    rows = compare_rows(ts, pw)
    doc = {"train_stats_info": ts["info"], "paper_window_info": pw["info"], "rows": rows, "summary": summary(rows),
           "leaks_query_statistics": {p: leaks_query_statistics(p) for p in PROTOCOLS},
           "sources": {"train_stats": leak_free_dir, "paper_window": paper_window_dir}}
    out = out or paper_window_dir
    os.makedirs(out, exist_ok=True)
    write_text(os.path.join(out, f"{FILE}.md"), markdown(doc))
    write_json(os.path.join(out, f"{FILE}.json"), doc)
    return doc
