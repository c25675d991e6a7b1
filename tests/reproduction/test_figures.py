"""The context and horizon figure: long-format rows, files, both sweeps required."""

import csv

import pytest

from robomorph.reproduction.figures import sweep_rows, write_context_figure

INFO = {"scale": "ci", "command": "c", "date": "d", "machine": "m", "budgets": {}}


def _point(key, x, r2):
    return {key: x, "model": {"r2": r2, "fit": 50.0, "r2_a2": r2, "fit_a2": 50.0}, "hold": {"r2": 0.1, "fit": 5.0}}


SWEEPS = {"horizon": [_point("horizon", h, 0.9 - h / 100) for h in (20, 40)],
          "context": [_point("context_len", c, 0.5 + c / 100) for c in (10, 20, 30)]}


def test_rows_have_one_entry_per_sweep_point_and_source():
    rows = sweep_rows(SWEEPS)
    assert len(rows) == (2 + 3) * 2
    first = rows[0]
    assert (first["sweep"], first["x"], first["source"], first["r2"]) == ("horizon", 20, "model", pytest.approx(0.7))
    assert str(next(r for r in rows if r["source"] == "hold")["r2_a2"]) == "nan"  # absent scores are NaN


def test_the_figure_and_its_data_are_written(tmp_path):
    write_context_figure(str(tmp_path), SWEEPS, {"ckpt": "x.ckpt", "context_len": 30, "horizon": 60}, INFO)
    assert (tmp_path / "context_horizon.png").stat().st_size > 1000
    with open(tmp_path / "context_horizon.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == 10
    with pytest.raises(ValueError, match="both sweeps"):
        write_context_figure(str(tmp_path), {"horizon": SWEEPS["horizon"]}, {}, INFO)
