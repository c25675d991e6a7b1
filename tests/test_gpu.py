"""Checks that need a CUDA device (skipped without one): fit on a GPU, and compiled training
(robomorph.training.compiling) against eager. The store is written with the project's own
writer, so no simulation runs; on a bare GPU box install the wheels of tools/device_site.sh
first (benchmarks/gpu_session.sh runs this file, then the training benchmark)."""

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


def _losses_of_a_run(compile: str, precision: str, steps: int = 8) -> tuple[list[float], torch.Tensor]:
    """Per-step training losses and how far each weight moved of a small model trained on fixed batches
    from seed 0, with the training step compiled as ``compile`` says (robomorph.training.compiling)."""
    import lightning.pytorch as L

    from robomorph.data.statistics import Stats
    from robomorph.training.module import MetaModule

    g = torch.Generator().manual_seed(0)
    batches = [{"u_ctx": torch.randn(8, 40, 2, generator=g), "y_ctx": torch.randn(8, 40, 3, generator=g),
                "u_query": torch.randn(8, 60, 2, generator=g), "y_query": torch.randn(8, 60, 3, generator=g)}
               for _ in range(steps)]
    torch.manual_seed(0)
    m = MetaModule(n_u=2, n_y=3, d_model=32, n_head=4, n_layer=2, patch=4, max_context=64, max_horizon=64,
                   warmup_steps=0, compile=compile)
    m.normalizer.set_stats(Stats(np.zeros(2), np.ones(2), np.zeros(3), np.ones(3)))
    m.stats_ready.fill_(True)
    start = torch.cat([p.detach().flatten().clone() for p in m.net.parameters()])

    class Losses(L.Callback):
        values: list[float] = []

        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
            self.values = [*self.values, float(outputs["loss"])]

    seen = Losses()
    L.Trainer(max_steps=steps, accelerator="gpu", devices=1, precision=precision, logger=False,
              enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
              limit_val_batches=0, gradient_clip_val=1.0, callbacks=[seen]
              ).fit(m, train_dataloaders=torch.utils.data.DataLoader(batches, batch_size=None))
    assert ("_compiled_step" in m.__dict__) == (compile != "off")
    moved = torch.cat([p.detach().flatten().float().cpu() for p in m.net.parameters()]) - start
    return seen.values, moved


@pytest.mark.parametrize(("precision", "rtol"), [("32-true", 1e-3), ("bf16-mixed", 3e-2)])
def test_compiled_and_eager_training_agree_from_the_same_seed(precision, rtol):
    torch._dynamo.reset()
    eager, eager_w = _losses_of_a_run("off", precision)
    graphed, graphed_w = _losses_of_a_run("reduce-overhead", precision)  # what auto picks on a GPU
    assert len(eager) == len(graphed) == 8 and np.isfinite(graphed).all()
    np.testing.assert_allclose(graphed, eager, rtol=rtol)
    assert float(eager_w.abs().max()) > 1e-3  # it trained: what is compared moved
    if precision == "32-true":  # in bf16, Adam's sign-like steps on near-zero gradients may differ
        torch.testing.assert_close(graphed_w, eager_w, rtol=rtol, atol=rtol * float(eager_w.abs().max()))


@pytest.mark.parametrize("compile", ["auto", "default"])
def test_fit_with_windows_of_varying_length_compiles_once_for_all_lengths(store, tmp_path, compile):
    import lightning.pytorch as L

    class Seen(L.Callback):
        lengths: set = set()

        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
            self.lengths = self.lengths | {(batch["u_ctx"].shape[1], batch["u_query"].shape[1])}
            self.step = module.__dict__.get("_compiled_step")
            self.loss = float(outputs["loss"])

    seen = Seen()
    args = {
        "data": {"stores": store, "context_len": 20, "horizon": 40, "context_min": 8, "horizon_min": 10,
                 "batch_size": 8, "val_subset": 8},
        "model": {"d_model": 16, "n_head": 2, "n_layer": 1, "patch": 2, "max_context": 64, "max_horizon": 64,
                  "compile": compile},
        "trainer": {"max_steps": 12, "val_check_interval": 12, "accelerator": "gpu", "devices": 1,
                    "enable_progress_bar": False, "enable_model_summary": False},
        "run": "varying", "runs_dir": str(tmp_path), "wandb": "disabled",
    }
    from torch._dynamo.utils import counters

    torch._dynamo.reset()
    counters.clear()
    result = fit(args, callbacks=[seen])
    assert result.global_step == 12 and len(seen.lengths) > 2 and np.isfinite(seen.loss)
    if compile == "auto":  # eager: no CUDA graphs recorded per length
        assert seen.step is None
        return
    assert seen.step.mode == "default" and not seen.step.graphed
    assert 1 <= counters["stats"]["unique_graphs"] < len(seen.lengths)  # not one compilation per length
