"""Checks that need a CUDA device (skipped without one). The store is written with the
project's own writer so that these run where MuJoCo is not installed (a bare GPU box)."""

import os

import numpy as np
import pytest
import torch

from robomorph.data.store import open_store
from robomorph.predictor import Predictor
from robomorph.training.fitting import fit

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")]


@pytest.fixture(scope="module")
def store(linear_store):
    # A damped linear system driven by random inputs: learnable in a few steps.
    return linear_store(n=64, steps=60, n_u=2, n_y=3)


def test_gpu_fit_uses_bf16_and_matches_the_cpu_predictor(store, tmp_path):
    import lightning.pytorch as L

    class Seen(L.Callback):
        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
            self.precision = trainer.precision
            self.device = next(module.parameters()).device.type

    seen = Seen()
    args = {
        "data": {"stores": store, "context_len": 20, "horizon": 40, "batch_size": 8, "val_subset": 8},
        "model": {"d_model": 16, "n_head": 2, "n_layer": 1, "lr": 3e-3, "warmup_steps": 5, "max_context": 64,
                  "max_horizon": 64},
        "trainer": {"max_steps": 20, "val_check_interval": 10, "accelerator": "gpu", "devices": 1,
                    "enable_progress_bar": False, "enable_model_summary": False},
        "run": "gpu", "runs_dir": str(tmp_path), "wandb": "disabled",
    }
    result = fit(args, callbacks=[seen])
    assert result.global_step == 20 and seen.device == "cuda"
    if torch.cuda.is_bf16_supported():  # the default precision on such a GPU
        assert seen.precision == "bf16-mixed"
    assert os.path.isfile(result.best_ckpt)
    ds = open_store(store)
    u, y = ds.read("u", slice(0, 4)), ds.read("y", slice(0, 4))
    on_gpu = Predictor.from_checkpoint(result.best_ckpt, device="cuda").simulate(u[:, :20], y[:, :20], u[:, 20:60])
    on_cpu = Predictor.from_checkpoint(result.best_ckpt, device="cpu").simulate(u[:, :20], y[:, :20], u[:, 20:60])
    assert on_gpu.shape == (4, 40, 3) and np.isfinite(on_gpu).all()
    np.testing.assert_allclose(on_gpu, on_cpu, atol=1e-3 * max(1.0, float(np.abs(on_cpu).max())))
