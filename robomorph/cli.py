"""``robomorph <command> ...``: one console script over the ``python -m robomorph.<command>`` doors."""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "generate": "randomized robot trajectories into a Zarr store",
    "inspect": "what a store holds (counts, channels, ranges, plots)",
    "ingest": "a real robot's logs (CSV, NPZ, MAT, ROS bags) into a store",
    "arms": "your own arms from a URDF or MJCF: add, list, remove",
    "merge": "shards of one generation into one store",
    "priors": "the hybrid's predictions over windows of a store, for a residual model",
    "fit": "train a meta-model",
    "evaluate": "a checkpoint on a store, beside the baselines",
    "calibrate": "a Gaussian head's standard deviation, rescaled by horizon on held-out robots",
    "export": "a checkpoint as an inference-only model folder (safetensors + JSON)",
    "report": "the static HTML dashboard",
    "sweep": "Optuna studies over fit()",
    "reproduce": "the paper's tables and figures",
    "control": "model-predictive control of unseen robots, beside the catalogue OSC and physics",
    "demo": "generate, train, evaluate and report on a small default",
}
# Commands whose door sits inside their room (the room's package is the command's name).
DOORS = {"control": "robomorph.control.cli"}


def _usage() -> str:
    rows = "\n".join(f"  {name:10s} {what}" for name, what in COMMANDS.items())
    return f"usage: robomorph <command> [options]\n\ncommands:\n{rows}\n\n`robomorph <command> --help` for its options."


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: unknown command {name!r}: choose one of {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    door = importlib.import_module(DOORS.get(name, f"robomorph.{name}"))
    sys.argv = [f"robomorph {name}", *rest]
    code = door.main(rest)
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
