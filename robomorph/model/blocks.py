"""The transformer's building blocks: attention, the MLP and the pre-LayerNorm blocks.

Used by :mod:`robomorph.model.transformer` (the encoder, the decoder and the parameter head's
encoder); the parameter names they create (``attn.c_attn``, ``cross.c_q``, ``mlp.c_fc``, ...)
are those of every checkpoint.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from robomorph.model.architecture import ModelConfig


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
        if memory.shape[0] > 1 and memory.stride(0) == 0:
            # One memory shared by every row (candidates on one context, robomorph.model.transformer):
            # projected once, which a third of the decoder's work for 256 candidates had been.
            kv = self.c_kv(memory[:1]).expand(memory.shape[0], -1, -1)
        else:
            kv = self.c_kv(memory)
        k, v = kv.chunk(2, dim=-1)  # 2 x (B, Tm, d)
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
