"""The seeded training stream: which window of which trajectory each training sample is.

Every random draw (store, trajectory, lengths, offset) happens here, in the main process,
so the data do not depend on ``num_workers`` or on worker seeding.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Sampler

# SeedSequence spawn key of the training stream (the datamodule's splits use 0, validation 1).
TRAIN_STREAM = 2


class MixtureSampler(Sampler):
    """Draws ``(row, offset, context_len, horizon)`` keys: store by weight, trajectory
    uniformly within the store, lengths uniformly within ``lengths`` (one pair per run of
    ``batch_size`` consecutive keys, i.e. per batch, so a batch stacks), offset uniformly
    over the valid range for those lengths (``random`` windows) or 0.

    Each pass uses a torch Generator seeded from ``(seed, epoch)``. Lightning calls
    :meth:`set_epoch` before each epoch; without it the epoch advances by one per pass.
    Fixed lengths draw nothing for them, so the stream equals that of fixed-length windows.
    """

    def __init__(self, base: np.ndarray, counts: np.ndarray, probs: np.ndarray, steps: np.ndarray,
                 n_samples: int, seed: int, random_window: bool,
                 lengths: tuple[int, int, int, int], batch_size: int):
        self.base, self.counts = torch.as_tensor(base), torch.as_tensor(counts)
        self.probs, self.steps = torch.as_tensor(probs, dtype=torch.float64), torch.as_tensor(steps)
        self.n_samples, self.seed, self.random_window = n_samples, seed, random_window
        self.lengths, self.batch_size = lengths, batch_size
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
        return iter(zip(row.tolist(), offset.tolist(), c.tolist(), h.tolist()))

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
