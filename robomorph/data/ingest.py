"""``python -m robomorph.ingest``: real robot logs into the RoboMorph dataset schema.

Each input file is one recording: a table of named columns sampled at a uniform rate.
Every recording is cut into windows of ``--steps`` samples, ``--stride`` samples apart
(default: non-overlapping), and the windows become the trajectories of one store with the
same layout as a simulated one (``params`` is empty, P = 0). Two extra arrays trace each
window back to its source: ``recording_index`` (position of the file on the command line,
also the index into ``attrs['sources']``) and ``window_start`` (its first sample in that
recording); training splits keep a recording's windows together. ``attrs['recordings']``
says, per recording, how many samples it held, how many windows it gave and how many tail
samples after its last window were dropped. ``--u-units`` / ``--y-units`` record each
column's unit (``attrs['u_units']``, ``attrs['y_units']``); plots label axes with them.

Input formats (CSV, NPZ, MAT; ``--format auto`` picks by extension): see
:mod:`robomorph.data.log_files`, which reads them.

All inputs are read and checked (columns, missing values, sample time) before the store
is created, so a bad log never leaves a half-written dataset behind.

``--u-cols`` names the total joint torque (the store's ``u``); ``--u-cmd-cols`` optionally
names the command sent before the gravity compensation the arm's controller adds (the
store's ``u_cmd``, read by ``data.inputs: command``), one column per joint as well.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from robomorph.core.locks import exclusive_on
from robomorph.data import real_logs
from robomorph.data.log_files import FORMATS, IngestError, read_log
from robomorph.data.store import Dataset, check_writable, create_store, open_store

__all__ = ["FORMATS", "IngestError", "ShortRecordingWarning", "ingest", "read_log"]

# Windows written per append: bounds memory when overlapping windows repeat samples.
_WRITE_BLOCK = 64
# The longest sample time a log may have: one an hour is no robot log.
MAX_DT = 3600.0


class ShortRecordingWarning(UserWarning):
    """A recording holds fewer samples than one window and was skipped."""


# The store holds float32: a larger magnitude would be written as inf without a word.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _check_columns(cols: dict[str, np.ndarray], wanted: list[str], path: str, stored: list[str] | None = None) -> None:
    """Refuses unknown columns (listing the available ones), non-finite values and, in the
    ``stored`` columns (written as float32), values beyond float32's range."""
    missing = [c for c in wanted if c not in cols]
    if missing:
        available = ", ".join(cols) or "(none: NPZ/MAT logs need one vector per column, or 'data' plus 'names')"
        raise IngestError(f"{path} has no column {', '.join(map(repr, missing))}; available columns: {available}")
    for c in wanted:
        bad = np.flatnonzero(~np.isfinite(cols[c]))
        if bad.size:
            raise IngestError(
                f"column {c!r} in {path} holds NaN/inf (first bad row: sample {bad[0]} counting from 0, {bad.size} in all); "
                "fill or cut the missing samples before ingesting"
            )
    for c in stored or []:
        big = np.flatnonzero(np.abs(cols[c]) > _FLOAT32_MAX)
        if big.size:
            raise IngestError(
                f"column {c!r} in {path}: sample {big[0]} (counting from 0; {big.size} in all) is {cols[c][big[0]]:.6g}, "
                f"beyond the float32 range (±{_FLOAT32_MAX:.4g}) the store holds; rescale the column (wrong unit?)")


def _sample_time(t: np.ndarray, path: str, tol: float) -> float:
    """The uniform sample time of a time column, or an error asking to resample."""
    if len(t) < 2:
        raise IngestError(f"{path}: the time column needs at least 2 samples to give a sample time")
    steps = np.diff(t)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    if dt <= 0 or np.any(steps <= 0):
        raise IngestError(f"{path}: the time column is not strictly increasing (first at sample "
                          f"{int(np.argmax(steps <= 0)) + 1}); sort the log or fix its clock")
    worst = int(np.argmax(np.abs(steps - dt)))
    if abs(steps[worst] - dt) > tol * dt:
        raise IngestError(
            f"{path}: non-uniform sampling: the step at sample {worst + 1} is {steps[worst]:.6g} s but the "
            f"mean is {dt:.6g} s (tolerance {tol:.1%}); the log must be resampled to a uniform rate first"
        )
    return float(dt)


def _window_starts(length: int, steps: int, stride: int) -> np.ndarray:
    if length < steps:
        return np.empty(0, dtype=np.int64)
    return np.arange(0, length - steps + 1, stride, dtype=np.int64)


def _check_units(u_cols: list[str], y_cols: list[str], u_units: list[str] | None,
                 y_units: list[str] | None) -> None:
    for flag, cols, units in (("--u-units", u_cols, u_units), ("--y-units", y_cols, y_units)):
        if units is not None and len(units) != len(cols):
            raise IngestError(f"{flag} gives {len(units)} units for {len(cols)} columns ({', '.join(cols)}); "
                              "give one unit per column, in the same order (e.g. 'N m' or rad)")


def _check_args(files: list[str], u_cols: list[str], y_cols: list[str], steps: int,
                dt: float | None, time_col: str | None, stride: int, time_tol: float,
                u_cmd_cols: list[str] | None = None) -> None:
    if not files:
        raise IngestError("give at least one log file")
    if u_cmd_cols is not None and len(u_cmd_cols) != len(u_cols):
        raise IngestError(f"--u-cmd-cols names {len(u_cmd_cols)} columns but --u-cols {len(u_cols)}: the command "
                          "and the total torque need one column per joint each, in the same joint order")
    for kind, cols in (("--u-cols", u_cols), ("--u-cmd-cols", u_cmd_cols), ("--y-cols", y_cols)):
        if cols is None:
            continue
        if not cols:
            raise IngestError(f"{kind} must name at least one column")
        dup = sorted({c for c in cols if cols.count(c) > 1})
        if dup:
            raise IngestError(f"{kind} names {dup} more than once")
    if steps < 1 or stride < 1:
        raise IngestError(f"--steps and --stride must be >= 1, got steps={steps}, stride={stride}")
    if (dt is None) == (time_col is None):
        raise IngestError("give exactly one of --dt (seconds) or --time-col (a column of timestamps in seconds)")
    if dt is not None and not 0 < dt <= MAX_DT:  # beyond it the time axis of a long log overflows
        raise IngestError(f"--dt must be a positive, finite number of seconds up to {MAX_DT:g}, got {dt}")
    if not time_tol >= 0:
        raise IngestError(f"--time-tol must be >= 0, got {time_tol}")


def _check_request(files: list[str], u_cols: list[str], y_cols: list[str], steps: int, dt: float | None,
                   time_col: str | None, stride: int, time_tol: float, u_cmd_cols: list[str] | None,
                   u_units: list[str] | None, y_units: list[str] | None, layout: str | None,
                   resample_hz: float | None) -> None:
    """Every check of ``ingest``'s arguments that needs no log: a bad call fails before any is read."""
    _check_args(files, u_cols, y_cols, steps, dt, time_col, stride, time_tol, u_cmd_cols)
    _check_units(u_cols, y_cols, u_units, y_units)
    real_logs.check_layout(layout, u_cols, y_cols, u_cmd_cols)
    if resample_hz is not None:  # refuse an impossible rate before reading the logs
        real_logs.check_rate(resample_hz)
        if dt is not None:
            real_logs.rate_ratio(dt, resample_hz)


def _load_recordings(files, u_cols, y_cols, steps, stride, time_col, fmt, time_tol, u_cmd_cols=None,
                     dt=None, resample_hz=None, layout=None):
    """Reads and checks every log: ``([(file index, u, y, starts, u_cmd)], dts, skipped, report)``,
    the report giving per recording its samples (at the store's rate), windows and dropped
    tail samples. With ``resample_hz`` each recording is resampled (anti-aliased) first;
    with ``layout`` its ``y`` is put in the layout's channels (:mod:`robomorph.data.real_logs`).
    Refuses logs of which no recording gives a window."""
    recs, dts, skipped, report = [], [], [], []
    for index, path in enumerate(files):
        cols = read_log(path, fmt)
        # Checked even for recordings skipped below: a wrong name is wrong in every file.
        _check_columns(cols, [*u_cols, *(u_cmd_cols or []), *y_cols, *([time_col] if time_col else [])], path,
                       stored=[*u_cols, *(u_cmd_cols or []), *y_cols])
        rec_dt = _sample_time(cols[time_col], path, time_tol) if time_col and len(cols[time_col]) >= 2 else dt
        arrays = [np.stack([cols[c] for c in names], axis=1).astype(np.float32) if names else None
                  for names in (u_cols, y_cols, u_cmd_cols)]  # (L, n_u), (L, n_y), (L, n_u) or None
        if resample_hz and rec_dt:
            arrays = [None if a is None else real_logs.resample(a, rec_dt, resample_hz) for a in arrays]
        u, y, u_cmd = arrays
        length = len(u)
        starts = _window_starts(length, steps, stride)
        # Samples after the last window that no window covers (all of a too-short recording).
        tail = length - int(starts[-1]) - steps if len(starts) else length
        report.append({"source": os.path.basename(path), "samples": length, "windows": len(starts),
                       "tail_dropped": tail, **({"original_samples": len(cols[u_cols[0]])} if resample_hz else {})})
        if length < steps:
            warnings.warn(f"skipping {path}: {length} samples, fewer than --steps {steps}",
                          ShortRecordingWarning, stacklevel=3)
            skipped.append(os.path.basename(path))
            continue
        if time_col:  # a 1-sample recording has no sample time: _sample_time says so
            dts.append((path, rec_dt if rec_dt is not None else _sample_time(cols[time_col], path, time_tol)))
        recs.append((index, u, real_logs.apply_layout(layout, y), starts, u_cmd))
    if not recs:
        raise IngestError(f"no windows: every recording is shorter than --steps {steps}; lower --steps")
    return recs, dts, skipped, report


def _common_dt(dts: list[tuple[str, float]], tol: float) -> float:
    values = np.array([d for _, d in dts])
    mean = float(values.mean())
    worst = int(np.argmax(np.abs(values - mean)))
    if abs(values[worst] - mean) > tol * mean:
        raise IngestError(
            f"recordings differ in sample time ({dts[0][0]}: {dts[0][1]:.6g} s, {dts[worst][0]}: "
            f"{dts[worst][1]:.6g} s); one dataset has one dt: resample the logs to a common rate"
        )
    return mean


@exclusive_on("out")  # one writer per store
def ingest(files: list[str], u_cols: list[str], y_cols: list[str], out: str, steps: int,
           dt: float | None = None, time_col: str | None = None, stride: int | None = None,
           fmt: str = "auto", overwrite: bool = False, name: str | None = None,
           time_tol: float = 0.01, u_cmd_cols: list[str] | None = None, u_units: list[str] | None = None,
           y_units: list[str] | None = None, resample_hz: float | None = None, layout: str | None = None) -> Dataset:
    """Cuts recorded logs into windows and writes them as a RoboMorph dataset.

    Args:
        files: log files, one recording each (CSV, NPZ or MAT; see :mod:`robomorph.data.log_files`).
        u_cols: total joint torque columns, in the order of the store's ``u`` channels.
        y_cols: output columns, in the order of the store's ``y`` channels.
        out: the store directory to create.
        steps: samples per window (T).
        dt: sample time in seconds; give this or ``time_col``.
        time_col: column of timestamps in seconds from which dt is derived.
        stride: samples between window starts (default ``steps``: no overlap).
        fmt: ``auto`` (by extension), ``csv``, ``npz`` or ``mat``, for all files.
        overwrite: replace an existing RoboMorph store at ``out`` (never anything else).
        name: the store's ``domain`` attribute (default ``real``).
        time_tol: largest relative deviation of a time step from the mean sample time.
        u_cmd_cols: command columns (what was commanded, before the gravity compensation
            the arm's controller adds), in the joint order of ``u_cols``; the store's
            ``u_cmd`` (``data.inputs: command``). None: the store has only ``u``.
        u_units, y_units: the unit of each input / output column (e.g. ``"N m"``, ``"rad"``),
            recorded in the store and used to label plots.
        resample_hz: resample every recording to this rate (Hz) with an anti-aliasing filter
            before cutting windows (``steps`` and ``stride`` count samples at this rate); the
            store's dt is ``1 / resample_hz`` and ``attrs['original_dt']`` the logs'.
        layout: an arm of :mod:`robomorph.sim.arms` (``"panda"``, ``"kinova3"``, ...): the columns are
            that arm's joint torques and joint angles; the store gets the simulator's channel
            names and EE pose and records the arm (see :mod:`robomorph.data.real_logs`);
            ``"joints"``: any arm's joint torques and angles, in joint order, named by role.

    Returns:
        The finished dataset, opened for reading.

    Raises:
        IngestError: a log or an argument cannot be used (the message says how to fix it).
        FileNotFoundError: a log file is missing.
        FileExistsError, SchemaError: ``out`` is a file, another store, or (without
            ``overwrite``) an existing dataset.
    """
    dt_arg, stride = dt, (steps if stride is None else stride)
    _check_request(files, u_cols, y_cols, steps, dt, time_col, stride, time_tol, u_cmd_cols, u_units, y_units,
                   layout, resample_hz)
    check_writable(out, overwrite)  # refuse a bad --out before reading large logs
    recs, dts, skipped, report = _load_recordings(files, u_cols, y_cols, steps, stride, time_col, fmt, time_tol,
                                                  u_cmd_cols, dt, resample_hz, layout)
    total = sum(len(r[3]) for r in recs)
    dt = _common_dt(dts, time_tol) if time_col else float(dt)
    original_dt, dt = dt, (1.0 / resample_hz if resample_hz else dt)
    u_names, y_names, cmd_names, y_units_stored = real_logs.layout_names(layout, u_cols, y_cols, u_cmd_cols, y_units)
    # The call's arguments as given: the store records how to ingest it again.
    config = {"files": list(files), "u_cols": list(u_cols), "u_cmd_cols": u_cmd_cols and list(u_cmd_cols),
              "y_cols": list(y_cols), "steps": steps, "stride": stride, "dt": dt_arg, "time_col": time_col, "fmt": fmt,
              "name": name, "time_tol": time_tol, "u_units": u_units, "y_units": y_units, "resample_hz": resample_hz,
              "layout": layout}
    attrs = _store_attrs(config, dt, original_dt, report, skipped, total, y_units_stored or [""] * len(y_names))
    _write_store(out, recs, steps, (u_names, y_names, cmd_names), attrs, overwrite)
    return open_store(out)


def _store_attrs(config: dict, dt: float, original_dt: float, report: list[dict], skipped: list[str],
                 total: int, y_units: list[str]) -> dict:
    """The ingested store's attributes: the call (``config``), its sources and what became of
    each recording, the units, the sample times and the counts (every window is kept)."""
    return {"dt": dt, "domain": config["name"] or "real", "task": "ingested", "config": config, "seed": None,
            "sources": [os.path.basename(f) for f in config["files"]], "skipped_recordings": skipped,
            "recordings": report, "u_units": list(config["u_units"] or [""] * len(config["u_cols"])),
            "y_units": list(y_units), "original_dt": original_dt,
            "requested": total, "attempted": total, "kept": total, "rejected": {},
            # The arm whose layout the channels follow: its catalogue physics can run beside the log.
            "arm": None if config["layout"] in (None, "joints") else config["layout"]}


def _write_store(out: str, recs: list, steps: int, names: tuple, attrs: dict, overwrite: bool) -> None:
    """Creates the store (``names``: u, y and command channel names), appends every
    recording's windows, ``_WRITE_BLOCK`` at a time, and marks it complete."""
    u_names, y_names, cmd_names = names
    writer = create_store(out, sum(len(r[3]) for r in recs), steps, u_names, y_names, [], attrs,
                          extras={"recording_index": ((), "int32"), "window_start": ((), "int64")},
                          overwrite=overwrite, u_cmd_names=cmd_names)
    for index, u, y, starts, u_cmd in recs:
        for b in range(0, len(starts), _WRITE_BLOCK):
            block = starts[b:b + _WRITE_BLOCK]
            rows = block[:, None] + np.arange(steps)  # (k, T) sample indices
            extras = {"recording_index": np.full(len(block), index, np.int32), "window_start": block}
            if u_cmd is not None:
                extras["u_cmd"] = u_cmd[rows]
            writer.append(u[rows], y[rows], np.zeros((len(block), 0), np.float32), extras=extras)
    writer.finalize()
