"""The hybrid model's parameter head: a robot's physical parameters read from its context.

:class:`robomorph.model.transformer.MetaModel` built with ``n_params > 0`` holds a second
encoder (``param_encoder``) and an MLP (``param_head``). They read the normalized context
alone, so no query value can reach the parameters (and the simulation made with them). The
tokens add each output's per-step change and the change of that change: damping, friction
and inertia show in velocities and accelerations, which at 60 Hz are a hundredth of a
normalized position's spread; given explicitly (scaled to about unit size) rather than left
for the embedding to difference and amplify. The encoder's memory is averaged over the
tokens and the MLP gives a mean and a log-variance per parameter, in unit coordinates (-1
and 1 at the randomization bounds).
"""

from __future__ import annotations

import torch
from torch import nn

from robomorph.model.architecture import LOGVAR_MAX, LOGVAR_MIN, ModelConfig

# Scales of the first and second differences of the normalized outputs (measured on
# multi-sine Panda stores: per-step changes at 60 Hz are 1/250 to 1/1000 of a channel's
# spread, their changes 1/1300 to 1/6000; scaled, both are of order one).
DIFF_SCALES = (100.0, 1500.0)


def mlp(cfg: ModelConfig) -> nn.Sequential:
    """The head's MLP: pooled memory -> mean and log-variance of each parameter."""
    return nn.Sequential(nn.LayerNorm(cfg.d_model, bias=cfg.bias), nn.Linear(cfg.d_model, cfg.d_model, bias=cfg.bias),
                         nn.GELU(), nn.Linear(cfg.d_model, 2 * cfg.n_params, bias=cfg.bias))


def forward(net, u_ctx: torch.Tensor, y_ctx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and log-variance (B, n_params) from a normalized context (B, Tc, n_u), (B, Tc, n_y)
    whose length is a multiple of the patch.

    Raises:
        ValueError: the network has no parameter head.
    """
    cfg = net.cfg
    if net.param_head is None:
        raise ValueError("this model has no parameter head (n_params 0): train it with --model.physics amortized")
    B, Tc = u_ctx.shape[:2]
    vel = torch.diff(y_ctx, dim=1, prepend=y_ctx[:, :1])
    acc = torch.diff(vel, dim=1, prepend=vel[:, :1])
    feats = torch.cat([u_ctx, y_ctx, DIFF_SCALES[0] * vel, DIFF_SCALES[1] * acc], dim=-1)
    tokens = feats.reshape(B, Tc // cfg.patch, cfg.patch * (cfg.n_u + 3 * cfg.n_y))
    mean, logvar = net.param_head(net.param_encoder(tokens).mean(dim=1)).split(cfg.n_params, dim=-1)
    return mean, logvar.clamp(LOGVAR_MIN, LOGVAR_MAX)
