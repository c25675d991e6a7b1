"""``python -m robomorph.calibrate``: rescale a Gaussian head's standard deviation by horizon.

    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt          # the fit's validation split
    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt --data data/ms_val.zarr
    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt --remove

Predicts the validation windows of the checkpoint (the robots its DataModule held out for
validation, read back from its stores; or a held-out store given with ``--data``) with the
head's own standard deviation, fits the per-step, per-channel scale of
:mod:`robomorph.model.calibration` on them, and stores it in the checkpoint (atomically, in
place or into ``--out``). From then on ``Predictor.simulate(..., return_std=True)``,
``evaluate`` and the dashboard use the recalibrated spread; the mean prediction does not
change. A training store given whole as ``--data`` is refused: the model has seen those
robots, and its errors there are smaller than on robots it has not seen.
"""

from __future__ import annotations

import os
import time

import numpy as np

from robomorph.core.atomic import atomic_open
from robomorph.core.errors import RoboMorphError
from robomorph.evaluation import training_data
from robomorph.evaluation.evaluator import predict
from robomorph.evaluation.horizons import coverage, parse_horizons
from robomorph.evaluation.windows import EvaluationError, check_counts, check_patch, load_window, parse_offset
from robomorph.model.calibration import CALIBRATION_KEY, CalibrationError, fit


def _predictor(ckpt: str, device: str | None):
    from robomorph.model.predictor import Predictor  # noqa: PLC0415  (torch only here)

    predictor = Predictor.from_checkpoint(ckpt, device=device)
    if not predictor.has_std:
        raise CalibrationError(f"{ckpt} has no Gaussian head, so it predicts no standard deviation to calibrate; "
                               "train one with --model.gaussian true --model.loss nll")
    return predictor


def _sources(ckpt_dict: dict, data: str | None) -> tuple[list[tuple[str, np.ndarray | None]], str]:
    """``[(store, rows or None for all)]`` to calibrate on, and the split's name."""
    if data is None:
        sources = training_data.split_of(ckpt_dict, "val", hint="--data (a held-out store)")
        if not sources:
            raise CalibrationError("the checkpoint's fit held out no validation robots (split val share 0): pass "
                                   "--data with a store of robots it was not trained on")
        return list(sources), "val"
    dm = ckpt_dict.get("datamodule_hyper_parameters") or {}
    stores = dm.get("stores") or []
    stores = [stores] if isinstance(stores, str) else list(stores)
    if os.path.realpath(data) in {os.path.realpath(p) for p in stores}:
        raise CalibrationError(f"{data} is a training store of this checkpoint: the model has seen most of its robots, "
                               "so its errors there understate those on new robots; drop --data to use the fit's "
                               "validation split, or give a store of other robots")
    return [(data, None)], "whole"


def _windows(predictor, sources, n, context_len, horizon, offset, seed):
    """(u_ctx, y_ctx, u_query, y_query) of all sources, and the last store's dt."""
    parts, dt = [], None
    left = n
    for path, rows in sources:
        if left is not None and left <= 0:
            break
        w = load_window(path, context_len, horizon, left, predictor.data_info, predictor.n_u, predictor.n_y, offset,
                        seed, predictor.inputs, rows=rows)
        parts.append(w.split())
        dt = w.dt
        left = None if left is None else left - len(w.u)
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(4)), dt


def calibrate(ckpt: str, data: str | None = None, out: str | None = None, n: int | None = None,
              context_len: int | None = None, horizon: int | None = None, offset: str | int = "start",
              seed: int = 0, method: str = "nll", batch_size: int = 64, device: str | None = None,
              horizons_spec: str | None = None) -> dict:
    """Fits the calibration and writes the checkpoint with it to ``out`` (default: in place).

    Args:
        data: a held-out store (default: the checkpoint's validation split).
        n: at most this many windows.
        context_len, horizon: the window (default: the checkpoint's training window).
        offset, seed: where each window starts (``start``, ``random`` or a step), as in evaluate.
        method: ``nll`` or ``quantile`` (:mod:`robomorph.model.calibration`).
        horizons_spec: the steps the report shows (evaluate's ``--horizons``).

    Returns:
        A report: the calibration's provenance, and the ±1σ/±2σ coverage of the calibration
        windows before and after at the reported steps.
    """
    from robomorph.model.checkpoint import load_checkpoint_file  # noqa: PLC0415

    check_counts(context_len=context_len, horizon=horizon, n=n, batch_size=batch_size)
    offset = parse_offset(offset)
    predictor = _predictor(ckpt, device)
    ckpt_dict = load_checkpoint_file(ckpt)
    sources, split = _sources(ckpt_dict, data)
    info = predictor.data_info or {}
    context_len, horizon = context_len or info.get("context_len"), horizon or info.get("horizon")
    if context_len is None or horizon is None:
        raise EvaluationError(f"{ckpt} does not record its training window: pass --context-len and --horizon")
    check_patch(predictor.patch, [int(context_len)])
    (u_ctx, y_ctx, u_q, y_q), dt = _windows(predictor, sources, n, int(context_len), int(horizon), offset, seed)
    if len(u_ctx) < 2:
        raise CalibrationError(f"only {len(u_ctx)} calibration window: pass --data with a store of more robots")
    y_q = y_q.astype(np.float64)
    with predictor.raw_std():
        mean, std = predict(predictor, u_ctx, y_ctx, u_q, batch_size, desc="calibration windows", y_query=y_q,
                            with_std=True)
    source = {"data": [p for p, _ in sources], "split": split, "n": int(len(u_ctx)), "context_len": int(context_len),
              "horizon": int(horizon), "offset": offset, "seed": int(seed), "normalization": predictor.normalization,
              "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    cal = fit(y_q, mean, std, method, source=source)
    steps = parse_horizons(horizons_spec, int(horizon), dt)
    factors = cal.factors(int(horizon))
    std_after = factors[None] * std
    report = {"ckpt": ckpt, "out": out or ckpt, "calibration": cal.to_dict(), "steps": steps,
              "seconds": [s * dt for s in steps] if dt else None,
              "before": coverage(y_q, mean, std, steps), "after": coverage(y_q, mean, std_after, steps),
              "scale": [float(np.median(factors[s - 1])) for s in steps]}
    cal.source["coverage"] = {"steps": steps, "before": report["before"], "after": report["after"]}
    ckpt_dict[CALIBRATION_KEY] = cal.to_dict()
    _write(ckpt_dict, out or ckpt)
    return report


def remove(ckpt: str, out: str | None = None) -> bool:
    """Drops a stored calibration (writing ``out``, default in place); False when there was none."""
    from robomorph.model.checkpoint import load_checkpoint_file  # noqa: PLC0415

    ckpt_dict = load_checkpoint_file(ckpt)
    had = ckpt_dict.pop(CALIBRATION_KEY, None) is not None
    if had or (out and os.path.abspath(out) != os.path.abspath(ckpt)):
        _write(ckpt_dict, out or ckpt)
    return had


def _write(ckpt_dict: dict, path: str) -> None:
    """The checkpoint, written whole or not at all (a reader sees the old file or the new)."""
    import torch  # noqa: PLC0415

    if os.path.isdir(path):
        raise RoboMorphError(f"--out {path} is a folder: give the checkpoint file to write")
    with atomic_open(path, "wb") as f:
        torch.save(ckpt_dict, f)


def report_text(report: dict) -> str:
    """The terminal summary: where it was fitted, and the coverage before and after."""
    src = report["calibration"]["source"]
    lines = [f"std calibration ({report['calibration']['method']}) fitted on {src['n']} windows of "
             f"{', '.join(src['data'])} ({'validation split' if src['split'] == 'val' else 'whole store'}), "
             f"context {src['context_len']}, horizon {src['horizon']}",
             "| step | seconds | scale (median over channels) | ±1σ before | ±1σ after | ±2σ before | ±2σ after |",
             "|---|---|---|---|---|---|---|"]
    secs = report.get("seconds") or [None] * len(report["steps"])
    for i, (s, t) in enumerate(zip(report["steps"], secs)):
        b, a = report["before"], report["after"]
        lines.append(f"| {s} | {'' if t is None else f'{t:.3g}'} | {report['scale'][i]:.3g} | {b['1sigma'][i]:.1%} | "
                     f"{a['1sigma'][i]:.1%} | {b['2sigma'][i]:.1%} | {a['2sigma'][i]:.1%} |")
    lines.append("(coverage on the calibration windows themselves; ideal 68.3 % / 95.4 %; score it on a test "
                 "store with robomorph.evaluate)")
    lines.append(f"written: {report['out']}")
    return "\n".join(lines)
