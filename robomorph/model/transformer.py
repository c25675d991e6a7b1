"""Encoder-decoder transformer meta-model for in-context simulation of dynamical systems.

The model maps a context window ``(u_ctx, y_ctx)`` of one system and a query input
sequence ``u_query`` to the outputs ``y_query`` that the same system would produce
(the paper's model-free simulation, after Forgione et al. 2023):

- encoder: ``Linear(n_u + n_y -> d)`` token embedding plus learned positions, non-causal
  pre-LayerNorm blocks, final LayerNorm, giving the memory ``zeta``;
- decoder: ``Linear(n_u -> d)`` embedding plus learned positions, pre-LayerNorm blocks
  with causal self-attention, cross-attention to ``zeta`` and a GELU MLP, final LayerNorm;
- head: ``Linear(d -> n_y)``.

Inputs arrive normalized; nothing in here looks at statistics of any tensor.

Token reduction (``patch = k > 1``): k consecutive steps are flattened into one token,
so the encoder embeds ``k * (n_u + n_y)`` values per token, the decoder ``k * n_u`` and
the head emits ``k * n_y`` values that are unflattened back to steps. Attention cost
falls by about ``k**2``. The decoder is causal between patches: the prediction for a
step in patch j sees query inputs of patches ``<= j`` only, i.e. at most ``k - 1``
future steps inside its own patch.

Length rules:
- positions are indexed from the first step of the context and from the first step of
  the query, so a shorter context or horizon than trained uses the first rows of the
  tables; lengths beyond ``max_context`` / ``max_horizon`` are errors (the tables are
  sized at training time);
- the context length must be a multiple of ``patch``: padding it would change what the
  non-causal encoder sees, so the caller decides which steps to drop (normally the
  oldest ``Tc % patch``);
- any horizon is accepted: the query is zero-padded at the end to a multiple of
  ``patch`` and the extra outputs are cut off. Causality between patches means the
  padding cannot reach earlier patches; steps of the final, partial patch see zeros in
  place of their own future inputs.

Initial conditions (``n_init > 0``, after Rufolo et al. 2024): the last ``n_init`` context
steps, inputs and outputs, enter the decoder as its first tokens (own embedding and
positions), ahead of the query tokens. Causal self-attention lets every query token see
them, so the prediction continues from the measured state instead of recovering it through
cross-attention alone. They are context values: no query output can reach them. Their
outputs are dropped.

Gaussian head (``gaussian=True``): the head emits a mean and a log-variance per step and
channel (:meth:`MetaModel.forward_dist`); ``forward`` returns the mean. With
``gaussian=False`` and ``n_init=0`` the parameters and outputs are those of the original
model, so its checkpoints load unchanged.

Absent channels (``channel_mask=True``, stores of arms with different joint counts): NaN in
an input channel marks it absent for that trajectory (the DataModule and the Predictor pad
an arm's arrays to the model's channel set with NaN). The channel enters as 0 (its training
mean, in normalized units) and ``absent``, a learned ``Linear(n_u + n_y -> d)`` of the
0/1 absent-channel vector, is added to every encoder, initial-condition and query token, so
the network knows a 0 that is missing from a 0 that was measured. The head still emits every
output channel; the loss and the metrics skip the absent ones.

Residual (``residual=True``): the decoder also reads a prior prediction of the query outputs
(normalized as the outputs are), concatenated to the query inputs step by step, so its embedding
takes ``k * (n_u + n_y)`` values per token. The head's output (zero at initialization) is then a
correction in units of ``prior_scale`` (a buffer, (max_horizon, n_y): the prior's RMS error per
query step and channel on the training data, normalized) that the caller adds to the prior
(:func:`robomorph.inference.checkpoint.predict_normalized_dist`). A prior is a prediction from the
context and the query inputs alone (the physics hybrid's), so no query output reaches the network
through it. With ``residual=False`` nothing changes.

Parameter names (for transfer and freezing): ``encoder.{embed,pos,absent,blocks,ln_f}``,
``decoder.{embed,pos,absent,init_embed,init_pos,blocks,ln_f}``, ``head``.
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F
from torch import nn

from robomorph.model import parameter_head
from robomorph.model.architecture import LOGVAR_MAX, LOGVAR_MIN, ModelConfig
from robomorph.model.blocks import DecoderBlock, EncoderBlock

__all__ = ["ModelConfig", "MetaModel"]

class Encoder(nn.Module):
    """Context tokens (B, Nc, k*(n_u+n_y)) -> memory (B, Nc, d)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.embed = nn.Linear(cfg.patch * (cfg.n_u + cfg.n_y), cfg.d_model, bias=cfg.bias)
        self.pos = nn.Embedding(cfg.context_tokens, cfg.d_model)
        if cfg.channel_mask:
            self.absent = nn.Linear(cfg.n_u + cfg.n_y, cfg.d_model, bias=False)
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(EncoderBlock(cfg) for _ in range(cfg.n_layer))
        self.ln_f = nn.LayerNorm(cfg.d_model, bias=cfg.bias)

    def forward(self, tokens: torch.Tensor, absent: torch.Tensor | None = None) -> torch.Tensor:
        pos = torch.arange(tokens.shape[1], device=tokens.device)
        x = self.embed(tokens) + self.pos(pos)  # (B, Nc, d)
        if absent is not None:
            x = x + self.absent(absent).unsqueeze(1)  # (B, 1, d): the same for every token
        x = self.drop(x)
        for block in self.blocks:
            x = block(x)
        return self.ln_f(x)


class Decoder(nn.Module):
    """Query tokens (B, Nq, k*(n_u+n_prior)), optional initial-condition tokens (B, Ni, k*(n_u+n_y))
    and memory (B, Nc, d) -> features of the query tokens (B, Nq, d)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.embed = nn.Linear(cfg.patch * (cfg.n_u + cfg.n_prior), cfg.d_model, bias=cfg.bias)
        self.pos = nn.Embedding(cfg.horizon_tokens, cfg.d_model)
        if cfg.channel_mask:
            self.absent = nn.Linear(cfg.n_u + cfg.n_y, cfg.d_model, bias=False)
        if cfg.n_init:
            self.init_embed = nn.Linear(cfg.patch * (cfg.n_u + cfg.n_y), cfg.d_model, bias=cfg.bias)
            self.init_pos = nn.Embedding(cfg.init_tokens, cfg.d_model)
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(DecoderBlock(cfg) for _ in range(cfg.decoder_layers))
        self.ln_f = nn.LayerNorm(cfg.d_model, bias=cfg.bias)

    def forward(self, tokens: torch.Tensor, memory: torch.Tensor, init: torch.Tensor | None = None,
                absent: torch.Tensor | None = None) -> torch.Tensor:
        pos = torch.arange(tokens.shape[1], device=tokens.device)
        x = self.embed(tokens) + self.pos(pos)  # (B, Nq, d)
        n_init = 0
        if init is not None:
            n_init = init.shape[1]
            ipos = torch.arange(n_init, device=init.device)
            # Ahead of the query: the causal mask lets every query token attend to them.
            x = torch.cat([self.init_embed(init) + self.init_pos(ipos), x], dim=1)  # (B, Ni+Nq, d)
        if absent is not None:
            x = x + self.absent(absent).unsqueeze(1)  # (B, 1, d)
        x = self.drop(x)
        for block in self.blocks:
            x = block(x, memory)
        return self.ln_f(x[:, n_init:])


class MetaModel(nn.Module):
    """In-context meta-model: ``(u_ctx, y_ctx, u_query) -> y_query``.

    Args:
        cfg: Architecture; kept as ``self.cfg``.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)
        self.head = nn.Linear(cfg.d_model, cfg.patch * cfg.n_y * (2 if cfg.gaussian else 1), bias=cfg.bias)
        # The parameter head (robomorph.model.parameter_head): its own encoder, over the context only.
        self.param_encoder = Encoder(dataclasses.replace(cfg, n_y=3 * cfg.n_y)) if cfg.n_params else None
        self.param_head = parameter_head.mlp(cfg) if cfg.n_params else None
        self.apply(_init_weights)
        if cfg.residual:
            # An untrained correction is zero: the residual model starts as its prior.
            nn.init.zeros_(self.head.weight)
            if self.head.bias is not None:
                nn.init.zeros_(self.head.bias)
            # The unit of the correction per query step and channel (normalized outputs): the prior's typical
            # error there on the training data, set by the training module; a buffer, so the checkpoint keeps it.
            self.register_buffer("prior_scale", torch.ones(cfg.max_horizon, cfg.n_y))
        # GPT-2: residual projections shrink with depth so the stream's variance stays put.
        for stack, n_layers in ((self.encoder, cfg.n_layer), (self.decoder, cfg.decoder_layers)):
            for name, p in stack.named_parameters():
                if name.endswith("c_proj.weight"):
                    nn.init.normal_(p, mean=0.0, std=0.02 / math.sqrt(2 * n_layers))

    def forward(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                prior: torch.Tensor | None = None) -> torch.Tensor:
        """Predict the outputs over the query horizon.

        Args:
            u_ctx: Context inputs (B, Tc, n_u), Tc a multiple of ``patch``, at most ``max_context``
                and at least ``n_init``.
            y_ctx: Context outputs (B, Tc, n_y).
            u_query: Query inputs (B, Th, n_u), Th at most ``max_horizon``.
            prior: A residual model's prior prediction of the query outputs (B, Th, n_y), normalized;
                required with ``residual`` and refused without it.

        Returns:
            Predicted query outputs (B, Th, n_y) (the mean of a Gaussian head); a residual model's
            correction to add to ``prior``.

        Raises:
            ValueError: On a wrong shape or a length the positional tables or patch do not admit.
        """
        return self.forward_dist(u_ctx, y_ctx, u_query, prior)[0]

    def forward_dist(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                     prior: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean (B, Th, n_y) and log-variance (B, Th, n_y), or None without a Gaussian head."""
        cfg = self.cfg
        B, Tc, Th = self._check_inputs(u_ctx, y_ctx, u_query)
        k = cfg.patch
        absent = None
        if cfg.channel_mask:
            u_ctx, y_ctx, u_query, absent = absent_channels(u_ctx, y_ctx, u_query)
        if cfg.residual or prior is not None:
            u_query = torch.cat([u_query, self._check_prior(prior, B, Th)], dim=-1)  # (B, Th, n_u + n_y)
        ctx = torch.cat([u_ctx, y_ctx], dim=-1)  # (B, Tc, n_u + n_y)
        ctx = ctx.reshape(B, Tc // k, k * (cfg.n_u + cfg.n_y))  # (B, Nc, k*(n_u+n_y))
        init = ctx[:, Tc // k - cfg.init_tokens:] if cfg.n_init else None  # (B, Ni, k*(n_u+n_y))
        pad = -Th % k
        if pad:
            u_query = F.pad(u_query, (0, 0, 0, pad))  # zeros after the last step
        query = u_query.reshape(B, (Th + pad) // k, k * (cfg.n_u + cfg.n_prior))  # (B, Nq, k*(n_u+n_prior))
        memory = self._encode(ctx, absent)  # (B, Nc, d)
        h = self.decoder(query, memory, init, absent)  # (B, Nq, d)
        m = 2 if cfg.gaussian else 1
        y = self.head(h).reshape(B, Th + pad, m * cfg.n_y)[:, :Th]  # (B, Th, m*n_y)
        if not cfg.gaussian:
            return y, None
        mean, logvar = y.split(cfg.n_y, dim=-1)
        # Bounded so that exp() can neither overflow nor divide by zero in the NLL.
        return mean, logvar.clamp(LOGVAR_MIN, LOGVAR_MAX)

    def _check_prior(self, prior: torch.Tensor | None, B: int, Th: int) -> torch.Tensor:
        if not self.cfg.residual:
            raise ValueError("this model takes no prior (ModelConfig.residual is false): drop prior")
        if prior is None:
            raise ValueError("a residual model needs the prior prediction of the query outputs: pass prior "
                             f"(B, Th, {self.cfg.n_y})")
        if prior.shape != (B, Th, self.cfg.n_y):
            raise ValueError(f"prior must have shape (B, Th, n_y) = ({B}, {Th}, {self.cfg.n_y}), got {tuple(prior.shape)}")
        return prior

    def _encode(self, ctx: torch.Tensor, absent: torch.Tensor | None) -> torch.Tensor:
        """The encoder's memory; candidates on one context (model-predictive control: every row
        the same context) are encoded once in inference, which gives the same memory."""
        B = ctx.shape[0]
        if B > 1 and not self.training and torch.equal(ctx, ctx[:1].expand_as(ctx)) and (
                absent is None or torch.equal(absent, absent[:1].expand_as(absent))):
            return self.encoder(ctx[:1], None if absent is None else absent[:1]).expand(B, -1, -1)
        return self.encoder(ctx, absent)

    def forward_params(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and log-variance (B, n_params) of the physical parameters in unit coordinates,
        from the normalized context alone (:func:`robomorph.model.parameter_head.forward`)."""
        self._check_inputs(u_ctx, y_ctx, u_ctx[:, :1])  # the context's checks (no query here)
        return parameter_head.forward(self, u_ctx, y_ctx)

    def num_params(self, trainable_only: bool = False) -> int:
        """Number of parameters (all of them, or only those with ``requires_grad``)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad or not trainable_only)

    def _check_inputs(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor) -> tuple[int, int, int]:
        cfg = self.cfg
        for name, x, width, length in (
            ("u_ctx", u_ctx, cfg.n_u, "Tc"),
            ("y_ctx", y_ctx, cfg.n_y, "Tc"),
            ("u_query", u_query, cfg.n_u, "Th"),
        ):
            if x.ndim != 3 or x.shape[-1] != width:
                raise ValueError(f"{name} must have shape (B, {length}, {width}), got {tuple(x.shape)}")
        B, Tc, Th = u_ctx.shape[0], u_ctx.shape[1], u_query.shape[1]
        if y_ctx.shape[:2] != u_ctx.shape[:2]:
            raise ValueError(f"y_ctx must have shape (B, Tc, {cfg.n_y}) = ({B}, {Tc}, {cfg.n_y}) to match u_ctx, "
                             f"got {tuple(y_ctx.shape)}")
        if u_query.shape[0] != B:
            raise ValueError(f"u_query must have shape (B, Th, {cfg.n_u}) with B = {B} as in u_ctx, got {tuple(u_query.shape)}")
        if Tc < 1 or Th < 1:
            raise ValueError(f"context and query need at least one step, got Tc = {Tc}, Th = {Th}")
        if Tc > cfg.max_context:
            raise ValueError(f"context length Tc = {Tc} exceeds max_context = {cfg.max_context}, the longest the "
                             "positional table covers; raise ModelConfig.max_context at training time")
        if Th > cfg.max_horizon:
            raise ValueError(f"query horizon Th = {Th} exceeds max_horizon = {cfg.max_horizon}, the longest the "
                             "positional table covers; raise ModelConfig.max_horizon at training time")
        if Tc < cfg.n_init:
            raise ValueError(f"context length Tc = {Tc} is shorter than n_init = {cfg.n_init}, the context steps "
                             "the decoder takes as initial conditions; give a longer context")
        if Tc % cfg.patch:
            raise ValueError(f"context length Tc = {Tc} is not a multiple of patch = {cfg.patch}; drop the oldest "
                             f"{Tc % cfg.patch} steps (u_ctx[:, {Tc % cfg.patch}:]) or choose a multiple of patch")
        return B, Tc, Th


def absent_channels(u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The inputs with NaN (absent channels) as 0, and the absent mask (B, n_u + n_y) of 0/1.

    A channel is absent for a trajectory when its context holds NaN (padding fills a whole
    channel, so one NaN marks it); the query inputs follow the context's channels.
    """
    absent = torch.cat([torch.isnan(u_ctx).any(dim=1), torch.isnan(y_ctx).any(dim=1)], dim=-1)  # (B, n_u+n_y)
    clean = [torch.nan_to_num(x, nan=0.0) for x in (u_ctx, y_ctx, u_query)]
    return clean[0], clean[1], clean[2], absent.to(u_ctx.dtype)


def _init_weights(module: nn.Module) -> None:
    if isinstance(module, nn.Linear):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
    elif isinstance(module, nn.Embedding):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
