"""Every physics mode's predictions, mean and std, equal to the bit what they were when the fixtures were
written (``python -m tests.inference.kept_predictions``): a reorganization of the code moves no number."""

from __future__ import annotations

import numpy as np

from tests.inference.kept_predictions import KEPT, predictions


def test_every_mode_predicts_what_it_predicted_when_the_fixtures_were_written():
    kept = np.load(KEPT / "predictions.npz")
    got = predictions()
    assert sorted(got) == sorted(kept.files)
    changed = [k for k in kept.files if not np.array_equal(got[k], kept[k])]
    assert not changed, f"predictions moved: {changed[:8]} (largest change " \
        f"{max(float(np.abs(got[k] - kept[k]).max()) for k in changed):.3g})"


def test_the_kept_cases_differ_from_each_other_so_the_check_can_fail():
    kept = np.load(KEPT / "predictions.npz")
    assert not np.array_equal(kept["command/regression/moving/mean"], kept["command/members=1/moving/mean"])
    assert not np.array_equal(kept["command/regression/moving/mean"], kept["command/learned/moving/mean"])
    assert not np.array_equal(kept["total_smoothed/smoothed/rest/mean"], kept["total_smoothed/none/rest/mean"])
    assert not np.array_equal(kept["command/points=draws/moving/std"], kept["command/points=draws,samples=4/moving/std"])
