"""The shipped recipe files: ``datamodules/*.yaml`` (data and training recipes) and
``sweeps/*.yaml`` (search spaces), found by name or by path from any directory.

Both folders live at the top level of the repository and are copied into the wheel as
``robomorph/_recipes/<kind>/`` (``setup.py``), so an installed package finds them with
:mod:`importlib.resources`. A source checkout or an editable install has no copy: there the
folders beside the package are the shipped ones, so an edit to ``datamodules/`` is seen
at once.

The rule of :func:`locate`: a path that exists wins (a user's own recipe); otherwise a
bare name (``multisine``, ``multisine.yaml``) or a path into a folder of that kind's name
(``datamodules/multisine.yaml``, as the docs write it) names a shipped file; anything else
is a one-line error that lists the names there are.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from robomorph.core.errors import MissingInputError

KINDS = ("datamodules", "sweeps")
WHAT = {"datamodules": "recipe", "sweeps": "sweep space"}
SUFFIXES = (".yaml", ".yml")


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown recipe kind {kind!r}; choose from {KINDS}")


def shipped_dir(kind: str) -> Path | None:
    """The folder of the shipped ``kind`` files: the wheel's copy, else the source
    checkout's top-level folder; None when neither exists."""
    _check_kind(kind)
    package = Path(str(resources.files("robomorph")))
    for folder in (package / "_recipes" / kind, package.parent / kind):
        if folder.is_dir():
            return folder
    return None


def available(kind: str) -> list[str]:
    """The names of the shipped ``kind`` files, sorted (``["chirp", "circle", ...]``)."""
    folder = shipped_dir(kind)
    if folder is None:
        return []
    return sorted(p.stem for p in folder.iterdir() if p.suffix in SUFFIXES and p.is_file())


def _shipped_name(ref: str, kind: str) -> str | None:
    """The name ``ref`` gives a shipped file, or None when it is a path elsewhere."""
    head, tail = os.path.split(os.path.normpath(ref))
    if head and os.path.basename(head) != kind:
        return None
    stem, suffix = os.path.splitext(tail)
    return stem if suffix in SUFFIXES else tail


def locate(ref: str, kind: str = "datamodules") -> str:
    """The file ``ref`` names: an existing path, else a shipped ``kind`` file.

    Args:
        ref: a path (``my/recipe.yaml``), a name (``multisine`` or ``multisine.yaml``), or
            a path into a folder named ``kind`` (``datamodules/multisine.yaml``) that need
            not exist in the working directory.
        kind: ``datamodules`` (recipes) or ``sweeps`` (search spaces).

    Raises:
        MissingInputError: ``ref`` is neither a file nor a shipped name (the message lists
            the shipped names), or it is a folder.
    """
    _check_kind(kind)
    if os.path.isfile(ref):
        return ref
    if os.path.isdir(ref):
        raise MissingInputError(f"{ref} is a folder, not a {WHAT[kind]} file")
    name = _shipped_name(ref, kind)
    folder = shipped_dir(kind)
    if name and folder is not None:
        for suffix in SUFFIXES:
            path = folder / f"{name}{suffix}"
            if path.is_file():
                return str(path)
    names = ", ".join(available(kind)) or "none"
    raise MissingInputError(f"config file not found: {ref} is neither a file nor the name of a shipped {WHAT[kind]} "
                            f"(shipped {kind}: {names})")


def locate_config_args(argv: list[str]) -> list[str]:
    """``argv`` with each ``--config VALUE`` (or ``--config=VALUE``) recipe located.

    A value that looks like inline YAML (it holds ``:`` or ``{``) is left for the parser.
    """
    out, take = [], False
    for arg in argv:
        if take:
            out.append(_config_value(arg))
            take = False
        elif arg == "--config":
            out.append(arg)
            take = True
        elif arg.startswith("--config="):
            out.append("--config=" + _config_value(arg[len("--config="):]))
        else:
            out.append(arg)
    return out


def _config_value(value: str) -> str:
    if os.path.isfile(value) or ":" in value or "{" in value:
        return value
    return locate(value, "datamodules")
