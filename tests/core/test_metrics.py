"""The per-channel scores: values by hand, numpy and torch alike, flat channels."""

import math
import subprocess
import sys

import numpy as np
import pytest
import torch

from robomorph.core import metrics


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


def test_scores_do_not_import_torch():
    code = ("import sys, numpy as np; from robomorph.core import metrics; "
            "metrics.r2(np.ones((3, 1)), np.ones((3, 1))); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
