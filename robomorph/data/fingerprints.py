"""Content fingerprints of stores: a training store recognized under another path.

``fit`` records a fingerprint of each training store in the checkpoint
(:func:`robomorph.training.data_record.data_info`); ``evaluate`` and ``calibrate`` compare
the store they are given with those (:func:`recorded_match`), so a copy of the training
data is marked in-sample wherever it lies, while a store that merely shares a name is not.
"""

from __future__ import annotations

import hashlib
import json
import os

from robomorph.core.errors import RoboMorphError
from robomorph.data.chunks import chunk_rows
from robomorph.data.store import open_store

# Attributes that differ between two writes of the same data (when, by which version): left
# out of the fingerprint, so a store regenerated from the same recipe and seed matches too.
_VOLATILE_ATTRS = ("created", "finished", "package_version")


def fingerprint(path: str) -> str:
    """A content fingerprint of a store: equal for a byte-identical copy wherever it lies.

    The hash covers the attributes (channels, dt, recipe or sources, seed, counts; not the
    time of writing) and the bytes of the first, middle and last chunk files of ``u`` and
    ``y``: cheap (three chunks per array) and different for any other store. ``fit``
    records it for each training store, so ``evaluate`` and ``calibrate`` recognize their
    training data under another path.
    """
    group = open_store(path, allow_incomplete=True).group  # the schema checks, whatever its status
    attrs = {k: v for k, v in dict(group.attrs).items() if k not in _VOLATILE_ATTRS}
    digest = hashlib.sha256(json.dumps(attrs, sort_keys=True, default=str).encode())
    n = int(attrs.get("n", 0))
    for name in ("u", "y"):
        keys = [key for _, key, _, _ in chunk_rows(group, name, n)]
        for key in sorted(set(keys[:1] + keys[len(keys) // 2:len(keys) // 2 + 1] + keys[-1:])):
            file = os.path.join(path, name, *key.split("/"))
            digest.update(f"{name}/{key}".encode())
            if os.path.isfile(file):
                with open(file, "rb") as f:
                    digest.update(f.read())
    return digest.hexdigest()[:32]


def robot_hashes(path: str, block: int = 256) -> list[str]:
    """One short hash per trajectory of a store (of its ``u`` and ``y`` bytes), in row order.

    A store is more than its robots: one generated with the training seed and more robots
    holds every training robot bit for bit under another fingerprint. ``fit`` records these,
    so ``evaluate`` and ``calibrate`` recognize a training robot in any store.
    """
    ds = open_store(path, allow_incomplete=True)
    out: list[str] = []
    for start in range(0, ds.n, block):
        rows = slice(start, min(start + block, ds.n))
        u, y = ds.read("u", rows), ds.read("y", rows)
        out += [hashlib.sha256(a.tobytes() + b.tobytes()).hexdigest()[:16] for a, b in zip(u, y)]
    return out


def recorded_match(path: str, stores: list[str], fingerprints: dict[str, str] | None,
                   robots: dict[str, list[str]] | None = None) -> str | None:
    """Which of ``stores`` (as a checkpoint recorded them) ``path`` is, or holds robots of, or None.

    Compared by content (:func:`fingerprint`) when ``fingerprints`` (store -> fingerprint,
    written at fit time) are given, so a copy under another path is recognized; by path
    otherwise (checkpoints written before fingerprints were recorded). With ``robots`` (store
    -> :func:`robot_hashes`), a store holding any of a training store's trajectories matches it.
    """
    real = os.path.realpath(path)
    for store in stores:
        if os.path.realpath(store) == real:
            return store
    if not fingerprints or not os.path.isdir(path):
        return None
    try:
        mine = fingerprint(path)
        same = next((store for store, recorded in fingerprints.items() if recorded == mine), None)
        if same is not None or not robots:
            return same
        held = set(robot_hashes(path))
    except RoboMorphError:
        return None
    return next((store for store, hashes in robots.items() if held.intersection(hashes)), None)
