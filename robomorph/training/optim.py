"""The optimizer and learning-rate schedule of :class:`robomorph.training.module.MetaModule`."""

from __future__ import annotations

import math

import torch
from lightning.pytorch.plugins.precision import Precision

# AdamW's fused kernel on a GPU (one launch per step instead of several per tensor;
# robomorph.training.compiling). benchmarks/train.py turns it off to time the step as it was.
FUSED_ON_GPU = True


def optimizers(module) -> dict:
    """AdamW (no decay on biases, norms and embeddings) with warmup and cosine decay, per step."""
    h, net = module.hparams, module.net
    params = [p for p in net.parameters() if p.requires_grad]
    if not params:
        raise ValueError("freeze left no trainable parameters")
    decay = [p for p in params if p.dim() >= 2 and not is_embedding(net, p)]
    no_decay = [p for p in params if all(p is not q for q in decay)]
    groups = [{"params": decay, "weight_decay": h.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    # Not under fp16's gradient scaler, which a fused AdamW would unscale inside its kernel,
    # after clipping; on a CPU, the default implementation, as before.
    fp16 = str(module.trainer.precision).startswith("16")
    fused = {"fused": True} if FUSED_ON_GPU and not fp16 and all(p.is_cuda for p in params) else {}
    opt = torch.optim.AdamW(groups, lr=h.lr, betas=tuple(h.betas), **fused)
    max_steps = module.trainer.max_steps
    total = h.decay_steps or (max_steps if max_steps > 0 else 10_000)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: lr_factor(step, h.warmup_steps, total, h.min_lr_ratio))
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def lr_factor(step: int, warmup: int, total: int, floor: float) -> float:
    """Linear warmup to 1, cosine decay to ``floor`` at ``total``, then flat."""
    if step < warmup:
        return (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress))


def is_embedding(net: torch.nn.Module, p: torch.Tensor) -> bool:
    return any(p is m.weight for m in net.modules() if isinstance(m, torch.nn.Embedding))


def clip_fused(module, optimizer: torch.optim.Optimizer, clip_val: float | None, algorithm: str | None) -> bool:
    """Clips a fused optimizer's gradients as Lightning clips any other's; False (nothing done) otherwise.

    Lightning's mixed-precision plugin refuses to clip for any fused optimizer, as if a gradient
    scaler unscaled inside it. Under bf16 and fp32 there is none (fused AdamW is not used under
    fp16, :func:`optimizers`), so the plugin's base class clips as usual.
    """
    if not (optimizer.defaults.get("fused") and clip_val):
        return False
    Precision.clip_gradients(module.trainer.precision_plugin, optimizer, clip_val, algorithm or "norm")
    return True
