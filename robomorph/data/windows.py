"""Trajectory splits, context/query windows and the seeded training sampler of the DataModule."""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from robomorph.data.sources import Source

# SeedSequence spawn keys of the independent random streams drawn from the DataModule's ``seed``.
SPLIT_STREAM, VAL_STREAM, TRAIN_STREAM = 0, 1, 2


def split_rows(n: int, fractions: tuple[float, float, float], seed: int, store_index: int
                ) -> dict[str, np.ndarray]:
    """Disjoint sorted trajectory indices ``{"train", "val", "test"}`` covering ``range(n)``."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(SPLIT_STREAM, store_index)))
    perm = rng.permutation(n)
    n_val, n_test = round(n * fractions[1]), round(n * fractions[2])
    return {"val": np.sort(perm[:n_val]), "test": np.sort(perm[n_val:n_val + n_test]),
            "train": np.sort(perm[n_val + n_test:])}


def pairs(per_store: list[np.ndarray]) -> np.ndarray:
    """(M, 2) int64 rows ``(store index, trajectory index)``, grouped by store."""
    parts = [np.stack([np.full(len(r), s), r], axis=1) for s, r in enumerate(per_store)]
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros((0, 2), np.int64)


class WindowDataset(Dataset):
    """Windows of fixed trajectories; a key is a row of ``pairs``, ``(row, offset)``,
    ``(row, offset, context_len, horizon)`` (horizon-aware training draws the lengths) or
    ``(row, offset, context_len, horizon, hide)``: ``hide`` true blanks the columns
    ``hidden_cols`` (``(u columns, y columns)``, set by the DataModule under joint dropout)
    with NaN, the mark of an absent channel."""

    def __init__(self, sources: list[Source], pairs: np.ndarray, context_len: int, horizon: int):
        self.sources, self.pairs = sources, pairs
        self.context_len, self.horizon = context_len, horizon
        # The robots' parameters ride along when the parameter head asks for them
        # (:meth:`add_params`); the sequence model never reads them.
        self.with_params = False
        self.hidden_cols: tuple[list[int], list[int]] | None = None
        # A residual model's prior of each window's query (prior stores, robomorph.data.priors).
        self.with_prior = False

    def __len__(self) -> int:
        return len(self.pairs)

    def add_params(self) -> bool:
        """Adds each robot's parameters (``params``) to the windows, when every store records
        them (a batch stacks the same keys); returns whether it did."""
        self.with_params = bool(self.sources) and all(getattr(s, "params", None) is not None for s in self.sources)
        return self.with_params

    def __getitem__(self, key: int | tuple[int, ...]) -> dict[str, torch.Tensor]:
        key = tuple(key) if isinstance(key, tuple) else (key,)
        row, offset, c, h, hide = key + (None, 0, self.context_len, self.horizon, False)[len(key):]
        s, i = self.pairs[row]
        u, y = self.sources[s].window(int(i), offset, offset + c + h)
        if hide and self.hidden_cols is not None:
            u, y = np.array(u, dtype=np.float32), np.array(y, dtype=np.float32)
            u[:, self.hidden_cols[0]], y[:, self.hidden_cols[1]] = np.nan, np.nan
        # Copies: a batch must not keep a view of a whole in-memory store alive.
        out = {k: torch.from_numpy(np.array(v, dtype=np.float32))
               for k, v in (("u_ctx", u[:c]), ("y_ctx", y[:c]), ("u_query", u[c:]), ("y_query", y[c:]))}
        if self.with_prior:
            # Prior stores hold fixed windows (offset 0, the record's context): the prior's first h steps.
            out["prior_query"] = torch.from_numpy(np.array(self.sources[s].prior[int(i), :h], dtype=np.float32))
        if self.with_params:
            out["params"] = torch.from_numpy(np.array(self.sources[s].params[int(i)], dtype=np.float64))
        return out


class MixtureSampler(Sampler):
    """Draws ``(row, offset, context_len, horizon)`` keys: store by weight, trajectory
    uniformly within the store, lengths uniformly within ``lengths`` (one pair per run of
    ``batch_size`` consecutive keys, i.e. per batch, so a batch stacks), offset uniformly
    over the valid range for those lengths (``random`` windows) or 0.

    With ``hide_prob`` > 0 each key gets a fifth entry, drawn last: whether the window hides
    the DataModule's ``joint_dropout`` columns (probability ``hide_prob``).

    Each pass uses a torch Generator seeded from ``(seed, epoch)``. Lightning calls
    :meth:`set_epoch` before each epoch; without it the epoch advances by one per pass.
    Fixed lengths draw nothing for them, so the stream equals that of fixed-length windows.
    """

    def __init__(self, base: np.ndarray, counts: np.ndarray, probs: np.ndarray, steps: np.ndarray,
                 n_samples: int, seed: int, random_window: bool,
                 lengths: tuple[int, int, int, int], batch_size: int, hide_prob: float = 0.0):
        self.base, self.counts = torch.as_tensor(base), torch.as_tensor(counts)
        self.probs, self.steps = torch.as_tensor(probs, dtype=torch.float64), torch.as_tensor(steps)
        self.n_samples, self.seed, self.random_window = n_samples, seed, random_window
        self.lengths, self.batch_size, self.hide_prob = lengths, batch_size, float(hide_prob)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n_samples

    def __iter__(self):
        state = np.random.SeedSequence(self.seed, spawn_key=(TRAIN_STREAM, self.epoch)).generate_state(1, np.uint64)
        g = torch.Generator().manual_seed(int(state[0]))
        self.epoch += 1
        store = torch.multinomial(self.probs, self.n_samples, replacement=True, generator=g)
        count = self.counts[store]
        within = (torch.rand(self.n_samples, generator=g, dtype=torch.float64) * count).long()
        row = self.base[store] + torch.minimum(within, count - 1)
        c, h = self._draw_lengths(g)
        offset = torch.zeros_like(row)
        if self.random_window:
            span = self.steps[store] - c - h + 1
            offset = torch.minimum((torch.rand(self.n_samples, generator=g, dtype=torch.float64) * span).long(), span - 1)
        keys = (row.tolist(), offset.tolist(), c.tolist(), h.tolist())
        if self.hide_prob > 0:  # drawn after the rest, so the windows themselves do not change
            keys += ((torch.rand(self.n_samples, generator=g, dtype=torch.float64) < self.hide_prob).tolist(),)
        return iter(zip(*keys))

    def _draw_lengths(self, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Context lengths and horizons (n_samples,), constant within each batch."""
        c_min, c_max, h_min, h_max = self.lengths
        n_batches = -(-self.n_samples // self.batch_size)
        out = []
        for low, high in ((c_min, c_max), (h_min, h_max)):
            per_batch = torch.full((n_batches,), high, dtype=torch.long)
            if low < high:
                per_batch = torch.randint(low, high + 1, (n_batches,), generator=g)
            out.append(per_batch.repeat_interleave(self.batch_size)[:self.n_samples])
        return out[0], out[1]
