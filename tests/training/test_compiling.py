"""The compiled training step (robomorph.training.compiling): which mode each device gets, the
refusal of unknown modes, and, on the CPU with torch's graph-only backend (no code
generation), that the step traces into one graph with no break (so CUDA graphs cover all of
it on a GPU) and computes the eager step's loss and gradients. The GPU run itself, with CUDA
graphs and bf16, is tests/test_gpu.py's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.data.statistics import Stats
from robomorph.training.compiling import CompiledStep, resolve_compile
from robomorph.training.losses import ModelOptionError
from robomorph.training.module import MetaModule
from robomorph.training.optim import optimizers

STATS = Stats(np.array([0.5, -1.0]), np.array([2.0, 0.5]), np.array([0.1, 0.2, -0.3]), np.array([0.3, 1.5, 0.7]))


def _module(**kw) -> MetaModule:
    torch.manual_seed(0)
    m = MetaModule(**{"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "n_layer": 2, "patch": 2,
                      "max_context": 32, "max_horizon": 32, **kw})
    m.normalizer.set_stats(STATS)
    m.stats_ready.fill_(True)
    return m


def _batch(seed=1, context=12, horizon=10) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {"u_ctx": torch.randn(4, context, 2, generator=g), "y_ctx": torch.randn(4, context, 3, generator=g),
            "u_query": torch.randn(4, horizon, 2, generator=g), "y_query": torch.randn(4, horizon, 3, generator=g)}


def test_auto_compiles_on_a_gpu_only_and_off_means_eager(monkeypatch):
    assert resolve_compile("auto", "cpu") is None  # the CPU path stays eager
    assert resolve_compile("off", "cuda") is None
    assert resolve_compile("default", "cpu") == "default"  # asked for: on any device
    monkeypatch.setattr("robomorph.training.compiling.has_triton", lambda: True)
    assert resolve_compile("auto", "cuda") == "reduce-overhead"
    # windows of varying length: no CUDA graphs recorded per length; eager unless a mode is asked for
    assert resolve_compile("auto", "cuda", varying=True) is None
    assert resolve_compile("default", "cuda", varying=True) == "default"
    monkeypatch.setattr("robomorph.training.compiling.has_triton", lambda: False)
    assert resolve_compile("auto", "cuda") is None  # no GPU compiler: eager rather than an error


def test_an_unknown_mode_is_refused_naming_the_flag():
    with pytest.raises(ModelOptionError, match=r"--model.compile must be one of auto, off, .*got 'fast'"):
        MetaModule(n_u=2, n_y=3, compile="fast")


def test_a_cpu_module_trains_eagerly_by_default():
    m = _module()
    assert m.hparams.compile == "auto"
    assert m._training_loss_fn() == m._train_loss and "_compiled_step" not in m.__dict__


@pytest.mark.parametrize("options", [{}, {"gaussian": True, "loss": "nll", "anchor": True, "horizon_weight": 2.0}])
def test_the_training_step_is_one_graph_with_the_eager_loss_and_gradients(options):
    torch._dynamo.reset()
    batch = _batch()
    eager, compiled = _module(**options), _module(**options)
    explained = torch._dynamo.explain(compiled._train_loss)(batch)
    assert explained.graph_break_count == 0 and explained.graph_count == 1, explained.break_reasons
    step = CompiledStep(compiled._train_loss, "default", backend="aot_eager")
    for m, fn in ((eager, eager._train_loss), (compiled, step)):
        loss, param_rmse = fn(batch)
        loss.backward()
        m.loss = loss.detach()
    assert param_rmse is None
    torch.testing.assert_close(compiled.loss, eager.loss, rtol=1e-6, atol=1e-7)
    for (name, p), q in zip(eager.net.named_parameters(), compiled.net.parameters()):
        torch.testing.assert_close(q.grad, p.grad, rtol=1e-5, atol=1e-7, msg=name)


def test_windows_of_varying_length_compile_once_and_match_eager():
    from torch._dynamo.testing import CompileCounter

    torch._dynamo.reset()
    counter = CompileCounter()
    eager, compiled = _module(), _module()
    step = CompiledStep(compiled._train_loss, "default", backend=counter, dynamic=True)
    for seed, (context, horizon) in enumerate([(12, 10), (8, 16), (16, 6), (10, 12)]):
        batch = _batch(seed, context, horizon)
        torch.testing.assert_close(step(batch)[0], eager._train_loss(batch)[0], rtol=1e-6, atol=1e-7)
    assert counter.frame_count == 1  # not once per length


def test_the_cpu_optimizer_is_not_the_fused_kernel():
    class Trainer:
        max_steps, precision = 10, "32-true"

    m = _module()
    m.__dict__["_trainer"] = Trainer()  # what optimizers() reads of a trainer
    opt = optimizers(m)["optimizer"]
    assert not opt.defaults.get("fused")


def test_a_fused_optimizer_is_clipped_under_bf16_mixed_precision():
    """Lightning's mixed-precision plugin refuses to clip for any fused optimizer (the first GPU
    run's failure); the module clips it itself, as Lightning clips any other (here on a CPU,
    where torch has a fused AdamW too)."""
    import lightning.pytorch as L

    m = _module()
    m.trainer = L.Trainer(accelerator="cpu", precision="bf16-mixed", logger=False, enable_progress_bar=False)
    opt = torch.optim.AdamW(m.net.parameters(), fused=True)
    loss, _ = m._train_loss(_batch())
    (loss * 1e3).backward()
    norm = lambda: float(torch.linalg.vector_norm(torch.stack([p.grad.norm() for p in m.net.parameters()])))  # noqa: E731
    assert norm() > 1.0
    with pytest.raises(RuntimeError, match="fused"):  # what Lightning's own path does
        L.LightningModule.configure_gradient_clipping(m, opt, 1.0, "norm")
    m.configure_gradient_clipping(opt, 1.0, "norm")
    assert norm() == pytest.approx(1.0, rel=1e-4)
