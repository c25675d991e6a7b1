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


def test_a_channel_that_moves_less_than_its_noise_is_quiet_and_left_out_of_the_medians():
    """Issue 61 §5: one channel at rest (noise only) in some windows gave FIT −1000 there and ruled the mean."""
    rng = np.random.default_rng(3)
    t = np.linspace(0, 2 * np.pi, 200)
    y = np.stack([np.stack([np.sin(t + k), 0.5 * np.cos(t + k)], -1) for k in range(6)])  # (6, 200, 2) moving
    y = y + rng.normal(scale=1e-3, size=y.shape)  # sensor noise
    y[:3, :, 1] = 0.2 + rng.normal(scale=1e-3, size=(3, 200))  # channel b rests in the first three windows
    yhat = y + 0.05 * np.sin(3 * t)[None, :, None]  # the same error everywhere
    noise = metrics.noise_std(y)
    assert noise.shape == (6, 2) and np.allclose(noise, 1e-3, rtol=0.2)  # the noise, read from the data
    quiet = metrics.quiet_windows(y)
    assert quiet[:3, 1].all() and not quiet[3:, 1].any() and not quiet[:, 0].any()
    a1 = metrics.approach1(y, yhat, ["a", "b"])
    assert a1["quiet"] == {"windows": 6, "ratio": metrics.QUIET_RATIO, "channels": {"a": 0, "b": 3}}
    fit = scores.fit_index(y, yhat)  # (6, 2): the resting windows' FIT of b is hugely negative
    assert fit[:3, 1].max() < -1000 and a1["mean"]["fit"]["mean"] < -200  # the paper's mean, kept as it is
    assert a1["channels"]["b"]["fit"]["median"] == pytest.approx(np.median(fit[3:, 1]), rel=1e-9)
    per_window = [fit[i, 0] if i < 3 else fit[i].mean() for i in range(6)]
    assert a1["mean"]["fit"]["median"] == pytest.approx(np.median(per_window), rel=1e-9)
    assert a1["mean"]["fit"]["median"] > 80  # what the model does where the channels move


def test_quiet_needs_three_steps_and_a_window_of_noise_alone_has_no_median():
    y = np.zeros((2, 2, 1))
    assert not metrics.quiet_windows(y).any() and metrics.approach1(y, y, ["c"])["quiet"]["channels"] == {"c": 0}
    noise = np.random.default_rng(4).normal(size=(3, 50, 1))
    a1 = metrics.approach1(noise, noise * 0.5, ["c"])
    assert a1["quiet"]["channels"] == {"c": 3} and a1["channels"]["c"]["fit"]["median"] is None
    assert a1["mean"]["fit"]["median"] is None and a1["mean"]["fit"]["mean"] == pytest.approx(50.0, abs=2)  # kept
