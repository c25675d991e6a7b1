"""One writer at a time: exclusive locks on stores and run folders.

Two ``generate --overwrite`` into one ``--out`` would interleave chunks of two seeds in one
store; two ``fit --run twin`` would interleave one CSV log and leave a ``config.yaml`` that
describes the other run. Every writer of a store (generate, merge, ingest) or of a run
folder (fit) therefore holds :func:`exclusive` on it while it writes, and a second writer
is refused at once with one line naming the holder.

The lock is an ``flock`` (the ``filelock`` package) on a hidden file beside the target,
``<folder>/.<name>.lock``; beside the target, not inside it, because a store written anew
is wiped first and a failed run's folder is removed. The kernel drops an ``flock`` when its
process ends, however it ends, so a killed writer never blocks the next one. Who holds it
(pid, host, command, since when) is written to ``<folder>/.<name>.lock.holder``, a JSON
note read only to word the refusal. Lock files stay after release: removing a lock file
that another process has open would let two processes lock two different files.

A command's result folder (``evaluate``, ``control``, ``export``) is written under
:func:`output_folder`: checked, locked and written whole, before any work is spent on it.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import filelock

from robomorph.core.atomic import atomic_folder, check_folder_replaceable, check_outside_stores, write_json
from robomorph.core.errors import RoboMorphError


# How a user names each kind of target, for the message of a refusal.
_FLAGS = {"store": "--out", "run folder": "--runs_dir/--run", "output folder": "--out"}


class LockedError(RoboMorphError, RuntimeError):
    """The target is being written by another process."""


def lock_path(target: str | os.PathLike) -> str:
    """The lock file of ``target``: ``.<name>.lock`` beside it (symlinks resolved, so two
    spellings of one folder share one lock)."""
    folder, name = os.path.split(os.path.realpath(os.fspath(target)))
    return os.path.join(folder, f".{name or 'root'}.lock")


def _holder_path(target: str | os.PathLike) -> str:
    return lock_path(target) + ".holder"


def holder(target: str | os.PathLike) -> dict[str, Any] | None:
    """The note of the process that holds (or last held, if it was killed) ``target``'s lock."""
    try:
        with open(_holder_path(target)) as f:
            note = json.load(f)
    except (OSError, ValueError):
        return None
    return note if isinstance(note, dict) else None


def _describe(note: dict[str, Any] | None) -> str:
    if not note:
        return "holder unknown"
    return (f"pid {note.get('pid')} on {note.get('host')}, since {note.get('since')}, "
            f"running: {note.get('command')}")


def _command() -> str:
    argv = [os.path.basename(sys.argv[0] or "python"), *sys.argv[1:]] if sys.argv else ["python"]
    text = shlex.join(argv)
    return text if len(text) <= 300 else text[:297] + "..."


@contextlib.contextmanager
def exclusive(target: str | os.PathLike, what: str = "store") -> Iterator[None]:
    """Holds the exclusive lock of ``target`` (a store or run folder) for the ``with`` block.

    Args:
        target: the folder the caller is about to write; it need not exist yet (its parent
            folders are made, as the writer would make them).
        what: what the target is, for the message (``store``, ``run folder``).

    Raises:
        OutputExistsError: the target lies inside a Zarr store.
        LockedError: another process holds the lock (the message names it). Never waits:
            a writer that found its target busy and then wrote would still race.

    Where no lock file can be made (a read-only folder, a parent that is a file), the block
    runs unlocked: no writer can create the target there either, and the writer's own
    check names the problem in its words.
    """
    # A writer never writes inside another Zarr store, and its lock file beside the target would
    # already be inside it: refused before the lock, whoever writes (a store, a run folder).
    check_outside_stores(target, _FLAGS.get(what, "--out"))
    path = lock_path(target)
    lock = filelock.FileLock(path, timeout=0)
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        lock.acquire()
    except filelock.Timeout:
        raise LockedError(f"{target} is being written by another process ({_describe(holder(target))}); wait "
                          f"for it to finish or stop it, then run this again (the lock of a stopped process "
                          f"frees itself): two writers at once would mix their {what}s") from None
    except OSError:
        lock = None
    if lock is None:
        yield
        return
    try:
        with contextlib.suppress(OSError):  # the note only words a refusal; the lock is what counts
            write_json(_holder_path(target), {"pid": os.getpid(), "host": socket.gethostname(),
                                              "command": _command(), "since": time.strftime("%Y-%m-%d %H:%M:%S")})
        yield
    finally:
        with contextlib.suppress(OSError):
            os.remove(_holder_path(target))
        lock.release()


def exclusive_on(arg: str, what: str = "store") -> Callable:
    """Decorator: the function runs under :func:`exclusive` of its argument named ``arg``."""

    def wrap(fn: Callable) -> Callable:
        signature = inspect.signature(fn)

        @functools.wraps(fn)
        def locked(*args: Any, **kwargs: Any) -> Any:
            target = signature.bind(*args, **kwargs).arguments[arg]
            with exclusive(target, what):
                return fn(*args, **kwargs)

        return locked

    return wrap


@contextlib.contextmanager
def output_folder(path: str | os.PathLike, kind: str, flag: str = "--out") -> Iterator[str]:
    """The one way a command writes a result folder: yields a temporary folder to fill.

    On entry ``path`` is checked (:func:`robomorph.core.atomic.check_folder_replaceable`:
    new, empty or an earlier folder of ``kind``; never another command's folder or a store)
    and locked against a second writer; on a clean exit the filled folder replaces ``path``
    whole; on any exception (a full disk, Ctrl-C) nothing of it is left.

    Raises:
        OutputExistsError: ``path`` is not for this writer; LockedError: another process
            writes it.
    """
    check_folder_replaceable(path, kind, flag)  # before the lock: no lock file inside a store
    with exclusive(path, "output folder"):
        check_folder_replaceable(path, kind, flag)  # what it is now that no one else writes it
        with atomic_folder(path) as tmp:
            yield tmp
