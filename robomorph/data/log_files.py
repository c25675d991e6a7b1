"""Reading one log file (CSV, NPZ or MAT) into named columns, for :mod:`robomorph.data.ingest`.

Input formats (``--format auto`` picks by extension):

* CSV (``.csv``): a header row with the column names, then one numeric row per sample.
  Empty cells and ``nan`` count as missing values and are refused.
* NPZ (``.npz``): one array per column, named after the column, of shape (L,) or (L, 1).
  Alternatively a 2-D array ``data`` of shape (L, C) plus a 1-D string array ``names`` of
  its C column names; that pair takes precedence when both are present.
* MAT (``.mat``, read with ``scipy.io.loadmat``): one variable per column, a row or column
  vector named after the column.
"""

from __future__ import annotations

import csv
import os
import warnings
import zipfile
from typing import Any, Mapping

import numpy as np

from robomorph.core.errors import MissingInputError, RoboMorphError

FORMATS = ("csv", "npz", "mat")
_EXTENSIONS = {".csv": "csv", ".npz": "npz", ".mat": "mat"}


# The one error of ingesting, raised first by the reader: :mod:`robomorph.data.ingest` re-exports it.
class IngestError(RoboMorphError, ValueError):
    """A log cannot be turned into a dataset as asked (the message says what to change)."""


def _detect_format(path: str, fmt: str) -> str:
    if fmt != "auto":
        if fmt not in FORMATS:
            raise IngestError(f"unknown format {fmt!r}; choose one of auto, {', '.join(FORMATS)}")
        return fmt
    ext = os.path.splitext(path)[1].lower()
    if ext not in _EXTENSIONS:
        raise IngestError(
            f"cannot tell the format of {path} from its extension {ext!r}; rename it to "
            f".csv/.npz/.mat or pass --format {'|'.join(FORMATS)}"
        )
    return _EXTENSIONS[ext]


def _float_cell(text: str) -> float:
    # Empty cells are missing samples: they become NaN and the NaN check names them.
    return float(text) if text.strip() else np.nan


def _read_csv(path: str) -> dict[str, np.ndarray]:
    # utf-8-sig: spreadsheet exports often start with a byte-order mark.
    with open(path, newline="", encoding="utf-8-sig") as f:
        header = next(csv.reader(f), None)
    if not header:
        raise IngestError(f"{path} is empty: a CSV log needs a header row of column names")
    names = [h.strip() for h in header]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise IngestError(f"{path}: the header names {dup} more than once; column names must be unique")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a header-only log is reported below as too short
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64, encoding="utf-8-sig")
    except ValueError:
        # loadtxt's message is vague; re-read slowly to name the bad cell.
        data = _read_csv_slowly(path, names)
    if data.size == 0:
        data = np.empty((0, len(names)))
    if data.shape[1] != len(names):
        raise IngestError(f"{path}: the header names {len(names)} columns but rows hold {data.shape[1]} values")
    return {name: data[:, j] for j, name in enumerate(names)}


def _read_csv_slowly(path: str, names: list[str]) -> np.ndarray:
    rows = []
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        next(reader)
        for line, row in enumerate(reader, start=2):
            if not row:
                continue  # blank lines, as loadtxt skips them
            if len(row) != len(names):
                raise IngestError(f"{path} line {line}: {len(row)} values but the header names {len(names)} columns")
            try:
                rows.append([_float_cell(c) for c in row])
            except ValueError:
                bad = next(j for j, c in enumerate(row) if not _is_number(c))
                raise IngestError(
                    f"{path} line {line}, column {names[bad]!r}: {row[bad]!r} is not a number"
                ) from None
    return np.asarray(rows, dtype=np.float64).reshape(-1, len(names))


def _is_number(text: str) -> bool:
    try:
        _float_cell(text)
    except ValueError:
        return False
    return True


def _columns_of(mapping: Mapping[str, Any], path: str) -> dict[str, np.ndarray]:
    """Named arrays of an NPZ/MAT file -> its columns (see the module docstring)."""
    if "data" in mapping and "names" in mapping:
        data, names = np.asarray(mapping["data"]), np.asarray(mapping["names"]).reshape(-1)
        if data.ndim != 2 or data.shape[1] != len(names):
            raise IngestError(f"{path}: 'data' has shape {data.shape} but 'names' lists {len(names)} columns")
        return {str(n).strip(): data[:, j] for j, n in enumerate(names)}
    cols = {}
    for key, value in mapping.items():
        arr = np.asarray(value)
        if key.startswith("__") or arr.dtype.kind not in "biuf":
            continue  # loadmat headers and non-numeric variables are not columns
        if arr.ndim == 1 or (arr.ndim == 2 and 1 in arr.shape):
            cols[key] = arr.reshape(-1)
    return cols


def read_log(path: str, fmt: str = "auto") -> dict[str, np.ndarray]:
    """Reads one log file into ``column name -> 1-D float64 array``.

    Args:
        path: the log file.
        fmt: ``auto`` (by extension), ``csv``, ``npz`` or ``mat``.

    Raises:
        FileNotFoundError: the file does not exist.
        IngestError: unknown format, unreadable file or unparsable values.
    """
    if not os.path.isfile(path):
        raise MissingInputError(f"log file not found: {path}")
    kind = _detect_format(path, fmt)
    try:
        if kind == "csv":
            cols = _read_csv(path)
        elif kind == "npz":
            if not zipfile.is_zipfile(path):  # else np.load guesses "pickle" and says so
                raise IngestError(f"{path} is not an NPZ archive (write it with numpy.savez)")
            with np.load(path, allow_pickle=False) as npz:
                cols = _columns_of({k: npz[k] for k in npz.files}, path)
        else:
            from scipy.io import loadmat  # noqa: PLC0415  (scipy only when MAT logs are read)

            cols = _columns_of(loadmat(path), path)
    except IngestError:
        raise
    except NotImplementedError as exc:  # loadmat on MATLAB v7.3 (HDF5) files
        raise IngestError(f"cannot read {path}: {exc}; save it with save(..., '-v7') instead") from exc
    except Exception as exc:  # noqa: BLE001  (any parser failure means: not a readable log)
        raise IngestError(f"cannot read {path} as {kind.upper()}: {exc}") from exc
    lengths = {len(v) for v in cols.values()}
    if len(lengths) > 1:
        raise IngestError(f"{path}: columns have different lengths {sorted(lengths)}; one recording needs one length")
    return {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
