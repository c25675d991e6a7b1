"""The paper's two evaluation approaches."""

import numpy as np
import pytest

from robomorph.core import metrics as scores
from robomorph.evaluation import metrics


def test_approaches_differ_as_defined():
    y = np.array([[[0.0], [2.0]], [[10.0], [12.0]]])  # (N=2, T=2, C=1)
    yhat = np.array([[[0.0], [2.0]], [[10.0], [13.0]]])
    a1 = metrics.approach1(y, yhat, ["c"])
    a2 = metrics.approach2(y, yhat, ["c"])
    # approach 1: R^2 = 1 and 1 - 1/2 per trajectory, mean 0.75
    assert a1["channels"]["c"]["r2"]["mean"] == pytest.approx(0.75)
    assert a1["channels"]["c"]["r2"]["std"] == pytest.approx(0.25)
    assert a1["mean"]["r2"]["mean"] == pytest.approx(0.75)
    # approach 2: one series 0, 2, 10, 12 (mean 6, SST 104), SSE 1
    assert a2["channels"]["c"]["r2"] == pytest.approx(1 - 1 / 104)


def test_approach2_is_the_metric_of_the_concatenation():
    rng = np.random.default_rng(1)
    y, yhat = rng.normal(size=(4, 30, 3)), rng.normal(size=(4, 30, 3))
    a2 = metrics.approach2(y, yhat, ["a", "b", "c"])
    cat_y, cat_hat = np.concatenate(list(y)), np.concatenate(list(yhat))  # (120, 3)
    for m, fn in metrics.METRICS.items():
        ref = fn(cat_y, cat_hat)
        assert [a2["channels"][c][m] for c in "abc"] == pytest.approx(list(ref))
        assert a2["mean"][m] == pytest.approx(float(ref.mean()))


def test_approach1_mean_averages_channels_then_trajectories():
    rng = np.random.default_rng(2)
    y, yhat = rng.normal(size=(5, 20, 2)), rng.normal(size=(5, 20, 2))
    per = scores.fit_index(y, yhat)  # (5, 2)
    a1 = metrics.approach1(y, yhat, ["a", "b"])
    assert a1["mean"]["fit"]["mean"] == pytest.approx(per.mean(1).mean())
    assert a1["mean"]["fit"]["std"] == pytest.approx(per.mean(1).std())
    assert a1["channels"]["b"]["fit"]["std"] == pytest.approx(per[:, 1].std())


def test_names_must_match_channels():
    with pytest.raises(ValueError, match="channels"):
        metrics.approach1(np.zeros((2, 5, 3)), np.zeros((2, 5, 3)), ["a", "b"])
