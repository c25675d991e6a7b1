"""The public logs of real arms the project is judged on: where each comes from, its licence,
how its files are read, which recordings are held out for test, and their stores.

Nothing here downloads: each source is a public repository the user clones (the command is in
:attr:`PublicLog.clone`) into one folder, ``--data DIR``, under the repository's own name.
Each reader takes the files as their authors wrote them and gives :class:`Recording` s of
joint torques ``u`` (N m) and joint angles ``q`` (rad); :func:`write_stores` then turns them
into RoboMorph stores, one per split, through :func:`robomorph.data.ingest.ingest` (its
anti-aliasing resampler, its layouts, its provenance), so a store made here is the store a
user gets from ``robomorph ingest`` on the same files.

Splits are by recording, never by window: no test window comes from a recording that
trained or identified anything. Each source's rule is in its ``split_rule``.
"""

from __future__ import annotations

import glob
import hashlib
import os
import tempfile
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from robomorph.core.atomic import replace_folder, staging_folder
from robomorph.core.errors import MissingInputError, RoboMorphError
from robomorph.core.locks import exclusive

SPLITS = ("train", "val", "test")


class PublicLogError(RoboMorphError, ValueError):
    """A public source that is not where it was asked for, or whose files cannot be read."""


@dataclass
class Recording:
    """One recording of a real arm, at its own (uniform) sample time.

    Attributes:
        name: where it comes from, relative to the source's folder.
        u: (L, n) joint torques [N m] (what the source logs as the arm's torque).
        q: (L, n) joint angles [rad].
        dt: sample time [s].
        split: ``train``, ``val`` or ``test``.
        note: what the reader did to the file beyond reading it (empty: nothing).
    """

    name: str
    u: np.ndarray
    q: np.ndarray
    dt: float
    split: str
    note: str = ""


@dataclass(frozen=True)
class PublicLog:
    """One public source of real-arm logs and how the benchmark windows it.

    Attributes:
        name: the source's key (``--robots``).
        robot: the robot, for people.
        arm: the arm of :mod:`robomorph.sim.arms` with this robot's catalogue model (its
            layout, EE pose and physics), or None.
        folders: where its files lie under ``--data``, the first that exists wins: the clone's
            folder, then (the industrial robot) the official loader's download.
        clone: the commands that fetch it.
        licence: the data's licence, as the source states it.
        torque: what ``u`` is, in the source's words.
        split_rule: which recordings are held out for test, and why.
        hz: the rate the benchmark resamples to (None: the log's own rate).
        context, horizon: window lengths in samples at that rate.
        stride: samples between test windows.
        reader: ``root -> [Recording]``.
        labels: where the user finds column ``j`` of ``u`` and of ``q`` in the source's own files: formats
            of ``j1`` (j + 1), ``j2`` (j + 2) and ``split``, so that a bad value is reported as the file holds it
            (``Position3``), not as the store would name it (``q2``).
    """

    name: str
    robot: str
    arm: str | None
    folders: tuple[str, ...]
    clone: str
    licence: str
    torque: str
    split_rule: str
    hz: float | None
    context: int
    horizon: int
    stride: int
    reader: Callable[[str], list[Recording]]
    labels: tuple[str, str] = ("column {j1} of u", "column {j1} of q")

    def root(self, data: str) -> str:
        """The clone's folder under ``data`` (the first of its names that exists; a local clone
        wins over a download); refuses one that is missing."""
        path = next((p for p in (os.path.join(data, n) for n in self.folders) if os.path.isdir(p)),
                    os.path.join(data, self.folders[0]))
        if not os.path.isdir(path):
            raise MissingInputError(f"{path} not found: fetch the {self.robot} logs with `{self.clone}` "
                                    f"inside {data} (see docs/guide/real-robots.md)")
        return path

    def recordings(self, data: str) -> list[Recording]:
        recs = self.reader(self.root(data))
        if not recs:
            raise PublicLogError(f"no {self.robot} recordings found under {self.root(data)}: is the clone complete?")
        if not any(r.split == "test" for r in recs) or not any(r.split == "train" for r in recs):
            raise PublicLogError(f"{self.robot}: the recordings found under {self.root(data)} leave the train or the "
                                 "test split empty; is the clone complete?")
        self._check(recs, self.root(data))
        return recs

    def _check(self, recs: list[Recording], root: str) -> None:
        """Refuses, before anything is written, a recording holding NaN or inf (named as the user's file and
        column hold it) and a train or test split none of whose recordings holds one window (issue 61: every
        recording too short used to exit 0 with nothing written and nothing said)."""
        for r in recs:
            for kind, x in (("u", r.u), ("q", r.q)):
                bad = ~np.isfinite(x)
                if bad.any():
                    row, j = (int(v[0]) for v in np.nonzero(bad))
                    label = self.labels[kind == "q"].format(j1=j + 1, j2=j + 2, split=r.split)
                    raise PublicLogError(
                        f"{os.path.join(root, r.name.split(':')[0])}: {label} holds NaN or inf (first at sample {row} "
                        f"of the recording, {int(bad[:, j].sum())} in all); restore the file from its clone "
                        "(docs/guide/real-robots.md) or remove the recording")
        steps, rate = self.context + self.horizon, (f"{self.hz:g} Hz" if self.hz else "the log's rate")
        for split in ("train", "test"):
            chosen = [r for r in recs if r.split == split]
            longest = max(int(np.ceil(len(r.u) * (self.hz * r.dt if self.hz else 1.0))) for r in chosen)
            if longest < steps:
                raise PublicLogError(
                    f"--source {self.name}: no {split} recording under {root} holds one window of {steps} samples "
                    f"at {rate} (context {self.context} + horizon {self.horizon}; the longest has {longest}): are the files "
                    "complete? Restore them from the clone (docs/guide/real-robots.md)")


# ---------------------------------------------------------------------------------- readers


def _numbers(path: str, min_cols: int) -> np.ndarray:
    """(L, k >= ``min_cols``) the rows of a headerless CSV of numbers, or one line naming the file,
    the line and what is wrong (a truncated last line, a cell that is no number, too few columns)."""
    from robomorph.data.log_files import IngestError  # noqa: PLC0415

    rows: list[list[float]] = []
    with open(path, encoding="utf-8-sig") as f:
        for line_no, line in enumerate(f, start=1):
            if not line.strip():
                continue
            try:
                row = [float(c) for c in line.split(",")]
            except ValueError:
                raise IngestError(f"{path} line {line_no}: {line.strip()[:60]!r} is not a row of numbers (a truncated "
                                  "or damaged file?); restore the file from its clone") from None
            if rows and len(row) != len(rows[0]):
                raise IngestError(f"{path} line {line_no}: {len(row)} values where the lines above hold {len(rows[0])} "
                                  "(a truncated or damaged file?); restore the file from its clone")
            rows.append(row)
    if rows and len(rows[0]) < min_cols:
        raise IngestError(f"{path}: {len(rows[0])} columns where this source's files hold at least {min_cols}; "
                          "is this the source's own file? Restore it from its clone")
    return np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)


def _kinova(root: str) -> list[Recording]:
    # Time is the sample index of the arm's 1 kHz loop. The joint torque is taken from
    # TorqueCur (the motors' currents through their torque constants): the sensors' Torque
    # columns read exactly 0 over whole files (Trajectory1, four of the joint-wise motions) and
    # on joint 7 in every file, which would hand every predictor a robot with no torque there.
    recs = []
    from robomorph.data.log_files import read_log  # noqa: PLC0415  (ingest's CSV reader: it names a bad line)

    for path in sorted(glob.glob(os.path.join(root, "pyDynaMapp", "data", "kinova", "*", "*.csv"))):
        cols = read_log(path, "csv")
        try:
            u = np.stack([cols[f"TorqueCur{j}"] for j in range(1, 8)], axis=1)
            q = np.stack([cols[f"Position{j}"] for j in range(1, 8)], axis=1)
        except KeyError:
            raise PublicLogError(f"{path} lacks the TorqueCur1..7 / Position1..7 columns of the Kinova logs") from None
        split = "test" if os.path.basename(os.path.dirname(path)) == "validation_data" else "train"
        recs.append(Recording(os.path.relpath(path, root), u, q, 1e-3, split))
    return recs


def _lenient_rows(path: str, width: int) -> tuple[np.ndarray, int]:
    """Rows of ``width`` numbers of a headerless CSV, and how many other rows were dropped
    (some of the UR5 logs end in a truncated line)."""
    rows, dropped = [], 0
    with open(path) as f:
        for line in f:
            parts = line.strip().split(",")
            try:
                if len(parts) != width:
                    raise ValueError
                rows.append([float(x) for x in parts])
            except ValueError:
                dropped += 1
    return np.asarray(rows, dtype=np.float64).reshape(-1, width), dropped


def _on_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    order = np.argsort(t, kind="stable")
    t, x = t[order], x[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return np.stack([np.interp(grid, t[keep], x[keep, j]) for j in range(x.shape[1])], axis=1)


_UR5_TEST = ("Verify_Model",)
_UR5_DT = 0.008


def _ur5(root: str) -> list[Recording]:
    # Each movement logs q_actual and m_target (the target torque the controller sends the
    # joints, gravity included) in their own CSVs: time [s], then 6 joints. Their clocks are
    # the robot's 125 Hz loop, with jitter and gaps in a few movements: both are interpolated
    # onto one uniform 8 ms grid over the span they share.
    recs = []
    base = os.path.join(root, "JointSpaceControl_Model_C_ForceEstim", "RecordedUR5Data")
    for folder in sorted(glob.glob(os.path.join(base, "*", "csv_files"))):
        q_path, u_path = os.path.join(folder, "log_q_actual.csv"), os.path.join(folder, "log_m_target.csv")
        if not (os.path.isfile(q_path) and os.path.isfile(u_path)):
            continue
        q, dq = _lenient_rows(q_path, 7)
        u, du = _lenient_rows(u_path, 7)
        if len(q) < 2 or len(u) < 2:
            continue
        dt = _UR5_DT
        start, stop = max(q[0, 0], u[0, 0]), min(q[-1, 0], u[-1, 0])
        grid = start + dt * np.arange(int(np.floor((stop - start) / dt)) + 1)
        movement = os.path.basename(os.path.dirname(folder))
        jitter = float(np.abs(np.diff(q[:, 0]) - dt).max())
        note = ", ".join(n for n in (f"{dq + du} malformed rows dropped" if dq + du else "",
                                     f"clock jitter up to {jitter * 1e3:.1f} ms, interpolated" if jitter > 0.05 * dt
                                     else "") if n)
        split = "test" if any(k in movement for k in _UR5_TEST) else "train"
        recs.append(Recording(os.path.relpath(folder, root), _on_grid(u[:, 0], u[:, 1:], grid),
                              _on_grid(q[:, 0], q[:, 1:], grid), dt, split, note))
    return recs


def _schunk(root: str) -> list[Recording]:
    # 100 runs of 6 excitation inputs: runs that share an input share a split, and the
    # input first used latest is held out (a test input no training run has seen).
    base = os.path.join(root, "autoKoopman_codeocean", "data", "Robot")
    runs = sorted(glob.glob(os.path.join(base, "measurement_*")), key=lambda p: int(p.rsplit("_", 1)[-1]))
    groups: dict[str, list[str]] = {}
    for run in runs:
        with open(os.path.join(run, "input.csv"), "rb") as f:
            groups.setdefault(hashlib.sha256(f.read()).hexdigest(), []).append(run)
    held_out = set(list(groups.values())[-1]) if groups else set()
    recs = []
    for run in runs:
        t = _numbers(os.path.join(run, "time.csv"), 1).reshape(-1)
        traj = _numbers(os.path.join(run, "trajectory.csv"), 6)  # the six joint angles first
        u = _numbers(os.path.join(run, "input.csv"), 6)
        n = min(len(t), len(traj), len(u))
        dt = float(np.median(np.diff(t[:n])))
        recs.append(Recording(os.path.relpath(run, root), u[:n], traj[:n, :6], dt,
                              "test" if run in held_out else "train"))
    return recs


INDUSTRIAL_MAT = os.path.join("data", "IndustRobo", "forward_identification_without_raw_data_shifted.mat")
# Where the official loader (nonlinear-benchmarks) leaves its download, under --data.
INDUSTRIAL_DOWNLOAD = "nonlinear_benchmarks"


def _industrial(root: str) -> list[Recording]:
    # The benchmark's own split: u_train / u_val / u_test (6, L) motor torques, y_* (6, L)
    # joint angles in degrees at 10 Hz (Weigand et al.); stored in radians here. The copy in
    # the clone, or the file the official loader downloads (the same variables).
    from scipy.io import loadmat  # noqa: PLC0415

    found = [os.path.join(root, INDUSTRIAL_MAT)] + sorted(
        glob.glob(os.path.join(root, "**", "forward_identification_without_raw_data*.mat"), recursive=True))
    path = next((p for p in found if os.path.isfile(p)), None)
    if path is None:
        return []
    try:
        m = loadmat(path)
    except Exception as exc:  # noqa: BLE001  (scipy's errors of a damaged file are of many classes)
        raise PublicLogError(f"cannot read {path} ({type(exc).__name__}: {exc}): a truncated or damaged download? "
                             "Fetch it again") from None
    if not all(f"{k}_{split}" in m for k in "uy" for split in ("train", "test")):
        raise PublicLogError(f"{path} lacks the benchmark's u_train / y_train / u_test / y_test variables")
    name = os.path.relpath(path, root)
    return [Recording(f"{name}:{split}", np.asarray(m[f"u_{split}"], np.float64).T,
                      np.deg2rad(np.asarray(m[f"y_{split}"], np.float64).T), 0.1, split)
            for split in SPLITS if f"u_{split}" in m]


def download_industrial(data: str) -> str:
    """Has the official loader (``nonlinear-benchmarks``' ``Industrial_robot``) download the
    industrial robot benchmark into ``data/nonlinear_benchmarks``, where :data:`SOURCES` reads
    it when no clone is there. Only on the user's request (``--download-industrial``): nothing
    else here reaches the network.

    Returns:
        The path of the downloaded ``.mat`` file.
    """
    try:
        import nonlinear_benchmarks  # noqa: PLC0415
    except ImportError:
        raise PublicLogError("downloading the industrial robot benchmark needs its official loader: "
                             "pip install nonlinear-benchmarks (or clone the copy named in docs/guide/real-robots.md)") from None
    target = os.path.join(data, INDUSTRIAL_DOWNLOAD)
    os.makedirs(target, exist_ok=True)
    try:
        return nonlinear_benchmarks.Industrial_robot(data_file_locations=True, dir_placement=target)
    except Exception as exc:  # the loader's own download and unpacking errors, whatever their class
        raise PublicLogError(f"the official loader could not download the industrial robot benchmark into {target}: "
                             f"{type(exc).__name__}: {exc}") from None


SOURCES: dict[str, PublicLog] = {s.name: s for s in (
    PublicLog("kinova_gen3", "Kinova Gen3 (7 joints, 1 kHz)", "kinova3", ("dynamic-identification",),
              "git clone https://github.com/wissem01chiha/dynamic-identification && git -C dynamic-identification "
              "checkout 90ba37d676d8da6c064d9edf5c1a09389309752e",
              "MIT (at that commit)", "TorqueCur1..7: joint torque from the motor currents, gravity included (the "
              "sensors' Torque columns read 0 in whole files and on joint 7 everywhere)",
              "validation_data/ (the authors' validation trajectories) is test; identification_data/ and "
              "jointwise_motion/ train",
              200.0, 200, 200, 50, _kinova, ("TorqueCur{j1}", "Position{j1}")),
    PublicLog("ur5", "Universal Robots UR5 (6 joints, 125 Hz)", "ur5e", ("ur5_modeling_force_estimate",),
              "git clone https://github.com/kkufieta/ur5_modeling_force_estimate",
              "Apache-2.0", "m_target: the target joint torques of the UR controller, gravity included",
              "the movements the authors recorded to verify their model (*Verify_Model*) are test; the rest train",
              60.0, 200, 300, 100, _ur5, ("log_m_target.csv column {j2}", "log_q_actual.csv column {j2}")),
    PublicLog("schunk", "Schunk LWA 4P (6 joints, 250 Hz; Liu & Althoff 2018)", None, ("AutoKoopman",),
              "git clone -b experiment_rerun https://github.com/nikhilushinde/AutoKoopman",
              "CC0", "input.csv: the six motor torques",
              "runs that repeat one input share a split; the input first used latest (its runs) is test",
              None, 200, 500, 500, _schunk, ("input.csv column {j1}", "trajectory.csv column {j1}")),
    PublicLog("industrial_robot", "KUKA KR300 R2500 ultra SE (6 joints, 10 Hz; Weigand et al.)", None,
              ("Physics-Guided-Recurrent-State-Space-Neural-Networks", INDUSTRIAL_DOWNLOAD),
              "git clone https://github.com/yifang0-0/Physics-Guided-Recurrent-State-Space-Neural-Networks",
              "the benchmark's terms (nonlinear-benchmarks: Industrial_robot)",
              "u: the six motor torques", "the benchmark's own split (train / val / test)",
              None, 200, 50, 50, _industrial, ("u_{split} row {j1}", "y_{split} row {j1}")),
)}


def get(name: str) -> PublicLog:
    if name not in SOURCES:
        raise PublicLogError(f"unknown public source {name!r}; choose from {', '.join(SOURCES)}")
    return SOURCES[name]


def write_stores(source: PublicLog, data: str, out: str, overwrite: bool = False) -> dict[str, str]:
    """Ingests every split of ``source`` (its clone under ``data``) into ``out/<split>.zarr``.

    Each recording goes through :func:`robomorph.data.ingest.ingest` as one NPZ log of its
    columns (written to a temporary folder), resampled to ``source.hz`` where set, cut into
    windows of ``context + horizon`` samples (test windows ``stride`` apart, training windows a
    quarter window apart), in the arm's layout where the arm is registered. Recordings too short
    for one window are skipped, as ``ingest`` skips them; a split none of whose recordings holds
    a window is not written.

    All or nothing: every split is written into a hidden folder inside ``out`` first and moved
    into place only when all of them were, so a split that is refused (a NaN in a test log)
    leaves no store of the others behind and a rerun is not refused for them.

    Returns:
        ``{split: store path}`` for the splits that have a window.
    """
    from robomorph.data import ingest  # noqa: PLC0415
    from robomorph.data.store import check_writable  # noqa: PLC0415

    recs = source.recordings(data)
    steps = source.context + source.horizon
    plan = _split_plan(source, recs, steps)
    targets = {split: os.path.join(out, f"{split}.zarr") for split in plan}
    for target in targets.values():  # every refusal of an output before anything is made
        check_writable(target, overwrite, inputs=(source.root(data),))
    with staging_folder(out, source.name) as staging:
        with tempfile.TemporaryDirectory(prefix="robomorph-public-") as tmp:
            for split, chosen in plan.items():
                _ingest_split(ingest, source, split, chosen, steps, tmp, os.path.join(staging, f"{split}.zarr"))
        for split, target in targets.items():
            with exclusive(target):
                check_writable(target, overwrite)  # what it is now that no one else writes it
                replace_folder(os.path.join(staging, f"{split}.zarr"), target)
    return targets


def _split_plan(source: PublicLog, recs: list[Recording], steps: int) -> dict[str, list[Recording]]:
    """``{split: its recordings}`` for the splits that hold a window, in :data:`SPLITS` order."""
    plan = {}
    for split in SPLITS:
        chosen = [r for r in recs if r.split == split]
        if not chosen:
            continue
        dts = {round(r.dt, 9) for r in chosen}
        if len(dts) > 1:
            raise PublicLogError(f"{source.name}: the {split} recordings have several sample times {sorted(dts)}")
        # Samples each recording keeps at the store's rate (resample_poly's output length).
        kept = [int(np.ceil(len(r.u) * (source.hz * r.dt if source.hz else 1.0))) for r in chosen]
        if max(kept) >= steps:  # else no recording of this split is long enough for one window
            plan[split] = chosen
    return plan


def _ingest_split(ingest, source: PublicLog, split: str, chosen: list[Recording], steps: int, tmp: str,
                  target: str) -> None:
    """One split's recordings, as NPZ logs in ``tmp``, through ``ingest`` into the store ``target``."""
    n = chosen[0].u.shape[1]
    cols_u, cols_q = [f"u{j}" for j in range(n)], [f"q{j}" for j in range(n)]
    files = []
    for k, r in enumerate(chosen):
        path = os.path.join(tmp, f"{split}_{k:03d}_{r.name.replace(os.sep, '_').replace(':', '_')}.npz")
        np.savez(path, **{c: r.u[:, j] for j, c in enumerate(cols_u)}, **{c: r.q[:, j] for j, c in enumerate(cols_q)})
        files.append(path)
    with warnings.catch_warnings():  # recordings shorter than a window are skipped, as ingest skips them
        warnings.simplefilter("ignore", ingest.ShortRecordingWarning)
        ingest.ingest(files, cols_u, cols_q, target, steps, dt=chosen[0].dt,
                      stride=source.stride if split == "test" else max(1, steps // 4),
                      name=source.name, resample_hz=source.hz,
                      layout=source.arm or "joints", u_units=["N m"] * n, y_units=["rad"] * n)
