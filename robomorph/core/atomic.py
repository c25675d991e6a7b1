"""Result files that are never half-written: the one atomic writer of the package.

Every writer of results (checkpoints, evaluation JSON/CSV/markdown and plots, the
dashboard, sweep summaries, the pruned training log, the paper's tables) goes through
:func:`atomic_open`: it writes a temporary file in the target's folder, flushes it to disk
and renames it over the target, so a reader (or a crash) sees the old file or the new one,
never a part.

Before replacing a file a user named (``report --out``, ``calibrate --out``), a writer calls
:func:`check_replaceable`: it replaces only a file of its own kind, never a checkpoint with a
page or a page with a checkpoint, and never writes into a Zarr store.
"""

from __future__ import annotations

import contextlib
import json
import os
import zipfile
from collections.abc import Iterator
from typing import IO, Any

from robomorph.core.errors import OutputExistsError


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


# What a writer may replace, recognised by content (a name's suffix says little: a user may
# call a checkpoint anything). torch.save writes a zip archive holding <name>/data.pkl.
_KIND_NAMES = {"html": "an HTML page", "checkpoint": "a checkpoint"}


def _is_html(head: bytes) -> bool:
    start = head.lstrip().lower()
    return start.startswith((b"<!doctype html", b"<html"))


def _is_checkpoint(path: str) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return any(n.endswith("data.pkl") for n in z.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def file_kind(path: str | os.PathLike) -> str | None:
    """``"html"`` or ``"checkpoint"`` for a file of that kind, ``"empty"``, else None."""
    with open(path, "rb") as f:
        head = f.read(512)
    if not head:
        return "empty"
    if _is_html(head):
        return "html"
    return "checkpoint" if _is_checkpoint(os.fspath(path)) else None


def zarr_store_holding(path: str | os.PathLike) -> str | None:
    """The Zarr store (a folder with ``zarr.json``) that ``path`` is or lies inside, or None."""
    folder = os.path.abspath(os.fspath(path))
    if not os.path.isdir(folder):
        folder = os.path.dirname(folder)
    while True:
        if os.path.isfile(os.path.join(folder, "zarr.json")):
            return folder
        parent = os.path.dirname(folder)
        if parent == folder:
            return None
        folder = parent


def check_replaceable(path: str | os.PathLike, kind: str, flag: str = "--out") -> None:
    """Raises unless a writer of ``kind`` files may (re)write ``path``.

    Allowed: a path that does not exist yet, an empty file, or a file of ``kind``. Refused:
    a folder, anything inside a Zarr store, and a file of another kind.

    Args:
        path: the file about to be written.
        kind: ``"html"`` or ``"checkpoint"``.
        flag: how the user gave ``path``, for the message.

    Raises:
        OutputExistsError: the message names what ``path`` holds.
    """
    if kind not in _KIND_NAMES:
        raise ValueError(f"kind must be one of {sorted(_KIND_NAMES)}, got {kind!r}")
    path = os.fspath(path)
    store = zarr_store_holding(path)
    if store is not None and os.path.abspath(store) != os.path.abspath(path):
        found = f"inside the Zarr store {store}"
    elif os.path.isdir(path):
        found = "a folder"
    elif not os.path.lexists(path) or not os.path.exists(path):
        return  # nothing there (or a dangling link, which the writer replaces, not follows)
    else:
        have = file_kind(path)
        if have in (kind, "empty"):
            return
        found = _KIND_NAMES.get(have, "a file of another kind")
    raise OutputExistsError(f"{flag} {path} is {found}, not {_KIND_NAMES[kind]}: refusing to replace it; "
                            f"choose another {flag}")


def overlapping(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` are one path (after resolving links) or one lies inside the
    other: replacing either would then destroy (part of) the other."""
    ra, rb = os.path.realpath(os.fspath(a)), os.path.realpath(os.fspath(b))
    return ra == rb or ra.startswith(rb.rstrip(os.sep) + os.sep) or rb.startswith(ra.rstrip(os.sep) + os.sep)
