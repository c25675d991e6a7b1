"""The paper's Tables 1 and 2 from evaluation results: rows, columns, colours, files."""

import json

import numpy as np

from robomorph.evaluation import metrics
from robomorph.evaluation.fit_bands import FIT_BANDS
from robomorph.reproduction.tables import table1_rows, table2_data, write_table1, write_table2

NAMES = ["ee_x", "q0"]
INFO = {"scale": "ci", "command": "python -m robomorph.reproduce all --scale ci", "date": "2026-01-01 00:00 UTC",
        "elapsed_min": 1.5, "machine": "test", "budgets": {"table1_steps_per_depth": 10, "max_time": None}}


def _result(noise, seed=0):
    rng = np.random.default_rng(seed)
    y = rng.normal(size=(5, 30, 2))
    yhat, hold = y + noise * rng.normal(size=y.shape), np.repeat(y[:, :1], 30, axis=1)
    return {"approach1": metrics.approach1(y, yhat, NAMES), "approach2": metrics.approach2(y, yhat, NAMES),
            "baselines": {"hold": {"approach1": metrics.approach1(y, hold, NAMES),
                                   "approach2": metrics.approach2(y, hold, NAMES)}},
            "meta": {"n": 5}}


def test_table1_has_a_row_per_depth_and_test_store(tmp_path):
    results = {d: {t: _result(0.1 * d, seed=i) for i, t in enumerate(("test0", "test1"))} for d in (1, 2)}
    rows = table1_rows(results)
    assert [(r["n_layer"], r["test"]) for r in rows] == [(1, "test0"), (1, "test1"), (2, "test0"), (2, "test1")]
    assert rows[0]["r2"] == results[1]["test0"]["approach1"]["mean"]["r2"]["mean"]
    doc = write_table1(str(tmp_path), rows, INFO)
    assert json.loads((tmp_path / "table1.json").read_text()) == json.loads(json.dumps(doc))
    md = (tmp_path / "table1.md").read_text()
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in md.splitlines() if ln.startswith("|")]
    assert ["2", "test1"] == rows[-1][:2] and "1.5 min into the command" in md
    assert (tmp_path / "table1.tex").read_text().count(r"\textbf{test0}") == 2


def test_table2_scores_by_approach_2_with_the_papers_colours(tmp_path):
    results = {"zero_shot": _result(1.0), "finetune": _result(0.3), "scratch": _result(0.05)}
    data = table2_data(results)
    assert data["regimes"] == ["zero_shot", "finetune", "scratch"] and data["channels"] == NAMES
    cell = data["rows"]["q0"]["scratch"]
    assert cell["fit"] == results["scratch"]["approach2"]["channels"]["q0"]["fit"]
    assert cell["mark"] == FIT_BANDS[cell["band"]].mark and cell["fit"] > data["rows"]["q0"]["zero_shot"]["fit"]
    titles = {"zero_shot": "Zero-shot", "finetune": "FT spiral (10 steps)", "scratch": "Scratch (10 steps)"}
    write_table2(str(tmp_path), data, titles, INFO)
    md = (tmp_path / "table2.md").read_text()
    assert "FT spiral (10 steps)" in md and cell["mark"] in md
    assert r"\cellcolor" in (tmp_path / "table2.tex").read_text()
