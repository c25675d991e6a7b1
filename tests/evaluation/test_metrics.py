import math

import numpy as np
import pytest
import torch

from robomorph.evaluation import metrics


def test_values_by_hand():
    y = np.array([[1.0], [2.0], [3.0]])
    yhat = np.array([[1.0], [2.0], [4.0]])
    # SSE = 1, SST = 2, RMSE = sqrt(1/3), std(y) = sqrt(2/3)
    assert metrics.r2(y, yhat)[0] == pytest.approx(0.5)
    assert metrics.rmse(y, yhat)[0] == pytest.approx(math.sqrt(1 / 3))
    assert metrics.nrmse(y, yhat)[0] == pytest.approx(math.sqrt(0.5))
    assert metrics.fit_index(y, yhat)[0] == pytest.approx(100 * (1 - 1 / math.sqrt(2)))


def test_numpy_and_torch_agree():
    rng = np.random.default_rng(0)
    y, yhat = rng.normal(size=(3, 50, 4)), rng.normal(size=(3, 50, 4))
    for name, fn in metrics.METRICS.items():
        a = fn(y, yhat)
        b = fn(torch.from_numpy(y), torch.from_numpy(yhat))
        assert isinstance(b, torch.Tensor) and a.shape == (3, 4), name
        np.testing.assert_allclose(a, b.numpy(), rtol=1e-10)


def test_flat_channel_is_defined_not_nan():
    y = np.ones((10, 2))
    y[:, 1] = np.arange(10)
    exact = metrics.r2(y, y.copy())
    off = y.copy()
    off[:, 0] += 0.5
    assert exact[0] == 1.0 and metrics.fit_index(y, y.copy())[0] == 100.0
    assert metrics.r2(y, off)[0] == 0.0 and metrics.fit_index(y, off)[0] == 0.0
    assert np.isfinite(metrics.nrmse(y, off)).all()
    assert metrics.r2(y, off)[1] == pytest.approx(1.0)
    # torch tensors follow the same rule
    import torch

    ty, toff = torch.as_tensor(y), torch.as_tensor(off)
    assert metrics.r2(ty, ty.clone())[0].item() == 1.0 and metrics.fit_index(ty, toff)[0].item() == 0.0
    assert torch.isfinite(metrics.nrmse(ty, toff)).all() and metrics.r2(ty, toff)[0].item() == 0.0


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
    per = metrics.fit_index(y, yhat)  # (5, 2)
    a1 = metrics.approach1(y, yhat, ["a", "b"])
    assert a1["mean"]["fit"]["mean"] == pytest.approx(per.mean(1).mean())
    assert a1["mean"]["fit"]["std"] == pytest.approx(per.mean(1).std())
    assert a1["channels"]["b"]["fit"]["std"] == pytest.approx(per[:, 1].std())


def test_names_must_match_channels():
    with pytest.raises(ValueError, match="channels"):
        metrics.approach1(np.zeros((2, 5, 3)), np.zeros((2, 5, 3)), ["a", "b"])


@pytest.mark.parametrize("fit, band", [(95, 0), (90, 0), (89.99, 1), (80, 1), (60, 2), (59.9, 3), (30, 3),
                                       (29.99, 4), (-250, 4), (float("nan"), 4)])
def test_fit_bands_follow_the_paper(fit, band):
    assert metrics.fit_band(fit) == band
