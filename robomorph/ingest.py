"""``python -m robomorph.ingest`` (or ``robomorph ingest``): a real robot's logs (NPZ, CSV, MAT, ROS bags) into a store.

The door only; the machinery is :mod:`robomorph.data.ingest`.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from robomorph.core.errors import run_command
from robomorph.data import ingest


def _names(text: str) -> list[str]:
    return [c.strip() for c in text.split(",") if c.strip()]


def _units(text: str) -> list[str]:
    # Empty entries are kept: "N m,,rad" leaves the second column without a unit.
    return [c.strip() for c in text.split(",")]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.ingest", description=ingest.__doc__.split("\n")[0])
    p.add_argument("files", nargs="*", help="log files, one recording each (.csv, .npz, .mat)")
    p.add_argument("--source", help="instead of files: a public real-arm source (kinova_gen3, ur5, schunk, "
                   "industrial_robot; docs: Real robots), read from its clone under --data and written as "
                   "OUT/train.zarr, OUT/test.zarr (and OUT/val.zarr), split by recording")
    p.add_argument("--data", help="with --source: the folder holding the sources' clones")
    p.add_argument("--rosbag", action="append", metavar="PATH",
                   help="instead of files: a ROS bag (ROS1 .bag; ROS2 folder, .db3 or .mcap) of sensor_msgs/JointState; "
                        "repeat for several bags. Effort is the store's input (total joint torque), position its output")
    p.add_argument("--topic", default="/joint_states", help="with --rosbag: the JointState topic (default: /joint_states)")
    p.add_argument("--joints", type=_names, help="with --rosbag: the joints to read, comma-separated, in order "
                   "(default: the --layout arm's joints, or every joint the bag names)")
    p.add_argument("--split-gap", type=float, metavar="SECONDS",
                   help="with --rosbag: a pause in the stamps longer than this starts a new recording")
    p.add_argument("--u-cols", type=_names,
                   help="total joint torque columns (the store's u), comma-separated")
    p.add_argument("--u-cmd-cols", type=_names, help="command columns before the arm's gravity compensation "
                   "(the store's u_cmd, for data.inputs: command), comma-separated, joint order of --u-cols")
    p.add_argument("--y-cols", type=_names, help="output columns, comma-separated")
    p.add_argument("--steps", type=int, help="samples per window (T)")
    p.add_argument("--stride", type=int, help="samples between window starts (default: --steps)")
    p.add_argument("--dt", type=float, help="sample time in seconds")
    p.add_argument("--time-col", help="timestamp column (seconds) to derive dt from; must be uniform")
    p.add_argument("--time-tol", type=float, default=0.01,
                   help="largest relative deviation of a time step from the mean (default: 0.01)")
    p.add_argument("--format", dest="fmt", default="auto", help="auto | csv | npz | mat (default: auto)")
    p.add_argument("--out", required=True, help="output store directory (e.g. data/real.zarr)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing RoboMorph store")
    p.add_argument("--name", help="domain name recorded in the store (default: real)")
    p.add_argument("--u-units", type=_units, help="unit of each --u-cols column, comma-separated (e.g. 'N m,N m')")
    p.add_argument("--y-units", type=_units, help="unit of each --y-cols column, comma-separated (e.g. rad,rad)")
    p.add_argument("--resample", type=float, metavar="HZ",
                   help="resample every log to HZ with an anti-aliasing filter before cutting windows (--steps and "
                        "--stride then count samples at HZ); the store records the logs' own rate (original_dt)")
    p.add_argument("--layout", metavar="ARM|joints",
                   help="ARM (panda, kinova3, ur5e, iiwa, ... any registered arm): --u-cols are its joint torques and "
                        "--y-cols its joint angles [rad], in joint order; the store gets the simulator's channel names "
                        "and EE pose computed with the catalogue kinematics. "
                        "joints: --u-cols and --y-cols are any arm's joint torques and angles in joint order; the "
                        "store names them by role (tau0.., q0..) so a model of several arms reads them")
    return p


def run_source(args: argparse.Namespace) -> int:
    from robomorph.data import public_logs  # noqa: PLC0415

    source = public_logs.get(args.source)
    stores = public_logs.write_stores(source, args.data, args.out, overwrite=args.overwrite)
    for split, path in stores.items():
        ds = ingest.open_store(path)
        print(f"{path}: {ds.n} windows x {ds.steps} steps (dt={ds.dt:.6g} s) from the {split} recordings")
    return 0


_BAG_ONLY = (("--topic", "topic", "/joint_states"), ("--joints", "joints", None), ("--split-gap", "split_gap", None))


def check_request(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Either ``--source`` with ``--data``, ``--rosbag`` with ``--steps``, or files with
    ``--u-cols``, ``--y-cols`` and ``--steps``."""
    bag_only = [flag for flag, key, default in _BAG_ONLY if getattr(args, key) != default]
    if args.rosbag:
        given = [flag for flag, v in (("files", args.files), ("--source", args.source), ("--u-cols", args.u_cols),
                                      ("--u-cmd-cols", args.u_cmd_cols), ("--y-cols", args.y_cols), ("--dt", args.dt),
                                      ("--time-col", args.time_col), ("--u-units", args.u_units),
                                      ("--y-units", args.y_units), ("--format", args.fmt != "auto")) if v]
        if given:
            p.error(f"--rosbag reads the joints' names, stamps and units from the bag: drop {', '.join(given)}")
        if not args.steps:
            p.error("--rosbag needs --steps (samples per window)")
        return
    if bag_only:
        p.error(f"{', '.join(bag_only)} only go with --rosbag PATH")
    if args.source:
        given = [flag for flag, v in (("files", args.files), ("--u-cols", args.u_cols), ("--y-cols", args.y_cols),
                                      ("--steps", args.steps)) if v]
        if given or not args.data:
            p.error("--source reads a public source's clone: pass --data DIR and none of " + ", ".join(given or ["files"]))
        return
    missing = [flag for flag, v in (("files", args.files), ("--u-cols", args.u_cols), ("--y-cols", args.y_cols),
                                    ("--steps", args.steps)) if not v]
    if missing:
        p.error(f"the following arguments are required: {', '.join(missing)} (or --source NAME --data DIR)")


def run_rosbag(args: argparse.Namespace) -> int:
    ds = _with_warnings(lambda: ingest.ingest_rosbag(
        args.rosbag, args.out, args.steps, topic=args.topic, joints=args.joints, split_gap=args.split_gap,
        stride=args.stride, overwrite=args.overwrite, name=args.name, resample_hz=args.resample, layout=args.layout,
        time_tol=args.time_tol))
    for r in ds.attrs["recordings"]:
        print(f"  {r['source']}: {r['messages']} messages ({r['stamps']} stamps) -> {r['samples']} samples -> "
              f"{r['windows']} windows; {r['interpolated']} samples interpolated (longest gap {r['longest_gap_s']:.3g} s), "
              f"{r['duplicate_stamps']} duplicate stamps dropped, {r['reordered']} messages out of order, "
              f"{r['tail_dropped']} tail samples dropped")
    skipped = ds.attrs["skipped_recordings"]
    print(f"{args.out}: {ds.n} windows x {ds.steps} steps (dt={ds.dt:.6g} s, n_u={len(ds.u_names)}, n_y={len(ds.y_names)}) "
          f"from {len(ds.attrs['recordings']) - len(skipped)} of {len(ds.attrs['recordings'])} recordings"
          + (", velocity kept (qvel)" if ds.attrs.get("velocity") else "")
          + (f", resampled from {1 / ds.attrs['original_dt']:.6g} Hz" if args.resample else ""))
    return 0


def _with_warnings(fn):
    """Runs ``fn``, printing warnings about skipped recordings before its result line (or its
    error), once the recording context is left (inside it, showwarning only records)."""
    caught: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ingest.ShortRecordingWarning)
            ds = fn()
    finally:
        _print_warnings(caught)
    return ds


def run(args: argparse.Namespace) -> int:
    if args.source:
        return run_source(args)
    if args.rosbag:
        return run_rosbag(args)
    ds = _with_warnings(lambda: ingest.ingest(
        args.files, args.u_cols, args.y_cols, args.out, args.steps, dt=args.dt, time_col=args.time_col,
        stride=args.stride, fmt=args.fmt, overwrite=args.overwrite, name=args.name, time_tol=args.time_tol,
        u_cmd_cols=args.u_cmd_cols, u_units=args.u_units, y_units=args.y_units, resample_hz=args.resample,
        layout=args.layout))
    used = len(args.files) - len(ds.attrs["skipped_recordings"])
    for r in ds.attrs["recordings"]:
        print(f"  {r['source']}: {r['samples']} samples -> {r['windows']} windows, "
              f"{r['tail_dropped']} tail samples dropped")
    print(f"{args.out}: {ds.n} windows x {ds.steps} steps (dt={ds.dt:.6g} s, n_u={len(ds.u_names)}, "
          f"n_y={len(ds.y_names)}) from {used} of {len(args.files)} recordings"
          + (f", resampled from {1 / ds.attrs['original_dt']:.6g} Hz" if args.resample else ""))
    return 0


def _print_warnings(caught: list[warnings.WarningMessage]) -> None:
    for w in caught:
        if issubclass(w.category, ingest.ShortRecordingWarning):
            print(f"warning: {w.message}", file=sys.stderr)
        else:  # warnings of other libraries keep their usual form
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    check_request(p, args)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
