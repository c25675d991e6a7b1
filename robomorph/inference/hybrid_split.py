"""Many windows' hybrid predictions by two hybrids at once (``Predictor.physics_workers``).

A window's regression (:mod:`robomorph.identification.regressor`) is Python and numpy on one core, while the
rollouts of its contexts and horizons fill every core. One hybrid does them in turn, so one core
waits while the other regresses. Two hybrids, each with its own MuJoCo models, data and regressor,
take chunks of :data:`CHUNK` windows in turn on two threads, so that one's regression overlaps the
other's rollouts (MuJoCo's calls release the GIL; small chunks let the two drift apart, where halves
started both regressions at once). Each window's prediction depends on its own row alone (its
regression, its correction, its rollouts, its spread), so the chunks give what the whole batch
gives, to the bit (a test holds them to it). Measured on 64 held-out windows from the start, the
fast setting with the correction (``regression~1/2+obs+springs+debias``), three rounds side by
side: 18.1-18.9 ms per window on one hybrid, 15.8-16.3 with two on halves, 14.9-15.5 on chunks of
8 (15.3-15.8 of 16; this machine's 2 cores).

Split: the modes that read no network (:data:`SPLIT_MODES`; a network's batched products may round
differently by batch size), with the std over the estimate's columns or the observed points (random
draws are drawn per batch). Not split: batches of one context (a planner's candidates, identified once:
:mod:`robomorph.identification.tangent`) and batches of fewer than two chunks.
"""

from __future__ import annotations

import os
import queue
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

# Windows per chunk; a batch of fewer than two chunks stays whole.
CHUNK = 8
# The modes that are split: a window's prediction depends on its own row alone, to the bit.
SPLIT_MODES = ("regression", "refined")
# What a worker copies from the first hybrid before each split call (what Predictor.hybrid and callers set).
SETTINGS = ("samples", "members", "points", "springs", "debias", "iterations", "refine_iters", "seed", "smoother")
BACKBONE_SETTINGS = ("coarse", "observe", "candidates")


def default_workers() -> int:
    """Two where there are two cores or more: one's regression runs beside the other's rollouts."""
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def predict_hybrid(pred, tensors: list[torch.Tensor], return_std: bool, at_rest=None, anchor=None
                   ) -> tuple[np.ndarray, np.ndarray | None]:
    """What ``pred.hybrid().predict`` gives for the batch ``tensors``, split over ``pred.physics_workers`` hybrids
    where that pays (the workers past the first built on first use, as :meth:`Predictor.hybrid` builds the first)."""
    from robomorph.inference.hybrid import Hybrid  # noqa: PLC0415  (MuJoCo only when used)

    first, mode = pred.hybrid(strict=return_std), pred.physics_mode
    parts = splits(tensors, pred.physics_workers, mode, first.points == "draws" and return_std)
    if parts is None:
        return first.predict(*tensors, at_rest=at_rest, mode=mode, anchor=anchor, return_std=return_std)
    while len(pred._workers) < int(pred.physics_workers) - 1:
        pred._workers.append(Hybrid(pred.model, pred.physics, pred.inputs))
    hybrids = [first, *pred._workers[:int(pred.physics_workers) - 1]]
    return predict_split(hybrids, parts, tensors, at_rest, anchor, mode=mode, return_std=return_std)


def splits(tensors: list[torch.Tensor], workers: int, mode: str, draws: bool = False) -> list[slice] | None:
    """The chunks of rows the hybrids predict in turn, or None where the batch stays whole (``draws``: a std over
    random draws is asked for; see the module's docstring)."""
    u_ctx, y_ctx = tensors[0], tensors[1]
    n = len(u_ctx)
    if int(workers) < 2 or n < 2 * CHUNK or mode not in SPLIT_MODES or draws:
        return None
    if bool((u_ctx == u_ctx[:1]).all()) and bool((y_ctx == y_ctx[:1]).all()):
        return None  # one context: identified once, its horizons batched
    edges = np.linspace(0, n, n // CHUNK + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def predict_split(hybrids: list, parts: list[slice], tensors: list[torch.Tensor], at_rest=None, anchor=None,
                  **kwargs) -> tuple[np.ndarray, np.ndarray | None]:
    """``hybrids[0].predict`` of the whole batch, its chunks of rows ``parts`` predicted in turn by whichever of
    ``hybrids`` is free, one thread each; the first hybrid then holds the whole batch's per-window record (held
    joints, covariances, fits)."""
    from robomorph.inference.hybrid import batch_record, merge_records  # noqa: PLC0415  (MuJoCo only when used)

    first = hybrids[0]
    for other in hybrids[1:]:
        for name in SETTINGS:
            setattr(other, name, getattr(first, name))
        for name in BACKBONE_SETTINGS:
            setattr(other.backbone, name, getattr(first.backbone, name))
    n = len(tensors[0])
    rest = None if at_rest is None else np.broadcast_to(np.asarray(at_rest, dtype=bool), (n,))
    anchors = None if anchor is None else np.asarray(anchor, dtype=np.float64).reshape(n, -1)
    free: queue.SimpleQueue = queue.SimpleQueue()
    for h in hybrids:
        free.put(h)

    def run(part: slice) -> tuple:
        h = free.get()  # never waits: as many threads as hybrids
        try:
            mean, std = h.predict(*(t[part] for t in tensors), at_rest=None if rest is None else rest[part],
                                  anchor=None if anchors is None else anchors[part], **kwargs)
            return mean, std, batch_record(h)
        finally:
            free.put(h)

    with ThreadPoolExecutor(len(hybrids)) as pool:
        outs = list(pool.map(run, parts))
    merge_records(first, [o[2] for o in outs], kwargs.get("mode") == "refined")
    mean = np.concatenate([o[0] for o in outs])
    std = None if outs[0][1] is None else np.concatenate([o[1] for o in outs])
    return mean, std
