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
    """Windows of fixed trajectories; a key is a row of ``pairs`` or ``(row, offset)``."""

    def __init__(self, sources: list[Source], pairs: np.ndarray, context_len: int, horizon: int):
        self.sources, self.pairs = sources, pairs
        self.context_len, self.horizon = context_len, horizon

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, key: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        row, offset = key if isinstance(key, tuple) else (key, 0)
        s, i = self.pairs[row]
        u, y = self.sources[s].window(int(i), offset, offset + self.context_len + self.horizon)
        c = self.context_len
        # Copies: a batch must not keep a view of a whole in-memory store alive.
        return {k: torch.from_numpy(np.array(v, dtype=np.float32))
                for k, v in (("u_ctx", u[:c]), ("y_ctx", y[:c]), ("u_query", u[c:]), ("y_query", y[c:]))}


class MixtureSampler(Sampler):
    """Draws ``(row, offset)`` keys: store by weight, trajectory uniformly within the store,
    offset uniformly over the valid range (``random`` windows) or 0.

    Each pass uses a torch Generator seeded from ``(seed, epoch)``. Lightning calls
    :meth:`set_epoch` before each epoch; without it the epoch advances by one per pass.
    """

    def __init__(self, base: np.ndarray, counts: np.ndarray, probs: np.ndarray, max_offsets: np.ndarray,
                 n_samples: int, seed: int, random_window: bool):
        self.base, self.counts = torch.as_tensor(base), torch.as_tensor(counts)
        self.probs, self.max_offsets = torch.as_tensor(probs, dtype=torch.float64), torch.as_tensor(max_offsets)
        self.n_samples, self.seed, self.random_window = n_samples, seed, random_window
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
        offset = torch.zeros_like(row)
        if self.random_window:
            span = self.max_offsets[store] + 1
            offset = torch.minimum((torch.rand(self.n_samples, generator=g, dtype=torch.float64) * span).long(), span - 1)
        return iter(zip(row.tolist(), offset.tolist()))
