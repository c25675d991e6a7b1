"""Many windows' hybrid predictions by two hybrids at once (``HybridSettings.workers``): the pool of a model's hybrids.

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

import queue
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

# Windows per chunk; a batch of fewer than two chunks stays whole.
CHUNK = 8
# The modes that are split: a window's prediction depends on its own row alone, to the bit.
SPLIT_MODES = ("regression", "refined")


class HybridPool:
    """The hybrids of one model: the first (what ``Predictor.hybrid`` returns) and the workers beside it, each
    built on first use with its own MuJoCo models, data and regressor, and each given the settings of every call
    (:class:`~robomorph.inference.settings.HybridSettings`, in effect)."""

    def __init__(self, model, physics: dict, inputs: str):
        self.model, self.physics, self.inputs = model, physics, inputs
        self.hybrids: list = []

    def first(self, settings):
        """The first hybrid, with ``settings``."""
        return self._ready(1, settings)[0]

    def _ready(self, n: int, settings) -> list:
        from robomorph.inference.hybrid import Hybrid  # noqa: PLC0415  (MuJoCo only when used)

        while len(self.hybrids) < n:
            self.hybrids.append(Hybrid(self.model, self.physics, self.inputs, settings))
        for h in self.hybrids[:n]:
            h.apply(settings)
        return self.hybrids[:n]

    @property
    def smoothing(self) -> dict | None:
        """The first hybrid's tally of smoothed windows (None before it exists)."""
        return self.hybrids[0].smoothing if self.hybrids else None

    @smoothing.setter
    def smoothing(self, report: dict) -> None:
        if self.hybrids:
            self.hybrids[0].smoothing = report

    def predict(self, settings, tensors: list[torch.Tensor], return_std: bool, at_rest=None, anchor=None
                ) -> tuple[np.ndarray, np.ndarray | None]:
        """What the first hybrid's ``predict`` gives for the batch ``tensors`` in ``settings.mode``, split over
        ``settings.workers`` hybrids where that pays."""
        mode = settings.mode
        parts = splits(tensors, settings.workers, mode, settings.points == "draws" and return_std)
        if parts is None:
            return self.first(settings).predict(*tensors, at_rest=at_rest, mode=mode, anchor=anchor,
                                                return_std=return_std)
        return predict_split(self._ready(settings.workers, settings), parts, tensors, at_rest, anchor, mode=mode,
                             return_std=return_std)


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
    ``hybrids`` (all with the same settings) is free, one thread each; the first hybrid then holds the whole
    batch's per-window record (held joints, covariances, fits)."""
    first = hybrids[0]
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
            return mean, std, h.record()
        finally:
            free.put(h)

    with ThreadPoolExecutor(len(hybrids)) as pool:
        outs = list(pool.map(run, parts))
    first.merge([o[2] for o in outs], kwargs.get("mode") == "refined")
    mean = np.concatenate([o[0] for o in outs])
    std = None if outs[0][1] is None else np.concatenate([o[1] for o in outs])
    return mean, std
