"""``python -m robomorph.evaluate``: a trained meta-model on a store, beside the baselines.

    python -m robomorph.evaluate --ckpt results/runs/ms/checkpoints/best.ckpt \\
        --data data/ms_test.zarr --out results/runs/ms/eval/ms_test \\
        --sweep-horizon 200:800:50 --sweep-context 20:200:20

Each trajectory's first ``context_len`` steps are the context (or, with ``--offset random``
or ``--offset N``, those of a window starting later); the next ``horizon`` steps are
predicted from the query torques alone. Writes ``metrics.json`` (both of the paper's
evaluation approaches for the model and every baseline, the RMS errors by horizon in
physical units and, when the model gives a standard deviation, its ±1σ/±2σ coverage, the
sweeps, and the run's meta-data), ``metrics.csv`` (one row per source, approach, channel
and metric), ``horizons.csv`` (one row per source, quantity and horizon), ``table.md``
(per-channel table in the paper's fit colour convention, then the per-horizon table) and
PNG plots.

A checkpoint trained with ``data.normalization: paper_window`` (the paper's protocol) is
scored as the paper scored it: each window rescaled with its own query outputs' mean and
std. ``metrics.json`` then says ``"leaks_query_statistics": true`` and ``table.md`` says so
in its header.

The horizon sweep predicts with shorter query windows after the same context; the context
sweep keeps the predicted window fixed and gives the model only the last ``c`` steps
before it, so every point of it scores the same targets.
"""

from __future__ import annotations

import inspect
import os
import sys

import numpy as np

from robomorph.core import metrics as scores
from robomorph.core.atomic import write_json
from robomorph.core.errors import RoboMorphError
from robomorph.core.normalizations import NormalizationError, leaks_query_statistics, query_output_stats
from robomorph.core.rundir import RunDir
from robomorph.evaluation import metrics, references, training_data
from robomorph.evaluation import plots as eval_plots
from robomorph.evaluation.baselines import ARX, BASELINES, CEILINGS, hold
from robomorph.evaluation.horizons import horizon_markdown, horizon_report, parse_horizons
from robomorph.evaluation.tables import diverged_note, write_csv, write_horizons_csv, write_table

# Window, EvaluationError and parse_range re-exported: callers import them from here.
from robomorph.evaluation.windows import (  # noqa: F401
    EvaluationError,
    Window,
    check_counts,
    check_patch,
    load_window,
    parse_offset,
    parse_range,
)


def predict(predictor, u_ctx, y_ctx, u_query, batch_size: int, desc: str = "model", y_query=None,
            with_std: bool = False):
    """The model's predictions in batches, with a progress bar on stderr.

    ``y_query`` (the true outputs) is read only by a ``paper_window`` model, which needs
    their statistics (the paper's protocol); any other model never receives them.

    Returns:
        (N, H, n_y) means, or with ``with_std`` the pair (means, standard deviations).
    """
    from tqdm.auto import tqdm  # noqa: PLC0415

    leaks = getattr(predictor, "leaks_query_statistics", False)
    if leaks and y_query is None:
        raise NormalizationError("a paper_window model needs the query outputs' statistics: pass y_query to predict()")
    means, stds = [], []
    for s in tqdm(range(0, len(u_ctx), batch_size), desc=desc, unit="batch", leave=False,
                  disable=not sys.stderr.isatty() and len(u_ctx) <= batch_size):
        part = slice(s, s + batch_size)
        out = predictor.simulate(u_ctx[part], y_ctx[part], u_query[part], **_extra(predictor, y_query, part, with_std))
        mean = out[0] if with_std else out
        if with_std:
            stds.append(out[1])
        means.append(mean)
    mean = np.concatenate(means).astype(np.float64)
    return (mean, np.concatenate(stds).astype(np.float64)) if with_std else mean


def _extra(predictor, y_query, part: slice, with_std: bool) -> dict:
    """Keyword arguments of ``simulate`` beyond the three arrays: only those this call needs,
    so any object with ``simulate(u_ctx, y_ctx, u_query)`` can be evaluated."""
    kwargs = {}
    if getattr(predictor, "leaks_query_statistics", False):
        kwargs["y_query_stats"] = query_output_stats(y_query[part])
    if with_std:
        kwargs["return_std"] = True
    return kwargs


def gives_std(predictor, u_ctx, y_ctx, u_query, y_query=None) -> bool:
    """Whether ``predictor.simulate(..., return_std=True)`` returns a standard deviation.

    Asked of the first trajectory: a predictor without the keyword, one that refuses it
    (a model without a Gaussian head) or one that answers ``(mean, None)`` gives none.
    """
    try:
        params = inspect.signature(predictor.simulate).parameters
        if "return_std" not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            return False
        out = predictor.simulate(u_ctx[:1], y_ctx[:1], u_query[:1], **_extra(predictor, y_query, slice(0, 1), True))
    except (NotImplementedError, RoboMorphError, ValueError, TypeError):
        return False
    return isinstance(out, tuple) and len(out) == 2 and out[1] is not None


def run_baselines(w: Window, names: tuple[str, ...], arx_orders: tuple[int, int],
                  train_blocks=None) -> tuple[dict, dict, dict]:
    """Predictions of the baselines that apply, the reasons of those skipped, and notes.

    ``train_blocks``: a function returning the training data as ``(u, y)`` blocks (for
    ``arx_train``; see :mod:`robomorph.evaluation.training_data`).
    """
    u_ctx, y_ctx, u_q, _ = w.split()
    preds, skipped, notes = {}, {}, {}
    for name in names:
        if name == "hold":
            preds[name] = hold(u_ctx, y_ctx, u_q).astype(np.float64)
        elif name in ("arx", "arx_train"):
            try:
                arx = ARX(*arx_orders) if name == "arx" else references.fit_arx_train(arx_orders, train_blocks)
                preds[name] = arx(u_ctx, y_ctx, u_q)
                notes[name] = {"na": arx.na, "nb": arx.nb, "diverged_held": arx.diverged}
                if name == "arx_train":
                    notes[name]["trajectories"] = arx.trajectories
            except ValueError as exc:  # too short a context, or no training data to read
                skipped[name] = str(exc)
        elif name in ("nominal_physics", "true_physics"):
            from robomorph.evaluation.physics import NominalPhysics, NotApplicable, check_params  # noqa: PLC0415

            try:
                sim = NominalPhysics(w.attrs, inputs=w.inputs)
                if name == "true_physics":
                    check_params(w.attrs)
            except NotApplicable as exc:
                skipped[name] = str(exc)
                continue
            params = w.params if name == "true_physics" else _nominal_params(sim, w)
            preds[name] = _batched(sim, u_ctx, y_ctx, u_q, name.replace("_", " "), params=params)
        else:
            raise EvaluationError(f"unknown baseline {name!r}; choose from {BASELINES + CEILINGS}")
    return preds, skipped, notes


def _nominal_params(sim, w: Window) -> np.ndarray | None:
    """Nominal parameters with the joint springs anchored where each robot started (its
    trajectory's first sample), as the generator anchored them; None (the simulator anchors
    at the context's first sample) when every window opens its trajectory, where they agree."""
    from robomorph.sim import panda  # noqa: PLC0415  (NominalPhysics checked the Panda layout)

    if not w.starts.any():
        return None
    q = w.y_first[:, [w.y_names.index(f"q{i}") for i in range(panda.N_JOINT)]]
    return np.stack([sim.params(q0.astype(np.float64)) for q0 in q])


def _batched(fn, u_ctx, y_ctx, u_q, desc: str, size: int = 16, params=None) -> np.ndarray:
    from tqdm.auto import tqdm  # noqa: PLC0415

    parts = [fn(u_ctx[s:s + size], y_ctx[s:s + size], u_q[s:s + size],
                params=None if params is None else params[s:s + size])
             for s in tqdm(range(0, len(u_ctx), size), desc=desc, unit="batch", leave=False)]
    return np.concatenate(parts).astype(np.float64)


def _summary(y, yhat) -> dict:
    """Channel-mean R^2 and FIT: ``r2``/``fit`` by approach 1, ``r2_a2``/``fit_a2`` by approach 2."""
    a2 = [np.asarray(f(y.reshape(1, -1, y.shape[-1]), yhat.reshape(1, -1, y.shape[-1])))[0].mean()
          for f in (scores.r2, scores.fit_index)]
    return {"r2": float(metrics.approach1_mean(y, yhat, "r2")), "fit": float(metrics.approach1_mean(y, yhat, "fit")),
            "r2_a2": float(a2[0]), "fit_a2": float(a2[1])}


def sweep_horizon(predictor, w: Window, horizons: list[int], baselines: dict, batch_size: int) -> list[dict]:
    """Mean approach-1 R^2 / FIT for each horizon, same context (baselines are causal: truncated)."""
    rows = []
    for h in horizons:
        u_ctx, y_ctx, u_q, y_q = w.split(horizon=h)
        y_q = y_q.astype(np.float64)
        row = {"horizon": h, "model": _summary(y_q, predict(predictor, u_ctx, y_ctx, u_q, batch_size, f"horizon {h}", y_q))}
        row.update({name: _summary(y_q, p[:, :h]) for name, p in baselines.items()})
        rows.append(row)
    return rows


def sweep_context(predictor, w: Window, contexts: list[int], batch_size: int) -> list[dict]:
    """Mean approach-1 R^2 / FIT for each context length, same predicted window."""
    rows = []
    for c in contexts:
        u_ctx, y_ctx, u_q, y_q = w.split(context_len=c)
        y_q = y_q.astype(np.float64)
        rows.append({"context_len": c, "model": _summary(y_q, predict(predictor, u_ctx, y_ctx, u_q, batch_size,
                                                                      f"context {c}", y_q)),
                     "hold": _summary(y_q, hold(u_ctx, y_ctx, u_q))})
    return rows


def evaluate(ckpt: str, data: str, out: str, context_len: int | None = None, horizon: int | None = None,
             n: int | None = None, baselines: tuple[str, ...] = BASELINES, sweep_horizon_spec: str | None = None,
             sweep_context_spec: str | None = None, batch_size: int = 64, device: str | None = None,
             samples: int = 3, arx_orders: tuple[int, int] = (2, 2), seed: int = 0,
             normalization: str | None = None, horizons_spec: str | None = None,
             offset: str | int | None = "start", inputs: str | None = None,
             arx_train_data: list[str] | None = None, compare: dict[str, str] | None = None) -> dict:
    """Evaluates a checkpoint on a store and writes every output file into ``out``.

    ``arx_train`` is fitted on the checkpoint's training split (read back from its stores),
    or on the whole of the ``arx_train_data`` stores when given. ``compare`` maps names to
    other checkpoints (e.g. ``{"scratch": ...}``) scored beside the baselines on the same data.

    Args:
        normalization: when given, the normalization the checkpoint must have been trained
            with (``train_stats`` or ``paper_window``); default: whatever it was trained with.
        horizons_spec: the steps of the per-horizon errors (:func:`parse_horizons`; default
            first step, 0.25 s, 1 s, 5 s and the end of the horizon).
        offset: where each window starts (:func:`parse_offset`): ``start``, ``random``
            (seeded by ``seed``) or a fixed step.
        inputs: when given, the input formulation the checkpoint must have been trained on
            (``total``: the store's ``u``, ``command``: its ``u_cmd``); the store's input
            array is always the checkpoint's, and a store without ``u_cmd`` is refused for a
            command model with a message saying to regenerate it.

    Returns:
        The ``metrics.json`` content.
    """
    check_counts(context_len=context_len, horizon=horizon, n=n, batch_size=batch_size)
    offset = parse_offset(offset)
    predictor = _checked_predictor(ckpt, device, baselines, inputs, normalization)
    info = predictor.data_info
    context_len = context_len or (info or {}).get("context_len")
    horizon = horizon or (info or {}).get("horizon")
    if context_len is None or horizon is None:
        raise EvaluationError(f"{ckpt} does not record its training window: pass --context-len and --horizon")
    w = load_window(data, int(context_len), int(horizon), n, info, predictor.n_u, predictor.n_y, offset, seed,
                    predictor.inputs)
    steps = parse_horizons(horizons_spec, w.horizon, w.dt)
    horizons = parse_range(sweep_horizon_spec, 1, w.horizon, "horizon")
    contexts = parse_range(sweep_context_spec, 1, w.context_len, "context")
    check_patch(predictor.patch, [w.context_len, *contexts])
    os.makedirs(out, exist_ok=True)
    others = {name: references.load_other(name, other, w, device) for name, other in (compare or {}).items()}
    result, preds, std, base = score(predictor, w, tuple(baselines), arx_orders, batch_size, steps,
                                     training_data.reader(ckpt, arx_train_data), others)
    result["meta"] = {"ckpt": ckpt, "data": data, **result["meta"], "offset": offset, "seed": seed}
    result["meta"]["baseline_notes"].update({name: {"ckpt": path} for name, path in (compare or {}).items()})
    result["sweeps"] = _sweeps(predictor, w, horizons, contexts, base, batch_size, out)
    _, y_ctx, _, y_q = w.split()
    eval_plots.write_all(out, y_ctx, y_q.astype(np.float64), preds, w.y_names, w.dt, samples, seed,
                         std=std, steps=steps, y_units=w.attrs.get("y_units"))
    _write_files(out, result)
    return result


def _checked_predictor(ckpt: str, device: str | None, baselines, inputs: str | None, normalization: str | None):
    """The checkpoint's Predictor, once the baselines, inputs and normalization asked for fit it."""
    from robomorph.model.predictor import Predictor  # noqa: PLC0415  (torch only here)

    for name in baselines:
        if name not in BASELINES + CEILINGS:
            raise EvaluationError(f"unknown baseline {name!r}; choose from {BASELINES + CEILINGS}")
    predictor = Predictor.from_checkpoint(ckpt, device=device)
    predictor.check_inputs(inputs)
    if normalization is not None and normalization != predictor.normalization:
        raise NormalizationError(f"{ckpt} was trained with normalization {predictor.normalization!r}, not "
                                 f"{normalization!r}: the normalization is fixed at training time (data.normalization)")
    return predictor


def _write_files(out: str, result: dict) -> None:
    write_csv(os.path.join(out, "metrics.csv"), result)
    write_horizons_csv(os.path.join(out, "horizons.csv"), result["horizons"])
    write_table(os.path.join(out, "table.md"), result)
    write_json(os.path.join(out, "metrics.json"), result)


def _sweeps(predictor, w: Window, horizons: list[int], contexts: list[int], base: dict, batch_size: int,
            out: str) -> dict:
    """The horizon and context sweeps asked for, each with its plot in ``out``."""
    sweeps = {}
    if horizons:
        sweeps["horizon"] = sweep_horizon(predictor, w, horizons, base, batch_size)
        eval_plots.plot_sweep(os.path.join(out, "sweep_horizon.png"), sweeps["horizon"], "horizon")
    if contexts:
        sweeps["context"] = sweep_context(predictor, w, contexts, batch_size)
        eval_plots.plot_sweep(os.path.join(out, "sweep_context.png"), sweeps["context"], "context_len")
    return sweeps


def score(predictor, w: Window, baselines: tuple[str, ...], arx_orders: tuple[int, int], batch_size: int,
          steps: list[int], train_blocks=None, others: dict | None = None
          ) -> tuple[dict, dict, np.ndarray | None, dict]:
    """Scores the model and the baselines on one window set.

    ``train_blocks`` reads the training data (``arx_train``); ``others`` maps names to other
    predictors (``--compare``), scored like the baselines.

    Returns:
        ``(result, preds, std, baseline preds)``: the ``metrics.json`` content without the
        sweeps, every source's predictions, and the model's standard deviation (None when
        the predictor gives none).
    """
    u_ctx, y_ctx, u_q, y_q = w.split()
    y_q = y_q.astype(np.float64)
    normalization = getattr(predictor, "normalization", None)
    std = None
    if gives_std(predictor, u_ctx, y_ctx, u_q, y_q):
        model, std = predict(predictor, u_ctx, y_ctx, u_q, batch_size, y_query=y_q, with_std=True)
    else:
        model = predict(predictor, u_ctx, y_ctx, u_q, batch_size, y_query=y_q)
    preds = {"model": model}
    base, skipped, notes = run_baselines(w, baselines, arx_orders, train_blocks)
    for name, other in (others or {}).items():
        base[name] = predict(other, u_ctx, y_ctx, u_q, batch_size, desc=name, y_query=y_q)
    preds.update(base)
    names = w.y_names
    result = {"approach1": metrics.approach1(y_q, model, names),
              "approach2": metrics.approach2(y_q, model, names),
              "baselines": {b: {"approach1": metrics.approach1(y_q, p, names), "approach2": metrics.approach2(y_q, p, names)}
                            for b, p in base.items()},
              "skipped_baselines": skipped,
              "horizons": horizon_report(y_q, preds, names, w.dt, steps, std, w.attrs.get("y_units")),
              "window_starts": w.starts.tolist(),
              "meta": {"context_len": w.context_len, "horizon": w.horizon, "n": len(w.u), "dt": w.dt,
                       "y_names": names, "u_names": w.u_names, "device": str(getattr(predictor, "device", "")),
                       "baseline_notes": notes, "domain": w.attrs.get("domain"), "task": w.attrs.get("task"),
                       "normalization": normalization, "std": std is not None, "inputs": w.inputs,
                       "std_calibration": _calibration_meta(predictor) if std is not None else None},
              # The paper's protocol scales each window with its query outputs' statistics: say so first.
              "leaks_query_statistics": leaks_query_statistics(normalization)}
    return result, preds, std, base


def _calibration_meta(predictor) -> dict | None:
    """Where the stored std calibration was fitted (``robomorph.calibrate``), or None."""
    cal = getattr(predictor, "calibration", None)
    if cal is None:
        return None
    src = {k: v for k, v in cal.source.items() if k != "coverage"}
    return {"method": cal.method, **src}


def default_out(ckpt: str, data: str) -> str:
    """``<run>/eval/<store name>`` for a checkpoint in ``<run>/checkpoints/``."""
    return RunDir.of_checkpoint(ckpt).eval_dir(data)


def summary_text(res: dict, out: str, horizons: bool = True) -> str:
    """A few lines for the terminal: mean approach-1 scores of the model and the baselines,
    then (with ``horizons``) the RMS errors by horizon in physical units."""
    m, meta = res["approach1"]["mean"], res["meta"]
    lines = [f"{meta['n']} trajectories, context {meta['context_len']}, horizon {meta['horizon']}, "
             f"inputs {meta.get('inputs', 'total')} (approach 1 mean):"]
    if res.get("leaks_query_statistics"):
        lines.append(f"  normalization {meta.get('normalization')}: scores use the query outputs' statistics (the "
                     "paper's protocol), not those of a deployable model")
    lines.append(f"  {'model':16s} R2 {m['r2']['mean']:8.3f}  FIT {m['fit']['mean']:8.2f}  RMSE {m['rmse']['mean']:.4g}")
    notes = meta.get("baseline_notes", {})
    for b, r in res["baselines"].items():
        mb = r["approach1"]["mean"]
        lines.append(f"  {b:16s} R2 {mb['r2']['mean']:8.3f}  FIT {mb['fit']['mean']:8.2f}  RMSE {mb['rmse']['mean']:.4g}"
                     + (f"  ({note})" if (note := diverged_note(notes.get(b, {}), meta["n"])) else ""))
    lines += [f"  skipped {b}: {why}" for b, why in res["skipped_baselines"].items()]
    cal = meta.get("std_calibration")
    if cal:
        where = "the fit's validation split" if cal.get("split") == "val" else ", ".join(cal.get("data") or [])
        same = cal.get("split") == "whole" and os.path.realpath(meta.get("data", "")) in {
            os.path.realpath(p) for p in cal.get("data") or []}
        lines.append(f"  std recalibrated by horizon ({cal['method']}) on {cal.get('n')} windows of {where}"
                     + (": this store, so its coverage here is in-sample" if same else ""))
    if horizons and "horizons" in res:
        lines += ["RMS error by horizon (step k: k dt after the last context sample):", horizon_markdown(res["horizons"])]
    lines.append(f"written: {out}/ (metrics.json, metrics.csv, horizons.csv, table.md, *.png)")
    return "\n".join(lines)

