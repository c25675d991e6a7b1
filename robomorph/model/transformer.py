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

Parameter names (for transfer and freezing): ``encoder.{embed,pos,blocks,ln_f}``,
``decoder.{embed,pos,init_embed,init_pos,blocks,ln_f}``, ``head``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from robomorph.core.config import ConfigError

__all__ = ["ModelConfig", "MetaModel"]

# Scales of the parameter encoder's first and second differences of the normalized outputs
# (measured on multi-sine Panda stores: per-step changes at 60 Hz are 1/250 to 1/1000 of a
# channel's spread, their changes 1/1300 to 1/6000; scaled, both are of order one).
DIFF_SCALES = (100.0, 1500.0)

# Range of the Gaussian head's log-variance (normalized units): std from 4.5e-5 to 150.
LOGVAR_MIN, LOGVAR_MAX = -20.0, 10.0


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the meta-model.

    Attributes:
        n_u: Input channels per step (joint torques).
        n_y: Output channels per step (pose and joint positions).
        d_model: Width of the residual stream.
        n_head: Attention heads; must divide ``d_model``.
        n_layer: Encoder blocks.
        n_layer_dec: Decoder blocks; ``None`` means the same as ``n_layer``.
        dropout: Dropout on embeddings, attention weights and residual branches.
        bias: Biases in the linear layers and LayerNorms.
        max_context: Longest context, in steps, the encoder's positional table covers.
        max_horizon: Longest query horizon, in steps, the decoder's table covers.
        patch: Steps per token (1 = one token per step, the paper's model). The default
            10 is the CPU-sized model's: about 13x faster per training step than 1 on two
            cores (README, "Training on a CPU"); the training module takes its defaults here.
        n_init: Last context steps given to the decoder as initial-condition tokens (0 = off);
            a multiple of ``patch``, at most ``max_context``; contexts must be at least this long.
        gaussian: The head also emits a log-variance per step and channel.
        n_params: Physical parameters the parameter head predicts from the encoder's memory
            (0 = no parameter head; the hybrid model's amortized identification,
            :meth:`MetaModel.forward_params`).
    """

    n_u: int = 7
    n_y: int = 14
    d_model: int = 128
    n_head: int = 4
    n_layer: int = 4
    n_layer_dec: int | None = None
    dropout: float = 0.0
    bias: bool = True
    max_context: int = 1024
    max_horizon: int = 1024
    patch: int = 10
    n_init: int = 0
    gaussian: bool = False
    n_params: int = 0

    def __post_init__(self) -> None:
        for name in ("n_u", "n_y", "d_model", "n_head", "n_layer", "max_context", "max_horizon", "patch"):
            _require_positive_int(name, getattr(self, name))
        if self.n_layer_dec is not None:
            _require_positive_int("n_layer_dec", self.n_layer_dec)
        if self.d_model % self.n_head != 0:
            raise ConfigError(f"ModelConfig.d_model ({self.d_model}) must be divisible by n_head ({self.n_head})")
        if isinstance(self.dropout, bool) or not isinstance(self.dropout, (int, float)) or not 0 <= self.dropout < 1:
            raise ConfigError(f"ModelConfig.dropout must be a number in [0, 1), got {self.dropout!r}")
        for name in ("bias", "gaussian"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"ModelConfig.{name} must be true or false, got {getattr(self, name)!r}")
        if isinstance(self.n_params, bool) or not isinstance(self.n_params, int) or self.n_params < 0:
            raise ConfigError(f"ModelConfig.n_params must be a non-negative integer, got {self.n_params!r}")
        if isinstance(self.n_init, bool) or not isinstance(self.n_init, int) or self.n_init < 0:
            raise ConfigError(f"ModelConfig.n_init must be a non-negative integer, got {self.n_init!r}")
        if self.n_init % self.patch or self.n_init > self.max_context:
            raise ConfigError(f"ModelConfig.n_init ({self.n_init}) must be a multiple of patch ({self.patch}) "
                              f"and at most max_context ({self.max_context})")
        for name in ("max_context", "max_horizon"):
            if getattr(self, name) < self.patch:
                raise ConfigError(f"ModelConfig.{name} ({getattr(self, name)}) must be at least patch ({self.patch})")

    @property
    def decoder_layers(self) -> int:
        """Number of decoder blocks."""
        return self.n_layer if self.n_layer_dec is None else self.n_layer_dec

    @property
    def context_tokens(self) -> int:
        """Rows of the encoder's positional table."""
        return math.ceil(self.max_context / self.patch)

    @property
    def horizon_tokens(self) -> int:
        """Rows of the decoder's positional table."""
        return math.ceil(self.max_horizon / self.patch)

    @property
    def init_tokens(self) -> int:
        """Initial-condition tokens ahead of the query tokens."""
        return self.n_init // self.patch


def _require_positive_int(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"ModelConfig.{name} must be a positive integer, got {value!r}")


def _attend(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, n_head: int, dropout: float, causal: bool) -> torch.Tensor:
    """Multi-head scaled dot-product attention on (B, T, d) projections, returns (B, Tq, d)."""
    B, Tq, d = q.shape
    Tk = k.shape[1]
    hd = d // n_head
    q = q.view(B, Tq, n_head, hd).transpose(1, 2)  # (B, h, Tq, hd)
    k = k.view(B, Tk, n_head, hd).transpose(1, 2)  # (B, h, Tk, hd)
    v = v.view(B, Tk, n_head, hd).transpose(1, 2)  # (B, h, Tk, hd)
    y = F.scaled_dot_product_attention(q, k, v, dropout_p=dropout, is_causal=causal)  # (B, h, Tq, hd)
    return y.transpose(1, 2).reshape(B, Tq, d)


class SelfAttention(nn.Module):
    """Multi-head self-attention, causal (decoder) or not (encoder)."""

    def __init__(self, cfg: ModelConfig, causal: bool) -> None:
        super().__init__()
        self.c_attn = nn.Linear(cfg.d_model, 3 * cfg.d_model, bias=cfg.bias)
        self.c_proj = nn.Linear(cfg.d_model, cfg.d_model, bias=cfg.bias)
        self.resid_drop = nn.Dropout(cfg.dropout)
        self.n_head, self.dropout, self.causal = cfg.n_head, cfg.dropout, causal

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        q, k, v = self.c_attn(x).chunk(3, dim=-1)  # 3 x (B, T, d)
        p = self.dropout if self.training else 0.0
        return self.resid_drop(self.c_proj(_attend(q, k, v, self.n_head, p, self.causal)))


class CrossAttention(nn.Module):
    """Multi-head attention from decoder tokens to the encoder memory (no mask)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.c_q = nn.Linear(cfg.d_model, cfg.d_model, bias=cfg.bias)
        self.c_kv = nn.Linear(cfg.d_model, 2 * cfg.d_model, bias=cfg.bias)
        self.c_proj = nn.Linear(cfg.d_model, cfg.d_model, bias=cfg.bias)
        self.resid_drop = nn.Dropout(cfg.dropout)
        self.n_head, self.dropout = cfg.n_head, cfg.dropout

    def forward(self, x: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        q = self.c_q(x)  # (B, Tq, d)
        k, v = self.c_kv(memory).chunk(2, dim=-1)  # 2 x (B, Tm, d)
        p = self.dropout if self.training else 0.0
        return self.resid_drop(self.c_proj(_attend(q, k, v, self.n_head, p, causal=False)))


class MLP(nn.Module):
    """Position-wise GELU feed-forward layer, 4x wide."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.c_fc = nn.Linear(cfg.d_model, 4 * cfg.d_model, bias=cfg.bias)
        self.c_proj = nn.Linear(4 * cfg.d_model, cfg.d_model, bias=cfg.bias)
        self.drop = nn.Dropout(cfg.dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.drop(self.c_proj(F.gelu(self.c_fc(x))))


class EncoderBlock(nn.Module):
    """Pre-LayerNorm block: non-causal self-attention, then MLP."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.ln_1 = nn.LayerNorm(cfg.d_model, bias=cfg.bias)
        self.attn = SelfAttention(cfg, causal=False)
        self.ln_2 = nn.LayerNorm(cfg.d_model, bias=cfg.bias)
        self.mlp = MLP(cfg)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x))
        return x + self.mlp(self.ln_2(x))


class DecoderBlock(nn.Module):
    """Pre-LayerNorm block: causal self-attention, cross-attention to the memory, MLP."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.ln_1 = nn.LayerNorm(cfg.d_model, bias=cfg.bias)
        self.attn = SelfAttention(cfg, causal=True)
        self.ln_2 = nn.LayerNorm(cfg.d_model, bias=cfg.bias)
        self.cross = CrossAttention(cfg)
        self.ln_3 = nn.LayerNorm(cfg.d_model, bias=cfg.bias)
        self.mlp = MLP(cfg)

    def forward(self, x: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x))
        x = x + self.cross(self.ln_2(x), memory)
        return x + self.mlp(self.ln_3(x))


class Encoder(nn.Module):
    """Context tokens (B, Nc, k*(n_u+n_y)) -> memory (B, Nc, d)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.embed = nn.Linear(cfg.patch * (cfg.n_u + cfg.n_y), cfg.d_model, bias=cfg.bias)
        self.pos = nn.Embedding(cfg.context_tokens, cfg.d_model)
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(EncoderBlock(cfg) for _ in range(cfg.n_layer))
        self.ln_f = nn.LayerNorm(cfg.d_model, bias=cfg.bias)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        pos = torch.arange(tokens.shape[1], device=tokens.device)
        x = self.drop(self.embed(tokens) + self.pos(pos))  # (B, Nc, d)
        for block in self.blocks:
            x = block(x)
        return self.ln_f(x)


class Decoder(nn.Module):
    """Query tokens (B, Nq, k*n_u), optional initial-condition tokens (B, Ni, k*(n_u+n_y))
    and memory (B, Nc, d) -> features of the query tokens (B, Nq, d)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.embed = nn.Linear(cfg.patch * cfg.n_u, cfg.d_model, bias=cfg.bias)
        self.pos = nn.Embedding(cfg.horizon_tokens, cfg.d_model)
        if cfg.n_init:
            self.init_embed = nn.Linear(cfg.patch * (cfg.n_u + cfg.n_y), cfg.d_model, bias=cfg.bias)
            self.init_pos = nn.Embedding(cfg.init_tokens, cfg.d_model)
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(DecoderBlock(cfg) for _ in range(cfg.decoder_layers))
        self.ln_f = nn.LayerNorm(cfg.d_model, bias=cfg.bias)

    def forward(self, tokens: torch.Tensor, memory: torch.Tensor, init: torch.Tensor | None = None) -> torch.Tensor:
        pos = torch.arange(tokens.shape[1], device=tokens.device)
        x = self.embed(tokens) + self.pos(pos)  # (B, Nq, d)
        n_init = 0
        if init is not None:
            n_init = init.shape[1]
            ipos = torch.arange(n_init, device=init.device)
            # Ahead of the query: the causal mask lets every query token attend to them.
            x = torch.cat([self.init_embed(init) + self.init_pos(ipos), x], dim=1)  # (B, Ni+Nq, d)
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
        # The parameter head has its own encoder over the context only, so no query value can
        # reach the parameters (and their simulation) by construction. Its tokens add each
        # output's per-step change and change of change (see forward_params).
        self.param_encoder = Encoder(dataclasses.replace(cfg, n_y=3 * cfg.n_y)) if cfg.n_params else None
        self.param_head = nn.Sequential(
            nn.LayerNorm(cfg.d_model, bias=cfg.bias), nn.Linear(cfg.d_model, cfg.d_model, bias=cfg.bias), nn.GELU(),
            nn.Linear(cfg.d_model, 2 * cfg.n_params, bias=cfg.bias)) if cfg.n_params else None
        self.apply(_init_weights)
        # GPT-2: residual projections shrink with depth so the stream's variance stays put.
        for stack, n_layers in ((self.encoder, cfg.n_layer), (self.decoder, cfg.decoder_layers)):
            for name, p in stack.named_parameters():
                if name.endswith("c_proj.weight"):
                    nn.init.normal_(p, mean=0.0, std=0.02 / math.sqrt(2 * n_layers))

    def forward(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor) -> torch.Tensor:
        """Predict the outputs over the query horizon.

        Args:
            u_ctx: Context inputs (B, Tc, n_u), Tc a multiple of ``patch``, at most ``max_context``
                and at least ``n_init``.
            y_ctx: Context outputs (B, Tc, n_y).
            u_query: Query inputs (B, Th, n_u), Th at most ``max_horizon``.

        Returns:
            Predicted query outputs (B, Th, n_y) (the mean of a Gaussian head).

        Raises:
            ValueError: On a wrong shape or a length the positional tables or patch do not admit.
        """
        return self.forward_dist(u_ctx, y_ctx, u_query)[0]

    def forward_dist(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean (B, Th, n_y) and log-variance (B, Th, n_y), or None without a Gaussian head."""
        cfg = self.cfg
        B, Tc, Th = self._check_inputs(u_ctx, y_ctx, u_query)
        k = cfg.patch
        ctx = torch.cat([u_ctx, y_ctx], dim=-1)  # (B, Tc, n_u + n_y)
        ctx = ctx.reshape(B, Tc // k, k * (cfg.n_u + cfg.n_y))  # (B, Nc, k*(n_u+n_y))
        init = ctx[:, Tc // k - cfg.init_tokens:] if cfg.n_init else None  # (B, Ni, k*(n_u+n_y))
        pad = -Th % k
        if pad:
            u_query = F.pad(u_query, (0, 0, 0, pad))  # zeros after the last step
        query = u_query.reshape(B, (Th + pad) // k, k * cfg.n_u)  # (B, Nq, k*n_u)
        memory = self.encoder(ctx)  # (B, Nc, d)
        h = self.decoder(query, memory, init)  # (B, Nq, d)
        m = 2 if cfg.gaussian else 1
        y = self.head(h).reshape(B, Th + pad, m * cfg.n_y)[:, :Th]  # (B, Th, m*n_y)
        if not cfg.gaussian:
            return y, None
        mean, logvar = y.split(cfg.n_y, dim=-1)
        # Bounded so that exp() can neither overflow nor divide by zero in the NLL.
        return mean, logvar.clamp(LOGVAR_MIN, LOGVAR_MAX)

    def forward_params(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and log-variance (B, n_params) of the physical parameters in unit coordinates
        (-1 and 1 at the randomization bounds), from the normalized context alone.

        Raises:
            ValueError: the model has no parameter head, or the context has a wrong shape.
        """
        cfg = self.cfg
        if self.param_head is None:
            raise ValueError("this model has no parameter head (n_params 0): train it with --model.physics amortized")
        B, Tc, _ = self._check_inputs(u_ctx, y_ctx, u_ctx[:, :1])  # the context's checks (no query here)
        # Damping, friction and inertia show in velocities and accelerations, which are a
        # hundredth of a normalized position's spread at 60 Hz: given explicitly (scaled to
        # about unit size) rather than left for the embedding to difference and amplify.
        vel = torch.diff(y_ctx, dim=1, prepend=y_ctx[:, :1])
        acc = torch.diff(vel, dim=1, prepend=vel[:, :1])
        feats = torch.cat([u_ctx, y_ctx, DIFF_SCALES[0] * vel, DIFF_SCALES[1] * acc], dim=-1)
        ctx = feats.reshape(B, Tc // cfg.patch, cfg.patch * (cfg.n_u + 3 * cfg.n_y))
        out = self.param_head(self.param_encoder(ctx).mean(dim=1))
        mean, logvar = out.split(cfg.n_params, dim=-1)
        return mean, logvar.clamp(LOGVAR_MIN, LOGVAR_MAX)

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


def _init_weights(module: nn.Module) -> None:
    if isinstance(module, nn.Linear):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
    elif isinstance(module, nn.Embedding):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
