"""Writing prior stores: the physics hybrid's predictions over fixed windows of a store.

:func:`write_priors` cuts windows of ``context + horizon`` steps from a source store (each
trajectory at each of ``offsets``), runs the catalogue arm's hybrid (``Predictor.from_arm`` with the
source store's own recipe, no training) on each window's context and query inputs, and writes the
windows with the hybrid's query prediction as a prior store (:mod:`robomorph.data.priors`), on which
``robomorph fit`` trains a residual model. The work is resumable: rows are written in batches in a
fixed order, a store left in progress by an interrupted run is continued where it stopped
(same source, settings and windows, checked), and a complete store of the same request is left as it is.

Every refusal comes before the store is created: ``out`` is checked first (never the source, a folder
around it or a path inside any store), and the first batch of priors is computed before the store
exists, so a setting the hybrid refuses only when it runs (a mode, a member count, a context too short
to identify from) leaves nothing behind.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import yaml

from robomorph.core.atomic import check_not_input, check_outside_stores
from robomorph.core.errors import RoboMorphError
from robomorph.core.names import RECORDED_SWITCHES
from robomorph.core.progress import progress
from robomorph.data.priors import PRIOR_ARRAY, PRIOR_ATTR, PriorError
from robomorph.data.splits import RECORDING_ARRAY
from robomorph.data.store import DatasetWriter, create_store, open_store
from robomorph.evaluation.sources import predict
from robomorph.evaluation.windows import load_window, start_joints
from robomorph.inference.predictor import Predictor
from robomorph.inference.residual import hybrid_of

@dataclass(frozen=True)
class PriorRequest:
    """What :func:`write_priors` writes.

    Attributes:
        source: the source store (simulated, with ``u_cmd`` and its recipe in ``attrs["config"]``).
        out: the prior store to write.
        context, horizon: the window's context and query steps.
        offsets: first steps of the windows cut from each trajectory.
        n: at most this many source trajectories (None: all).
        settings: changes of the hybrid's settings (:class:`HybridSettings` field names) over ``Predictor.from_arm``'s,
            which has the payload, the wider friction and the denoising on (robomorph.core.names.TODAYS_RECORD).
        batch: windows per batch (rows written at once: the unit of resuming).
        overwrite: replace a complete store at ``out``.
    """

    source: str
    out: str
    context: int = 200
    horizon: int = 300
    offsets: tuple[int, ...] = (0,)
    n: int | None = None
    settings: tuple[tuple[str, object], ...] = ()
    batch: int = 16
    overwrite: bool = False

    def __post_init__(self) -> None:
        for name, flag in (("context", "--context-len"), ("horizon", "--horizon"), ("batch", "--batch-size")):
            if isinstance(getattr(self, name), bool) or int(getattr(self, name)) < 1:
                raise PriorError(f"{flag} must be a positive number of steps, got {getattr(self, name)!r}")
        if not self.offsets or any(int(o) < 0 for o in self.offsets) or len(set(self.offsets)) != len(self.offsets):
            raise PriorError(f"--offsets must be distinct steps >= 0, got {list(self.offsets)}")
        if self.n is not None and self.n < 1:
            raise PriorError(f"--n must be >= 1, got {self.n}")


def write_priors(req: PriorRequest) -> dict:
    """Writes (or resumes) the prior store of ``req``; returns its prior record.

    Raises:
        PriorError: a source without commands or recipe, windows that do not fit, or a store in progress
            at ``out`` that was begun with other arguments.
    """
    _check_out(req)
    src = open_store(req.source)
    if "u_cmd" not in src.arrays:
        raise PriorError(f"{req.source} has no commands (u_cmd): the hybrid predicts from the command formulation; "
                         "generate the store with this version")
    length = req.context + req.horizon
    if max(req.offsets) + length > src.steps:
        raise PriorError(f"offset {max(req.offsets)} + context {req.context} + horizon {req.horizon} exceed the "
                         f"store's T={src.steps} steps: use smaller --offsets or a shorter window")
    n_src = min(req.n or src.n, src.n)
    settings = dict(req.settings)
    hybrid, arm = hybrid_of(Predictor, src.attrs.get("config"), settings)
    key = hybrid.settings.key
    record = {"source": os.path.abspath(req.source), "source_n": n_src, "source_seed": src.attrs.get("seed"),
              "settings": key,
              # Every recorded switch as it was, beside the changes asked for: the record rebuilds this very hybrid
              # whatever from_arm's defaults become.
              "fields": {k: _plain(v) for k, v in {**{name: getattr(hybrid.settings, name) for name in RECORDED_SWITCHES},
                                                    **settings}.items()},
              "context": req.context, "horizon": req.horizon,
              "offsets": [int(o) for o in req.offsets], "arm": arm, "inputs": "command",
              "recipe": _recipe(src.attrs.get("config"))}
    rows = [(i, int(o)) for o in req.offsets for i in range(n_src)]  # window order: by offset, then row
    if _done(req, record):
        return record
    writer = _in_progress(req, record)
    start = writer.n if writer is not None else 0
    # The first batch before the store exists: whatever the hybrid refuses, it refuses here.
    first = _batch(req, src, hybrid, rows[start:start + req.batch]) if start < len(rows) else None
    if writer is None:
        writer = _new_store(req, src, record, len(rows), length)
    if first is not None:
        _append(writer, first)
    for b in progress(range(writer.n, len(rows), req.batch), "priors", unit="batch"):
        _write_batch(writer, req, src, hybrid, rows[b:b + req.batch])
    if writer.n == writer.capacity and writer.attrs.get("status") != "complete":
        writer.finalize()
    return record


def _check_out(req: PriorRequest) -> None:
    """Refuses an ``out`` that is the source store, a folder around it, or inside any store, before
    anything is read or written (``--overwrite`` would wipe the source before it is read)."""
    check_not_input(req.out, (req.source,))
    check_outside_stores(req.out)


def _window(req: PriorRequest, src, rows: np.ndarray, offset: int, inputs: str):
    """The windows of trajectories ``rows`` from step ``offset``, with ``inputs``' torques."""
    return load_window(req.source, req.context, req.horizon, None, None, len(src.u_names), len(src.y_names),
                       offset, 0, inputs, rows=rows)


def _write_batch(writer: DatasetWriter, req: PriorRequest, src, hybrid, part: list[tuple[int, int]]) -> None:
    """Windows ``part`` ((row, offset) pairs, grouped by offset) with the hybrid's prior, appended."""
    _append(writer, _batch(req, src, hybrid, part))


def _batch(req: PriorRequest, src, hybrid, part: list[tuple[int, int]]) -> dict[str, np.ndarray]:
    """The arrays of windows ``part`` ((row, offset) pairs, grouped by offset) with the hybrid's prior."""
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("u", "u_cmd", "y", "params", PRIOR_ARRAY, "source_row",
                                                         "offset", "y_first")}
    for offset in dict.fromkeys(o for _, o in part):
        idx = np.array([i for i, o in part if o == offset], dtype=np.int64)
        w = _window(req, src, idx, offset, "command")
        u_ctx, y_ctx, u_q, _ = w.split()
        # The hybrid reads the context and the query's commands only: the query outputs never reach the prior.
        prior = predict(hybrid, u_ctx, y_ctx, u_q, len(idx), desc="hybrid", at_rest=w.starts == 0,
                        anchor=start_joints(w))
        for k, v in (("u", _window(req, src, idx, offset, "total").u), ("u_cmd", w.u), ("y", w.y),
                     ("params", w.params), (PRIOR_ARRAY, prior), ("source_row", idx),
                     ("offset", np.full(len(idx), offset)), ("y_first", w.y_first)):
            cols[k].append(v)
    return {k: np.concatenate(v) for k, v in cols.items()}


def _append(writer: DatasetWriter, out: dict[str, np.ndarray]) -> None:
    """Appends the arrays of :func:`_batch` to the store."""
    extras = {k: out[k].astype(np.int64 if k in ("source_row", "offset") else np.float32)
              for k in ("u_cmd", PRIOR_ARRAY, "source_row", "offset", "y_first")}
    extras[RECORDING_ARRAY] = extras["source_row"]  # a robot's windows stay in one split
    writer.append(out["u"].astype(np.float32), out["y"].astype(np.float32), out["params"].astype(np.float32), extras)


def _done(req: PriorRequest, record: dict) -> bool:
    """Whether ``req.out`` is a complete prior store of this very record (nothing left to do)."""
    if req.overwrite or not os.path.exists(req.out):
        return False
    try:
        done = open_store(req.out)
    except RoboMorphError:
        return False
    return done.attrs.get(PRIOR_ATTR) == record


def _in_progress(req: PriorRequest, record: dict) -> DatasetWriter | None:
    """The store in progress at ``req.out`` when it was begun with the same record (None: none to resume)."""
    if not os.path.exists(req.out) or req.overwrite:
        return None
    try:
        done = open_store(req.out, allow_incomplete=True)
    except RoboMorphError:
        return None
    if done.attrs.get("status") == "complete":
        return None
    if done.attrs.get(PRIOR_ATTR) != record:
        if done.n == 0 and done.attrs.get(PRIOR_ATTR) is not None:
            return None  # a prior store that holds no window yet: nothing to keep, begun anew
        raise PriorError(f"{req.out} is a prior store in progress begun with other arguments "
                         f"({done.attrs.get(PRIOR_ATTR)}); pass --overwrite to start it again")
    return DatasetWriter.reopen(req.out)


def _new_store(req: PriorRequest, src, record: dict, n_rows: int, length: int) -> DatasetWriter:
    """A new store at ``req.out`` (an empty prior store of an earlier request there is replaced)."""
    n_y = len(src.y_names)
    attrs = {k: v for k, v in src.attrs.items() if k in _KEPT_ATTRS}
    extras = {"u_cmd": ((length, len(src.u_names)), "float32"), PRIOR_ARRAY: ((req.horizon, n_y), "float32"),
              "source_row": ((), "int64"), "offset": ((), "int64"), "y_first": ((n_y,), "float32"),
              RECORDING_ARRAY: ((), "int64")}
    return create_store(req.out, n_rows, length, src.u_names, src.y_names, list(src.attrs.get("param_names", [])),
                        {**attrs, PRIOR_ATTR: record}, extras, chunk=64, overwrite=req.overwrite or _empty_prior(req.out),
                        u_cmd_names=list(src.attrs.get("u_cmd_names", [f"cmd{i}" for i in range(len(src.u_names))])))


def _empty_prior(path: str) -> bool:
    """Whether ``path`` is a prior store in progress that holds no window (safe to replace)."""
    try:
        ds = open_store(path, allow_incomplete=True)
    except RoboMorphError:
        return False
    return ds.n == 0 and ds.attrs.get("status") != "complete" and ds.attrs.get(PRIOR_ATTR) is not None


# The source store's attributes a prior store keeps (what its windows are and how they were made).
_KEPT_ATTRS = ("dt", "domain", "task", "task_names", "config", "seed", "substeps", "gravity_compensation",
               "u_cmd_compensation", "robot", "joint_names", "torque_limits", "realism_names", "original_dt")


def _recipe(config) -> dict:
    """The source's generator recipe as a plain dict (stored with the priors: the Predictor rebuilds the hybrid)."""
    return yaml.safe_load(config) if isinstance(config, str) else dict(config or {})


def _plain(value):
    """A settings value as YAML/JSON writes it."""
    return value.item() if isinstance(value, np.generic) else value
