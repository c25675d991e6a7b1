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

from robomorph.core.locks import exclusive
from robomorph.data import real_logs, rosbag
from robomorph.data.log_files import FORMATS, IngestError, read_log
from robomorph.data.store import Dataset, check_writable, create_store, open_store

__all__ = ["FORMATS", "IngestError", "ShortRecordingWarning", "ingest", "ingest_rosbag", "read_log"]

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


def _file_logs(files: list[str], fmt: str):
    """``(index, path, columns)`` of each log file, read as its turn comes (one in memory at a time)."""
    for index, path in enumerate(files):
        yield index, path, read_log(path, fmt)


def _load_recordings(logs, u_cols, y_cols, steps, stride, time_col, time_tol, u_cmd_cols=None,
                     dt=None, resample_hz=None, layout=None, qvel_cols=None):
    """Reads and checks every log of ``logs`` (``(index, path, columns)``):
    ``([(index, u, y, starts, extras)], dts, skipped, report)``, ``extras`` holding ``u_cmd``
    and ``qvel`` where asked, the report giving per recording its samples (at the store's rate),
    windows and dropped tail samples. With ``resample_hz`` each recording is resampled
    (anti-aliased) first; with ``layout`` its ``y`` is put in the layout's channels
    (:mod:`robomorph.data.real_logs`). Refuses logs of which no recording gives a window."""
    recs, dts, skipped, report = [], [], [], []
    for index, path, cols in logs:
        # Checked even for recordings skipped below: a wrong name is wrong in every file.
        stored = [*u_cols, *(u_cmd_cols or []), *y_cols, *(qvel_cols or [])]
        _check_columns(cols, [*stored, *([time_col] if time_col else [])], path, stored=stored)
        rec_dt = _sample_time(cols[time_col], path, time_tol) if time_col and len(cols[time_col]) >= 2 else dt
        arrays = [np.stack([cols[c] for c in names], axis=1).astype(np.float32) if names else None
                  for names in (u_cols, y_cols, u_cmd_cols, qvel_cols)]  # (L, n_u), (L, n_y), (L, n_u), (L, n_y)
        if resample_hz and rec_dt:
            arrays = [None if a is None else real_logs.resample(a, rec_dt, resample_hz) for a in arrays]
        u, y, u_cmd, qvel = arrays
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
        extras = {k: v for k, v in (("u_cmd", u_cmd), ("qvel", qvel)) if v is not None}
        recs.append((index, u, real_logs.apply_layout(layout, y), starts, extras))
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
    check_writable(out, overwrite, inputs=tuple(files))  # refuse a bad --out before reading large logs
    recs, dts, skipped, report = _load_recordings(_file_logs(files, fmt), u_cols, y_cols, steps, stride, time_col,
                                                  time_tol, u_cmd_cols, dt, resample_hz, layout)
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
    # Locked only now, once every log was read and checked: a refusal above leaves nothing, not even a lock file.
    with exclusive(out):  # one writer per store
        _write_store(out, recs, steps, (u_names, y_names, cmd_names), attrs, overwrite)
    return open_store(out)


def ingest_rosbag(bags: list[str], out: str, steps: int, topic: str = rosbag.DEFAULT_TOPIC,
                  joints: list[str] | None = None, split_gap: float | None = None, stride: int | None = None,
                  overwrite: bool = False, name: str | None = None, resample_hz: float | None = None,
                  layout: str | None = None, time_tol: float = 0.01) -> Dataset:
    """Writes the ``sensor_msgs/JointState`` messages of ROS bags as a RoboMorph dataset.

    Each bag is one recording, or several with ``split_gap`` (:mod:`robomorph.data.rosbag` says
    how messages become samples on a uniform clock); from there the recordings go the way of
    every log (:func:`ingest`): resampled, cut into windows, written. Effort is the store's
    ``u`` (the total joint torque), position its ``y``; velocity, where the messages hold one
    for every joint, the extra array ``qvel`` (N, T, n).

    Args:
        bags: ROS1 ``.bag`` files, ROS2 bag folders, or ROS2 ``.db3`` / ``.mcap`` files.
        out: the store directory to create.
        steps: samples per window (T), at the bag's rate or at ``resample_hz``.
        topic: the JointState topic.
        joints: the joints, in order; default: a ``layout`` arm's joints, or every joint the
            first bag names, in the order they first appear.
        split_gap: seconds: a longer pause in the stamps starts a new recording.
        stride, overwrite, name, resample_hz, layout, time_tol: as for :func:`ingest`.

    Raises:
        IngestError: a bag or an argument that cannot be used (nothing is written).
    """
    stride = steps if stride is None else stride
    arm = real_logs.layout_arm(layout)
    joints = list(arm.joint_names) if arm is not None and joints is None else joints
    if arm is not None and len(joints) != arm.n_joint:
        raise IngestError(f"--layout {arm.name} needs its {arm.n_joint} joints, got {len(joints)} in --joints; leave --joints "
                          f"out to read {', '.join(arm.joint_names)}")
    probe = joints or ["joint"]  # the column checks below need names; the bag gives them otherwise
    _check_request(list(bags), probe, probe, steps, None, "t", stride, time_tol, None, None, None, layout, resample_hz)
    check_writable(out, overwrite, inputs=tuple(bags))  # refuse a bad --out before reading large bags
    recs_in, bag_reports = [], []
    for path in bags:
        log = rosbag.read_joint_states(path, topic, joints)
        joints = joints or log.joints  # later bags must hold the first one's joints
        for rec in rosbag.recordings(log, os.path.basename(os.path.normpath(path)), split_gap):
            recs_in.append(rec)
            bag_reports.append({**log.report, **rec.report})
    cols = {q: [rosbag.column(q, j) for j in joints] for q in rosbag.QUANTITIES}
    velocity = all(r.report["velocity"] for r in recs_in)
    logs = ((i, r.label, r.columns) for i, r in enumerate(recs_in))
    recs, dts, skipped, report = _load_recordings(logs, cols["effort"], cols["position"], steps, stride, "t", time_tol,
                                                  None, None, resample_hz, layout, cols["velocity"] if velocity else None)
    original_dt = _common_dt(dts, time_tol)
    dt = 1.0 / resample_hz if resample_hz else original_dt
    u_names, y_names, _, y_units = real_logs.layout_names(layout, cols["effort"], cols["position"], None,
                                                          ["rad"] * len(joints))
    config = {"rosbag": [str(b) for b in bags], "topic": topic, "joints": list(joints), "split_gap": split_gap,
              "steps": steps, "stride": stride, "name": name, "time_tol": time_tol, "resample_hz": resample_hz,
              "layout": layout, "u_cols": cols["effort"], "y_cols": cols["position"],
              "u_units": ["N m"] * len(joints), "files": [r.label for r in recs_in]}
    for rec, bag in zip(report, bag_reports):
        rec.update({k: bag[k] for k in ("messages", "interpolated", "duplicate_stamps", "reordered", "stamps",
                                        "longest_gap_s", "decoded_one_by_one")})
    attrs = _store_attrs(config, dt, original_dt, report, skipped, sum(len(r[3]) for r in recs), y_units)
    attrs["velocity"] = "qvel" if velocity else None
    with exclusive(out):  # locked only to write, as ingest: a refused bag leaves nothing, not even a lock file
        _write_store(out, recs, steps, (u_names, y_names, None), attrs, overwrite)
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
    extras = {"recording_index": ((), "int32"), "window_start": ((), "int64")}
    velocity = recs[0][4].get("qvel")
    if velocity is not None:  # the logged joint velocity, where the log has one (ROS bags)
        extras["qvel"] = ((steps, velocity.shape[1]), "float32")
    writer = create_store(out, sum(len(r[3]) for r in recs), steps, u_names, y_names, [], attrs,
                          extras=extras, overwrite=overwrite, u_cmd_names=cmd_names)
    for index, u, y, starts, more in recs:
        for b in range(0, len(starts), _WRITE_BLOCK):
            block = starts[b:b + _WRITE_BLOCK]
            rows = block[:, None] + np.arange(steps)  # (k, T) sample indices
            extras = {"recording_index": np.full(len(block), index, np.int32), "window_start": block,
                      **{name: arr[rows] for name, arr in more.items()}}
            writer.append(u[rows], y[rows], np.zeros((len(block), 0), np.float32), extras=extras)
    writer.finalize()
