"""The one error base class for bad input, and how every command reports it.

Every error the package raises because of what a user gave it (a flag, a file, a store, a
checkpoint, a recipe) derives from :class:`RoboMorphError`, and its message names the
problem and what to do. Commands turn it into one line on stderr and exit code 2, with no
traceback; so do the operating system's errors about the place a command was pointed at
(read-only, no permission, full, a path through a file). Anything else is a bug and still
raises.
"""

from __future__ import annotations

import errno
import os
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


class DeviceError(RoboMorphError, ValueError):
    """A ``--device`` / accelerator that this machine does not have or torch does not know."""


class FileSystemError(RoboMorphError, OSError):
    """The file system refused a read or write: read-only, no permission, full, or a path
    through a file. Raised by :func:`run_command` from the operating system's error."""


# Errors of the operating system that come from where a command was pointed (a read-only
# mount, a folder without write permission, a full disk or quota, a path through a file),
# not from a bug: every command reports them as one line. Others (EBADF, EINVAL, ...) still raise.
_PATH_ERRNOS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EFBIG,
                errno.ENOTDIR, errno.EISDIR, errno.ENOENT, errno.EEXIST, errno.ENAMETOOLONG, errno.ENOTEMPTY,
                errno.EXDEV, errno.ELOOP}
_PATH_ADVICE = {
    errno.EROFS: "the file system is mounted read-only; choose an output on a writable one",
    errno.EACCES: "choose another output folder or change its permissions",
    errno.EPERM: "choose another output folder or change its permissions",
    errno.ENOSPC: "the disk is full; free space or choose an output on another disk",
    errno.EDQUOT: "the disk quota is exhausted; free space or choose an output on another disk",
    errno.EFBIG: "the file grew past the file-size limit; raise the limit or write less",
    errno.ENOTDIR: "a part of the path is a file, not a folder; choose another path",
    errno.EEXIST: "something is in the way (a file where a folder is needed?); choose another path",
}


def describe_os_error(exc: OSError) -> str:
    """One line for an operating-system error: what failed, on which path, and what to do."""
    where = " -> ".join(os.fsdecode(f) if isinstance(f, (str, bytes, os.PathLike)) else str(f)
                        for f in (exc.filename, exc.filename2) if f is not None)
    what = exc.strerror or str(exc)
    advice = _PATH_ADVICE.get(exc.errno, "check the path")
    return f"{what}: {where}; {advice}" if where else f"{what}; {advice}"


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
INTERRUPT_EXIT = 128 + 2  # the shell's code for a Ctrl-C (SIGINT) stop


def run_command(fn: Callable[[], int | None], kept: str | None = None) -> int:
    """Runs a command body; a :class:`RoboMorphError` becomes one line and exit code 2.

    So does an :class:`OSError` of the file system the command was pointed at (read-only,
    no permission, full, a path through a file: see ``_PATH_ERRNOS``), whichever library
    raised it: the user fixes the path or the disk, not the code. A Ctrl-C stops the command
    with one line saying what was kept (``kept``, the command's own words) and exit code 130.
    """
    try:
        return int(fn() or 0)
    except KeyboardInterrupt:
        print(f"stopped by Ctrl-C: {kept or 'what was finished before it is kept; nothing is half-written'}",
              file=sys.stderr)
        return INTERRUPT_EXIT
    except RoboMorphError as exc:
        return report(exc)
    except OSError as exc:
        if exc.errno not in _PATH_ERRNOS:
            raise
        return report(FileSystemError(describe_os_error(exc)))
