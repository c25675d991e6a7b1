"""metrics.csv rows and the markdown table of an evaluation result."""

import numpy as np

from robomorph.core.results import read_rows
from robomorph.evaluation import metrics
from robomorph.evaluation.tables import csv_rows, table_markdown, write_csv, write_table

NAMES = ["a", "b"]


def _result():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(4, 20, 2))
    model, hold = y + 0.1 * rng.normal(size=y.shape), np.repeat(y[:, :1], 20, axis=1)
    return {"approach1": metrics.approach1(y, model, NAMES), "approach2": metrics.approach2(y, model, NAMES),
            "baselines": {"hold": {"approach1": metrics.approach1(y, hold, NAMES),
                                   "approach2": metrics.approach2(y, hold, NAMES)}},
            "skipped_baselines": {"arx": "too few steps"},
            "meta": {"ckpt": "runs/x/checkpoints/best.ckpt", "data": "t.zarr", "n": 4, "context_len": 10, "horizon": 20}}


def test_one_csv_row_per_source_approach_channel_and_metric(tmp_path):
    result = _result()
    rows = csv_rows(result)
    # 2 sources x 2 approaches x (2 channels + mean) x 4 metrics
    assert len(rows) == 2 * 2 * 3 * 4
    row = next(r for r in rows if (r["source"], r["approach"], r["channel"], r["metric"]) == ("model", 1, "a", "fit"))
    assert row["value"] == result["approach1"]["channels"]["a"]["fit"]["mean"]
    write_csv(str(tmp_path / "m.csv"), result)
    assert len(read_rows(str(tmp_path / "m.csv"))) == len(rows)


def test_the_table_has_a_row_per_channel_the_mean_and_the_skipped_baselines(tmp_path):
    text = table_markdown(_result())
    lines = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if line.startswith("| ")]
    assert len(lines) == 1 + 2 + 1  # header, channels, mean
    assert lines[0][-1] == "hold FIT (1)" and lines[-1][0] == "**mean**"
    assert len({len(cells) for cells in lines}) == 1  # every row has every column
    assert "Skipped baseline `arx`: too few steps" in text and "`best.ckpt` on `t.zarr`" in text
    write_table(str(tmp_path / "t.md"), _result())
    assert (tmp_path / "t.md").read_text() == text


def test_the_table_says_when_the_smoothed_physics_was_out_of_its_depth():
    from robomorph.identification.smoother import new_report

    result = _result()
    quiet = new_report()
    quiet["windows"] = 4
    result["meta"]["smoothing"] = quiet
    assert "smoothed physics" not in table_markdown(result)  # in distribution: nothing to say
    result["meta"]["smoothing"] = {"windows": 16, "staged": 7, "handed_from": [212, 131, 390]}
    line = next(ln for ln in table_markdown(result).splitlines() if "smoothed physics" in ln)
    assert "7 of 16 windows solved in stages" in line and "3 handed to the decoder" in line
    assert "from steps 131-390" in line
