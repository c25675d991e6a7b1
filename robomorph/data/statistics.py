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

from robomorph.core.channels import channel_kind

# Rows per block when reducing large arrays: float64 copies of a block stay small.
_BLOCK_ROWS = 256
# Each channel's std is floored at this fraction of the median std of the channels of its kind
# (joint angles together, torques together: robomorph.core.channels.channel_kind). A joint that
# barely moves in the training split (the Kinova's last joint: 10^-5 of its test spread) would
# otherwise be divided by a near-zero spread, and a from-scratch model trained on it diverged
# (issue 62); a tenth of its kind's spread still leaves a channel that moves less its own scale.
STD_FLOOR_FRACTION = 0.1


class _Moments:
    """Streaming per-channel count, mean and sum of squared deviations (Chan et al.).

    Each block is reduced in float64 and merged exactly, so reading a store chunk by chunk
    gives the same result as one pass over the whole array (up to rounding). Counts are per
    channel: a block may cover some channels only (a store of an arm with fewer joints).
    """

    def __init__(self, width: int):
        self.count = np.zeros(width, dtype=np.int64)
        self.mean = np.zeros(width)
        self.m2 = np.zeros(width)

    def update(self, x: np.ndarray, cols: list[int] | None = None) -> None:
        sel = slice(None) if cols is None else np.asarray(cols, dtype=np.int64)
        width = self.mean.shape[0] if cols is None else len(cols)
        x = np.asarray(x, dtype=np.float64).reshape(-1, width)
        k = x.shape[0]
        if k == 0:
            return
        mean_b = x.mean(axis=0)
        m2_b = ((x - mean_b) ** 2).sum(axis=0)
        count = self.count[sel]
        total = count + k
        delta = mean_b - self.mean[sel]
        self.mean[sel] = self.mean[sel] + delta * (k / total)
        self.m2[sel] = self.m2[sel] + m2_b + delta**2 * (count * k / total)
        self.count[sel] = total

    def std(self, eps: float, kinds: list[str] | None = None, fraction: float = STD_FLOOR_FRACTION) -> np.ndarray:
        """Population std floored at ``eps`` and, with ``kinds`` (one per channel), at ``fraction`` of the
        median std of the covered channels of the same kind (:data:`STD_FLOOR_FRACTION`)."""
        std = np.maximum(np.sqrt(self.m2 / np.maximum(self.count, 1)), eps)
        if kinds is None:
            return std
        if len(kinds) != len(std):
            raise ValueError(f"{len(kinds)} channel kinds for {len(std)} channels")
        kinds_arr, covered = np.asarray(kinds), self.count > 0
        floored = std.copy()
        for kind in set(kinds_arr[covered]):
            group = covered & (kinds_arr == kind)
            floored[group] = np.maximum(std[group], fraction * np.median(std[group]))
        return floored


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
        """Number of time steps seen so far (of the channel seen most)."""
        return int(self._u.count.max(initial=0))

    def update(self, u: np.ndarray, y: np.ndarray, u_cols: list[int] | None = None,
               y_cols: list[int] | None = None) -> None:
        """Adds a block of trajectories ``u (k, T, n_u)`` and ``y (k, T, n_y)``.

        ``u_cols`` / ``y_cols``: the channels (columns of this accumulator) that the block's
        columns are, for a store that has some of the channels only (per channel role: each
        channel's statistics come from the stores that have it); default all, in order.
        """
        if u.shape[:-1] != y.shape[:-1]:
            raise ValueError(f"u {u.shape} and y {y.shape} must share their leading (N, T) axes")
        for start in range(0, max(len(u), 1), _BLOCK_ROWS):
            self._u.update(u[start:start + _BLOCK_ROWS], u_cols)
            self._y.update(y[start:start + _BLOCK_ROWS], y_cols)

    def finalize(self, eps: float = 1e-6, u_names: list[str] | None = None, y_names: list[str] | None = None,
                 fraction: float = STD_FLOOR_FRACTION) -> "Stats":
        """Returns the statistics; std is floored at ``eps`` so a flat channel stays finite, and, where the
        channels are named, at ``fraction`` of the median std of the channels of its kind
        (:func:`robomorph.core.channels.channel_kind`; :data:`STD_FLOOR_FRACTION`): a joint that barely
        moves in the training split is scaled as a tenth of a typical joint's motion, not by its own
        near-zero spread.

        A channel no block covered (a channel set wider than the data, e.g. a multi-arm model
        fine-tuned on an arm with fewer joints, for which the channel is always absent) gets
        mean 0 and std 1: it is never read on this data.
        """
        if self.count == 0:
            raise ValueError("no samples were given: cannot compute normalization statistics")
        u_kinds, y_kinds = (None if names is None else [channel_kind(n) for n in names] for names in (u_names, y_names))
        u_std, y_std = self._u.std(eps, u_kinds, fraction), self._y.std(eps, y_kinds, fraction)
        u_std[self._u.count == 0], y_std[self._y.count == 0] = 1.0, 1.0
        return Stats(u_mean=self._u.mean.copy(), u_std=u_std, y_mean=self._y.mean.copy(), y_std=y_std)


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
    def from_arrays(cls, u: np.ndarray, y: np.ndarray, eps: float = 1e-6, u_names: list[str] | None = None,
                    y_names: list[str] | None = None) -> "Stats":
        """Statistics over all trajectories and all steps of ``u (N, T, n_u)``, ``y (N, T, n_y)``; with the
        channels' names, each std floored by its kind as :meth:`StatsAccumulator.finalize` says.

        Reduces in float64 blocks of trajectories, so a large float32 array is never copied whole.
        """
        acc = StatsAccumulator(u.shape[-1], y.shape[-1])
        acc.update(u, y)
        return acc.finalize(eps, u_names, y_names)

