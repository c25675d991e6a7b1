"""The splits a checkpoint was fitted with, read back from its stores (``arx_train``'s
training data, the validation windows ``robomorph.calibrate`` fits on).

Lightning saves the DataModule's arguments in the checkpoint (stores, split, seed,
val_store, test_store); the same split function then gives back exactly the training
trajectories, so a baseline fitted on them sees what the model saw and nothing of its
validation or test data.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterator

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.data.splits import RECORDING_ARRAY, SplitAdaptedWarning, split_store
from robomorph.data.store import open_store

# Trajectories read per block, and at most this many in all (a least-squares fit of a few
# dozen coefficients gains nothing from more; it bounds the time on a huge store).
BLOCK, MAX_TRAJECTORIES = 256, 4096


class TrainingDataUnavailable(RoboMorphError, ValueError):
    """The checkpoint's training data cannot be read back (the message says what to pass)."""


def training_rows(ckpt: dict, stores: list[str] | None = None) -> list[tuple[str, np.ndarray]]:
    """``(store path, training rows)`` of each training store of a checkpoint.

    Args:
        ckpt: a loaded checkpoint (``robomorph.inference.checkpoint.load_checkpoint_file``).
        stores: use these stores whole instead (``--arx-train-data``).
    """
    if stores:
        return [(p, np.arange(_open(p, "--arx-train-data").n)) for p in stores]
    return split_of(ckpt, "train")


def split_of(ckpt: dict, which: str, hint: str = "--arx-train-data") -> list[tuple[str, np.ndarray]]:
    """``(store path, rows)`` of the checkpoint's ``train``, ``val`` or ``test`` split, as its
    DataModule drew them; a ``val_store`` / ``test_store`` it was given counts whole.
    ``hint`` names the option that replaces stores which cannot be read back."""
    dm = ckpt.get("datamodule_hyper_parameters") or {}
    paths = dm.get("stores")
    if not paths:
        raise TrainingDataUnavailable(f"the checkpoint does not record its training stores: pass {hint}")
    own = dm.get(f"{which}_store") if which in ("val", "test") else None
    if own:
        return [(own, np.arange(_open(own, f"the checkpoint's {which}_store", hint).n))]
    paths = [paths] if isinstance(paths, str) else list(paths)
    split = tuple(dm.get("split", (0.8, 0.1, 0.1)))
    out = []
    for k, path in enumerate(paths):
        ds = _open(path, "the checkpoint's training store", hint)
        groups = ds.read(RECORDING_ARRAY) if RECORDING_ARRAY in ds.arrays else None
        with warnings.catch_warnings():  # the fit said so already; the rows are the fit's either way
            warnings.simplefilter("ignore", SplitAdaptedWarning)
            rows = split_store(ds.n, split, int(dm.get("seed", 0)), k, groups, path, dm.get("val_store"),
                               dm.get("test_store"))[which]
        if len(rows):
            out.append((path, rows))
    return out


def check_stores(stores: list[str], data: str, attrs: dict, y_names: list[str], n_u: int) -> str | None:
    """Checks the ``--arx-train-data`` stores against the evaluated store ``data`` (its ``attrs``, output
    channels and input width) before anything is fitted or written.

    Returns:
        The one of ``stores`` that is ``data``, a copy of it, or holds any of its trajectories (the baselines
        fitted there are then scored on robots they were fitted on: reported in-sample), else None.

    Raises:
        TrainingDataUnavailable: a store of other channels or another registered arm than
            ``data`` (a fit on it used to skip the baselines with numpy's matmul message, exit code 0).
    """
    from robomorph.data.fingerprints import fingerprint, recorded_match, robot_hashes  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415

    stores = [p for p in stores if os.path.isdir(p)]  # a missing one skips its baselines, with the reason, as before
    for path in stores:
        ds = _open(path, "--arx-train-data")
        theirs, mine = arms.of_store(dict(ds.attrs)), arms.of_store(attrs)
        if list(ds.y_names) != list(y_names) or len(ds.u_names) != n_u or (theirs and mine and theirs != mine):
            raise TrainingDataUnavailable(
                f"--arx-train-data {path} holds {attrs_label(ds.attrs, ds.u_names, ds.y_names)} where {data} holds "
                f"{attrs_label(attrs, range(n_u), y_names)}: fit the ARX baselines on stores of the evaluated arm "
                "and channels")
    if not stores:
        return None
    try:
        return recorded_match(data, list(stores), {p: fingerprint(p) for p in stores},
                              {p: robot_hashes(p) for p in stores})
    except RoboMorphError:
        return None


def attrs_label(attrs: dict, u_names, y_names) -> str:
    """``arm panda, 7 inputs and 14 outputs`` (the arm where the store names a registered one)."""
    arm = str(attrs.get("domain")) if attrs.get("domain") else "no registered arm"
    return f"arm {arm}, {len(list(u_names))} inputs and {len(list(y_names))} outputs"


def _open(path: str, what: str, hint: str = "--arx-train-data"):
    if not os.path.isdir(path):
        raise TrainingDataUnavailable(f"{what} {path} is not found (moved?): pass {hint} with its new path")
    return open_store(path)


def blocks(rows: list[tuple[str, np.ndarray]], limit: int = MAX_TRAJECTORIES,
           inputs: str = "total") -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``(u, y)`` blocks of the training trajectories, at most ``limit`` of them, spread
    evenly over the stores' rows in order (deterministic); ``u`` is the input formulation
    the model was trained on (``data.inputs``: the total torque or the command)."""
    total = sum(len(r) for _, r in rows)
    keep = min(1.0, limit / max(total, 1))
    for path, r in rows:
        if keep < 1:
            r = r[np.linspace(0, len(r) - 1, max(1, int(len(r) * keep))).astype(np.int64)]
        ds = open_store(path)
        for b in range(0, len(r), BLOCK):
            sel = r[b:b + BLOCK]
            yield ds.read_inputs(inputs, sel), ds.read("y", sel)


def reader(ckpt: dict | None, stores: list[str] | None = None, inputs: str = "total",
           owner: str = "the checkpoint") -> Callable[[], Iterator[tuple[np.ndarray, np.ndarray]]]:
    """A function that reads the training blocks when called (only a baseline that needs them pays for
    the reading).

    Args:
        ckpt: the checkpoint's record as :func:`robomorph.model.files.read_model` read it (its weights may be
            left out: only the DataModule's arguments are read), or None for a model with no training data
            (a catalogue arm's hybrid): ``stores`` are then the only training data.
        stores: stores read whole instead (``--arx-train-data``).
        inputs: the input formulation read where ``ckpt`` does not record it (None ``ckpt``).
        owner: what has no training data, in the message of a None ``ckpt`` without ``stores``.
    """
    def read() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if ckpt is None:
            if not stores:
                raise TrainingDataUnavailable(f"{owner} has no training data: pass --arx-train-data")
            return blocks(training_rows({}, stores), inputs=inputs)
        kind = (ckpt.get("datamodule_hyper_parameters") or {}).get("inputs") or "total"
        return blocks(training_rows(ckpt, stores), inputs=kind)
    return read
