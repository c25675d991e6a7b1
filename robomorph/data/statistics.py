"""Training-split statistics of (u, y): per-channel mean and std, streamed over blocks.

The paper's code z-scored every trajectory over its whole window, query included, so a
test-time prediction was rescaled with statistics of the very outputs it predicted
(README, section 9). Here the scale comes from the training split only
(:class:`Stats`, computed here without torch), and the optional per-trajectory recentring
(:class:`robomorph.model.normalization.Normalizer` with ``recenter=True``) uses the context
window only.

The paper's own protocol is still available, labelled, for reproducing its numbers:
``normalization: paper_window`` (:mod:`robomorph.core.normalizations`) z-scores every window
with its own mean and std over context and query together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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

