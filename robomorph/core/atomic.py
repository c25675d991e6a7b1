"""Result files that are never half-written: the one atomic writer of the package.

Every writer of results (checkpoints, evaluation JSON/CSV/markdown and plots, the
dashboard, sweep summaries, the pruned training log, the paper's tables) goes through
:func:`atomic_open`: it writes a temporary file in the target's folder, flushes it to disk
and renames it over the target, so a reader (or a crash) sees the old file or the new one,
never a part.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from typing import IO, Any


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO]:
    """Opens a temporary file beside ``path``; on a clean exit it replaces ``path``.

    Args:
        path: the file to (re)write; its folder is created.
        mode: ``"w"`` (text) or ``"wb"`` (bytes).
        encoding: text encoding (ignored for bytes).

    On an exception the temporary file is removed and ``path`` keeps its old content.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes whole files: mode 'w' or 'wb', got {mode!r}")
    path = os.fspath(path)
    folder, name = os.path.split(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    # Same folder, so the rename stays on one file system; the pid keeps concurrent writers
    # (sweep workers, DDP ranks) off each other's temporary files. A plain open() rather
    # than mkstemp gives the file the usual umask permissions, not 0600.
    tmp = os.path.join(folder, f".{name}.{os.getpid()}.tmp")
    binary = "b" in mode
    try:
        with open(tmp, mode, **({} if binary else {"encoding": encoding, "newline": ""})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """Writes ``text`` to ``path`` so that a reader sees the old file or the new one, never a part."""
    with atomic_open(path, "w") as f:
        f.write(text)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """:func:`write_text` for bytes."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """:func:`write_text` of ``obj`` as indented JSON (NaN allowed, as in metrics files)."""
    write_text(path, json.dumps(obj, indent=1, allow_nan=True) + "\n")


def save_figure(fig: Any, path: str | os.PathLike, **savefig_kwargs: Any) -> None:
    """A matplotlib figure to ``path`` (format from the extension, PNG without one), atomically."""
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format=fmt, **savefig_kwargs)
