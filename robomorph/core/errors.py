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


class StoppedBySignal(Exception):
    """A run was stopped by SIGTERM (a scheduler's stop); ``last.ckpt`` holds ``step``.

    Raised by :func:`robomorph.training.fitting.fit`; the doors that train print it as one
    line and exit with :data:`SIGTERM_EXIT` (torch-free here, so they can catch it
    without importing the training stack).
    """

    def __init__(self, run_dir: str, last_ckpt: str, step: int):
        super().__init__(f"stopped by SIGTERM at step {step}: saved {last_ckpt}; "
                         "re-run the same command to resume from there")
        self.run_dir, self.last_ckpt, self.step = run_dir, last_ckpt, step


SIGTERM_EXIT = 128 + 15  # the shell's code for a SIGTERM stop: schedulers may requeue on it


def run_command(fn: Callable[[], int | None]) -> int:
    """Runs a command body; a :class:`RoboMorphError` becomes one line and exit code 2."""
    try:
        return int(fn() or 0)
    except RoboMorphError as exc:
        return report(exc)
