"""The page's building blocks: FIT colours, escaping, metric text, the channel table, and the
per-horizon table from what ``evaluate`` writes into metrics.json."""

import html as stdlib_html
import json
import re

import numpy as np
import pytest

from robomorph.evaluation import metrics
from robomorph.evaluation.horizons import horizon_report
from robomorph.reporting.dashboard import build_report
from robomorph.reporting.html import (
    Cell,
    Row,
    Table,
    _macro,
    best_baseline,
    channel_table,
    fit_colour,
    fmt,
    horizon_table,
    mean_stat,
    page,
)

NAMES = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]


def _horizons(with_std: bool) -> dict:
    rng = np.random.default_rng(0)
    y = rng.normal(size=(4, 20, len(NAMES)))
    # The model is better than hold at the first step, worse at the last two.
    model = y + np.linspace(0.0, 0.5, 20)[None, :, None]
    hold = y + 0.2
    std = np.full_like(y, 0.1) if with_std else None
    return horizon_report(y, {"model": model, "hold": hold}, NAMES, 0.05, [1, 10, 20], std)


def test_horizon_table_marks_where_the_model_beats_hold_and_shows_coverage():
    html = horizon_table({"horizons": _horizons(True)})
    assert "step 10 (0.5 s)" in html and "joints [mrad]" in html and "ee_pos [mm]" in html
    model_rows = re.findall(r'<tr><td class="name">joints \[mrad\]</td><td class="name">model</td>(.*?)</tr>', html)
    assert len(model_rows) == 1
    colours = re.findall(r'style="background:([^"]+)"', model_rows[0])
    assert colours == ["rgb(204, 235, 204)", "rgb(248, 209, 204)", "rgb(248, 209, 204)"]
    assert "inside ±1σ [%] (ideal 68.3)" in html and "inside ±2σ [%] (ideal 95.4)" in html
    assert "inside ±1σ" not in horizon_table({"horizons": _horizons(False)})
    assert "recalibrated" not in html
    cal = {"method": "nll", "split": "val", "n": 51, "data": ["ms_train.zarr"]}
    marked = horizon_table({"horizons": _horizons(True), "meta": {"std_calibration": cal}})
    assert "recalibrated by horizon (nll) on 51 windows of the training run&#39;s validation robots" in marked


def test_horizon_table_is_empty_without_a_readable_horizons_entry():
    assert horizon_table({}) == ""
    assert horizon_table({"horizons": {"steps": "x"}}) == ""
    broken = _horizons(False)
    broken["rms"]["hold"]["joints"] = [1.0]  # wrong length: shown without colours, not a crash
    assert "joints [mrad]" in horizon_table({"horizons": broken})


def test_report_shows_the_horizon_table_of_an_evaluation(tmp_path):
    folder = tmp_path / "runs" / "r" / "eval" / "heldout"
    folder.mkdir(parents=True)
    metrics = {"approach1": {"channels": {"q0": {"r2": {"mean": 0.5, "std": 0.1}, "fit": {"mean": 30.0, "std": 1.0}}}},
               "approach2": {"channels": {"q0": {"r2": 0.5, "fit": 30.0}}}, "horizons": _horizons(True)}
    (folder / "metrics.json").write_text(json.dumps(metrics))
    page = open(build_report(str(tmp_path / "runs"), str(tmp_path / "report.html"))).read()
    assert "RMS error by horizon" in page and "ee_rot [mrad]" in page and "inside ±2σ" in page
    overview = page.split("<h2>Overview</h2>")[1].split("<h2>")[0]
    heads = re.findall(r"<th[^>]*>([^<]*)</th>", overview)
    assert heads[2] == "joints RMS [mrad] at step 1 / 0.25 s / 1 s"  # the overview leads with them
    assert heads[heads.index("normalization") + 1:][:3] == ["model", "hold", "constant velocity"]


def test_overview_leads_with_the_joint_error_of_the_model_hold_and_constant_velocity():
    from robomorph.reporting.html import horizon_cells

    y = np.zeros((2, 80, len(NAMES)))
    preds = {"model": y + 0.001 * np.arange(1, 81)[None, :, None], "hold": y + 0.002,
             "constant_velocity": y + 0.003 * np.arange(1, 81)[None, :, None]}
    h = horizon_report(y, preds, NAMES, 1 / 60, [1, 15, 60, 80])
    cells = horizon_cells({"horizons": h})
    assert [c.text for c in cells] == ["1 / 15 / 60", "2 / 2 / 2", "3 / 45 / 180"]
    assert cells[0].colour is None  # better than both at the first step, not at 0.25 s: neither green nor red
    h["rms"]["model"]["joints"] = [v * 1e-3 for v in h["rms"]["model"]["joints"]]
    assert horizon_cells({"horizons": h})[0].colour == "rgb(204, 235, 204)"  # below both at every step: green
    h["rms"]["model"]["joints"] = [v * 1e6 for v in h["rms"]["model"]["joints"]]
    assert horizon_cells({"horizons": h})[0].colour == "rgb(248, 209, 204)"  # above the better at every step: red
    del h["rms"]["constant_velocity"]
    assert [c.text for c in horizon_cells({"horizons": h})][1:] == ["2 / 2 / 2", "—"]  # not scored: a dash
    assert [c.text for c in horizon_cells({})] == ["—"] * 3
    bad = {"horizons": {"steps": [1], "seconds": ["x"], "rms": {"model": {"joints": [1.0]}}}}
    assert [c.text for c in horizon_cells(bad)] == ["—"] * 3


@pytest.mark.parametrize(
    "fit, colour",
    [(100.0, "rgb(166, 241, 166)"), (90.0, "rgb(166, 241, 166)"), (89.99, "rgb(200, 247, 200)"),
     (80.0, "rgb(200, 247, 200)"), (79.99, "rgb(255, 255, 128)"), (60.0, "rgb(255, 255, 128)"),
     (59.99, "rgb(255, 210, 128)"), (30.0, "rgb(255, 210, 128)"), (29.99, "rgb(255, 179, 179)"),
     (-250.0, "rgb(255, 179, 179)"), (None, None), (float("nan"), None)],
)
def test_fit_colour_follows_the_paper_convention(fit, colour):
    assert fit_colour(fit) == colour


def test_text_is_escaped_and_numbers_formatted():
    nasty = '<a href="x">\'&'
    cell = _macro("cell", Cell(nasty, colour='red"><script>', cls="name", href='#"><b>', badges=("<i>",)))
    assert "<a href=\"x\">" not in cell and "<script>" not in cell and "<b>" not in cell and "<i>" not in cell
    assert cell.count("&lt;a href=&#34;x&#34;&gt;&#39;&amp;") == 1  # text escaped, quotes included
    assert stdlib_html.unescape(re.sub(r"<[^>]+>", "", cell)) == nasty + "<i>"
    grid = _macro("grid", Table(("<th>",), (Row((Cell("<td>"),), cls='x"'),)))
    assert "&lt;th&gt;" in grid and "&lt;td&gt;" in grid and 'class="x&#34;"' in grid
    assert (fmt(0.91234, 0.01, "r2"), fmt(87.25, None, "fit"), fmt(0.012345, None, "rmse"), fmt(None, None, "r2")) == \
        ("0.912 ± 0.010", "87.2", "0.0123", "—")


def _moving(rng, n: int = 3, t: int = 20, c: int = 2) -> np.ndarray:
    """Channels that move (a sine each, a little noise), as measured outputs do."""
    phase = rng.uniform(0, 2 * np.pi, size=(n, 1, c))
    return np.sin(np.linspace(0, 2 * np.pi, t)[None, :, None] + phase) + 1e-3 * rng.normal(size=(n, t, c))


def _metrics():
    rng = np.random.default_rng(0)
    y = _moving(rng)
    model, hold = y + 0.1 * rng.normal(size=y.shape), np.repeat(y[:, :1], 20, axis=1)
    names = ["a", "<b>"]
    return {"approach1": metrics.approach1(y, model, names), "approach2": metrics.approach2(y, model, names),
            "baselines": {"hold": {"approach1": metrics.approach1(y, hold, names)},
                          "true_physics": {"approach1": metrics.approach1(y, y, names)}}}


def test_the_channel_table_has_every_channel_and_the_mean_escaped():
    m = _metrics()
    text = channel_table(m)
    assert text.count("<tr>") == 2 + 2 and '<tr class="mean">' in text  # two header rows, two channels
    assert "&lt;b&gt;" in text and "<b>" not in text
    # without a stored mean the average of the channels stands in; with nothing, nothing
    assert mean_stat({"approach2": {"channels": {"a": {"r2": 0.5}, "b": {"r2": 0.7}}}}, "approach2", "r2") == \
        (pytest.approx(0.6), None)
    assert mean_stat(m["baselines"]["hold"], "approach2", "r2") == (None, None)
    assert mean_stat(m, "approach1", "fit")[0] == pytest.approx(m["approach1"]["mean"]["fit"]["mean"])


def test_the_true_physics_ceiling_never_counts_as_the_best_baseline():
    name, fit = best_baseline(_metrics())
    assert name == "hold" and fit < 100


def test_a_page_is_a_whole_html_document_with_an_escaped_title():
    text = page("a < b", "<p>x</p>")
    assert text.lstrip().lower().startswith("<!doctype html>") and "<title>a &lt; b</title>" in text


def test_horizon_table_shows_how_well_the_std_ranks_the_errors_where_it_can():
    rng = np.random.default_rng(1)
    y = np.zeros((32, 20, len(NAMES)))
    std = rng.uniform(0.01, 1.0, size=y.shape)
    model = std * rng.choice([-1.0, 1.0], size=y.shape)  # every error its own std: a perfect ranking
    h = horizon_report(y, {"model": model, "hold": y + 0.2}, NAMES, 0.05, [1, 10, 20], std)
    html = horizon_table({"horizons": h})
    row = re.findall(r'std-error rank corr\. \(1: ranks the errors\)</td><td class="name">model</td>(.*?)</tr>', html)
    assert len(row) == 1 and row[0].count("1.00") == 3
    # A std that is the same everywhere ranks nothing, and a metrics file from before has no skill: no row.
    assert "rank corr." not in horizon_table({"horizons": _horizons(True)})
    assert "rank corr." not in horizon_table({"horizons": {k: v for k, v in h.items() if k != "skill"}})


def test_a_diverged_baseline_is_marked_in_the_tables_and_out_of_the_best_when_mostly_diverged():
    m = _metrics()
    y = _moving(np.random.default_rng(1))
    m["baselines"]["arx"] = {"approach1": metrics.approach1(y, y + 0.01, ["a", "<b>"])}  # near perfect...
    m["meta"] = {"n": 3, "baseline_notes": {"arx": {"diverged_held": 2}, "hold": {"diverged_held": 0}}}
    assert "arx (diverged on 2/3, held)" in channel_table(m) and "hold (diverged" not in channel_table(m)
    assert best_baseline(m)[0] == "hold"  # ...but held on 2 of 3 windows: not the best baseline
    m["meta"]["baseline_notes"]["arx"]["diverged_held"] = 1  # on a minority: marked, still in the running
    assert "arx (diverged on 1/3, held)" in channel_table(m) and best_baseline(m)[0] == "arx"
    h = {"horizons": _horizons(False), "meta": {"n": 4, "baseline_notes": {"hold": {"diverged_held": 3}}}}
    assert '<td class="name">hold (diverged on 3/4, held)</td>' in horizon_table(h)
