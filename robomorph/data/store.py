"""The one reader/writer of RoboMorph's Zarr v3 dataset schema.

Layout (README, section 4)::

    <name>.zarr/
      u       float32 (N, T, n_u)   inputs: total joint torque (the paper's input)
      u_cmd   float32 (N, T, n_u)   the command without the compensation the arm adds
                                    (schema 2 on; generated stores always, ingested ones
                                    when the log names its command columns)
      y       float32 (N, T, n_y)
      params  float32 (N, P)
      <extra> optional arrays with N as first axis (e.g. ``target``, ``task_index``)
      attrs   schema_version, u_names, [u_cmd_names,] y_names, param_names, dt, domain, task, config,
              seed, status, n, requested, attempted, rejected, package_version, ...

Arrays are allocated at their final capacity and filled in row blocks; ``attrs['n']`` says
how many leading rows are valid and ``attrs['status']`` is ``complete`` only after the last
block and its counts are written. Readers refuse a store whose status is not complete
unless asked to read its valid prefix, so an interrupted job never looks finished.
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec
from zarr.storage import LocalStore

import robomorph.data.chunks as chunks  # not via the package: its __init__ imports this module
from robomorph.core.atomic import check_not_input, check_outside_stores
from robomorph.core.errors import MissingInputError, OutputExistsError, RoboMorphError, describe_os_error
from robomorph.core.inputs import INPUT_ARRAYS, InputsError, check_inputs
from robomorph.data.chunks import StoreDamagedError  # noqa: F401  (part of this module's API)

# 2 added ``u_cmd`` (the command formulation). Version 1 stores read as before; they
# have only the total torque, and asking them for the command says to regenerate.
SCHEMA_VERSION = 2
READABLE_VERSIONS = (1, 2)
SCHEMA_NAME = "robomorph.dataset"
STATUS_IN_PROGRESS = "in_progress"
STATUS_COMPLETE = "complete"
# lz4 over zstd: simulated floats barely compress either way and lz4 writes faster
# (README, section 4).
# The CRC32C checksum after it makes a chunk whose bytes were flipped (disk, copy, network)
# fail to read instead of decoding to wrong values; stores written before it read as before.
_COMPRESSORS = [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"), Crc32cCodec()]
_REQUIRED_ATTRS = ("schema", "schema_version", "u_names", "y_names", "param_names", "dt", "status", "n")


class SchemaError(RoboMorphError, ValueError):
    """A path is not a RoboMorph dataset of the supported schema."""


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _check_names(kind: str, names: list[str], width: int) -> None:
    if len(names) != width:
        raise ValueError(f"{kind} has {width} channels but {len(names)} names were given")
    if len(set(names)) != len(names):
        raise ValueError(f"{kind} names must be unique, got {names}")


class StorePathError(RoboMorphError, OSError):
    """A store cannot be written where it was asked for (under a file, read-only, ...)."""


def _check_creatable(path: str) -> None:
    """Raises unless the folders down to ``path`` can be made: the nearest existing ancestor
    must be a writable directory."""
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise StorePathError(f"cannot create {path}: {parent} is a file, not a folder; choose another --out")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise StorePathError(f"cannot create {path}: {parent} is not writable; choose another --out "
                             "or change the folder's permissions")


def check_writable(path: str, overwrite: bool, inputs: tuple = (), flag: str = "--out") -> None:
    """Raises unless ``path`` may be (re)created: never a file or a store of another schema,
    never inside another store, never one of the command's ``inputs`` (or a folder around one),
    and an existing RoboMorph store only with ``overwrite``; its folder must be writable.
    Cheap: call it before long work."""
    check_not_input(path, inputs, flag)
    check_outside_stores(path, flag)
    if os.path.islink(path) and not os.path.exists(path):  # a dangling link: "File exists" was all zarr said
        raise OutputExistsError(f"{flag} {path} is a link to {os.readlink(path)}, which does not exist: remove the "
                                f"link, or choose another {flag}")
    if not os.path.exists(path):
        _check_creatable(path)
        return
    if os.path.isfile(path):
        raise OutputExistsError(f"{path} is a file, not a dataset directory; choose another --out")
    if not os.listdir(path):
        return
    try:
        attrs = dict(zarr.open_group(LocalStore(path), mode="r").attrs)
    except Exception as exc:  # noqa: BLE001  (any unreadable directory is refused)
        raise OutputExistsError(
            f"{path} exists and is not a Zarr store; refusing to overwrite it"
        ) from exc
    if attrs.get("schema") != SCHEMA_NAME:
        raise SchemaError(
            f"{path} is a Zarr store of another schema (schema={attrs.get('schema')!r}); "
            "refusing to overwrite it: choose another output path"
        )
    if not overwrite:
        raise OutputExistsError(
            f"{path} already holds a RoboMorph dataset (status={attrs.get('status')}, "
            f"n={attrs.get('n')}); pass --overwrite to replace it, or choose another output path"
        )


def create_store(path: str, n: int, steps: int, u_names: list[str], y_names: list[str], param_names: list[str],
                 attrs: dict[str, Any], extras: dict[str, tuple[tuple[int, ...], str]] | None = None,
                 chunk: int = 64, overwrite: bool = False, u_cmd_names: list[str] | None = None) -> "DatasetWriter":
    """Creates an empty store of capacity ``n`` trajectories of ``steps`` samples.

    Args:
        path: directory of the new store.
        n: capacity (number of trajectories).
        steps: samples per trajectory (T).
        u_names, y_names, param_names: channel names (their lengths fix n_u, n_y, P).
        attrs: descriptive attributes (dt, domain, task, config, seed, ...).
        extras: optional arrays ``name -> (trailing shape, dtype)``.
        chunk: trajectories per chunk along N.
        overwrite: replace an existing RoboMorph store (never anything else).
        u_cmd_names: names of the command channels; given, the store gets a ``u_cmd``
            array (as wide as ``u``) that :meth:`DatasetWriter.append` fills from ``extras``.
    """
    if n < 1 or steps < 1:
        raise ValueError(f"a dataset needs n >= 1 and steps >= 1, got n={n}, steps={steps}")
    if "dt" not in attrs or not float(attrs["dt"]) > 0:
        raise ValueError("attrs must carry a positive sample time 'dt' in seconds")
    if u_cmd_names is not None:
        _check_names("u_cmd", list(u_cmd_names), len(u_names))
    check_writable(path, overwrite)
    try:
        return _create(path, n, steps, u_names, y_names, param_names, attrs, extras, max(1, min(chunk, n)),
                       u_cmd_names)
    except OSError as exc:  # e.g. a read-only file system, or a disk that is full
        raise StorePathError(f"cannot write the store {path}: {exc.strerror or exc}; choose another --out") from exc
    except zarr.errors.BaseZarrError as exc:  # e.g. ContainsArrayError: a second writer created it first
        raise StorePathError(f"cannot create the store {path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}; "
                             "is another command writing it at the same time? Wait for it or choose another --out") from exc


def _create(path: str, n: int, steps: int, u_names: list[str], y_names: list[str], param_names: list[str],
            attrs: dict[str, Any], extras: dict | None, chunk: int, u_cmd_names: list[str] | None
            ) -> "DatasetWriter":
    group = zarr.open_group(LocalStore(path), mode="w")
    extras = {k: v for k, v in (extras or {}).items() if k != "u_cmd"}
    widths = [("u", len(u_names)), ("y", len(y_names))]
    if u_cmd_names is not None:
        widths.append(("u_cmd", len(u_names)))
    _create_arrays(group, n, steps, chunk, widths, len(param_names), extras)
    meta = {
        **attrs,
        "schema": SCHEMA_NAME,
        "schema_version": SCHEMA_VERSION,
        "u_names": list(u_names),
        **({"u_cmd_names": list(u_cmd_names)} if u_cmd_names is not None else {}),
        "y_names": list(y_names),
        "param_names": list(param_names),
        "dt": float(attrs["dt"]),
        "steps": int(steps),
        "capacity": int(n),
        "n": 0,
        "status": STATUS_IN_PROGRESS,
        "package_version": package_version(),
        "created": _now(),
    }
    group.attrs.update(meta)
    return DatasetWriter(path, group)


def package_version() -> str:
    """The installed package's version (pyproject's), from its metadata rather than ``robomorph.__version__``:
    the data room imports nothing above it (the package's top level reaches the Predictor). ``unknown`` when
    the code runs from a checkout that was never installed."""
    try:
        return metadata.version("robomorph")
    except metadata.PackageNotFoundError:
        return "unknown"


def _create_arrays(group: zarr.Group, n: int, steps: int, chunk: int, widths: list[tuple[str, int]],
                   n_params: int, extras: dict[str, tuple[tuple[int, ...], str]]) -> None:
    """The store's arrays at full capacity: signals and params NaN-filled until written."""
    for name, width in widths:
        group.create_array(name, shape=(n, steps, width), chunks=(chunk, steps, width),
                           dtype="float32", compressors=_COMPRESSORS, fill_value=np.nan)
    group.create_array("params", shape=(n, n_params), chunks=(chunk, max(1, n_params)),
                       dtype="float32", compressors=_COMPRESSORS, fill_value=np.nan)
    for name, (tail, dtype) in extras.items():
        group.create_array(name, shape=(n, *tail), chunks=(chunk, *tail), dtype=dtype,
                           compressors=_COMPRESSORS)


class DatasetWriter:
    """Fills a store created by :func:`create_store` (or reopened to resume)."""

    def __init__(self, path: str, group: zarr.Group):
        self.path = path
        self.group = group
        self.capacity = int(group.attrs["capacity"])
        self.n = int(group.attrs["n"])

    @classmethod
    def reopen(cls, path: str) -> "DatasetWriter":
        """Reopens an in-progress store to append more rows (resume)."""
        group = _open_group(path, mode="r+")
        if group.attrs["status"] == STATUS_COMPLETE:
            raise ValueError(f"{path} is already complete; nothing to resume")
        return cls(path, group)

    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self.group.attrs)

    def append(self, u: np.ndarray, y: np.ndarray, params: np.ndarray,
               extras: dict[str, np.ndarray] | None = None, progress: dict[str, Any] | None = None) -> None:
        """Writes rows ``[n, n + len(u))`` then, only after the data, advances ``n``.

        ``progress`` (counts, resume cursor) goes into the same attrs update as ``n``, so
        the attrs never claim rows or counts that are not on disk.
        """
        k = len(u)
        if not (len(y) == len(params) == k):
            raise ValueError(f"row counts differ: u {len(u)}, y {len(y)}, params {len(params)}")
        if "u_cmd" in self.group and "u_cmd" not in (extras or {}):
            raise ValueError(f"{self.path} has a u_cmd array: give its rows in extras['u_cmd']")
        if self.n + k > self.capacity:
            raise ValueError(f"appending {k} rows would exceed capacity {self.capacity} (n={self.n})")
        for name, arr in (("u", u), ("y", y), ("params", params), *(extras or {}).items()):
            target = self.group[name]
            if tuple(arr.shape[1:]) != tuple(target.shape[1:]):
                raise ValueError(f"{name} rows have shape {arr.shape[1:]}, the store expects {target.shape[1:]}")
        try:
            for name, arr in (("u", u), ("y", y), ("params", params), *(extras or {}).items()):
                if k:
                    self.group[name][self.n:self.n + k] = arr
            self.n += k
            self.group.attrs.update({"n": self.n, **(progress or {})})
        except OSError as exc:  # a full disk, a file system turned read-only: name the store
            raise StorePathError(
                f"cannot write the store {self.path}: {describe_os_error(exc)}; its first {self.n} trajectories are "
                "kept and it stays marked in progress (generate resumes it when run again)") from exc

    def finalize(self, **attrs: Any) -> None:
        """Marks the store complete (the last write of a job)."""
        if self.n != self.capacity:
            raise ValueError(f"cannot finalize {self.path}: {self.n} of {self.capacity} rows written")
        self.group.attrs.update({**attrs, "status": STATUS_COMPLETE, "finished": _now()})


def _open_group(path: str, mode: str = "r") -> zarr.Group:
    if not os.path.exists(path):
        raise MissingInputError(f"dataset not found: {path}; check the path, or generate it first (robomorph generate)")
    if not os.path.isdir(path):
        raise SchemaError(f"{path} is a file, not a Zarr dataset directory")
    try:
        group = zarr.open_group(LocalStore(path, read_only=(mode == "r")), mode=mode)
    except Exception as exc:  # noqa: BLE001
        raise SchemaError(f"{path} is not a readable Zarr v3 group: {exc}") from exc
    attrs = dict(group.attrs)
    if attrs.get("schema") != SCHEMA_NAME:
        raise SchemaError(
            f"{path} is not a RoboMorph dataset (schema={attrs.get('schema')!r}); create one with "
            "`python -m robomorph.generate` or `python -m robomorph.ingest`"
        )
    if attrs.get("schema_version") not in READABLE_VERSIONS:
        raise SchemaError(
            f"{path} has schema_version {attrs.get('schema_version')}, this robomorph reads "
            f"{', '.join(map(str, READABLE_VERSIONS))}; regenerate it with this version"
        )
    missing = [a for a in _REQUIRED_ATTRS if a not in attrs]
    missing += [a for a in ("u", "y", "params") if a not in group]
    if missing:
        raise SchemaError(f"{path} lacks {missing}: the store is damaged or of another schema")
    return group


@dataclass
class Dataset:
    """A read-only view of a store: lazy arrays, names and attributes."""

    path: str
    group: zarr.Group
    n: int

    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self.group.attrs)

    @property
    def u_names(self) -> list[str]:
        return list(self.group.attrs["u_names"])

    @property
    def y_names(self) -> list[str]:
        return list(self.group.attrs["y_names"])

    @property
    def param_names(self) -> list[str]:
        return list(self.group.attrs["param_names"])

    @property
    def dt(self) -> float:
        return float(self.group.attrs["dt"])

    @property
    def steps(self) -> int:
        return int(self.group["u"].shape[1])

    @property
    def chunk(self) -> int:
        """Trajectories per chunk along N (read whole chunks for speed)."""
        return int(self.group["u"].chunks[0])

    def has_inputs(self, inputs: str) -> bool:
        """Whether the store holds the input array of formulation ``inputs``."""
        return INPUT_ARRAYS[check_inputs(inputs)] in self.group

    def check_inputs(self, inputs: str) -> str:
        """The array name of formulation ``inputs``, or an error that says how to get it."""
        name = INPUT_ARRAYS[check_inputs(inputs)]
        if name not in self.group:
            raise InputsError(
                f"{self.path} has no command inputs (u_cmd): it was written "
                f"{'before schema 2' if self.attrs.get('schema_version', 1) < 2 else 'without command columns'}"
                ". Regenerate it with this robomorph (`robomorph generate` with the same recipe) or, for "
                "ingested logs, re-ingest naming the command with --u-cmd-cols; or use inputs=total")
        return name

    def input_names(self, inputs: str) -> list[str]:
        """Channel names of formulation ``inputs`` (``u_names`` or ``u_cmd_names``)."""
        if self.check_inputs(inputs) == "u":
            return self.u_names
        return list(self.group.attrs.get("u_cmd_names", self.u_names))

    def read_inputs(self, inputs: str, rows: slice | np.ndarray | None = None) -> np.ndarray:
        """Reads the input array of formulation ``inputs`` (``u`` or ``u_cmd``)."""
        return self.read(self.check_inputs(inputs), rows)

    @property
    def arrays(self) -> list[str]:
        return sorted(self.group.array_keys())

    def read(self, name: str, rows: slice | np.ndarray | None = None) -> np.ndarray:
        """Reads the valid rows of one array (all of them by default) into memory.

        Raises:
            StoreDamagedError: a chunk in the way is missing, truncated or cannot be decoded
                (it is named, with its trajectories).
        """
        arr = self.group[name]
        if rows is not None and not isinstance(rows, slice):
            rows = np.asarray(rows)
            if rows.size and (rows.min() < 0 or rows.max() >= self.n):
                raise IndexError(f"rows out of range for {self.n} trajectories")
        if isinstance(rows, np.ndarray):
            touched = rows // arr.chunks[0]
        else:
            start, stop, step = (rows if rows is not None else slice(None)).indices(self.n)
            touched = np.arange(start, stop, step) // arr.chunks[0]
        damaged = self.damaged_chunks([name], set(np.unique(touched).tolist()))
        if damaged:
            raise StoreDamagedError(chunks.describe(self.path, damaged))
        try:
            if isinstance(rows, np.ndarray):
                return np.asarray(arr.get_orthogonal_selection((rows,)))
            return np.asarray(arr[start:stop:step])
        except Exception as exc:  # noqa: BLE001  (codec errors vary: blosc, zstd, json, ...)
            raise chunks.undecodable(self.path, self.group, self.n, name, exc) from exc

    def damaged_chunks(self, names: list[str] | None = None, indices: set[int] | None = None
                       ) -> list[tuple[str, str, int, int, str]]:
        """``(array, chunk key, first row, last row, problem)`` of every chunk of valid rows
        that is missing or truncated (all arrays and chunks unless narrowed)."""
        return chunks.damaged(self.path, self.group, self.n, names or self.arrays, indices)

    def describe_damage(self, decode: bool = False) -> str | None:
        """One line naming the damaged chunks and what to do, or None when there are none.
        With ``decode`` every chunk is read too: a flipped one fails its checksum, not its length."""
        damaged = self.damaged_chunks()
        return chunks.describe(self.path, damaged) if damaged else chunks.undecoded(self) if decode else None


def open_store(path: str, allow_incomplete: bool = False) -> Dataset:
    """Opens a dataset for reading, refusing other schemas and unfinished stores.

    Args:
        path: the store directory.
        allow_incomplete: read the valid prefix of an interrupted job instead of failing.
    """
    group = _open_group(path, mode="r")
    attrs = dict(group.attrs)
    if attrs["status"] != STATUS_COMPLETE and not allow_incomplete:
        raise SchemaError(
            f"{path} is incomplete (status={attrs['status']}, {attrs['n']} of "
            f"{attrs.get('capacity')} trajectories): resume the job that wrote it "
            "(re-run the same generate command) or open it with allow_incomplete=True"
        )
    return Dataset(path=path, group=group, n=int(attrs["n"]))
