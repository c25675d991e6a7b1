"""Reading ``sensor_msgs/JointState`` from ROS bags into the columns every other log gives.

A robot's logs are most often ROS bags: the driver publishes ``sensor_msgs/JointState`` on
``/joint_states`` (name, position, velocity and effort per joint, stamped by the driver). This
module reads them through ``rosbags`` (pure Python, no ROS installation): ROS1 ``.bag`` files
and ROS2 bags (a folder with ``metadata.yaml``, or one ``.db3`` / ``.mcap`` file). What it
returns is what :func:`robomorph.data.log_files.read_log` returns for a CSV: named columns on a
uniform clock (``t``, ``position/<joint>``, ``velocity/<joint>``, ``effort/<joint>``), one set
per recording, so :mod:`robomorph.data.ingest` cuts windows, resamples and splits them along
the one path it has for every log.

The reading rules:

* Time is the messages' header stamps, not the bag's arrival times (a driver stamps a sample
  when it was measured; arrival adds transport jitter). Only a bag whose stamps are all zero
  (a driver that never stamps) falls back to arrival times, and the report says so.
* Messages are sorted by stamp (the report counts those that arrived out of order); a joint's
  duplicate stamps keep the last message.
* Joints are matched by name in every message, so a driver that reorders its names, or two
  drivers that publish different joints on one topic, are read alike. A joint missing from
  some messages, or a gap, is filled by linear interpolation onto the uniform clock (the
  report counts the clock's samples that no message held).
* ``split_gap``: a pause in the stamps longer than this many seconds starts a new recording
  (one bag, several sessions); without it, one bag is one recording.
* Effort is the store's input, the total joint torque, gravity included (what a joint torque
  sensor or a current-based driver reports).

Bad input is refused with one line before anything is written: a missing or truncated bag,
a missing topic, a topic of another message type, a joint absent throughout, a joint without
effort, NaN or infinite values.

Decoding is vectorized: messages whose layout (frame id, names, array lengths) matches a first
message decoded and checked with ``rosbags`` are read as fixed-offset numbers straight from
their bytes (an hour at 1 kHz is 3.6 million messages); any other message is deserialized by
``rosbags`` one at a time.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robomorph.core.errors import MissingInputError
from robomorph.data.log_files import IngestError

JOINT_STATE = "sensor_msgs/msg/JointState"
DEFAULT_TOPIC = "/joint_states"
QUANTITIES = ("position", "velocity", "effort")
# Messages decoded per block: bounds memory (an hour at 1 kHz holds about a gigabyte of messages).
_BLOCK = 200_000
# Layouts tried per block before the rest is decoded one message at a time.
_MAX_LAYOUTS = 32
# A clock sample counts as held by a message when one lies within this fraction of a step.
_HELD_TOL = 0.01


def column(quantity: str, joint: str) -> str:
    """The column name of a joint's quantity (``position/joint1``)."""
    return f"{quantity}/{joint}"


@dataclass
class JointLog:
    """The messages of one topic, decoded: ``(M,)`` stamps and ``(M, J)`` values, NaN where a
    message did not hold a joint's value."""

    joints: list[str]
    stamp_ns: np.ndarray
    values: dict[str, np.ndarray]  # quantity -> (M, J) float64
    report: dict = field(default_factory=dict)


@dataclass
class Recording:
    """One recording on a uniform clock: ``columns`` as :func:`robomorph.data.log_files.read_log`
    gives them (``t`` in seconds from the recording's start), and what became of its messages."""

    label: str
    columns: dict[str, np.ndarray]
    report: dict


def _bag_paths(path: str) -> Path:
    """The path rosbags opens: a ``.bag`` file, a ROS2 bag folder or one of its storage files."""
    p = Path(path)
    if not p.exists():
        raise MissingInputError(f"bag not found: {path}")
    if p.is_dir():
        if not (p / "metadata.yaml").is_file():
            raise IngestError(f"{path} is a folder without metadata.yaml: a ROS2 bag folder holds one; give the folder "
                              "of `ros2 bag record`, a .db3 or .mcap file, or a ROS1 .bag file")
        return p
    if p.suffix not in (".bag", ".db3", ".mcap"):
        raise IngestError(f"{path}: a ROS bag is a .bag file (ROS1), a .db3 or .mcap file or a bag folder (ROS2); "
                          f"got a {p.suffix or 'file without extension'}")
    if p.suffix != ".bag" and (p.parent / "metadata.yaml").is_file():
        return p.parent  # the folder's metadata names every storage file of the bag
    return p


def _cannot_read(path: str, exc: BaseException) -> IngestError:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return IngestError(f"cannot read the bag {path}: {text}; is it truncated or still being recorded? "
                       "(`rosbag reindex` or `ros2 bag reindex` repairs an unclosed bag)")


def read_joint_states(path: str, topic: str = DEFAULT_TOPIC, joints: list[str] | None = None) -> JointLog:
    """Reads every ``sensor_msgs/JointState`` message of ``topic`` in one bag.

    Args:
        path: a ROS1 ``.bag`` file, a ROS2 bag folder, or a ROS2 ``.db3`` / ``.mcap`` file.
        topic: the topic to read.
        joints: the joints to keep, in this order; None: every joint the messages name, in
            the order they first appear.

    Raises:
        MissingInputError: the bag is not there.
        IngestError: an unreadable or truncated bag, a missing topic, another message type,
            a joint absent throughout, a joint without effort, NaN or infinite values.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError  # noqa: PLC0415  (only when a bag is read)

    bag = _bag_paths(path)
    try:
        with AnyReader([bag]) as reader:
            return _read_topic(reader, path, topic, joints)
    except (IngestError, MissingInputError):
        raise
    except AnyReaderError as exc:
        raise _cannot_read(path, exc) from exc
    except Exception as exc:
        # rosbags and its storage libraries raise many kinds (struct.error, KeyError, sqlite's, lz4's) on a damaged
        # bag: an error raised inside them is the bag's; one raised in this module is a bug and goes on.
        if _raised_by_reader(exc):
            raise _cannot_read(path, exc) from exc
        raise


_READER_PACKAGES = ("rosbags", "sqlite3", "apsw", "lz4", "zstd", "backports")


def _raised_by_reader(exc: BaseException) -> bool:
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    where = tb.tb_frame.f_code.co_filename if tb is not None else ""
    parts = set(Path(where).parts)
    return type(exc).__module__.startswith(_READER_PACKAGES) or any(p in parts for p in _READER_PACKAGES)


def _read_topic(reader, path: str, topic: str, joints: list[str] | None) -> JointLog:
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
        raise IngestError(f"{path} has no topic {topic!r}; its topics: {have}; choose one with --topic")
    other = sorted({c.msgtype for c in conns if c.msgtype != JOINT_STATE})
    if other:
        raise IngestError(f"topic {topic!r} in {path} carries {', '.join(other)}, not sensor_msgs/JointState: "
                          "ingest --rosbag reads joint states (choose their topic with --topic)")
    decoder = _Decoder(reader, reader.is2, path, topic, joints)
    raws, arrivals = [], []
    for _, arrival, raw in reader.messages(connections=conns):
        raws.append(raw)
        arrivals.append(arrival)
        if len(raws) == _BLOCK:
            decoder.decode(raws, arrivals)
            raws, arrivals = [], []
    if raws:
        decoder.decode(raws, arrivals)
    if not decoder.blocks:
        raise IngestError(f"topic {topic!r} in {path} holds no message")
    return decoder.finish()


class _Decoder:
    """Decodes blocks of raw JointState messages into stamps and per-name values."""

    def __init__(self, reader, is_ros2: bool, path: str, topic: str, joints: list[str] | None):
        self.reader, self.is_ros2, self.path, self.topic, self.wanted = reader, is_ros2, path, topic, joints
        self.blocks: list[tuple[np.ndarray, np.ndarray, list[str], dict[str, np.ndarray]]] = []
        self.names: list[str] = []  # every joint name seen, in order of first appearance
        self.slow, self.seen = 0, 0

    def _columns(self, names: list[str]) -> list[int]:
        for n in names:
            if n not in self.names:
                self.names.append(n)
        return [self.names.index(n) for n in names]

    def decode(self, raws: list[bytes], arrivals: list[int]) -> None:
        # Each message's place in the bag: the log keeps the bag's order, whatever order layouts are read in.
        arrivals = np.stack([np.asarray(arrivals, dtype=np.int64), self.seen + np.arange(len(raws))], axis=1)
        self.seen += len(raws)
        lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
        left = np.ones(len(raws), dtype=bool)
        for _ in range(_MAX_LAYOUTS):
            if not left.any():
                break
            first = int(np.argmax(left))
            layout = _Layout.of(raws[first], self.is_ros2)
            if layout is None or not layout.agrees(self._deserialize(raws[first])):
                break  # an unusual encoding: the rest goes the slow way
            same = np.flatnonzero(left & (lengths == len(raws[first])))
            rows = np.frombuffer(b"".join(raws[i] for i in same), dtype=np.uint8).reshape(len(same), -1)
            match = layout.matches(rows)
            self._add(arrivals[same[match]], *layout.read(rows[match]), layout.names)
            left[same[match]] = False
        for i in np.flatnonzero(left):
            self.slow += 1
            msg = self._deserialize(raws[i])
            stamp = np.array([int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)], dtype=np.int64)
            vals = {q: _as_row(getattr(msg, q), len(msg.name)) for q in QUANTITIES}
            self._add(arrivals[i:i + 1], stamp, vals, list(msg.name))

    def _deserialize(self, raw: bytes):
        return self.reader.deserialize(raw, JOINT_STATE)

    def _add(self, arrivals, stamps, vals, names) -> None:
        if len(stamps):
            self._check_finite(stamps, vals, list(names))
            self.blocks.append((arrivals, stamps, self._columns(list(names)), vals))

    def _check_finite(self, stamps: np.ndarray, vals: dict[str, np.ndarray], names: list[str]) -> None:
        """Refuses NaN or infinite positions and efforts of the joints read (others, a gripper's, may hold
        them). A velocity that is not finite counts as not logged (drivers without a velocity estimate
        publish NaN): the clock interpolates it from the messages that have one."""
        keep = [k for k, n in enumerate(names) if self.wanted is None or n in self.wanted]
        if vals["velocity"].size and not np.isfinite(vals["velocity"]).all():
            vals["velocity"] = np.where(np.isfinite(vals["velocity"]), vals["velocity"], np.nan)
        for q in ("position", "effort"):
            v = vals[q][:, keep] if vals[q].shape[1] else vals[q]
            bad = ~np.isfinite(v)
            if bad.any():
                row, col = (int(i[0]) for i in np.nonzero(bad))
                stamp = int(stamps[row])
                raise IngestError(f"{q} of joint {names[keep[col]]!r} is {v[row, col]} at stamp {stamp // 10**9}."
                                  f"{stamp % 10**9:09d} s in "
                                  f"{self.path} ({self.topic}; {int(bad.sum())} such values in this part of the bag): "
                                  "fix the driver's log or cut the bag before ingesting")

    def finish(self) -> JointLog:
        path, topic = self.path, self.topic
        wanted = list(self.names) if self.wanted is None else list(self.wanted)
        absent = [j for j in wanted if j not in self.names]
        if absent:
            raise IngestError(f"joint {', '.join(map(repr, absent))} is absent from every message of {topic!r} in {path}; "
                              f"the messages name {', '.join(self.names)} (choose with --joints)")
        where = {j: k for k, j in enumerate(wanted)}
        m = self.seen
        values = {q: np.full((m, len(wanted)), np.nan) for q in QUANTITIES}
        stamps, arrivals = np.empty(m, np.int64), np.empty(m, np.int64)
        for arr, st, cols, vals in self.blocks:
            rows = arr[:, 1]
            stamps[rows], arrivals[rows] = st, arr[:, 0]
            for src, name_col in enumerate(cols):
                dst = where.get(self.names[name_col])
                if dst is None:
                    continue
                for q in QUANTITIES:
                    if vals[q].shape[1]:
                        values[q][rows, dst] = vals[q][:, src]
        report = {"messages": m, "decoded_one_by_one": self.slow, "stamps": "header"}
        if not stamps.any():  # a driver that never stamps: arrival is the only clock there is
            stamps, report["stamps"] = arrivals, "arrival (every header stamp is zero)"
        _check_missing(values, wanted, path, topic)
        return JointLog(wanted, stamps, values, report)


def _as_row(seq, n: int) -> np.ndarray:
    arr = np.asarray(seq, dtype=np.float64).reshape(1, -1)
    return arr if arr.shape[1] in (0, n) else _bad_count(arr.shape[1], n)


def _bad_count(count: int, n: int):
    raise IngestError(f"a JointState message names {n} joints but holds {count} values of one quantity; "
                      "every array must have one value per name, or none")


def _check_missing(values: dict[str, np.ndarray], joints: list[str], path: str, topic: str) -> None:
    for q in ("position", "effort"):
        missing = [j for k, j in enumerate(joints) if np.isnan(values[q][:, k]).all()]
        if missing:
            role = "the store's output" if q == "position" else "the store's input (the total joint torque)"
            raise IngestError(f"joint {', '.join(map(repr, missing))} has no {q} in any message of {topic!r} in {path}: "
                              f"{q} is {role}")


class _Layout:
    """Where the numbers of one JointState message lie, for every message laid out alike."""

    def __init__(self, is_ros2: bool, names: list[str], fixed: list[tuple[int, int]], arrays: dict[str, tuple[int, int]],
                 size: int):
        self.is_ros2, self.names, self.fixed, self.arrays, self.size = is_ros2, names, fixed, arrays, size

    @classmethod
    def of(cls, raw: bytes, is_ros2: bool) -> "_Layout | None":
        """Parses one message (ROS1 or little-endian CDR); None for anything else."""
        try:
            return cls._parse(bytes(raw), is_ros2)
        except (struct.error, UnicodeDecodeError, ValueError):
            return None

    @classmethod
    def _parse(cls, raw: bytes, is_ros2: bool) -> "_Layout | None":
        base = 4 if is_ros2 else 0  # CDR: the encapsulation header; alignment counts from after it
        if is_ros2 and raw[:2] != b"\x00\x01":
            return None  # big-endian CDR: rare, decoded one by one
        fixed: list[tuple[int, int]] = []  # byte ranges that must equal the first message's
        pos = 12  # ROS1: seq, sec, nsec; CDR: header, sec, nanosec

        def align(n: int) -> None:
            nonlocal pos
            if is_ros2:
                pos += (-(pos - base)) % n

        def uint() -> int:
            nonlocal pos
            align(4)
            (v,) = struct.unpack_from("<I", raw, pos)
            fixed.append((pos, pos + 4))
            pos += 4
            return v

        def string() -> str:
            nonlocal pos
            n = uint()
            text = raw[pos:pos + n]
            fixed.append((pos, pos + n))
            pos += n
            return text.rstrip(b"\x00").decode()

        string()  # frame_id
        names = [string() for _ in range(uint())]
        arrays = {}
        for q in QUANTITIES:
            count = uint()
            if count not in (0, len(names)):
                return None
            align(8)
            arrays[q] = (pos, count)
            pos += 8 * count
        if pos != len(raw):
            return None
        return cls(is_ros2, names, fixed, arrays, len(raw))

    def agrees(self, msg) -> bool:
        """Whether this parse reads what rosbags reads from the same message."""
        if list(msg.name) != self.names:
            return False
        return all(len(getattr(msg, q)) == self.arrays[q][1] for q in QUANTITIES)

    def matches(self, rows: np.ndarray) -> np.ndarray:
        """(k,) which of ``rows`` (k, size) bytes share this layout (names, lengths, frame id)."""
        cols = np.concatenate([np.arange(a, b) for a, b in self.fixed])
        return (rows[:, cols] == rows[0, cols]).all(axis=1)

    def read(self, rows: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """(k,) stamps [ns] and quantity -> (k, count) values of messages laid out alike."""
        sec = np.ascontiguousarray(rows[:, 4:8]).view("<i4" if self.is_ros2 else "<u4")[:, 0].astype(np.int64)
        nsec = np.ascontiguousarray(rows[:, 8:12]).view("<u4")[:, 0].astype(np.int64)
        vals = {}
        for q, (at, count) in self.arrays.items():
            v = np.ascontiguousarray(rows[:, at:at + 8 * count]).view("<f8").astype(np.float64)
            vals[q] = v
        return sec * 10**9 + nsec, vals



def _rate(stamps: np.ndarray) -> float:
    """The recording's sample time [s]: the median step, refined so that a clock of whole
    steps from the first stamp to the last lands on both (stamps of a 1/60 s driver are
    rounded to nanoseconds; the mean over the run undoes that rounding)."""
    steps = np.diff(stamps)
    median = float(np.median(steps))
    n = int(round((stamps[-1] - stamps[0]) / median))
    return (stamps[-1] - stamps[0]) / n / 1e9


def recordings(log: JointLog, label: str, split_gap: float | None = None) -> list[Recording]:
    """A bag's messages as recordings on uniform clocks (see the module docstring).

    Args:
        log: the decoded messages (:func:`read_joint_states`).
        label: the bag's name, for the recordings' labels (``run.bag``, ``run.bag#2``).
        split_gap: seconds: a longer pause between two stamps starts a new recording.

    Raises:
        IngestError: a recording with fewer than two distinct stamps, or a bad ``split_gap``.
    """
    if split_gap is not None and not (np.isfinite(split_gap) and split_gap > 0):
        raise IngestError(f"--split-gap must be a positive number of seconds, got {split_gap}")
    order = np.argsort(log.stamp_ns, kind="stable")
    stamps = log.stamp_ns[order]
    # Out of order: arrived after a message stamped later.
    reordered = int(np.sum(log.stamp_ns < np.maximum.accumulate(log.stamp_ns)))
    values = {q: v[order] for q, v in log.values.items()}
    cuts = [0, len(stamps)]
    if split_gap is not None:
        gaps = np.flatnonzero(np.diff(stamps) > split_gap * 1e9) + 1
        cuts = [0, *gaps.tolist(), len(stamps)]
    out = []
    for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        name = label if len(cuts) == 2 else f"{label}#{k + 1}"
        rec = _uniform(name, log.joints, stamps[a:b], {q: v[a:b] for q, v in values.items()})
        rec.report.update({"reordered": reordered if k == 0 else 0, "stamps": log.report["stamps"]})
        out.append(rec)
    return out


def _uniform(label: str, joints: list[str], stamps: np.ndarray, values: dict[str, np.ndarray]) -> Recording:
    """One recording's messages onto the uniform clock of its own rate, joint by joint."""
    distinct = np.unique(stamps)
    if len(distinct) < 2:
        raise IngestError(f"{label}: {len(distinct)} distinct stamp(s): a recording needs at least two to have a rate "
                          "(a larger --split-gap keeps sessions together)")
    dt = _rate(distinct)
    n = int(round((distinct[-1] - distinct[0]) / (dt * 1e9))) + 1
    rel = (distinct - distinct[0]) / 1e9  # seconds, float64: exact to well under a nanosecond for days
    clock = np.arange(n) * dt
    # Clock samples no message lies near: filled by interpolation.
    nearest = np.minimum(np.searchsorted(rel, clock), len(rel) - 1)
    near = np.minimum(np.abs(rel[nearest] - clock), np.abs(rel[np.maximum(nearest - 1, 0)] - clock))
    interpolated = int(np.sum(near > _HELD_TOL * dt))
    t_all = (stamps - distinct[0]) / 1e9
    cols, duplicates = {"t": clock}, 0
    for q in QUANTITIES:
        for k, joint in enumerate(joints):
            x = values[q][:, k]
            held = ~np.isnan(x)
            if not held.any():
                continue  # velocity (or another quantity) this joint never had: not a column
            t, x = t_all[held], x[held]
            # Equal stamps: the last message wins (np.unique keeps the first of reversed arrays).
            last = len(t) - 1 - np.unique(t[::-1], return_index=True)[1]
            duplicates += len(t) - len(last)
            cols[column(q, joint)] = _on_clock(clock, t[last], x[last], _HELD_TOL * dt)
    report = {"messages": int(len(stamps)), "samples": n, "dt": dt, "interpolated": interpolated,
              "duplicate_stamps": duplicates, "longest_gap_s": float(np.max(np.diff(rel))),
              "velocity": all(column("velocity", j) in cols for j in joints)}
    return Recording(label, cols, report)


def _on_clock(clock: np.ndarray, t: np.ndarray, x: np.ndarray, tol: float) -> np.ndarray:
    """``x`` sampled at ``t`` onto ``clock``: a message's own value where one lies within
    ``tol`` of a clock sample (its stamp's nanosecond rounding is no reason to blend it with
    its neighbour), linear interpolation between messages elsewhere."""
    out = np.interp(clock, t, x)
    i = np.clip(np.searchsorted(t, clock), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(clock), int)
    i = np.where(np.abs(t[i - 1] - clock) < np.abs(t[i] - clock), i - 1, i) if len(t) > 1 else i
    held = np.abs(t[i] - clock) <= tol
    out[held] = x[i[held]]
    return out
