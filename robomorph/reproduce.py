"""``python -m robomorph.reproduce`` (or ``robomorph reproduce``): the paper's tables and figures.

The door only; the machinery is :mod:`robomorph.reproduction.pipeline`.
"""

from __future__ import annotations

import argparse
import os
import sys

from robomorph.core.errors import SIGTERM_EXIT, StoppedBySignal, run_command
from robomorph.core.names import COMPILE_MODES, INPUTS, NORMALIZATIONS
from robomorph.reproduction import pipeline
from robomorph.reproduction.scales import SCALES


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.reproduce", description=pipeline.__doc__.split("\n")[0])
    p.add_argument("target", choices=pipeline.TARGETS, help="what to reproduce")
    p.add_argument("--scale", choices=list(SCALES), default="small", help="sizes and budgets (robomorph.reproduction.scales)")
    p.add_argument("--out", help="tables and figures (default results/paper/<scale>, or <scale>_paper_window)")
    p.add_argument("--work", help="stores, runs and evaluations (default data/reproduce/<scale>)")
    p.add_argument("--scratch-ratio", type=float, help="scratch budget / fine-tuning budget (default: the scale's)")
    p.add_argument("--steps-factor", type=float, default=1.0, help="multiply every training budget (e.g. 0.1)")
    p.add_argument("--compile", choices=COMPILE_MODES,
                   help="every run's --model.compile (default: the scale's; robomorph.training.compiling)")
    p.add_argument("--workers", type=int, help="generation threads/processes (default: all cores)")
    p.add_argument("--device", help="evaluation device: cpu, cuda, ... (default: cuda when available)")
    p.add_argument("--wandb", choices=("offline", "online", "disabled"), default=os.environ.get("WANDB_MODE", "offline"))
    p.add_argument("--normalization", choices=NORMALIZATIONS, default="train_stats",
                   help="train_stats (leak-free) or paper_window (the paper's protocol: each window z-scored over "
                        "context and query; its scores use the query outputs' statistics)")
    p.add_argument("--leak-free", help="compare: the train_stats output folder (default results/paper/<scale>); "
                                       "--out is the paper_window one")
    p.add_argument("--inputs", choices=INPUTS, default="total",
                   help="input formulation: total joint torque (the paper's) or command (without the arm's "
                        "gravity compensation); tables go to results/paper/<scale>-command by default")
    return p


def run(args: argparse.Namespace, argv: list[str]) -> int:
    scale = SCALES[args.scale].scaled(args.steps_factor, args.scratch_ratio, args.compile)
    command = " ".join(["python -m robomorph.reproduce", *argv])  # recorded in the tables' headers
    try:
        pipeline.reproduce(args.target, scale, args.out, args.work, command, args.workers, args.device, args.wandb,
                           args.normalization, args.leak_free, args.inputs)
    except StoppedBySignal as stop:  # a scheduler's stop mid-training: the run resumes from last.ckpt
        print(stop, file=sys.stderr)
        return SIGTERM_EXIT
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args, argv))


if __name__ == "__main__":
    sys.exit(main())
