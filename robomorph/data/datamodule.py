"""The training DataModule: stores -> trajectory splits -> context/query windows -> batches.

Batches are dicts of float32 tensors in physical units::

    u_ctx (B, Tc, n_u), y_ctx (B, Tc, n_y), u_query (B, Th, n_u), y_query (B, Th, n_y)

Normalization belongs to the model (:class:`robomorph.model.normalization.Normalizer`), fed with
``datamodule.stats``: statistics of the training split only.

Randomness comes from one ``seed`` through ``numpy.random.SeedSequence`` streams (splits,
validation subset, training stream per epoch). Every random draw of the training stream
(store, trajectory, window offset) happens in the sampler in the main process, so the data
do not depend on ``num_workers`` or on worker seeding.
"""

from __future__ import annotations

import math
import os
from typing import Literal

import lightning.pytorch as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from robomorph.data.sampling import TRAIN_STREAM, MixtureSampler
from robomorph.data.statistics import Stats, StatsAccumulator, check_normalization
from robomorph.data.store import check_inputs, open_store

# Stores whose u and y together fit in this many bytes are read into memory once (a random
# batch from disk costs 34-55 ms against 0.1 ms from memory, REFERENCE.md section 3).
MEMORY_BUDGET_BYTES = 4 * 2**30
# SeedSequence spawn keys of the independent random streams drawn from ``seed``
# (the training stream's key, TRAIN_STREAM = 2, lives with its sampler).
_SPLIT_STREAM, _VAL_STREAM = 0, 1


class _Source:
    """One store's u and y: numpy arrays in memory, or read one chunk of rows at a time.

    The on-demand mode keeps a one-chunk cache and reopens the store in each process (a
    handle is never shared across fork or pickling), so DataLoader workers are safe.
    """

    def __init__(self, path: str, inputs: str = "total"):
        ds = open_store(path)
        if ds.n < 1:
            raise ValueError(f"{path} holds no trajectories (n=0)")
        self.path, self.n, self.steps, self.chunk = path, ds.n, ds.steps, ds.chunk
        # The array the model reads as u: the total torque or the command (data.inputs).
        self.u_array = ds.check_inputs(inputs)
        self.u_names, self.y_names, self.dt = ds.input_names(inputs), ds.y_names, ds.dt
        self.u: np.ndarray | None = None
        self.y: np.ndarray | None = None
        self._ds, self._pid = ds, os.getpid()
        self._cache: tuple[int, np.ndarray | None, np.ndarray | None] = (-1, None, None)

    @property
    def nbytes(self) -> int:
        return self.n * self.steps * (len(self.u_names) + len(self.y_names)) * 4

    @property
    def n_blocks(self) -> int:
        return -(-self.n // self.chunk)

    def _store(self):
        if self._ds is None or self._pid != os.getpid():
            self._ds, self._pid, self._cache = open_store(self.path), os.getpid(), (-1, None, None)
        return self._ds

    def load(self) -> None:
        """Reads all of u and y into memory."""
        ds = self._store()
        self.u, self.y = ds.read(self.u_array), ds.read("y")

    def block(self, c: int) -> tuple[int, np.ndarray, np.ndarray]:
        """Rows of chunk ``c``: ``(first row, u (k, T, n_u), y (k, T, n_y))``."""
        c0, c1 = c * self.chunk, min(self.n, (c + 1) * self.chunk)
        if self.u is not None:
            return c0, self.u[c0:c1], self.y[c0:c1]
        if self._cache[0] != c:
            ds = self._store()
            self._cache = (c, ds.read(self.u_array, slice(c0, c1)), ds.read("y", slice(c0, c1)))
        return c0, self._cache[1], self._cache[2]

    def window(self, i: int, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Steps ``[start, stop)`` of trajectory ``i``: ``(u (L, n_u), y (L, n_y))``."""
        c0, u, y = self.block(i // self.chunk)
        return u[i - c0, start:stop], y[i - c0, start:stop]

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_ds"], state["_cache"] = None, (-1, None, None)
        return state


def _scan(src: _Source, train_rows: np.ndarray, stop: int, acc: StatsAccumulator | None) -> None:
    """One pass over a store: refuses non-finite values and feeds training rows' steps
    ``[0, stop)`` to ``acc``."""
    in_train = np.zeros(src.n, dtype=bool)
    in_train[train_rows] = True
    for c in range(src.n_blocks):
        c0, u, y = src.block(c)
        for name, arr in (("u", u), ("y", y)):
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=(1, 2)))
            if bad.size:
                raise ValueError(f"{src.path}: trajectory {c0 + int(bad[0])} has NaN/inf values in '{name}' "
                                 f"({bad.size} bad trajectories in rows {c0}..{c0 + len(u) - 1}); "
                                 "regenerate the store or drop those rows")
        mask = in_train[c0:c0 + len(u)]
        if acc is not None and mask.any():
            acc.update(u[mask, :stop], y[mask, :stop])


def _split_rows(n: int, fractions: tuple[float, float, float], seed: int, store_index: int
                ) -> dict[str, np.ndarray]:
    """Disjoint sorted trajectory indices ``{"train", "val", "test"}`` covering ``range(n)``."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_SPLIT_STREAM, store_index)))
    perm = rng.permutation(n)
    n_val, n_test = round(n * fractions[1]), round(n * fractions[2])
    return {"val": np.sort(perm[:n_val]), "test": np.sort(perm[n_val:n_val + n_test]),
            "train": np.sort(perm[n_val + n_test:])}


def _pairs(per_store: list[np.ndarray]) -> np.ndarray:
    """(M, 2) int64 rows ``(store index, trajectory index)``, grouped by store."""
    parts = [np.stack([np.full(len(r), s), r], axis=1) for s, r in enumerate(per_store)]
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros((0, 2), np.int64)


class _WindowDataset(Dataset):
    """Windows of fixed trajectories; a key is a row of ``pairs``, ``(row, offset)`` or
    ``(row, offset, context_len, horizon)`` (horizon-aware training draws the lengths)."""

    def __init__(self, sources: list[_Source], pairs: np.ndarray, context_len: int, horizon: int):
        self.sources, self.pairs = sources, pairs
        self.context_len, self.horizon = context_len, horizon

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, key: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        row, offset, c, h = (key + (self.context_len, self.horizon))[:4] if isinstance(key, tuple) else \
            (key, 0, self.context_len, self.horizon)
        s, i = self.pairs[row]
        u, y = self.sources[s].window(int(i), offset, offset + c + h)
        # Copies: a batch must not keep a view of a whole in-memory store alive.
        return {k: torch.from_numpy(np.array(v, dtype=np.float32))
                for k, v in (("u_ctx", u[:c]), ("y_ctx", y[:c]), ("u_query", u[c:]), ("y_query", y[c:]))}


class RoboMorphDataModule(L.LightningDataModule):
    """Trajectory splits, context/query windows and a weighted mixture of stores.

    Args:
        stores: training store paths (one path or a list); all must share u_names, y_names and dt.
        weights: sampling probability of each store in the training stream (normalized);
            default proportional to each store's number of training trajectories.
        test_store: a separate store used whole as the test split; ``split``'s test fraction is
            then ignored and train/val keep their ratio.
        context_len: context steps; exactly one of ``context_len`` and ``context_frac``.
        context_frac: context as a fraction of the trajectory length:
            ``context_len = round(context_frac * T)`` with T the shortest store's length.
        horizon: query steps predicted after the context.
        window: ``start``: windows begin at step 0 (the paper: 200 + 800 of 1000); ``random``:
            a seeded random offset per training sample (validation and test still use ``start``).
        context_min, horizon_min: horizon-aware training: each training batch draws its context
            length from ``[context_min, context_len]`` and its horizon from ``[horizon_min,
            horizon]`` (seeded; validation and test keep the maxima), so short horizons are
            trained for as well. ``None``: always the maxima.
        split: (train, val, test) fractions of each store's trajectories; they sum to 1.
        seed: root seed of the splits, the validation subset and the training stream.
        batch_size: trajectories per batch.
        num_workers: DataLoader worker processes (the data do not depend on it).
        in_memory: read stores fully into memory; default: when they all fit in 4 GiB.
        recenter: recorded for the model's Normalizer (context-mean recentring); not used here.
        normalization: recorded for the model's Normalizer: ``train_stats`` (``stats`` below)
            or ``paper_window`` (the paper's protocol, each window z-scored over context and
            query; it leaks the query outputs' statistics and is labelled so wherever it is used).
        val_subset: at most this many validation trajectories (a fixed seeded subset).
        inputs: ``total``: u is the total joint torque (the paper's input, array ``u``);
            ``command``: u is the command without the gravity compensation the arm adds
            (array ``u_cmd``; stores of schema 2 on). The checkpoint records the choice.
        train_samples_per_epoch: windows per training epoch; default the number of training
            trajectories.
    """

    def __init__(self, stores: list[str] | str = "data/demo/multisine.zarr", weights: list[float] | None = None,
                 test_store: str | None = None, context_len: int | None = 200, context_frac: float | None = None,
                 horizon: int = 800, window: Literal["start", "random"] = "start",
                 context_min: int | None = None, horizon_min: int | None = None,
                 split: tuple[float, float, float] = (0.8, 0.1, 0.1), seed: int = 0, batch_size: int = 16,
                 num_workers: int = 0, in_memory: bool | None = None, recenter: bool = False,
                 val_subset: int = 256, train_samples_per_epoch: int | None = None,
                 normalization: Literal["train_stats", "paper_window"] = "train_stats",
                 inputs: Literal["total", "command"] = "total"):
        super().__init__()
        self.save_hyperparameters()
        self.stores = [stores] if isinstance(stores, str) else list(stores)
        self.weights, self.test_store = weights, test_store
        self.context_len, self.context_frac, self.horizon, self.window = context_len, context_frac, horizon, window
        self.context_min, self.horizon_min = context_min, horizon_min
        self.split, self.seed, self.batch_size, self.num_workers = tuple(split), seed, batch_size, num_workers
        self.in_memory, self.recenter, self.val_subset = in_memory, recenter, val_subset
        self.train_samples_per_epoch = train_samples_per_epoch
        self.inputs = inputs
        self.normalization = normalization
        self._validate()
        self._ready = False

    def _validate(self) -> None:
        if not self.stores:
            raise ValueError("stores: give at least one store path")
        check_inputs(self.inputs)
        paths = [os.path.realpath(p) for p in self.stores]
        if len(set(paths)) != len(paths):
            raise ValueError(f"stores lists a store twice: {self.stores}")
        if self.test_store is not None and os.path.realpath(self.test_store) in paths:
            raise ValueError(f"test_store {self.test_store} is also a training store: its trajectories would leak")
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != (len(self.stores),) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
                raise ValueError(f"weights must be {len(self.stores)} non-negative numbers with a positive sum "
                                 f"(one per store), got {self.weights}")
        if (self.context_len is None) == (self.context_frac is None):
            raise ValueError("give exactly one of context_len and context_frac "
                             f"(got context_len={self.context_len}, context_frac={self.context_frac})")
        if self.context_len is not None and self.context_len < 1:
            raise ValueError(f"context_len must be >= 1, got {self.context_len}")
        if self.context_frac is not None and not 0 < self.context_frac < 1:
            raise ValueError(f"context_frac must be in (0, 1), got {self.context_frac}")
        if self.window not in ("start", "random"):
            raise ValueError(f"window must be 'start' or 'random', got {self.window!r}")
        f = self.split
        if len(f) != 3 or any(not math.isfinite(x) or x < 0 for x in f) or abs(sum(f) - 1) > 1e-6 or f[0] <= 0:
            raise ValueError(f"split must be three non-negative fractions (train, val, test) summing to 1 "
                             f"with train > 0, got {self.split}")
        for name, value, low in (("horizon", self.horizon, 1), ("batch_size", self.batch_size, 1),
                                 ("num_workers", self.num_workers, 0), ("val_subset", self.val_subset, 1),
                                 ("seed", self.seed, 0)):
            if value < low:
                raise ValueError(f"{name} must be >= {low}, got {value}")
        if self.horizon_min is not None and not 1 <= self.horizon_min <= self.horizon:
            raise ValueError(f"horizon_min must be in [1, horizon={self.horizon}], got {self.horizon_min}")
        if self.context_min is not None and (self.context_min < 1 or (
                self.context_len is not None and self.context_min > self.context_len)):
            raise ValueError(f"context_min must be in [1, context_len={self.context_len}], got {self.context_min}")
        check_normalization(self.normalization, self.recenter)
        if self.train_samples_per_epoch is not None and self.train_samples_per_epoch < 1:
            raise ValueError(f"train_samples_per_epoch must be >= 1, got {self.train_samples_per_epoch}")

    def setup(self, stage: str | None = None) -> None:
        """Opens and checks the stores, splits them and computes the training statistics.

        ``self.stats`` covers every training trajectory of every training store (each counted
        once, whatever ``weights`` says) over the steps that training windows can cover:
        ``[0, context_len + horizon)`` for ``window="start"``, all ``T`` steps for ``"random"``.
        Validation and test trajectories never enter it. Idempotent.
        """
        if self._ready:
            return
        sources = [_Source(p, self.inputs) for p in self.stores]
        if self.test_store is not None:
            sources.append(_Source(self.test_store, self.inputs))
        self._check_compatible(sources)
        self._resolve_lengths(sources)
        total = sum(s.nbytes for s in sources)
        self.loaded = self.in_memory if self.in_memory is not None else total <= MEMORY_BUDGET_BYTES
        if self.loaded:
            for src in sources:
                src.load()
        self._make_splits(sources)
        self._compute_stats(sources)
        self._build_datasets(sources)
        self.sources, self._ready = sources, True

    def _check_compatible(self, sources: list[_Source]) -> None:
        ref = sources[0]
        for src in sources[1:]:
            for what, a, b in (("u_names", ref.u_names, src.u_names), ("y_names", ref.y_names, src.y_names)):
                if a != b:
                    raise ValueError(f"stores disagree on {what}: {ref.path} has {a}, {src.path} has {b}; "
                                     "all stores of one run must share u_names, y_names and dt")
            if not math.isclose(ref.dt, src.dt, rel_tol=1e-9):
                raise ValueError(f"stores disagree on dt: {ref.path} has {ref.dt}, {src.path} has {src.dt}")
        self.u_names, self.y_names, self.dt = ref.u_names, ref.y_names, ref.dt
        self.n_u, self.n_y = len(ref.u_names), len(ref.y_names)

    def _resolve_lengths(self, sources: list[_Source]) -> None:
        if self.context_frac is not None:
            t_min = min(s.steps for s in sources)
            self.context_len = round(self.context_frac * t_min)
            if self.context_len < 1:
                raise ValueError(f"context_frac {self.context_frac} of T={t_min} gives no context step")
            if self.context_min is not None and self.context_min > self.context_len:
                raise ValueError(f"context_min {self.context_min} exceeds the context of {self.context_len} steps "
                                 f"that context_frac {self.context_frac} gives")
        need = self.context_len + self.horizon
        for src in sources:
            if src.steps < need:
                raise ValueError(f"{src.path} has trajectories of T={src.steps} steps, but context_len "
                                 f"{self.context_len} + horizon {self.horizon} = {need} are needed")

    def _make_splits(self, sources: list[_Source]) -> None:
        f = self.split
        if self.test_store is not None:
            f = (f[0] / (f[0] + f[1]), f[1] / (f[0] + f[1]), 0.0)
        self.splits = [_split_rows(src.n, f, self.seed, k) for k, src in enumerate(sources[:len(self.stores)])]
        if self.test_store is not None:
            empty = np.zeros(0, dtype=np.int64)
            self.splits.append({"train": empty, "val": empty, "test": np.arange(sources[-1].n)})
        counts = np.array([len(s["train"]) for s in self.splits[:len(self.stores)]])
        w = np.asarray(self.weights if self.weights is not None else counts, dtype=float)
        for k, ck in enumerate(counts):
            if ck == 0:
                raise ValueError(f"{self.stores[k]} has no training trajectories (n={sources[k].n}, split "
                                 f"{self.split}): add trajectories or change split")
        self.probs = w / w.sum()

    def _compute_stats(self, sources: list[_Source]) -> None:
        acc = StatsAccumulator(self.n_u, self.n_y)
        for k, src in enumerate(sources):
            stop = src.steps if self.window == "random" else self.context_len + self.horizon
            _scan(src, self.splits[k]["train"], stop, acc if k < len(self.stores) else None)
        self.stats: Stats = acc.finalize()

    def _build_datasets(self, sources: list[_Source]) -> None:
        train = _pairs([s["train"] for s in self.splits])
        val = _pairs([s["val"] for s in self.splits])
        self.n_val_total = len(val)
        if len(val) > self.val_subset:
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(_VAL_STREAM,)))
            val = val[np.sort(rng.choice(len(val), self.val_subset, replace=False))]
        test = _pairs([s["test"] for s in self.splits])
        ctx, h = self.context_len, self.horizon
        self.train_set, self.val_set, self.test_set = (_WindowDataset(sources, p, ctx, h) for p in (train, val, test))
        counts = np.array([len(s["train"]) for s in self.splits[:len(self.stores)]])
        self.train_sampler = MixtureSampler(
            base=np.concatenate([[0], np.cumsum(counts)[:-1]]), counts=counts, probs=self.probs,
            steps=np.array([src.steps for src in sources[:len(self.stores)]]),
            n_samples=self.train_samples_per_epoch or len(train), seed=self.seed,
            random_window=self.window == "random", batch_size=self.batch_size,
            lengths=(self.context_min or ctx, ctx, self.horizon_min or h, h))

    def _loader(self, split: str) -> DataLoader:
        self.setup()
        sampler = self.train_sampler if split == "train" else None
        return DataLoader(getattr(self, f"{split}_set"), batch_size=self.batch_size, sampler=sampler,
                          shuffle=False, num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        """The weighted, seeded training stream (``train_samples_per_epoch`` windows)."""
        return self._loader("train")

    def val_dataloader(self) -> DataLoader:
        """The fixed validation subset, in order, start windows."""
        return self._loader("val")

    def test_dataloader(self) -> DataLoader:
        """The test split (or the whole ``test_store``), in order, start windows."""
        return self._loader("test")

    def describe(self) -> dict:
        """A JSON-able summary for logging: stores, split sizes, window lengths."""
        self.setup()
        per_store = {src.path: {"n": src.n, "steps": src.steps, **{k: len(v) for k, v in sp.items()}}
                     for src, sp in zip(self.sources, self.splits)}
        return {
            "stores": list(self.stores), "test_store": self.test_store, "per_store": per_store,
            "weights": [float(p) for p in self.probs],
            "train": len(self.train_set), "val": self.n_val_total, "val_used": len(self.val_set),
            "test": len(self.test_set), "train_samples_per_epoch": len(self.train_sampler),
            "context_len": self.context_len, "horizon": self.horizon, "window": self.window,
            "context_min": self.context_min, "horizon_min": self.horizon_min,
            "n_u": self.n_u, "n_y": self.n_y, "dt": self.dt, "in_memory": bool(self.loaded),
            "seed": self.seed, "split": list(self.split), "normalization": self.normalization,
            "inputs": self.inputs,
        }
