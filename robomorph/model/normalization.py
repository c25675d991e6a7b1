"""The normalization a model carries: z-scores with training statistics, decodes predictions.

An ``nn.Module`` with the statistics as buffers, so a checkpoint restores it without the data.
With ``normalization="paper_window"`` it reproduces the paper's protocol instead: every window
z-scored with its own mean and std over context and query, which needs the query outputs'
statistics (``y_query_stats``) and so leaks them into the prediction (labelled everywhere).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch
from torch import nn

from robomorph.core.normalizations import NormalizationError, check_normalization

# Floor of a window's std (physical units): a flat channel stays finite, as StatsAccumulator's eps.
WINDOW_EPS = 1e-6


class Stats(Protocol):
    """Per-channel statistics as the Normalizer reads them (``robomorph.data.statistics.Stats``
    computes them from the training split; the model needs only this shape of them, so
    inference never imports the data code)."""

    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    n_u: int
    n_y: int


class Normalizer(nn.Module):
    """z-scores model inputs and targets with training statistics; decodes predictions.

    The statistics are persistent buffers, so a checkpoint of a model holding a Normalizer
    carries them and a loaded model predicts in physical units without the datamodule.

    With ``recenter=True`` the normalized context mean of each trajectory and channel is
    subtracted as well (from u_ctx and u_query with the u context mean; from y_ctx and the
    target with the y context mean) and added back by :meth:`decode`. Only the context window
    enters these means, so nothing derived from the query outputs reaches the prediction.

    Args:
        stats: training statistics; if None, identity statistics of width ``n_u``/``n_y``
            (to be filled by :meth:`set_stats` or ``load_state_dict``).
        n_u: input channels (needed without ``stats``; checked against it otherwise).
        n_y: output channels (as ``n_u``).
        recenter: also subtract the per-trajectory context mean.
        normalization: ``train_stats`` (the above) or ``paper_window`` (each window z-scored
            with its own context + query mean and std; the buffers are then unused).
    """

    def __init__(self, stats: Stats | None = None, n_u: int | None = None, n_y: int | None = None,
                 recenter: bool = False, normalization: str = "train_stats"):
        super().__init__()
        self.normalization = check_normalization(normalization, recenter)
        if stats is not None:
            for name, given, actual in (("n_u", n_u, stats.n_u), ("n_y", n_y, stats.n_y)):
                if given is not None and given != actual:
                    raise ValueError(f"{name}={given} disagrees with the statistics ({actual} channels)")
            n_u, n_y = stats.n_u, stats.n_y
        if n_u is None or n_y is None or n_u < 1 or n_y < 1:
            raise ValueError(f"Normalizer needs stats or positive n_u and n_y, got n_u={n_u}, n_y={n_y}")
        self.recenter = bool(recenter)
        self.register_buffer("u_mean", torch.zeros(n_u))
        self.register_buffer("u_std", torch.ones(n_u))
        self.register_buffer("y_mean", torch.zeros(n_y))
        self.register_buffer("y_std", torch.ones(n_y))
        if stats is not None:
            self.set_stats(stats)

    @property
    def uses_query_stats(self) -> bool:
        """True under ``paper_window``: encode and decode need ``y_query_stats``."""
        return self.normalization == "paper_window"

    @property
    def n_u(self) -> int:
        return int(self.u_mean.shape[0])

    @property
    def n_y(self) -> int:
        return int(self.y_mean.shape[0])

    def set_stats(self, stats: Stats) -> None:
        """Copies ``stats`` into the buffers (keeping their device and dtype)."""
        if (stats.n_u, stats.n_y) != (self.n_u, self.n_y):
            raise ValueError(f"statistics have n_u={stats.n_u}, n_y={stats.n_y}; "
                             f"this Normalizer has n_u={self.n_u}, n_y={self.n_y}")
        with torch.no_grad():
            for name in ("u_mean", "u_std", "y_mean", "y_std"):
                buf = getattr(self, name)
                buf.copy_(torch.as_tensor(getattr(stats, name), dtype=buf.dtype, device=buf.device))

    def _check(self, name: str, x: torch.Tensor, width: int) -> None:
        if x.dim() != 3 or x.shape[-1] != width:
            raise ValueError(f"{name} must be (B, T, {width}), got {tuple(x.shape)}")

    def _y_center(self, y_ctx: torch.Tensor) -> torch.Tensor | float:
        """Per-trajectory mean of the normalized context outputs, (B, 1, n_y); 0 without recenter."""
        if not self.recenter:
            return 0.0
        self._check("y_ctx", y_ctx, self.n_y)
        return ((y_ctx - self.y_mean) / self.y_std).mean(dim=1, keepdim=True)

    def _y_window(self, y_ctx: torch.Tensor, y_query_stats, th: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``paper_window``'s y mean and std (B, 1, n_y) over the context and ``th`` query steps."""
        if y_query_stats is None:
            raise NormalizationError(
                "normalization 'paper_window' scales each window with the mean and std of its query outputs: "
                "pass y_query_stats=(mean, std) of the outputs being predicted (only an evaluation has them)")
        q_mean, q_std = (torch.as_tensor(v, dtype=y_ctx.dtype, device=y_ctx.device).expand(len(y_ctx), self.n_y)
                         for v in y_query_stats)
        return pooled_moments(y_ctx, q_mean, q_std, th)

    def encode(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, y_query_stats=None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalizes the model inputs.

        Args:
            u_ctx: (B, Tc, n_u) context inputs, physical units.
            y_ctx: (B, Tc, n_y) context outputs, physical units.
            u_query: (B, Th, n_u) query inputs, physical units.
            y_query_stats: ``paper_window`` only: (mean, std) of the query outputs, (B, n_y) each.

        Returns:
            ``(u_ctx_n, y_ctx_n, u_query_n)`` with the same shapes.
        """
        self._check("u_ctx", u_ctx, self.n_u)
        self._check("y_ctx", y_ctx, self.n_y)
        self._check("u_query", u_query, self.n_u)
        if self.uses_query_stats:
            u_m, u_s = window_moments(torch.cat([u_ctx, u_query], dim=1))  # (B, 1, n_u): inputs, known at run time
            y_m, y_s = self._y_window(y_ctx, y_query_stats, u_query.shape[1])  # (B, 1, n_y): the leak
            return (u_ctx - u_m) / u_s, (y_ctx - y_m) / y_s, (u_query - u_m) / u_s
        u_ctx_n = (u_ctx - self.u_mean) / self.u_std
        u_query_n = (u_query - self.u_mean) / self.u_std
        y_ctx_n = (y_ctx - self.y_mean) / self.y_std
        if self.recenter:
            # Context-only means: the query window never feeds the statistics.
            u_c = u_ctx_n.mean(dim=1, keepdim=True)  # (B, 1, n_u)
            y_c = y_ctx_n.mean(dim=1, keepdim=True)  # (B, 1, n_y)
            u_ctx_n, u_query_n, y_ctx_n = u_ctx_n - u_c, u_query_n - u_c, y_ctx_n - y_c
        return u_ctx_n, y_ctx_n, u_query_n

    def encode_target(self, y_query: torch.Tensor, y_ctx: torch.Tensor, y_query_stats=None) -> torch.Tensor:
        """Normalizes target outputs with the transform applied to ``y_ctx`` (for the loss).

        Under ``paper_window`` the statistics default to those of ``y_query`` itself.
        """
        self._check("y_query", y_query, self.n_y)
        if self.uses_query_stats:
            stats = query_stats(y_query) if y_query_stats is None else y_query_stats
            m, s = self._y_window(y_ctx, stats, y_query.shape[1])
            return (y_query - m) / s
        return (y_query - self.y_mean) / self.y_std - self._y_center(y_ctx)

    def decode_scale(self, y_ctx: torch.Tensor, y_query_stats=None, th: int = 1) -> torch.Tensor:
        """The factor from normalized to physical units of the outputs (a std maps by it alone):
        the training std (n_y,), or under ``paper_window`` each window's std (B, 1, n_y)."""
        if self.uses_query_stats:
            return self._y_window(y_ctx, y_query_stats, th)[1]
        return self.y_std

    def decode(self, y_query_n: torch.Tensor, y_ctx: torch.Tensor, y_query_stats=None) -> torch.Tensor:
        """Maps normalized predictions (B, Th, n_y) back to physical units."""
        self._check("y_query_n", y_query_n, self.n_y)
        if self.uses_query_stats:
            m, s = self._y_window(y_ctx, y_query_stats, y_query_n.shape[1])
            return y_query_n * s + m
        return (y_query_n + self._y_center(y_ctx)) * self.y_std + self.y_mean

    def extra_repr(self) -> str:
        return f"n_u={self.n_u}, n_y={self.n_y}, recenter={self.recenter}, normalization={self.normalization}"


def window_moments(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-trajectory mean and population std over time of ``x (B, T, C)``: (B, 1, C) each."""
    mean = x.mean(dim=1, keepdim=True)
    return mean, x.var(dim=1, unbiased=False, keepdim=True).sqrt().clamp_min(WINDOW_EPS)


def query_stats(y_query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and population std over time of the query outputs (B, Th, n_y): (B, n_y) each."""
    return y_query.mean(dim=1), y_query.var(dim=1, unbiased=False).sqrt()


def pooled_moments(ctx: torch.Tensor, q_mean: torch.Tensor, q_std: torch.Tensor, th: int
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std over context + query from the context (B, Tc, C) and the query's moments.

    Exactly :func:`window_moments` of the concatenated window (Chan's merge of two samples),
    so a caller needs only the query outputs' mean and std, not the outputs themselves.
    """
    tc = ctx.shape[1]
    c_mean, c_var = ctx.mean(dim=1), ctx.var(dim=1, unbiased=False)  # (B, C)
    n = tc + th
    mean = (tc * c_mean + th * q_mean) / n
    var = (tc * (c_var + (c_mean - mean) ** 2) + th * (q_std ** 2 + (q_mean - mean) ** 2)) / n
    return mean.unsqueeze(1), var.clamp_min(0).sqrt().clamp_min(WINDOW_EPS).unsqueeze(1)
