"""Many windows' hybrid predictions on two workers at once (``Predictor.physics_workers``).

A window's regression (:mod:`robomorph.sim.regressor`) is Python and numpy on one core, while the
rollouts of its contexts and horizons fill every core. One hybrid does them in turn, so one core
waits while the other regresses. Two hybrids, each with its own MuJoCo models, data and regressor,
given half of the windows each on two threads, overlap one's regression with the other's rollouts
(MuJoCo's calls release the GIL). Each window's prediction depends on its own row alone (its
regression, its correction, its rollouts, its spread), so the halves give what the whole batch
gives, to the bit (a test holds them to it). Measured on 64 held-out windows from the start, the
fast setting with the correction (``regression~1/2+obs+springs+debias``): 19 ms per window on one
worker, 16 on two (this machine's 2 cores; ``benchmarks/hybrid.py``).

Not split: batches of one context (a planner's candidates, identified once: :mod:`robomorph.sim.tangent`),
small batches, and the modes that read the decoder over the whole horizon (``smoothed``, ``blend``).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

# Rows per worker below which a split is not worth building and running a second hybrid for.
MIN_ROWS = 8
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
    from robomorph.model.hybrid import Hybrid, solves_whole_horizon  # noqa: PLC0415  (MuJoCo only when used)

    first, mode = pred.hybrid(strict=return_std), pred.physics_mode
    parts = splits(tensors, pred.physics_workers, mode, solves_whole_horizon(pred.model, mode))
    if parts is None:
        return first.predict(*tensors, at_rest=at_rest, mode=mode, anchor=anchor, return_std=return_std)
    while len(pred._workers) < len(parts) - 1:
        pred._workers.append(Hybrid(pred.model, pred.physics, pred.inputs))
    return predict_split([first, *pred._workers], parts, tensors, at_rest, anchor, mode=mode, return_std=return_std)


def splits(tensors: list[torch.Tensor], workers: int, mode: str, whole_horizon: bool) -> list[slice] | None:
    """The rows each worker predicts, or None where the batch stays whole (see the module's docstring)."""
    u_ctx, y_ctx = tensors[0], tensors[1]
    n = len(u_ctx)
    workers = min(int(workers), n // MIN_ROWS)
    if workers < 2 or whole_horizon or mode == "blend":
        return None
    if bool((u_ctx == u_ctx[:1]).all()) and bool((y_ctx == y_ctx[:1]).all()):
        return None  # one context: identified once, its horizons batched
    edges = np.linspace(0, n, workers + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def predict_split(hybrids: list, parts: list[slice], tensors: list[torch.Tensor], at_rest=None, anchor=None,
                  **kwargs) -> tuple[np.ndarray, np.ndarray | None]:
    """``hybrids[0].predict`` of the whole batch, its rows ``parts`` predicted by ``hybrids[k]`` each on a thread;
    the first hybrid then holds the whole batch's per-window record (held joints, covariances, fits)."""
    first = hybrids[0]
    for other in hybrids[1:]:
        for name in SETTINGS:
            setattr(other, name, getattr(first, name))
        for name in BACKBONE_SETTINGS:
            setattr(other.backbone, name, getattr(first.backbone, name))
    n = len(tensors[0])
    rest = None if at_rest is None else np.broadcast_to(np.asarray(at_rest, dtype=bool), (n,))
    anchors = None if anchor is None else np.asarray(anchor, dtype=np.float64).reshape(n, -1)

    def run(k: int):
        part = parts[k]
        return hybrids[k].predict(*(t[part] for t in tensors), at_rest=None if rest is None else rest[part],
                                  anchor=None if anchors is None else anchors[part], **kwargs)

    with ThreadPoolExecutor(len(parts) - 1) as pool:
        later = [pool.submit(run, k) for k in range(1, len(parts))]
        outs = [run(0)] + [f.result() for f in later]
    used = hybrids[:len(parts)]
    first._held = np.concatenate([h._held for h in used]) if all(h._held is not None for h in used) else None
    first._covs = [c for h in used for c in h._covs]
    first.last_fits = [f for h in used for f in h.last_fits]
    mean = np.concatenate([o[0] for o in outs])
    std = None if outs[0][1] is None else np.concatenate([o[1] for o in outs])
    return mean, std
