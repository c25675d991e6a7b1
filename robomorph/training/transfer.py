"""Transfer-learning regimes as configuration: what :func:`robomorph.training.fitting.fit` is given for each.

The paper's Table 2 compares three ways to get a model for a new task (the spiral):

- ``zero_shot``: no training; the pre-trained checkpoint is evaluated as it is.
- ``finetune``: start from the pre-trained weights (``model.init_ckpt``), optionally
  freezing part of the network, with a lower learning rate, for a budget of ``steps``
  optimizer steps. The normalization statistics follow ``model.normalization_from``
  (default ``target``: the fine-tuning data's; ``source``: the checkpoint's).
- ``scratch``: the same architecture from a random initialization, ``steps`` steps.

The overrides are nested dicts in :func:`robomorph.training.fitting.fit`'s vocabulary, to be merged
into a base configuration with :func:`merge`::

    args = merge(base_args, regime_overrides("finetune", "runs/pre/checkpoints/best.ckpt", 2000))
"""

from __future__ import annotations

import copy
from typing import Any

REGIMES = ("zero_shot", "finetune", "scratch")
# The paper's fine-tuning follows Piga, Forgione et al. (2024): a pre-trained meta-model
# adapts with a smaller step than it was trained with (the CPU default trains at 1e-3).
FINETUNE_LR = 3e-4
# Mirrors robomorph.training.module.FREEZE_MODES, which cannot be imported here without torch.
_FREEZE_MODES = ("none", "encoder", "all_but_head")


def regime_overrides(regime: str, init_ckpt: str | None, steps: int, lr: float | None = None,
                     freeze: str = "none") -> dict[str, Any] | None:
    """The nested :func:`robomorph.training.fitting.fit` overrides of one transfer regime.

    Args:
        regime: one of :data:`REGIMES`.
        init_ckpt: the pre-trained checkpoint (required by ``finetune``, ignored by the others).
        steps: training budget in optimizer steps (``trainer.max_steps``); unused by ``zero_shot``.
        lr: peak learning rate; ``finetune`` defaults to :data:`FINETUNE_LR`, ``scratch`` keeps
            the base configuration's.
        freeze: ``none``, ``encoder`` or ``all_but_head`` (``finetune`` only).

    Returns:
        ``None`` for ``zero_shot`` (nothing to train), else ``{"model": {...}, "trainer": {...}}``.

    Raises:
        ValueError: an unknown regime or freeze mode, ``finetune`` without ``init_ckpt``, a
            freeze other than ``none`` outside ``finetune``, ``steps < 1`` or ``lr <= 0``.
    """
    if regime not in REGIMES:
        raise ValueError(f"unknown transfer regime {regime!r}; choose from {list(REGIMES)}")
    if freeze not in _FREEZE_MODES:
        raise ValueError(f"freeze must be one of {list(_FREEZE_MODES)}, got {freeze!r}")
    if regime == "zero_shot":
        return None
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive integer for {regime}, got {steps!r}")
    if lr is not None and not lr > 0:
        raise ValueError(f"lr must be > 0, got {lr!r}")
    trainer = {"max_steps": steps}
    if regime == "scratch":
        if freeze != "none":
            raise ValueError(f"freeze={freeze!r} applies to finetune only: a frozen random network is not 'scratch'")
        model: dict[str, Any] = {"init_ckpt": None, "freeze": "none"}
        if lr is not None:
            model["lr"] = lr
        return {"model": model, "trainer": trainer}
    if not init_ckpt:
        raise ValueError("finetune needs init_ckpt: the pre-trained checkpoint to start from")
    model = {"init_ckpt": init_ckpt, "freeze": freeze, "lr": FINETUNE_LR if lr is None else lr}
    return {"model": model, "trainer": trainer}


def merge(base: dict[str, Any], overrides: dict[str, Any] | None) -> dict[str, Any]:
    """A deep copy of ``base`` with ``overrides`` merged in, nested dicts key by key (overrides win)."""
    out = copy.deepcopy(base)
    for key, value in (overrides or {}).items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out
