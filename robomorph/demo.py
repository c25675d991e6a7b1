"""``python -m robomorph.demo`` (or ``robomorph demo``, ``make demo``): the main job end to end on a small default.

The door only; the machinery is :mod:`robomorph.reproduction.demo`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.core.options import Parser, add_alias, integer, number
from robomorph.reproduction import demo


MIN_TRAIN_ROBOTS = 20


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m robomorph.demo", description=demo.__doc__.split("\n")[0])
    p.add_argument("--out", default="data/demo", help="folder of the showcase and training stores")
    p.add_argument("--robots", type=integer(1, 100_000), default=16, help="robots per task in the showcase datasets")
    p.add_argument("--steps", type=integer(1, 1_000_000), default=1000, help="steps per showcase trajectory")
    # Training holds out 10 % of these for validation: fewer than 20 leave it (nearly) empty.
    p.add_argument("--train-robots", type=integer(MIN_TRAIN_ROBOTS, 1_000_000), default=128,
                   help=f"robots of the realistic recipe to train on (at least {MIN_TRAIN_ROBOTS}: 10 %% of them validate)")
    p.add_argument("--minutes", type=number(0, 7 * 24 * 60, low_open=True), default=1.5,
                   help="training budget (wall clock; the hybrid's default mode reads no network, so its "
                        "predictions do not depend on it)")
    p.add_argument("--runs-dir", default="results/runs", help="folder of training runs; the report goes beside it")
    p.add_argument("--workers", type=integer(1, 1024), default=None)
    p.add_argument("--inputs", choices=("command", "total"), default="command",
                   help="input formulation: command (the torque a torque-controlled Panda is sent; its physics "
                        "is predictable, so the hybrid model identifies the robot and simulates it) or total "
                        "(the paper's total joint torque)")
    p.add_argument("--identified-physics", action="store_true",
                   help="also score the identified_physics baseline (a per-window parameter fit: minutes more)")
    p.add_argument("--verbose", action="store_true",
                   help="also print the per-channel table, every baseline's mean scores and the calibration's "
                        "table (all of them are in the evaluation folder and the report either way)")
    add_alias(p, "--out-dir", "--out")  # its name before core.options.VOCABULARY: kept one release
    return p


def run(args: argparse.Namespace) -> int:
    res = demo.run_demo(args.out, args.robots, args.steps, args.train_robots, args.minutes, args.runs_dir,
                        args.workers, args.identified_physics, args.inputs, args.verbose)
    print(demo.horizon_summary(res.result))
    took = ", ".join(f"{name} {seconds / 60:.1f}" for name, seconds in res.seconds.items())
    print(f"written (minutes: {took}):")
    print(f"  datasets: {', '.join(res.stores)} (each with its summary .txt and plots .png)")
    print(f"  training run: {res.run_dir} (config.yaml, checkpoints/best.ckpt, logs/metrics.csv)")
    print(f"  evaluation: {res.eval_dir} (table.md, metrics.json, metrics.csv, horizons.csv, plots)")
    print(f"  report: {res.report} (open it in a browser; it works offline)")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
