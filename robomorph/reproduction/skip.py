"""Skip work whose outputs already exist: complete stores, finished runs, fresh evaluations.

What the demo and ``robomorph.reproduce`` share so that re-running an interrupted
command redoes only what is missing: stores via :func:`robomorph.data.generation.generate`
(which resumes a partial store itself), training runs via a ``reproduce_done.json``
marker written once a run reached its budget (``robomorph.fit`` resumes an unfinished
run from ``last.ckpt`` itself), evaluations via their ``metrics.json``.
"""

from __future__ import annotations

import json
import os
from typing import Any, Literal

from robomorph.core.atomic import write_json
from robomorph.core.rundir import RunDir
from robomorph.data.generation import generate
from robomorph.data.store import STATUS_COMPLETE, open_store
from robomorph.sim.recipe import Recipe

StoreState = Literal["missing", "stale", "partial", "complete"]
DONE_FILE = "reproduce_done.json"


def store_state(path: str, recipe: Recipe, need_command: bool = False) -> StoreState:
    """Whether ``path`` holds the store of ``recipe``, part of it, or something else.

    ``stale`` is a RoboMorph store written from another recipe (e.g. by an older version
    of the caller), or, with ``need_command``, one written before ``u_cmd`` existed; a
    directory that is not a RoboMorph store counts as ``missing`` so that
    :func:`generate` refuses to touch it.
    """
    if not os.path.isdir(path):
        return "missing"
    try:
        ds = open_store(path, allow_incomplete=True)
    except Exception:  # noqa: BLE001  (unreadable: nothing of ours to keep or replace)
        return "missing"
    attrs = ds.attrs
    if attrs.get("config") != recipe.to_dict() or (need_command and not ds.has_inputs("command")):
        return "stale"
    return "complete" if attrs.get("status") == STATUS_COMPLETE else "partial"


def ensure_store(recipe: Recipe, path: str, workers: int | None = None, progress: bool = True,
                 need_command: bool = False) -> StoreState:
    """Makes ``path`` hold the complete store of ``recipe``; returns the state it was found in.

    A complete store is kept, a partial one resumed, and a store of another recipe replaced
    (the callers own these paths; a foreign directory is refused by :func:`generate`).
    """
    state = store_state(path, recipe, need_command)
    if state != "complete":
        generate(recipe, path, workers=workers, overwrite=state == "stale", progress=progress)
    return state


def run_finished(run_dir: str, budget: dict[str, Any]) -> bool:
    """True when :func:`mark_finished` recorded this exact training budget for the run."""
    try:
        with open(RunDir(run_dir).file(DONE_FILE)) as f:
            done = json.load(f)
    except (OSError, ValueError):
        return False
    return done.get("budget") == _plain(budget) and os.path.isfile(str(done.get("ckpt")))


def mark_finished(run_dir: str, budget: dict[str, Any], ckpt: str, global_step: int) -> None:
    """Records that the run reached its budget and which checkpoint stands for it."""
    write_json(RunDir(run_dir).file(DONE_FILE), {"budget": _plain(budget), "ckpt": ckpt, "global_step": global_step})


def finished_ckpt(run_dir: str) -> str:
    """The checkpoint :func:`mark_finished` recorded."""
    with open(RunDir(run_dir).file(DONE_FILE)) as f:
        return json.load(f)["ckpt"]


def eval_fresh(out: str, ckpt: str) -> bool:
    """True when ``out/metrics.json`` exists, scores ``ckpt`` and is newer than it.

    A checkpoint rewritten after the evaluation (a run trained further) makes it stale.
    """
    path = os.path.join(out, "metrics.json")
    try:
        with open(path) as f:
            meta = json.load(f).get("meta", {})
    except (OSError, ValueError):
        return False
    same = os.path.abspath(str(meta.get("ckpt"))) == os.path.abspath(ckpt)
    return same and os.path.getmtime(path) >= os.path.getmtime(ckpt)


def stale_evaluation(out: str) -> bool:
    """True when ``out`` holds an evaluation's result files but no ``metrics.json`` (removed, or
    an interrupted write of a version before evaluations were written whole): the pipeline's own
    output under its run, to be redone whole. Anything else in it (a folder, a link, a file of
    another kind) makes it the user's, and it is left alone."""
    if not os.path.isdir(out) or os.path.exists(os.path.join(out, "metrics.json")):
        return False
    entries = os.listdir(out)
    return bool(entries) and all(os.path.isfile(os.path.join(out, e)) and not os.path.islink(os.path.join(out, e))
                                 and e.endswith((".json", ".csv", ".md", ".png")) for e in entries)


def read_json(path: str) -> dict:
    """The content of a JSON file."""
    with open(path) as f:
        return json.load(f)


def _plain(obj: Any) -> Any:
    """JSON's view of ``obj`` (tuples become lists) so that a budget compares equal after a round trip."""
    return json.loads(json.dumps(obj))

