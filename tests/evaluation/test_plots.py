"""The evaluation's figures: the standard set is written, seeded, as real PNG images."""

import matplotlib.image
import numpy as np

from robomorph.evaluation.plots import _grid, plot_sweep, write_all


def _data(n=5, tc=10, th=15, c=3):
    rng = np.random.default_rng(0)
    y_ctx, y_true = rng.normal(size=(n, tc, c)), rng.normal(size=(n, th, c))
    return y_ctx, y_true, {"model": y_true + 0.1, "hold": np.repeat(y_ctx[:, -1:], th, axis=1)}


def test_the_standard_set_is_seeded_and_complete(tmp_path):
    y_ctx, y_true, preds = _data()
    paths = write_all(str(tmp_path), y_ctx, y_true, preds, ["a", "b", "c"], 0.1, samples=2, seed=3)
    names = sorted(p.split("/")[-1] for p in paths)
    assert len(names) == 4 and names[:2] == ["error_growth.png", "r2_distribution.png"]
    (tmp_path / "again").mkdir()
    again = write_all(str(tmp_path / "again"), y_ctx, y_true, preds, ["a", "b", "c"], 0.1, samples=2, seed=3)
    assert sorted(p.split("/")[-1] for p in again) == names  # the same trajectories are drawn
    image = matplotlib.image.imread(paths[0])
    assert image.ndim == 3 and image.shape[0] > 100 and image.std() > 0


def test_a_sweep_plot_is_drawn_and_the_panel_grid_fits_the_channels(tmp_path):
    rows = [{"horizon": h, "model": {"r2": 0.9, "fit": 70.0, "r2_a2": 0.8, "fit_a2": 60.0},
             "hold": {"r2": -5.0, "fit": -300.0}} for h in (10, 20, 30)]
    path = plot_sweep(str(tmp_path / "s.png"), rows, "horizon")
    assert matplotlib.image.imread(path).shape[1] > 1000
    assert [_grid(n) for n in (1, 4, 5, 14)] == [(1, 1), (1, 4), (2, 4), (4, 4)]
