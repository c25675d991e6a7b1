"""Damaged chunks of a store: missing, truncated or undecodable files, named with their rows.

A Zarr reader meets a damaged chunk in one of three ways, none of which says which rows
are lost: a missing file reads as the fill value (NaN) without a word; a truncated file
raises a codec error ("error during blosc decompression"), or, when blosc stored the data
uncompressed, decodes to garbage without an error. :func:`damaged` finds the first two
kinds from the files alone (cheap: a stat and 16 bytes per chunk); :func:`undecodable`
names the chunk behind a codec error. Flipped bytes of unchanged size decode to wrong values
without a word, unless the store carries checksums: stores written now end every chunk in a
CRC32C (Zarr's ``crc32c`` codec), whose mismatch fails the read and is named the same way.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

from zarr.codecs import BloscCodec, Crc32cCodec

from robomorph.core.errors import RoboMorphError

# What to do about a damaged chunk: the rows are lost, the command that wrote them is not.
REPAIR = ("rewrite the store: re-run the command that made it with --overwrite (generate: its recipe is in "
          "the store's 'config' attribute; or ingest / merge), or copy it again from an intact source")
# Arrays every valid row fills (u_cmd: stores of schema 2 made by generate): Zarr skips
# writing a chunk equal to its fill value, so only these must have a file for every chunk
# of valid rows.
_FILLED = ("u", "u_cmd", "y", "params")

Damage = tuple[str, str, int, int, str]  # (array, chunk key, first row, last row, problem)


class StoreDamagedError(RoboMorphError, ValueError):
    """A chunk of a store is missing or cannot be decoded; the message names it and its rows."""


def chunk_rows(group, name: str, n: int) -> Iterator[tuple[int, str, int, int]]:
    """``(index, key, first row, last row)`` of each chunk of ``name`` holding rows ``< n``."""
    arr = group[name]
    if 0 in arr.shape[1:]:
        return  # a zero-width array (P = 0) has no chunk files
    step = int(arr.chunks[0])
    for c in range(-(-n // step)):
        key = arr.metadata.encode_chunk_key((c,) + (0,) * (arr.ndim - 1))
        yield c, key, c * step, min(n, (c + 1) * step) - 1


def problem(path: str, group, name: str, key: str) -> str | None:
    """Why a chunk file cannot hold its rows: missing, or shorter than its blosc header says."""
    file = os.path.join(path, name, *key.split("/"))
    if not os.path.isfile(file):
        return "missing" if name in _FILLED else None
    codecs = list(group[name].metadata.codecs)
    # Stores of this version end in a 4-byte CRC32C after the blosc frame; older ones in the frame.
    tail = 4 if isinstance(codecs[-1], Crc32cCodec) else 0
    if len(codecs) < 1 + bool(tail) or not isinstance(codecs[-1 - bool(tail)], BloscCodec):
        return None
    size = os.path.getsize(file)
    with open(file, "rb") as f:
        head = f.read(16)
    # A blosc frame records its own length in bytes 12..15.
    expected = int.from_bytes(head[12:16], "little") + tail if len(head) == 16 else None
    return None if expected == size else f"truncated ({size} of {expected or '?'} bytes)"


def damaged(path: str, group, n: int, names: list[str], indices: set[int] | None = None) -> list[Damage]:
    """The missing or truncated chunks of ``names`` (only chunk ``indices`` when given)."""
    found = []
    for name in names:
        for c, key, first, last in chunk_rows(group, name, n):
            if indices is None or c in indices:
                why = problem(path, group, name, key)
                if why:
                    found.append((name, key, first, last, why))
    return found


def describe(path: str, found: list[Damage]) -> str:
    """One line naming the damaged chunks (at most four), their rows and the fix."""
    shown = ", ".join(f"'{a}' chunk {k} (trajectories {f}..{last}) {why}" for a, k, f, last, why in found[:4])
    more = f" and {len(found) - 4} more chunks" if len(found) > 4 else ""
    return f"{path} is damaged: {shown}{more}; {REPAIR}"


def undecodable(path: str, group, n: int, name: str, exc: BaseException) -> StoreDamagedError:
    """The error for a failed read of ``name``: its first chunk that cannot be decoded, named."""
    arr = group[name]
    for _, key, first, last in chunk_rows(group, name, n):
        try:
            arr[first:last + 1]
        except Exception as bad:  # noqa: BLE001  (codec errors vary: blosc, zstd, json, ...)
            why = (str(bad).strip().splitlines() or [type(bad).__name__])[0]
            if "checksum" in why.lower():  # zarr's Crc32cCodec: flipped bytes, same size
                why = "it fails its checksum (bytes corrupted)"
            return StoreDamagedError(describe(path, [(name, key, first, last, f"cannot be decoded: {why}")]))
    why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return StoreDamagedError(f"{path}: reading array '{name}' failed ({why}); {REPAIR}")


def undecoded(ds) -> str | None:
    """The message naming the first chunk of a store (a Dataset) that cannot be decoded, or None."""
    for name in ds.arrays if ds.n else ():
        try:
            ds.read(name)
        except StoreDamagedError as exc:
            return str(exc)
    return None
