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
