"""The one error base class for bad input, and how every command reports it.

Every error the package raises because of what a user gave it (a flag, a file, a store, a
checkpoint, a recipe) derives from :class:`RoboMorphError`, and its message names the
problem and what to do. Commands turn it into one line on stderr and exit code 2, with no
traceback; anything else is a bug and still raises.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

USAGE_EXIT = 2


class RoboMorphError(Exception):
    """Bad input: the message says what is wrong and how to fix it."""


class UsageError(RoboMorphError, ValueError):
    """A flag or argument value that no more specific error class covers."""


class MissingInputError(RoboMorphError, FileNotFoundError):
    """An input file or folder (store, checkpoint, log, recipe) that is not there."""


class OutputExistsError(RoboMorphError, FileExistsError):
    """An output path holds something the command refuses to replace."""


def report(exc: BaseException) -> int:
    """Prints ``error: <message>`` (one line) to stderr; returns the exit code 2."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    print(f"error: {text}", file=sys.stderr)
    return USAGE_EXIT


def run_command(fn: Callable[[], int | None]) -> int:
    """Runs a command body; a :class:`RoboMorphError` becomes one line and exit code 2."""
    try:
        return int(fn() or 0)
    except RoboMorphError as exc:
        return report(exc)
