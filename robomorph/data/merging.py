"""``python -m robomorph.merge``: combine the shards of a generate run into one store.

Shards made with ``--shard i/n`` of one recipe hold disjoint attempts; merging concatenates
them in shard order (streamed chunk by chunk) and sums the counts. The merged store
records the shard stores it came from.

The output is never one of the shards, nor inside or around one: ``--overwrite`` would wipe
it before it is read. While merging, the output store is locked against other writers.
"""

from __future__ import annotations

from robomorph.core.atomic import overlapping
from robomorph.core.errors import RoboMorphError
from robomorph.core.locks import exclusive_on
from robomorph.data.store import create_store, open_store


class MergeError(RoboMorphError, ValueError):
    """The given stores are not shards of one generation."""


def merge(parts: list[str], out: str, overwrite: bool = False, chunk: int = 64, allow_partial: bool = False) -> dict:
    """Concatenates complete shard stores of one recipe into ``out``.

    Every shard ``0..n-1`` of the generation must be among ``parts``; with ``allow_partial``
    a subset is merged and the store records ``partial: true`` and the ``missing_shards``.
    """
    if not parts:
        raise MergeError("give at least one shard store to merge")
    for part in parts:
        if overlapping(out, part):
            raise MergeError(f"--out {out} is one of the stores to merge ({part}), or inside or around one: "
                             "writing it would destroy an input before it is read; choose another --out")
    return _merge(parts, out, overwrite, chunk, allow_partial)


@exclusive_on("out")
def _merge(parts: list[str], out: str, overwrite: bool, chunk: int, allow_partial: bool) -> dict:
    stores = [open_store(p) for p in parts]
    first = stores[0].attrs
    shards = sorted(tuple(s.attrs.get("shard", [0, 1])) for s in stores)
    for s in stores[1:]:
        a = s.attrs
        for key in ("config", "u_names", "u_cmd_names", "y_names", "param_names", "dt"):
            if a.get(key) != first.get(key):
                raise MergeError(f"{s.path} differs from {stores[0].path} in {key}: shards must share one recipe")
    if len(set(shards)) != len(shards):
        raise MergeError(f"duplicate shards among the parts: {shards}")
    missing = _missing_shards(shards)
    if missing and not allow_partial:
        raise MergeError(f"the parts are shards {[i for i, _ in shards]} of {shards[0][1]}: shards {missing} are "
                         "missing, so the store would lack their robots; give every shard, or pass --allow-partial "
                         "to merge these into a store marked partial")
    total = sum(s.n for s in stores)
    extras = {k: (tuple(stores[0].group[k].shape[1:]), str(stores[0].group[k].dtype))
              for k in stores[0].arrays if k not in ("u", "y", "params")}
    u_cmd_names = first.get("u_cmd_names") if "u_cmd" in extras else None
    rejected: dict[str, int] = {}
    for s in stores:
        for k, v in s.attrs.get("rejected", {}).items():
            rejected[k] = rejected.get(k, 0) + v
    keep = {k: v for k, v in first.items() if k not in (
        "schema", "schema_version", "u_names", "u_cmd_names", "y_names", "param_names", "status", "n", "capacity",
        "created", "finished", "shard", "cursor")}
    keep.update(requested=sum(s.attrs.get("requested", s.n) for s in stores),
                attempted=sum(s.attrs.get("attempted", s.n) for s in stores),
                kept=total, rejected=rejected, merged_from=[list(x) for x in shards],
                merged_paths=list(parts), partial=bool(missing), missing_shards=missing)
    writer = create_store(out, total, stores[0].steps, stores[0].u_names, stores[0].y_names,
                          stores[0].param_names, keep, extras=extras, chunk=chunk, overwrite=overwrite,
                          u_cmd_names=u_cmd_names)
    for s in stores:
        for start in range(0, s.n, chunk):
            rows = slice(start, min(start + chunk, s.n))
            writer.append(s.read("u", rows), s.read("y", rows), s.read("params", rows),
                          extras={k: s.read(k, rows) for k in extras})
    writer.finalize()
    return open_store(out).attrs


def _missing_shards(shards: list[tuple[int, int]]) -> list[int]:
    """The shard indices of the generation that ``shards`` (``(index, count)`` pairs) lack."""
    counts = sorted({n for _, n in shards})
    if len(counts) > 1:
        raise MergeError(f"the parts come from generations split into different numbers of shards {counts}: "
                         "merge the shards of one --shard i/n run")
    return sorted(set(range(counts[0])) - {i for i, _ in shards})
