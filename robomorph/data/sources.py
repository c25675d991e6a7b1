"""A training store's u and y as the DataModule reads them: in memory or chunk by chunk."""

from __future__ import annotations

import math
import os

import numpy as np

from robomorph.core.channels import pad_columns
from robomorph.core.errors import RoboMorphError
from robomorph.data.priors import PRIOR_ARRAY, prior_record
from robomorph.data.splits import RECORDING_ARRAY
from robomorph.data.statistics import StatsAccumulator
from robomorph.data.store import open_store


class DataError(RoboMorphError, ValueError):
    """Data settings or stores that cannot feed training; the message names the fix."""


class Source:
    """One store's u and y: numpy arrays in memory, or read one chunk of rows at a time.

    The on-demand mode keeps a one-chunk cache and reopens the store in each process (a
    handle is never shared across fork or pickling), so DataLoader workers are safe.
    """

    def __init__(self, path: str, inputs: str = "total"):
        ds = open_store(path)
        if ds.n < 1:
            raise DataError(f"{path} holds no trajectories (n=0)")
        self.path, self.n, self.steps, self.chunk = path, ds.n, ds.steps, ds.chunk
        # The array the model reads as u: the total torque or the command (data.inputs).
        self.u_array = ds.check_inputs(inputs)
        self.u_names, self.y_names, self.dt = ds.input_names(inputs), ds.y_names, ds.dt
        # Recording of each window (ingested logs): splits keep a recording's windows together.
        self.groups = ds.read(RECORDING_ARRAY) if RECORDING_ARRAY in ds.arrays else None
        # Each robot's physical parameters (simulated stores): the parameter head's targets.
        self.attrs = dict(ds.attrs)
        self.params = ds.read("params").astype(np.float64) if "params" in ds.arrays and self.attrs.get(
            "param_names") else None
        # A prior store's priors of each row's query (robomorph.data.priors): small, read whole.
        self.prior_record = prior_record(self.attrs)
        self.prior = ds.read(PRIOR_ARRAY) if self.prior_record is not None and PRIOR_ARRAY in ds.arrays else None
        if self.prior_record is not None and self.prior is None:
            raise DataError(f"{path} records priors but holds no '{PRIOR_ARRAY}' array: write it again (robomorph priors)")
        self.u: np.ndarray | None = None
        self.y: np.ndarray | None = None
        self._ds, self._pid = ds, os.getpid()
        self._cache: tuple[int, np.ndarray | None, np.ndarray | None] = (-1, None, None)
        # (u columns, y columns, n_u, n_y) of this store's channels in the run's channel set,
        # when it has fewer (an arm with fewer joints): windows are padded to the set's width.
        self.layout: tuple[list[int], list[int], int, int] | None = None

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
        u, y = u[i - c0, start:stop], y[i - c0, start:stop]
        if self.layout is None:
            return u, y
        u_cols, y_cols, n_u, n_y = self.layout
        return pad_columns(u, u_cols, n_u), pad_columns(y, y_cols, n_y)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_ds"], state["_cache"] = None, (-1, None, None)
        return state


def scan(src: Source, train_rows: np.ndarray, stop: int, acc: StatsAccumulator | None) -> None:
    """One pass over a store: refuses non-finite values and feeds training rows' steps
    ``[0, stop)`` to ``acc``."""
    in_train = np.zeros(src.n, dtype=bool)
    in_train[train_rows] = True
    for c in range(src.n_blocks):
        c0, u, y = src.block(c)
        for name, arr in (("u", u), ("y", y)):
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=(1, 2)))
            if bad.size:
                raise DataError(f"{src.path}: trajectory {c0 + int(bad[0])} has NaN/inf values in '{name}' "
                                f"({bad.size} bad trajectories in rows {c0}..{c0 + len(u) - 1}); "
                                "regenerate the store or drop those rows")
        mask = in_train[c0:c0 + len(u)]
        if acc is not None and mask.any():
            acc.update(u[mask, :stop], y[mask, :stop])


def compatible(sources: list[Source]) -> list[Source]:
    """``sources`` unchanged, after checking that they share channel names and dt."""
    ref = sources[0]
    for src in sources[1:]:
        for what, a, b in (("u_names", ref.u_names, src.u_names), ("y_names", ref.y_names, src.y_names)):
            if a != b:
                raise DataError(f"stores disagree on {what}: {ref.path} has {a}, {src.path} has {b}; "
                                "all stores of one run must share u_names, y_names and dt")
        if not math.isclose(ref.dt, src.dt, rel_tol=1e-9):
            raise DataError(f"stores disagree on dt: {ref.path} has {ref.dt}, {src.path} has {src.dt}")
    return sources


def check_lengths(sources: list[Source], context_len: int, horizon: int) -> None:
    need = context_len + horizon
    for src in sources:
        if src.steps < need:
            raise DataError(f"{src.path} has trajectories of T={src.steps} steps, but context_len "
                            f"{context_len} + horizon {horizon} = {need} are needed: shorten "
                            "--data.context_len / --data.horizon")
