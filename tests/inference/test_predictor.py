"""The Predictor: a checkpoint read into the plain model, without Lightning, predicting as
the training module does."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from robomorph.data.store import open_store
from robomorph.inference.checkpoint import CheckpointError
from robomorph.predictor import Predictor
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON

C, H = CKPT_CONTEXT, CKPT_HORIZON
# What inference may load of the package: the API, the model room and core.
ALLOWED_ROOMS = ("robomorph.inference", "robomorph.model", "robomorph.core")
ALLOWED_MODULES = ("robomorph", "robomorph.predictor")


@pytest.fixture(scope="module")
def window(simulated_store):
    ds = open_store(simulated_store(robots=24, steps=C + H, seed=1))
    return ds.read("u", slice(0, 4)), ds.read("y", slice(0, 4))


def _training_module_forward(ckpt, u, y):
    from robomorph.training.module import MetaModule

    module = MetaModule.load_from_checkpoint(ckpt, map_location="cpu").eval()
    with torch.no_grad():
        return module(*(torch.as_tensor(x) for x in (u[:, :C], y[:, :C], u[:, C:]))).numpy()


def test_inference_loads_no_training_code_and_matches_the_training_module(tiny_checkpoint, window, tmp_path):
    u, y = window
    np.savez(tmp_path / "in.npz", u=u, y=y)
    script = f"""
import json, sys
import numpy as np
from robomorph import Predictor
d = np.load({str(tmp_path / "in.npz")!r})
pred = Predictor.from_checkpoint({tiny_checkpoint!r}, device="cpu")
np.save({str(tmp_path / "out.npy")!r}, pred.simulate(d["u"][:, :{C}], d["y"][:, :{C}], d["u"][:, {C}:]))
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("robomorph", "lightning", "pytorch_lightning"))))
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "robomorph.inference.checkpoint" in loaded  # the check sees the package's modules
    extra = [m for m in loaded if m not in ALLOWED_MODULES
             and not any(m == room or m.startswith(room + ".") for room in ALLOWED_ROOMS)]
    assert not extra, f"inference imported {extra}"
    np.testing.assert_allclose(np.load(tmp_path / "out.npy"), _training_module_forward(tiny_checkpoint, u, y),
                               rtol=0, atol=1e-6)


def test_single_batched_numpy_and_torch_agree(tiny_checkpoint, window):
    u, y = window
    pred = Predictor.from_checkpoint(tiny_checkpoint, device="cpu")
    assert (pred.n_u, pred.n_y, pred.patch) == (7, 14, 5)
    batched = pred.simulate(u[:, :C], y[:, :C], u[:, C:])
    assert isinstance(batched, np.ndarray) and batched.shape == (4, H, 14) and batched.dtype == np.float32
    np.testing.assert_allclose(pred.simulate(u[1, :C], y[1, :C], u[1, C:]), batched[1], atol=1e-5)
    as_torch = pred.simulate(*(torch.as_tensor(x) for x in (u[:, :C], y[:, :C], u[:, C:])))
    assert isinstance(as_torch, torch.Tensor)
    np.testing.assert_allclose(as_torch.numpy(), batched, atol=1e-6)
    # the prediction uses the context: another robot's context changes it
    assert not np.allclose(pred.simulate(u[2, :C], y[2, :C], u[1, C:]), batched[1])


def test_bad_inputs_are_named(tiny_checkpoint, window):
    u, y = window
    pred = Predictor.from_checkpoint(tiny_checkpoint, device="cpu")
    with pytest.raises(ValueError, match="channels"):
        pred.simulate(u[1, :C, :3], y[1, :C], u[1, C:])
    with pytest.raises(ValueError, match="NaN"):
        pred.simulate(u[1, :C] * np.nan, y[1, :C], u[1, C:])
    one_inf = y[1, :C].copy()
    one_inf[7, 3] = np.inf
    with pytest.raises(ValueError, match="y_ctx holds NaN or inf"):
        pred.simulate(u[1, :C], one_inf, u[1, C:])
    with pytest.raises(ValueError, match="unbatched"):
        pred.simulate(u[:, :C], y[1, :C], u[1, C:])


def test_all_finite_is_exact_where_the_sum_is_not():
    from robomorph.inference.predictor import all_finite

    big = torch.full((4, 100, 7), 3e38)  # finite values whose sum overflows to inf
    assert all_finite(big) and all_finite(torch.zeros(0, 3)) and all_finite(torch.randn(8, 5, 2))
    for bad in (float("nan"), float("inf"), -float("inf")):
        t = torch.randn(8, 5, 2)
        t[3, 2, 1] = bad
        assert not all_finite(t)
    t = big.clone()
    t[0, 0, 0] = float("nan")
    assert not all_finite(t)


def test_bad_checkpoints(tiny_checkpoint, tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        Predictor.from_checkpoint(str(tmp_path / "missing.ckpt"))
    data = open(tiny_checkpoint, "rb").read()
    cut = tmp_path / "cut.ckpt"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        Predictor.from_checkpoint(str(cut))
    junk = tmp_path / "junk.ckpt"
    torch.save({"hello": 1}, junk)
    with pytest.raises(CheckpointError, match="not a RoboMorph"):
        Predictor.from_checkpoint(str(junk))
