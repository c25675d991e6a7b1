"""Result files that are never half-written: the one atomic writer of the package.

Every writer of results (checkpoints, evaluation JSON/CSV/markdown and plots, the
dashboard, sweep summaries, the pruned training log, the paper's tables) goes through
:func:`atomic_open`: it writes a temporary file in the target's folder, flushes it to disk
and renames it over the target, so a reader (or a crash) sees the old file or the new one,
never a part.

Before replacing a file a user named (``report --out``, ``calibrate --out``), a writer calls
:func:`check_replaceable`: it replaces only a file of its own kind, never a checkpoint with a
page or a page with a checkpoint, and never writes into a Zarr store.

A Markdown result file (``write_markdown``: every benchmark's ``--md``) is replaced the same
way, only over an earlier result file (one that opens with its provenance line). A store
(``generate``, ``merge``, ``ingest``, ``priors``) or a scratch folder of a script is never
written inside another store (:func:`check_outside_stores`), nor over one of the command's own
inputs (:func:`check_not_input`): the two rules every writer shares, checked before anything is
created.

A result folder (``evaluate --out``, ``control --out``, ``export --out``) is written the same
way, whole: :func:`atomic_folder` fills a temporary folder beside the target and swaps it in,
after :func:`check_folder_replaceable` made sure the target is empty or an earlier result of
the same kind (recognised by content, as files are), never another command's folder or a
store. :func:`robomorph.core.locks.output_folder` puts the two under one writer's lock.
Several folders that stand or fall together (``ingest --source``'s train, val and test stores)
are built in one :func:`staging_folder` and each moved into place by :func:`replace_folder` once
all of them were written.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
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
_KIND_NAMES = {"html": "an HTML page", "checkpoint": "a checkpoint",
               "markdown": "a Markdown result file (robomorph.core.results.write_markdown)",
               "csv": "a CSV table"}
# The first line every Markdown result file opens with (robomorph.core.results.provenance_markdown).
MARKDOWN_MARK = b"*Produced by `"


def _is_html(head: bytes) -> bool:
    start = head.lstrip().lower()
    return start.startswith((b"<!doctype html", b"<html"))


def _is_csv(head: bytes) -> bool:
    """A table of text whose first line is a provenance comment or a header of names (our result
    CSVs, with or without provenance), not a page, a binary file or a user's prose."""
    if b"\0" in head or _is_html(head):
        return False
    first = head.split(b"\n", 1)[0].rstrip(b"\r")
    if first.startswith(b"# command: "):
        return True
    names = first.split(b",")
    return len(names) > 1 and all(n.strip() and b" " not in n.strip() for n in names)


def _is_checkpoint(path: str) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return any(n.endswith("data.pkl") for n in z.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def file_kind(path: str | os.PathLike) -> str | None:
    """``"html"``, ``"markdown"``, ``"csv"`` or ``"checkpoint"`` for a file of that kind, ``"empty"``, else None."""
    with open(path, "rb") as f:
        head = f.read(512)
    if not head:
        return "empty"
    if _is_html(head):
        return "html"
    if head.startswith(MARKDOWN_MARK):
        return "markdown"
    if _is_csv(head):
        return "csv"
    return "checkpoint" if _is_checkpoint(os.fspath(path)) else None


def zarr_store_holding(path: str | os.PathLike) -> str | None:
    """The Zarr store (a folder with ``zarr.json``) that ``path`` is or lies inside, or None."""
    folder = os.path.abspath(os.fspath(path))
    return _store_at_or_above(folder if os.path.isdir(folder) else os.path.dirname(folder))


def _store_at_or_above(folder: str) -> str | None:
    """The first folder from ``folder`` up to the root that holds ``zarr.json``, or None."""
    while True:
        if os.path.isfile(os.path.join(folder, "zarr.json")):
            return folder
        parent = os.path.dirname(folder)
        if parent == folder:
            return None
        folder = parent


def store_around(path: str | os.PathLike) -> str | None:
    """The Zarr store that ``path`` lies strictly inside (``S.zarr/x``, ``S.zarr/u/c``), or None.

    ``path`` itself may be a store (a writer of stores replaces its own kind); a folder above it
    that holds ``zarr.json`` may not: writing there would add foreign files to that store, which
    its readers and ``--overwrite`` treat as their own. Links are followed, so a link into a
    store counts as the store.
    """
    for spelled in {os.path.abspath(os.fspath(path)), os.path.realpath(os.fspath(path))}:
        if (store := _store_at_or_above(os.path.dirname(spelled))) is not None:
            return store
    return None


def check_outside_stores(path: str | os.PathLike, flag: str = "--out", may_be_store: bool = True) -> None:
    """Raises unless ``path`` lies outside every Zarr store (it may be a store itself, when
    ``may_be_store``: a writer of stores; a folder of other files may not).

    Raises:
        OutputExistsError: the message names the store.
    """
    if not may_be_store and os.path.isfile(os.path.join(os.fspath(path), "zarr.json")):
        raise OutputExistsError(f"{flag} {os.fspath(path)} is a Zarr store, not a folder for other files: choose "
                                f"another {flag} outside any store")
    store = store_around(path)
    if store is not None:
        raise OutputExistsError(f"{flag} {os.fspath(path)} is inside the Zarr store {store}: writing there would "
                                "mix foreign files into that store; choose another " + flag + " outside any store")


def check_not_input(path: str | os.PathLike, inputs, flag: str = "--out") -> None:
    """Raises when ``path`` is one of ``inputs`` or a folder around one (links resolved).

    Replacing (``--overwrite``) or filling such a path would destroy an input before, or while,
    it is read. A path inside an input folder is left to :func:`check_outside_stores` (an input
    store) or allowed (a folder of logs).

    Raises:
        OutputExistsError: the message names the input.
    """
    out = os.path.realpath(os.fspath(path)).rstrip(os.sep) or os.sep
    for item in inputs:
        if item is None:
            continue
        given = os.path.realpath(os.fspath(item))
        if given == out or given.startswith(out.rstrip(os.sep) + os.sep):
            what = "is the input" if given == out else "is a folder around the input"
            raise OutputExistsError(f"{flag} {os.fspath(path)} {what} {os.fspath(item)}: writing it would destroy "
                                    f"what the command reads; choose another {flag}")


def check_replaceable(path: str | os.PathLike, kind: str, flag: str = "--out") -> None:
    """Raises unless a writer of ``kind`` files may (re)write ``path``.

    Allowed: a path that does not exist yet, an empty file, or a file of ``kind``. Refused:
    a folder, anything inside a Zarr store, and a file of another kind.

    Args:
        path: the file about to be written.
        kind: ``"html"``, ``"markdown"``, ``"csv"`` or ``"checkpoint"``.
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


# The result folders a command may replace, recognised by what they hold: only files of the
# writer's own names, and the file that says which command wrote it.
_FOLDER_KINDS = {"evaluation": "an evaluation folder (robomorph evaluate)",
                 "control": "a control folder (robomorph control)",
                 "model": "a model folder (robomorph export)"}
_RESULT_SUFFIXES = (".json", ".csv", ".md", ".png")


def _read_json(path: str) -> Any:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, UnicodeDecodeError, ValueError):
        return None


def folder_kind(path: str | os.PathLike) -> str | None:
    """``"evaluation"``, ``"control"`` or ``"model"`` for a folder a command wrote, ``"empty"``
    for an empty one, else None (a folder of anything else, or with anything else in it)."""
    path = os.fspath(path)
    entries = os.listdir(path)
    if not entries:
        return "empty"
    if any(not os.path.isfile(os.path.join(path, e)) or os.path.islink(os.path.join(path, e)) for e in entries):
        return None
    if set(entries) <= {"config.json", "model.safetensors"}:
        config = _read_json(os.path.join(path, "config.json"))
        return "model" if isinstance(config, dict) and config.get("format") == "robomorph-model" else None
    if not all(e.endswith(_RESULT_SUFFIXES) for e in entries):
        return None
    metrics = _read_json(os.path.join(path, "metrics.json"))
    if not isinstance(metrics, dict):
        return None
    if isinstance(metrics.get("_config"), dict) and "controllers" in metrics["_config"]:
        return "control"
    return "evaluation" if "approach1" in metrics and "meta" in metrics else None


def check_folder_replaceable(path: str | os.PathLike, kind: str, flag: str = "--out") -> None:
    """Raises unless a writer of ``kind`` folders may (re)write the folder ``path``.

    Allowed: a path that does not exist yet, an empty folder, or an earlier folder of
    ``kind`` holding nothing else. Refused: a file, anything in or of a Zarr store, and a
    folder of another kind (another command's results, a user's files).

    Raises:
        OutputExistsError: the message names what ``path`` holds.
    """
    if kind not in _FOLDER_KINDS:
        raise ValueError(f"kind must be one of {sorted(_FOLDER_KINDS)}, got {kind!r}")
    path = os.fspath(path)
    store = zarr_store_holding(path)
    if store is not None:
        found = "a Zarr store" if os.path.realpath(store) == os.path.realpath(path) else f"inside the Zarr store {store}"
    elif not os.path.exists(path):
        return
    elif not os.path.isdir(path):
        found = "a file"
    else:
        have = folder_kind(path)
        if have in (kind, "empty"):
            return
        found = _FOLDER_KINDS.get(have, "a folder holding other files")
    raise OutputExistsError(f"{flag} {path} is {found}, not {_FOLDER_KINDS[kind]}: refusing to write into it; "
                            f"choose another {flag} (a new or empty folder)")


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[str]:
    """Yields a temporary folder beside ``path``; on a clean exit it replaces ``path`` whole.

    A reader (or a crash, a full disk, a Ctrl-C) sees the old folder or the new one, never a
    part of either: on an exception the temporary folder is removed and ``path`` is as it was.
    A symbolic link is followed, so the folder it leads to is replaced and the link stays.
    """
    target = os.path.realpath(os.fspath(path))
    parent, name = os.path.split(target)
    tmp, old = (os.path.join(parent, f".{name}.{os.getpid()}.{s}") for s in ("tmp", "old"))
    try:
        os.makedirs(parent, exist_ok=True)
        shutil.rmtree(tmp, ignore_errors=True)
        os.makedirs(tmp)
    except OSError as exc:
        # Named as the user gave it (not the hidden temporary), and a file on the way as what it is.
        code = errno.ENOTDIR if exc.errno == errno.EEXIST and not os.path.isdir(parent) else exc.errno
        raise OSError(code, os.strerror(code) if code != exc.errno else exc.strerror, os.fspath(path)) from None
    try:
        yield tmp
        _swap(tmp, target, old)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)


def _swap(new: str, target: str, old: str) -> None:
    """``new`` renamed to ``target``; a folder there is first renamed to ``old`` (and back if the
    second rename fails). The caller removes ``old``."""
    moved = os.path.isdir(target)
    if moved:
        os.replace(target, old)
    try:
        os.replace(new, target)
    except BaseException:
        if moved:
            os.replace(old, target)
        raise


def replace_folder(new: str | os.PathLike, target: str | os.PathLike) -> None:
    """Moves the finished folder ``new`` (on ``target``'s file system: built in a
    :func:`staging_folder` beside it) to ``target``, replacing a folder there whole.

    The caller has checked that ``target`` may be replaced (a store writer: :func:`check_outside_stores`
    and its own kind); a link at ``target`` is followed, as :func:`atomic_folder` follows it.
    """
    target = os.path.realpath(os.fspath(target))
    parent, name = os.path.split(target)
    old = os.path.join(parent, f".{name}.{os.getpid()}.old")
    try:
        _swap(os.fspath(new), target, old)
    finally:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staging_folder(parent: str | os.PathLike, name: str = "staging") -> Iterator[str]:
    """A hidden folder inside ``parent`` in which several results are built before any of them is
    moved into place (:func:`replace_folder`), so that a refusal of the last one leaves none of
    the others behind.

    Removed on exit, whatever happens; on an exception the folders down to it that it made
    (``parent`` and those above it that did not exist) go too, where nothing else landed in them.
    """
    parent = os.path.abspath(os.fspath(parent))
    made, folder = [], parent
    while not os.path.exists(folder):
        made.append(folder)
        folder = os.path.dirname(folder)
    path = os.path.join(parent, f".{name}.{os.getpid()}.tmp")
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    try:
        yield path
    except BaseException:
        shutil.rmtree(path, ignore_errors=True)
        for folder in made:  # innermost first
            with contextlib.suppress(OSError):
                os.rmdir(folder)
        raise
    finally:
        shutil.rmtree(path, ignore_errors=True)


def set_aside(path: str | os.PathLike) -> str:
    """Renames ``path`` (a folder or a file) to the first free ``<path>.previous-<k>``; returns that name.

    Keeps an earlier output that cannot be resumed (the demo's run folder of an older version) instead of
    deleting it. The name is claimed first, by creating it exclusively (an empty folder or file), and the
    rename then goes over that claim: two writers setting aside at once never take one name, and nothing
    that was already there is replaced.
    """
    path = os.fspath(path)
    folder = os.path.isdir(path) and not os.path.islink(path)
    k = 1
    while True:
        aside = f"{path}.previous-{k}"
        try:
            if folder:
                os.mkdir(aside)
            else:
                os.close(os.open(aside, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            break
        except FileExistsError:
            k += 1
    try:
        os.replace(path, aside)  # a folder over its empty claim, a file over its empty claim
    except BaseException:
        (os.rmdir if folder else os.remove)(aside)
        raise
    return aside
