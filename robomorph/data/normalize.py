"""Normalization of (u, y) with training-split statistics, never with the predicted outputs.

The paper's code z-scored every trajectory over its whole window, query included, so a
test-time prediction was rescaled with statistics of the very outputs it predicted
(REFERENCE.md section 1). Here the scale comes from the training split only
(:class:`Stats`), and the optional per-trajectory recentring (:class:`Normalizer` with
``recenter=True``) uses the context window only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

# Rows per block when reducing large arrays: float64 copies of a block stay small.
_BLOCK_ROWS = 256


class _Moments:
    """Streaming per-channel count, mean and sum of squared deviations (Chan et al.).

    Each block is reduced in float64 and merged exactly, so reading a store chunk by chunk
    gives the same result as one pass over the whole array (up to rounding).
    """

    def __init__(self, width: int):
        self.count = 0
        self.mean = np.zeros(width)
        self.m2 = np.zeros(width)

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.mean.shape[0])
        k = x.shape[0]
        if k == 0:
            return
        mean_b = x.mean(axis=0)
        m2_b = ((x - mean_b) ** 2).sum(axis=0)
        total = self.count + k
        delta = mean_b - self.mean
        self.mean = self.mean + delta * (k / total)
        self.m2 = self.m2 + m2_b + delta**2 * (self.count * k / total)
        self.count = total

    def std(self, eps: float) -> np.ndarray:
        return np.maximum(np.sqrt(self.m2 / max(self.count, 1)), eps)


class StatsAccumulator:
    """Builds :class:`Stats` from blocks of trajectories (for stores larger than memory).

    Example::

        acc = StatsAccumulator(n_u, n_y)
        for u_block, y_block in blocks:      # (k, T, n_u), (k, T, n_y)
            acc.update(u_block, y_block)
        stats = acc.finalize()
    """

    def __init__(self, n_u: int, n_y: int):
        self._u = _Moments(n_u)
        self._y = _Moments(n_y)

    @property
    def count(self) -> int:
        """Number of time steps (samples per channel) seen so far."""
        return self._u.count

    def update(self, u: np.ndarray, y: np.ndarray) -> None:
        """Adds a block of trajectories ``u (k, T, n_u)`` and ``y (k, T, n_y)``."""
        if u.shape[:-1] != y.shape[:-1]:
            raise ValueError(f"u {u.shape} and y {y.shape} must share their leading (N, T) axes")
        for start in range(0, max(len(u), 1), _BLOCK_ROWS):
            self._u.update(u[start:start + _BLOCK_ROWS])
            self._y.update(y[start:start + _BLOCK_ROWS])

    def finalize(self, eps: float = 1e-6) -> "Stats":
        """Returns the statistics; std is floored at ``eps`` so a flat channel stays finite."""
        if self.count == 0:
            raise ValueError("no samples were given: cannot compute normalization statistics")
        return Stats(u_mean=self._u.mean.copy(), u_std=self._u.std(eps),
                     y_mean=self._y.mean.copy(), y_std=self._y.std(eps))


@dataclass
class Stats:
    """Per-channel mean and standard deviation (population std, float64) of u and y."""

    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray

    def __post_init__(self) -> None:
        for name in ("u_mean", "u_std", "y_mean", "y_std"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1))
        if self.u_mean.shape != self.u_std.shape or self.y_mean.shape != self.y_std.shape:
            raise ValueError("mean and std must have one value per channel")
        if (self.u_std <= 0).any() or (self.y_std <= 0).any():
            raise ValueError("standard deviations must be positive")

    @property
    def n_u(self) -> int:
        return int(self.u_mean.shape[0])

    @property
    def n_y(self) -> int:
        return int(self.y_mean.shape[0])

    @classmethod
    def from_arrays(cls, u: np.ndarray, y: np.ndarray, eps: float = 1e-6) -> "Stats":
        """Statistics over all trajectories and all steps of ``u (N, T, n_u)``, ``y (N, T, n_y)``.

        Reduces in float64 blocks of trajectories, so a large float32 array is never copied whole.
        """
        acc = StatsAccumulator(u.shape[-1], y.shape[-1])
        acc.update(u, y)
        return acc.finalize(eps)

    @classmethod
    def from_blocks(cls, blocks: Iterable[tuple[np.ndarray, np.ndarray]], n_u: int, n_y: int,
                    eps: float = 1e-6) -> "Stats":
        """Statistics over an iterable of ``(u, y)`` blocks (e.g. a store read chunk by chunk)."""
        acc = StatsAccumulator(n_u, n_y)
        for u, y in blocks:
            acc.update(u, y)
        return acc.finalize(eps)

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-able form (lists of floats), for checkpoints and run records."""
        return {k: getattr(self, k).tolist() for k in ("u_mean", "u_std", "y_mean", "y_std")}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Stats":
        """Inverse of :meth:`to_dict`."""
        return cls(**{k: np.asarray(d[k], dtype=np.float64) for k in ("u_mean", "u_std", "y_mean", "y_std")})


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
    """

    def __init__(self, stats: Stats | None = None, n_u: int | None = None, n_y: int | None = None,
                 recenter: bool = False):
        super().__init__()
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

    @property
    def stats(self) -> Stats:
        """The current statistics as a :class:`Stats` (float64 numpy)."""
        return Stats(*(getattr(self, k).detach().cpu().double().numpy()
                       for k in ("u_mean", "u_std", "y_mean", "y_std")))

    def _check(self, name: str, x: torch.Tensor, width: int) -> None:
        if x.dim() != 3 or x.shape[-1] != width:
            raise ValueError(f"{name} must be (B, T, {width}), got {tuple(x.shape)}")

    def _y_center(self, y_ctx: torch.Tensor) -> torch.Tensor | float:
        """Per-trajectory mean of the normalized context outputs, (B, 1, n_y); 0 without recenter."""
        if not self.recenter:
            return 0.0
        self._check("y_ctx", y_ctx, self.n_y)
        return ((y_ctx - self.y_mean) / self.y_std).mean(dim=1, keepdim=True)

    def encode(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalizes the model inputs.

        Args:
            u_ctx: (B, Tc, n_u) context inputs, physical units.
            y_ctx: (B, Tc, n_y) context outputs, physical units.
            u_query: (B, Th, n_u) query inputs, physical units.

        Returns:
            ``(u_ctx_n, y_ctx_n, u_query_n)`` with the same shapes.
        """
        self._check("u_ctx", u_ctx, self.n_u)
        self._check("y_ctx", y_ctx, self.n_y)
        self._check("u_query", u_query, self.n_u)
        u_ctx_n = (u_ctx - self.u_mean) / self.u_std
        u_query_n = (u_query - self.u_mean) / self.u_std
        y_ctx_n = (y_ctx - self.y_mean) / self.y_std
        if self.recenter:
            # Context-only means: the query window never feeds the statistics.
            u_c = u_ctx_n.mean(dim=1, keepdim=True)  # (B, 1, n_u)
            y_c = y_ctx_n.mean(dim=1, keepdim=True)  # (B, 1, n_y)
            u_ctx_n, u_query_n, y_ctx_n = u_ctx_n - u_c, u_query_n - u_c, y_ctx_n - y_c
        return u_ctx_n, y_ctx_n, u_query_n

    def encode_target(self, y_query: torch.Tensor, y_ctx: torch.Tensor) -> torch.Tensor:
        """Normalizes target outputs with the transform applied to ``y_ctx`` (for the loss)."""
        self._check("y_query", y_query, self.n_y)
        return (y_query - self.y_mean) / self.y_std - self._y_center(y_ctx)

    def decode(self, y_query_n: torch.Tensor, y_ctx: torch.Tensor) -> torch.Tensor:
        """Maps normalized predictions (B, Th, n_y) back to physical units."""
        self._check("y_query_n", y_query_n, self.n_y)
        return (y_query_n + self._y_center(y_ctx)) * self.y_std + self.y_mean

    def extra_repr(self) -> str:
        return f"n_u={self.n_u}, n_y={self.n_y}, recenter={self.recenter}"
