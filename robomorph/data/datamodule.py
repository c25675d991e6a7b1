"""The training DataModule: stores -> trajectory splits -> context/query windows -> batches.

Batches are dicts of float32 tensors in physical units::

    u_ctx (B, Tc, n_u), y_ctx (B, Tc, n_y), u_query (B, Th, n_u), y_query (B, Th, n_y)

and, from prior stores (:mod:`robomorph.data.priors`), ``prior_query`` (B, Th, n_y): a physics
prior's prediction of the query outputs, which a residual model corrects.

Normalization belongs to the model (:class:`robomorph.model.normalization.Normalizer`), fed with
``datamodule.stats``: statistics of the training split only.

Randomness comes from one ``seed`` through ``numpy.random.SeedSequence`` streams (splits,
validation subset, training stream per epoch). Every random draw of the training stream
(store, trajectory, context and query lengths, window offset) happens in the sampler in the main process, so the data
do not depend on ``num_workers`` or on worker seeding.
"""

from __future__ import annotations

import math
import os
from typing import Literal

import lightning.pytorch as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from robomorph.core.inputs import check_inputs
from robomorph.core.names import INPUTS, NORMALIZATIONS
from robomorph.core.normalizations import check_normalization

from robomorph.data.priors import check_prior_windows, common_prior, prior_error_rms
from robomorph.data.channel_sets import ColumnAccumulator, channel_set, last_joint, layouts, pads_any

# DataError re-exported: callers catch it from here.
from robomorph.data.sources import DataError, Source, check_lengths, compatible, scan  # noqa: F401
from robomorph.data.splits import check_held_out, split_store
from robomorph.data.statistics import Stats, StatsAccumulator
from robomorph.data.windows import VAL_STREAM, MixtureSampler, WindowDataset, pairs

# Stores whose u and y together fit in this many bytes are read into memory once: a random
# batch read from disk costs hundreds of times one taken from memory (README, section 9).
MEMORY_BUDGET_BYTES = 4 * 2**30


class RoboMorphDataModule(L.LightningDataModule):
    """Trajectory splits, context/query windows and a weighted mixture of stores.

    Args:
        stores: training store paths (one path or a list); all share dt, and u_names and y_names or a
            subset of the widest store's (arms with fewer joints, padded: :mod:`robomorph.data.channel_sets`).
        weights: sampling probability of each store in the training stream (normalized);
            default proportional to each store's number of training trajectories.
        val_store: a separate store used whole as the validation split (e.g. another
            recording of a real robot); ``split``'s validation fraction is then ignored and
            train/test keep their ratio. ``best.ckpt`` is chosen on this store.
        test_store: a separate store used whole as the test split; ``split``'s test fraction is
            then ignored and train/val keep their ratio.
        context_len: context steps; exactly one of ``context_len`` and ``context_frac``.
        context_frac: context as a fraction of the trajectory length:
            ``context_len = round(context_frac * T)`` with T the shortest store's length.
        horizon: query steps predicted after the context.
        window: ``start``: windows begin at step 0 (the paper: 200 + 800 of 1000); ``random``:
            a seeded random offset per training sample (validation and test still use ``start``).
        context_min, horizon_min: horizon-aware training: each training batch draws its context length
            from ``[context_min, context_len]`` and its horizon from ``[horizon_min, horizon]``
            (seeded; validation and test keep the maxima). ``None``: always the maxima.
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
        channels: ``{"u": [...], "y": [...]}``, the run's channel set; default the widest training
            store's. Give a multi-arm model's set to fine-tune it on one arm (the channel mask is
            then on, as in the model's architecture).
        joint_dropout: probability that a training window hides the last joint of the channel
            set (its ``tau`` and ``q`` channels, as NaN): the model then learns to read an arm
            with one joint fewer (a 6-joint arm with a model of 7-joint arms: zero-shot to a
            UR5e). Validation and test windows hide nothing. Turns the channel mask on.
    """

    def __init__(self, stores: list[str] | str = "data/demo/multisine.zarr", weights: list[float] | None = None,
                 test_store: str | None = None, val_store: str | None = None, context_len: int | None = 200,
                 context_frac: float | None = None, horizon: int = 800, window: Literal["start", "random"] = "start",
                 context_min: int | None = None, horizon_min: int | None = None,
                 split: tuple[float, float, float] = (0.8, 0.1, 0.1), seed: int = 0, batch_size: int = 16,
                 num_workers: int = 0, in_memory: bool | None = None, recenter: bool = False,
                 val_subset: int = 256, train_samples_per_epoch: int | None = None,
                 normalization: Literal[NORMALIZATIONS] = "train_stats",
                 inputs: Literal[INPUTS] = "total", channels: dict[str, list[str]] | None = None,
                 joint_dropout: float = 0.0):
        super().__init__()
        self.save_hyperparameters(ignore=["context_len"])  # the module logs the resolved length (one key, one value)
        self.stores = [stores] if isinstance(stores, str) else list(stores)
        self.weights, self.test_store, self.val_store = weights, test_store, val_store
        # The argument; the resolved length (also from context_frac) is the property context_len.
        self._context_len_arg = context_len
        self.context_frac, self.horizon, self.window = context_frac, horizon, window
        self.split, self.seed, self.batch_size, self.num_workers = tuple(split), seed, batch_size, num_workers
        self.in_memory, self.recenter, self.val_subset = in_memory, recenter, val_subset
        self.train_samples_per_epoch, self.context_min, self.horizon_min = train_samples_per_epoch, context_min, horizon_min
        self.inputs, self.normalization, self.channels = inputs, normalization, channels
        self.joint_dropout = joint_dropout
        self._check_arguments()
        self._ready = False
        self._sources: list[Source] | None = None

    def setup(self, stage: str | None = None) -> None:
        """Opens and checks the stores, splits them and computes the training statistics.

        ``self.stats`` covers every training trajectory of every training store (each counted
        once, whatever ``weights`` says) over the steps that training windows can cover:
        ``[0, context_len + horizon)`` for ``window="start"``, all ``T`` steps for ``"random"``.
        Validation and test trajectories never enter it. Idempotent.
        """
        if self._ready:
            return
        sources = self.open_sources()
        check_lengths(sources, self.context_len, self.horizon)
        self._check_context_min()
        self.prior = check_prior_windows([s.prior_record for s in sources], [s.path for s in sources],
                                         self.context_len, self.horizon, self.window, self.context_min,
                                         self.inputs)
        total = sum(s.nbytes for s in sources)
        self.loaded = self.in_memory if self.in_memory is not None else total <= MEMORY_BUDGET_BYTES
        if self.loaded:
            for src in sources:
                src.load()
        self._make_splits(sources)
        self._compute_stats(sources)
        self._build_datasets(sources)
        self.sources, self._ready = sources, True

    # The layout of the data, read from the stores' metadata without setup: robomorph fit
    # links n_u, n_y and context_len into the model when it instantiates the two.
    def open_sources(self) -> list[Source]:
        """The training stores' sources (then the test store's), checked to agree; opened once."""
        if self._sources is None:
            # Held-out stores follow the training stores: [train..., val_store?, test_store?].
            paths = self.stores + [p for p in (self.val_store, self.test_store) if p is not None]
            sources = [Source(p, self.inputs) for p in paths]
            self._names = channel_set(sources, len(self.stores), self.channels)
            self._sources = sources
        return self._sources

    def _make_splits(self, sources: list[Source]) -> None:
        """Each store's trajectory split and the training stream's store probabilities."""
        # A store that records recording_index (ingest) is split by recording.
        self.splits = [split_store(src.n, self.split, self.seed, k, src.groups, src.path, self.val_store,
                                   self.test_store) for k, src in enumerate(sources[:len(self.stores)])]
        empty = np.zeros(0, dtype=np.int64)
        for role, path in (("val", self.val_store), ("test", self.test_store)):
            if path is not None:
                whole = np.arange(sources[len(self.splits)].n)
                self.splits.append({"train": empty, "val": empty, "test": empty, role: whole})
        counts = np.array([len(s["train"]) for s in self.splits[:len(self.stores)]])
        w = np.asarray(self.weights if self.weights is not None else counts, dtype=float)
        for k, ck in enumerate(counts):
            if ck == 0:
                raise DataError(f"{self.stores[k]} has no training trajectories (n={sources[k].n}, split "
                                f"{self.split}): add trajectories or change split")
        self.probs = w / w.sum()

    def _compute_stats(self, sources: list[Source]) -> None:
        """Training statistics per channel role: each channel's from the training stores that have it."""
        acc = StatsAccumulator(self.n_u, self.n_y)
        for k, src in enumerate(sources):
            stop = src.steps if self.window == "random" else self.context_len + self.horizon
            scan(src, self.splits[k]["train"], stop, ColumnAccumulator(acc, src.layout) if k < len(self.stores) else None)
        # Floored by channel kind: a joint that barely moves in the training split is not scaled by its own
        # near-zero spread (issue 62: the Kinova's from-scratch model diverged on it).
        self.stats: Stats = acc.finalize(u_names=self._names[0], y_names=self._names[1])
        # A residual model counts its correction in the prior's RMS error per step and channel (training rows only).
        self.prior_error = None if self.prior is None else prior_error_rms(
            [(np.stack([src.window(int(i), self.context_len, self.context_len + self.horizon)[1]
                        for i in self.splits[k]["train"]]), src.prior[self.splits[k]["train"]])
             for k, src in enumerate(sources[:len(self.stores)])], self.horizon)

    @property
    def u_names(self) -> list[str]:
        self.open_sources()
        return list(self._names[0])

    @property
    def y_names(self) -> list[str]:
        self.open_sources()
        return list(self._names[1])

    @property
    def channel_mask(self) -> bool:
        """True when a store lacks some of the run's channels (an arm with fewer joints),
        ``joint_dropout`` hides some, or ``channels`` names the set (a multi-arm model's, to
        fine-tune it: its architecture reads the mask): robomorph fit links it."""
        self.residual  # noqa: B018  (prior stores of several arms are refused as such, before any mask is read)
        return pads_any(self.open_sources()) or self.joint_dropout > 0 or self.channels is not None

    @property
    def residual(self) -> bool:
        """True when the stores are prior stores (:mod:`robomorph.data.priors`): the model then learns the
        correction of the prior and its batches carry ``prior_query`` (B, Th, n_y); robomorph fit links it.
        Priors of another arm, recipe or setting than the first store's are refused here (:func:`common_prior`)."""
        sources = self.open_sources()
        return common_prior([s.prior_record for s in sources], [s.path for s in sources]) is not None

    @property
    def layouts(self) -> list[dict[str, list[str]]]:
        """The training stores' distinct channel layouts (the checkpoint records them for the
        Predictor), and under ``joint_dropout`` the set without its last joint."""
        out = layouts(self.open_sources()[:len(self.stores)])
        if self.joint_dropout > 0:
            (u_col,), (y_col,) = last_joint(self.u_names, self.y_names)
            fewer = {"u_names": [n for i, n in enumerate(self.u_names) if i != u_col],
                     "y_names": [n for i, n in enumerate(self.y_names) if i != y_col]}
            out += [fewer] if fewer not in out else []
        return out

    @property
    def dt(self) -> float:
        return self.open_sources()[0].dt

    @property
    def n_u(self) -> int:
        return len(self.u_names)

    @property
    def n_y(self) -> int:
        return len(self.y_names)

    @property
    def context_len(self) -> int:
        """Context steps: the argument, or ``round(context_frac * T)`` with T the shortest store's."""
        if self._context_len_arg is not None:
            return self._context_len_arg
        t_min = min(s.steps for s in self.open_sources())
        n = round(self.context_frac * t_min)
        if n < 1:
            raise DataError(f"context_frac {self.context_frac} of T={t_min} gives no context step")
        return n

    def _build_datasets(self, sources: list[Source]) -> None:
        train = pairs([s["train"] for s in self.splits])
        val = pairs([s["val"] for s in self.splits])
        self.n_val_total = len(val)
        if len(val) > self.val_subset:
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(VAL_STREAM,)))
            val = val[np.sort(rng.choice(len(val), self.val_subset, replace=False))]
        test = pairs([s["test"] for s in self.splits])
        ctx, h = self.context_len, self.horizon
        self.train_set, self.val_set, self.test_set = (WindowDataset(sources, p, ctx, h) for p in (train, val, test))
        if self.joint_dropout > 0:
            self.train_set.hidden_cols = last_joint(self.u_names, self.y_names)
        for dataset in (self.train_set, self.val_set, self.test_set):
            dataset.with_prior = self.prior is not None
        self.train_sampler = self._train_sampler(sources, len(train))

    def _loader(self, split: str) -> DataLoader:
        self.setup()
        sampler = self.train_sampler if split == "train" else None
        # Pinned host memory lets a GPU's copy of the batch run without stopping the host.
        return DataLoader(getattr(self, f"{split}_set"), batch_size=self.batch_size, sampler=sampler,
                          shuffle=False, num_workers=self.num_workers, persistent_workers=self.num_workers > 0,
                          pin_memory=torch.cuda.is_available())

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
        return self._summary()

    def _check_arguments(self) -> None:
        """Refuses arguments that cannot work, naming the argument and the fix."""
        if not self.stores:
            raise DataError("stores: give at least one store path")
        check_inputs(self.inputs)
        paths = [os.path.realpath(p) for p in self.stores]
        if len(set(paths)) != len(paths):
            raise DataError(f"stores lists a store twice: {self.stores}")
        check_held_out(paths, self.val_store, self.test_store)
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != (len(self.stores),) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
                raise DataError(f"weights must be {len(self.stores)} non-negative numbers with a positive sum "
                                f"(one per store), got {self.weights}")
        if (self._context_len_arg is None) == (self.context_frac is None):
            raise DataError("give exactly one of context_len and context_frac "
                            f"(got context_len={self._context_len_arg}, context_frac={self.context_frac})")
        if self._context_len_arg is not None and self._context_len_arg < 1:
            raise DataError(f"context_len must be >= 1, got {self._context_len_arg}")
        if self.context_frac is not None and not 0 < self.context_frac < 1:
            raise DataError(f"context_frac must be in (0, 1), got {self.context_frac}")
        if self.window not in ("start", "random"):
            raise DataError(f"window must be 'start' or 'random', got {self.window!r}")
        f = self.split
        if len(f) != 3 or any(not math.isfinite(x) or x < 0 for x in f) or abs(sum(f) - 1) > 1e-6 or f[0] <= 0:
            raise DataError(f"split must be three non-negative fractions (train, val, test) summing to 1 "
                            f"with train > 0, got {self.split}")
        for name, value, low in (("horizon", self.horizon, 1), ("batch_size", self.batch_size, 1),
                                 ("num_workers", self.num_workers, 0), ("val_subset", self.val_subset, 1),
                                 ("seed", self.seed, 0)):
            if value < low:
                raise DataError(f"{name} must be >= {low}, got {value}")
        if self.horizon_min is not None and not 1 <= self.horizon_min <= self.horizon:
            raise DataError(f"horizon_min must be in [1, horizon={self.horizon}], got {self.horizon_min}")
        if self.context_min is not None and (self.context_min < 1 or (
                self._context_len_arg is not None and self.context_min > self._context_len_arg)):
            raise DataError(f"context_min must be in [1, context_len={self._context_len_arg}], got {self.context_min}")
        check_normalization(self.normalization, self.recenter)
        jd = self.joint_dropout
        if isinstance(jd, bool) or not isinstance(jd, (int, float)) or not 0 <= jd < 1:
            raise DataError(f"joint_dropout must be a probability in [0, 1), got {jd!r}")
        if self.train_samples_per_epoch is not None and self.train_samples_per_epoch < 1:
            raise DataError(f"train_samples_per_epoch must be >= 1, got {self.train_samples_per_epoch}")

    def _train_sampler(self, sources: list[Source], n_train: int) -> MixtureSampler:
        """The seeded training stream: stores by weight, random offsets and lengths as configured."""
        counts = np.array([len(s["train"]) for s in self.splits[:len(self.stores)]])
        ctx, h = self.context_len, self.horizon
        return MixtureSampler(
            base=np.concatenate([[0], np.cumsum(counts)[:-1]]), counts=counts, probs=self.probs,
            steps=np.array([src.steps for src in sources[:len(self.stores)]]),
            n_samples=self.train_samples_per_epoch or n_train, seed=self.seed,
            random_window=self.window == "random", batch_size=self.batch_size,
            lengths=(self.context_min or ctx, ctx, self.horizon_min or h, h), hide_prob=self.joint_dropout)

    def _check_context_min(self) -> None:
        """``context_min`` within the resolved context (``context_frac`` is known only from the stores)."""
        if self.context_min is not None and self.context_min > self.context_len:
            raise DataError(f"context_min {self.context_min} exceeds the context of {self.context_len} steps"
                            + (f" that context_frac {self.context_frac} gives" if self.context_frac else ""))

    def _summary(self) -> dict:
        """The set-up data module's summary (:meth:`RoboMorphDataModule.describe`)."""
        per_store = {src.path: {"n": src.n, "steps": src.steps, **{k: len(v) for k, v in sp.items()}}
                     for src, sp in zip(self.sources, self.splits)}
        return {
            "stores": list(self.stores), "val_store": self.val_store, "test_store": self.test_store,
            "per_store": per_store,
            "split_by": ["recording" if src.groups is not None else "trajectory" for src in self.sources],
            "weights": [float(p) for p in self.probs],
            "train": len(self.train_set), "val": self.n_val_total, "val_used": len(self.val_set),
            "test": len(self.test_set), "train_samples_per_epoch": len(self.train_sampler),
            "context_len": self.context_len, "horizon": self.horizon, "window": self.window,
            "context_min": self.context_min, "horizon_min": self.horizon_min,
            "n_u": self.n_u, "n_y": self.n_y, "dt": self.dt, "in_memory": bool(self.loaded),
            "seed": self.seed, "split": list(self.split), "normalization": self.normalization,
            "inputs": self.inputs, "channel_mask": self.channel_mask, "residual": self.prior is not None,
        }

