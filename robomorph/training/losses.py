"""The training losses on normalized outputs and their weights over the horizon."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from robomorph.core.errors import RoboMorphError
from robomorph.core.names import LOSSES


class ModelOptionError(RoboMorphError, ValueError):
    """Model or loss options that do not fit together."""


def check_loss(loss: str, gaussian: bool, horizon_weight: float, horizon_tau: float) -> None:
    """The loss needs what it names: ``nll`` a Gaussian head; the horizon weights a sane shape."""
    if loss not in LOSSES:
        raise ModelOptionError(f"--model.loss must be one of {LOSSES}, got {loss!r}")
    if loss == "nll" and not gaussian:
        raise ModelOptionError("loss 'nll' needs the Gaussian head: set gaussian=true (--model.gaussian true)")
    if not horizon_weight >= 0 or not horizon_tau > 0:
        raise ModelOptionError(f"need --model.horizon_weight >= 0 and --model.horizon_tau > 0, "
                               f"got {horizon_weight}, {horizon_tau}")


def horizon_weights(horizon: int, weight: float, tau: float, device=None) -> torch.Tensor:
    """Loss weight of each query step (horizon,): ``1 + weight * exp(-t / tau)``, mean 1."""
    t = torch.arange(horizon, dtype=torch.float32, device=device)
    w = 1 + weight * torch.exp(-t / tau)
    return w / w.mean()


def elementwise_loss(kind: str, pred: torch.Tensor, logvar: torch.Tensor | None, target: torch.Tensor,
                     huber_delta: float = 1.0) -> torch.Tensor:
    """Per step and channel loss (B, Th, n_y) on normalized outputs: ``huber``, ``mse`` or
    ``nll`` (Gaussian negative log-likelihood with the head's log-variance)."""
    if kind == "nll":
        return 0.5 * (logvar + (target - pred) ** 2 * torch.exp(-logvar) + math.log(2 * math.pi))
    if kind == "mse":
        return (pred - target) ** 2
    return F.huber_loss(pred, target, delta=huber_delta, reduction="none")


def masked_loss(kind: str, pred: torch.Tensor, logvar: torch.Tensor | None, target: torch.Tensor,
                weights: torch.Tensor, huber_delta: float = 1.0) -> torch.Tensor:
    """The horizon-weighted loss averaged over the present outputs only: a NaN target marks a
    channel the trajectory's arm lacks (padding), which neither adds to the loss nor to its
    count, so absent channels (and what the network predicts for them) change nothing.

    Absent entries are zeroed before the loss, not after: a NaN there would turn the
    gradient of the whole batch into NaN even when multiplied by 0.
    """
    present = ~torch.isnan(target)  # (B, Th, n_y)
    zero = torch.zeros((), dtype=pred.dtype, device=pred.device)
    pred, target = torch.where(present, pred, zero), torch.where(present, target, zero)
    logvar = None if logvar is None else torch.where(present, logvar, zero)
    elem = elementwise_loss(kind, pred, logvar, target, huber_delta) * weights[:, None] * present
    return elem.sum() / present.sum().clamp_min(1)


def whole_patches(batch: dict, patch: int) -> dict:
    """The batch with the oldest context steps cut to a multiple of ``patch`` (random context
    lengths need not be multiples of it)."""
    drop = batch["u_ctx"].shape[1] % patch
    return {**batch, "u_ctx": batch["u_ctx"][:, drop:], "y_ctx": batch["y_ctx"][:, drop:]} if drop else batch
