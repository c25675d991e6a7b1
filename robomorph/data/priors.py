"""Prior stores: windows of a store with a physics prior's prediction of their query outputs.

A prior store is an ordinary store (:mod:`robomorph.data.store`) whose rows are fixed windows of
``context + horizon`` steps cut from a source store, with three extra arrays:

- ``prior`` (N, horizon, n_y): the prior's prediction of the window's query outputs, made from the
  window's context and query inputs alone (the physics hybrid's,
  :func:`robomorph.evaluation.priors.write_priors` writes them);
- ``source_row`` (N,) and ``offset`` (N,): where the window was cut (trajectory row and first step);
  ``recording_index`` (N,), the same rows, so that the DataModule's splits keep a robot's windows
  together (:data:`robomorph.data.splits.RECORDING_ARRAY`);
- ``y_first`` (N, n_y): the first output of that trajectory (where the robot started, which the
  hybrid is given for windows that do not open their trajectory).

``attrs["prior"]`` records how (:data:`PRIOR_ATTR`): the source store, the hybrid's settings key and
fields, the context and horizon, the offsets, the arm and the input formulation. A residual model
(:class:`robomorph.model.architecture.ModelConfig` ``residual``) trains on such a store: the
DataModule hands it the prior of each window's query beside the window (``prior_query``), and the
model learns the correction ``y - prior``.
"""

from __future__ import annotations

import numpy as np

from robomorph.core.errors import RoboMorphError

PRIOR_ARRAY = "prior"
PRIOR_ATTR = "prior"
# Extra arrays of a prior store beside the prior: where each window was cut.
WINDOW_ARRAYS = ("source_row", "offset", "y_first")


class PriorError(RoboMorphError, ValueError):
    """A prior store that cannot feed the run as asked; the message names the fix."""


def prior_record(attrs: dict) -> dict | None:
    """The store's prior record (``attrs["prior"]``), or None for a store without priors."""
    record = attrs.get(PRIOR_ATTR)
    return dict(record) if isinstance(record, dict) else None


# Recipe fields that change which robots are drawn, not the hybrid that predicts them: prior stores of two
# seeds or sizes of one recipe feed one residual run.
_SAMPLING_FIELDS = ("robots", "seed", "steps", "chunk", "max_attempts_factor")


def common_prior(records: list[dict | None], paths: list[str]) -> dict | None:
    """The training stores' common prior record (the first's), or None where no store holds priors.

    A residual model records one hybrid, which it rebuilds at inference to make its prior: every store
    must hold priors of that very hybrid (one arm, one recipe but for its sampling fields, one settings key,
    one window and formulation). Checked as soon as the stores are opened (before ``fit`` builds the model
    from them), so a mix of arms is named as one, not as the model's channel mask.

    Raises:
        PriorError: a mix of stores with and without priors, or priors of different arms, recipes, settings
            or windows.
    """
    have = [r is not None for r in records]
    if not any(have):
        return None
    if not all(have):
        lacking = [p for p, h in zip(paths, have) if not h]
        raise PriorError(f"{lacking[0]} holds no priors while other stores of this run do: a residual model "
                         "trains on prior stores only (robomorph priors writes them)")
    first = records[0]
    for path, rec in zip(paths[1:], records[1:]):
        if rec.get("arm") != first.get("arm"):
            raise PriorError(f"{path} holds priors of the {rec.get('arm')} and {paths[0]} of the {first.get('arm')}: "
                             "a residual model corrects the hybrid of one arm, which it rebuilds at inference; train "
                             "one residual model per arm")
        for key in ("settings", "context", "inputs"):
            if rec.get(key) != first.get(key):
                raise PriorError(f"{path} has priors with {key} {rec.get(key)!r}, {paths[0]} with {first.get(key)!r}: "
                                 "the stores of one residual run share the prior's settings and window")
        mine, theirs = (_hybrid_recipe(r) for r in (first, rec))
        if mine != theirs:
            key = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))[0]
            raise PriorError(f"{path} holds priors of another hybrid than {paths[0]}: their recipes differ in {key} "
                             f"({theirs.get(key)!r} against {mine.get(key)!r}), and a residual model rebuilds one "
                             "hybrid at inference (it would record the first's alone); train one per recipe")
    return first


def _hybrid_recipe(record: dict) -> dict:
    """A prior record's generator recipe without the fields that only draw robots (:data:`_SAMPLING_FIELDS`)."""
    recipe = record.get("recipe")
    return {k: v for k, v in recipe.items() if k not in _SAMPLING_FIELDS} if isinstance(recipe, dict) else {}


def check_prior_windows(records: list[dict | None], paths: list[str], context_len: int, horizon: int,
                        window: str, context_min: int | None, inputs: str) -> dict | None:
    """The training stores' common prior record (:func:`common_prior`), after checking the run's windows
    against it.

    A prior predicts the query that follows the store's own context, so a run over prior stores
    takes its context whole (``context_len`` = the record's, ``context_min`` off), its windows from
    the start of each row (``window: start``) and a horizon within the record's. Stores without
    priors give None (all of them: a run mixes none with prior stores).

    Raises:
        PriorError: what :func:`common_prior` refuses, or windows the priors do not cover.
    """
    first = common_prior(records, paths)
    if first is None:
        return None
    if context_len != first["context"]:
        raise PriorError(f"--data.context_len {context_len}: the priors of {paths[0]} follow a context of "
                         f"{first['context']} steps; use --data.context_len {first['context']}")
    if horizon > first["horizon"]:
        raise PriorError(f"--data.horizon {horizon} exceeds the {first['horizon']} query steps the priors of "
                         f"{paths[0]} cover; use --data.horizon {first['horizon']} or less")
    if inputs != first.get("inputs", "command"):
        raise PriorError(f"--data.inputs {inputs}: the priors of {paths[0]} were predicted from the "
                         f"{first.get('inputs', 'command')} formulation, which the residual model must read too; use "
                         f"--data.inputs {first.get('inputs', 'command')}")
    if window != "start" or context_min is not None:
        raise PriorError("prior stores hold fixed windows: use --data.window start and no --data.context_min "
                         "(the prior follows the whole context)")
    return first



def prior_error_rms(pairs: list[tuple[np.ndarray, np.ndarray]], horizon: int) -> np.ndarray:
    """(horizon, n_y) RMS of ``y_query - prior`` per query step and channel over ``pairs`` of
    (y_query (k, >= horizon, n_y), prior (k, >= horizon, n_y)): the unit a residual model's correction
    is counted in (the training rows' only)."""
    total, count = None, 0
    for y_query, prior in pairs:
        err = (y_query[:, :horizon].astype(np.float64) - prior[:, :horizon].astype(np.float64)) ** 2
        total = err.sum(axis=0) if total is None else total + err.sum(axis=0)
        count += len(err)
    if not count:
        raise PriorError("no training windows to measure the prior's error on")
    return np.sqrt(total / count)
