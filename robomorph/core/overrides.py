"""Nested override dicts: the one merge that recipes, sweeps, transfer regimes and the
reproduction use to layer settings over a base configuration."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any


def merge(base: Mapping[str, Any] | None, overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """A deep copy of ``base`` with ``overrides`` merged in (overrides win).

    Mappings are merged key by key at every depth; any other value (lists included)
    replaces the base's. Neither argument is modified.
    """
    out = copy.deepcopy(dict(base or {}))
    for key, value in (overrides or {}).items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def unflatten(flat: Mapping[str, Any], sep: str = ".") -> dict[str, Any]:
    """``{"model.lr": 1e-3, "run": "a"}`` into ``{"model": {"lr": 1e-3}, "run": "a"}``.

    Keys given twice along one path merge (``a.b`` and ``a.c``); the result is ready for
    :func:`merge`.
    """
    out: dict[str, Any] = {}
    for key, value in flat.items():
        nested: Any = value
        for part in reversed(key.split(sep)):
            nested = {part: nested}
        out = merge(out, nested)
    return out
