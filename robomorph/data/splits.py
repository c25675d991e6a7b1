"""Train / validation / test splits of one store's trajectories, by trajectory or by recording.

Windows ingested from real logs (:mod:`robomorph.data.ingest`) are cut from a few long
recordings, often overlapping (``--stride`` < ``--steps``). Split window by window, the same
samples land in training and validation and the validation score flatters the model (a
real arm's logs gave validation FIT 70 against 22 on a separate recording). A store that
records each window's ``recording_index`` is therefore split by recording: every window of
one recording lands in the same split.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from robomorph.core.errors import RoboMorphError

# SeedSequence spawn key of the split stream (shared with the DataModule's other streams).
SPLIT_STREAM = 0
# The array in which ingested stores record each window's recording (splits group by it).
RECORDING_ARRAY = "recording_index"


class SplitError(RoboMorphError, ValueError):
    """The trajectories of a store cannot be split as asked (the message says what to change)."""


def _rng(seed: int, store_index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(SPLIT_STREAM, store_index)))


def split_rows(n: int, fractions: tuple[float, float, float], seed: int, store_index: int,
               groups: np.ndarray | None = None, path: str = "store") -> dict[str, np.ndarray]:
    """Disjoint sorted trajectory indices ``{"train", "val", "test"}`` covering ``range(n)``.

    Args:
        n: trajectories in the store.
        fractions: (train, val, test) shares of the trajectories.
        seed, store_index: pick the seeded permutation.
        groups: (n,) recording id of each trajectory, or None: trajectories are then split one
            by one; with it, whole recordings are assigned (in a seeded order) to validation
            until it holds at least its share of windows, then to test, the rest to training.
        path: the store, named in errors.
    """
    if groups is None:
        perm = _rng(seed, store_index).permutation(n)
        n_val, n_test = round(n * fractions[1]), round(n * fractions[2])
        return {"val": np.sort(perm[:n_val]), "test": np.sort(perm[n_val:n_val + n_test]),
                "train": np.sort(perm[n_val + n_test:])}
    groups = np.asarray(groups)
    ids = np.unique(groups)
    order = ids[_rng(seed, store_index).permutation(len(ids))]
    sizes = {g: int((groups == g).sum()) for g in ids}
    chosen: dict[str, list] = {"val": [], "test": [], "train": []}
    targets = {"val": round(n * fractions[1]), "test": round(n * fractions[2])}
    held = {"val": 0, "test": 0}
    for g in order:
        name = next((k for k in ("val", "test") if held[k] < targets[k]), "train")
        chosen[name].append(g)
        if name != "train":
            held[name] += sizes[g]
    if not chosen["train"]:
        raise SplitError(
            f"{path}: its {n} windows come from {len(ids)} recording(s), and a split by recording "
            f"(shares {[round(f, 3) for f in fractions]} of train, val, test) leaves none for training")
    return {k: np.flatnonzero(np.isin(groups, v)) for k, v in chosen.items()}


class SplitAdaptedWarning(UserWarning):
    """A store's in-store held-out share was dropped so that it keeps training data."""


def split_store(n: int, split: tuple[float, float, float], seed: int, store_index: int, groups: np.ndarray | None,
                path: str, val_store: str | None, test_store: str | None) -> dict[str, np.ndarray]:
    """:func:`split_rows` of one training store when validation and/or test may come from
    their own stores (``val_store``, ``test_store``).

    When a split by recording leaves no recording for training (one or two long logs) and
    validation comes from ``val_store``, the store's remaining test share is dropped (with a
    :class:`SplitAdaptedWarning`): every recording trains, the test split is empty. Otherwise
    the error names what to give: ``--data.val_store`` / ``--data.test_store`` or ``--data.split``.
    """
    fractions = held_out_fractions(split, val_store is not None, test_store is not None)
    try:
        return split_rows(n, fractions, seed, store_index, groups=groups, path=path)
    except SplitError as exc:
        if val_store is None:
            raise SplitError(f"{exc}; give --data.val_store (and --data.test_store) ingested from other "
                             "recordings, or record more logs") from None
        if test_store is None:
            warnings.warn(f"{path}: its windows come from too few recordings to hold out a test share and still "
                          "train; every recording trains and the test split is empty (give --data.test_store to "
                          "test, or --data.split with a test share of 0 to silence this)", SplitAdaptedWarning,
                          stacklevel=2)
            return split_rows(n, (1.0, 0.0, 0.0), seed, store_index, groups=groups, path=path)
        raise SplitError(f"{exc}; with --data.val_store and --data.test_store given, pass --data.split "
                         "'[1, 0, 0]' to train on all of it") from None


def held_out_fractions(split: tuple[float, float, float], val_store: bool, test_store: bool
                       ) -> tuple[float, float, float]:
    """The split of the training stores when validation and/or test come from their own
    stores: those shares are dropped and the rest renormalized (train and the remaining
    held-out split keep their ratio)."""
    f = [split[0], 0.0 if val_store else split[1], 0.0 if test_store else split[2]]
    total = sum(f)
    return (f[0] / total, f[1] / total, f[2] / total)


def check_held_out(train_paths: list[str], val_store: str | None, test_store: str | None) -> None:
    """Refuses a validation or test store that is also a training store, or one store as both."""
    held_out = [(k, p) for k, p in (("test_store", test_store), ("val_store", val_store)) if p is not None]
    for key, path in held_out:
        if os.path.realpath(path) in train_paths:
            raise SplitError(f"{key} {path} is also a training store: its trajectories would leak; "
                             "give a store of other recordings")
    if len(held_out) == 2 and os.path.realpath(test_store) == os.path.realpath(val_store):
        raise SplitError(f"val_store and test_store are the same store {val_store}: the test "
                         "score would be the one best.ckpt was chosen on; give two stores")
