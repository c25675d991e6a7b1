"""Command-line options checked where they are parsed: numbers finite and in range.

A door declares each numeric option with :func:`integer` or :func:`number` and its bounds,
so ``--noise inf``, ``--duration 1e9`` or ``--seed -1`` never reach the machinery (where
they would run for hours, exhaust memory or be read as something else). :class:`Parser`
reports a refused option as every command reports bad input: one ``error:`` line naming the
option, what it takes and what was given, and exit code 2. An option renamed so that every
command names one concept alike keeps its old name one release as a :class:`DeprecatedAlias`.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable

from robomorph.core.errors import USAGE_EXIT


class Parser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are one ``error:`` line (exit code 2), no usage block."""

    def error(self, message: str):
        text = " ".join(message.split())
        print(f"error: {self.prog}: {text} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(USAGE_EXIT)


def _bounds(low: float | None, high: float | None, low_open: bool) -> str:
    if low is not None and high is not None:
        return f"{'>' if low_open else '>='} {low:g} and <= {high:g}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    return f"<= {high:g}"


def number(low: float | None = None, high: float | None = None, low_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type``: a finite float within ``[low, high]`` (``(low, high]`` with ``low_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"takes a number, got {text!r}") from None
        bad_low = low is not None and (value <= low if low_open else value < low)
        if not math.isfinite(value) or bad_low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"takes a finite number {_bounds(low, high, low_open)}, got {text}")
        return value

    parse.__name__ = "number"
    return parse


def integer(low: int | None = None, high: int | None = None) -> Callable[[str], int]:
    """An argparse ``type``: a whole number within ``[low, high]``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"takes a whole number, got {text!r}") from None
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"takes a whole number {_bounds(low, high, False)}, got {text}")
        return value

    parse.__name__ = "integer"
    return parse


class DeprecatedAlias(argparse.Action):
    """An option's old name, kept one release: it stores into the new option's ``dest`` and says, on
    stderr, which name to use (``add_argument("--physics-mode", action=DeprecatedAlias, new="--physics",
    dest="physics", help=argparse.SUPPRESS)``)."""

    def __init__(self, option_strings, dest, new: str, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.new = new

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"warning: {option_string} is deprecated and will be removed: use {self.new} (the same values)",
              file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_alias(parser: argparse.ArgumentParser, old: str, new: str) -> None:
    """Accepts ``old`` one more release as a deprecated name of the option ``new`` (already declared): the same
    destination, type and choices, not shown in ``--help``, and a warning naming ``new`` each time it is used."""
    (action,) = [a for a in parser._actions if new in a.option_strings]  # private: argparse has no public lookup
    parser.add_argument(old, dest=action.dest, type=action.type, choices=action.choices, metavar=action.metavar,
                        action=DeprecatedAlias, new=new, help=argparse.SUPPRESS)


# One name per meaning across the commands, so that an option learnt on one command means the same on every
# other: each option that two or more commands take, what it means, and the names it had before (accepted one
# more release as a DeprecatedAlias that says which name to use). fit's options are its config's keys, spelt
# with underscores (--runs_dir, --data.context_len): the same names. tests/test_option_names.py walks every
# command's parser against this table.
VOCABULARY: dict[str, tuple[str, tuple[str, ...]]] = {
    "--robot": ("the registered arm (robomorph.sim.arms) simulated, evaluated or controlled", ("--arm",)),
    "--robots": ("how many robots (randomized instances of the arm) are drawn", ()),
    "--context-len": ("context steps the model reads before it predicts", ("--context",)),
    "--horizon": ("steps predicted (or planned) after the context", ()),
    "--horizons": ("the steps at which errors are reported: steps, seconds (0.25s) or 'end'", ()),
    "--offset": ("where each window starts: start, random (seeded) or a step", ()),
    "--n": ("use at most N trajectories (windows) of the store", ()),
    "--batch-size": ("windows computed together", ("--batch",)),
    "--plot-trajectories": ("trajectories drawn in the plots", ("--n-traj",)),
    "--candidates": ("MPPI candidate command sequences scored per re-plan", ()),
    "--out": ("where the command writes: a store, a folder or a file", ("--out-dir",)),
    "--overwrite": ("replace an earlier output of the same kind", ()),
    "--data": ("what the command reads: a store (for ingest --source, the folder of the source's clones)", ()),
    "--ckpt": ("the model: a checkpoint written by fit or a folder written by export", ()),
    "--physics": ("a hybrid model's physics mode, or none for its decoder", ("--physics-mode",)),
    "--inputs": ("the input formulation: command or total torques", ()),
    "--normalization": ("how windows are normalized: train_stats or paper_window", ()),
    "--seed": ("the root seed of every random choice", ()),
    "--device": ("where the network runs: cpu, cuda, ...", ()),
    "--workers": ("processes (or threads) run in parallel", ()),
    "--steps": ("samples per trajectory", ()),
    "--joints": ("the robot's joints by name, comma-separated, base first", ()),
    "--task": ("what the robot is asked to do (a signal or a path)", ()),
    "--runs-dir": ("the folder of training runs", ()),
    "--wandb": ("Weights & Biases logging: offline, online or disabled", ()),
    "--set": ("a setting changed, NAME=VALUE (repeatable)", ()),
    "--storage": ("the Optuna study's SQLAlchemy URL", ()),
    "--study-name": ("the Optuna study", ()),
    "--verbose": ("print more: the tables and messages left out by default", ()),
}
# Renamed options whose old name had a meaning of its own on one command: the old name, per command.
RENAMED_ON: dict[tuple[str, str], str] = {
    ("evaluate", "--samples"): "--plot-trajectories",
    ("control", "--samples"): "--candidates",
}


def canonical(option: str) -> str:
    """The one name an option of this spelling has: ``--runs_dir`` → ``--runs-dir``, ``--data.context_len`` →
    ``--context-len`` (fit's config keys), anything else as it is."""
    name = option.split(".", 1)[1] if option.startswith(("--data.", "--model.")) else option[2:]
    return "--" + name.replace("_", "-")
