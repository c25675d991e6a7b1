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

import copy
import os

from robomorph.core.atomic import write_json
from robomorph.core.locks import output_folder
from robomorph.core.normalizations import NormalizationError
from robomorph.core.progress import progress
from robomorph.core.results import provenance
from robomorph.core.rundir import RunDir
from robomorph.evaluation import plots as eval_plots
from robomorph.evaluation import references, training_data
from robomorph.evaluation.baselines import BASELINES
from robomorph.evaluation.horizons import horizon_markdown, parse_horizons
from robomorph.evaluation.scoring import Scores, score_windows
from robomorph.evaluation.sources import check_baselines
from robomorph.evaluation.tables import (cost_note, diverged_note, smoothing_note, write_csv, write_horizons_csv,
                                         write_table)

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


def sweep_horizon(predictor, w: Window, horizons: list[int], baselines: dict, batch_size: int) -> list[dict]:
    """Mean R^2 / FIT (approaches 1 and 2) for each horizon, same context; the baselines'
    predictions (causal) are those of the full horizon, cut."""
    rows = []
    for h in progress(horizons, "horizon sweep", unit="setting"):
        # Means alone: a sweep reports R² and FIT, and a hybrid's std costs many simulations more.
        s = score_windows(predictor, w.cut(horizon=h), (), [], others=baselines, batch_size=batch_size, score_std=False)
        rows.append({"horizon": h, **{src: s.summary(src) for src in s.preds}})
    return rows


def sweep_context(predictor, w: Window, contexts: list[int], batch_size: int) -> list[dict]:
    """Mean R^2 / FIT (approaches 1 and 2) of the model and hold for each context length, same predicted window."""
    rows = []
    for c in progress(contexts, "context sweep", unit="setting"):
        s = score_windows(predictor, w.cut(context_len=c), ("hold",), [], batch_size=batch_size, score_std=False)
        rows.append({"context_len": c, "model": s.summary(), "hold": s.summary("hold")})
    return rows


def evaluate(ckpt: str, data: str, out: str, context_len: int | None = None, horizon: int | None = None,
             n: int | None = None, baselines: tuple[str, ...] = BASELINES, sweep_horizon_spec: str | None = None,
             sweep_context_spec: str | None = None, batch_size: int = 64, device: str | None = None,
             samples: int = 3, arx_orders: tuple[int, int] = (2, 2), seed: int = 0,
             normalization: str | None = None, horizons_spec: str | None = None,
             offset: str | int | None = "start", inputs: str | None = None,
             arx_train_data: list[str] | None = None, compare: dict[str, str] | None = None,
             physics: str | None = None) -> dict:
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
    predictor = _checked_predictor(ckpt, device, baselines, inputs, normalization, physics)
    info = predictor.data_info
    context_len = context_len or (info or {}).get("context_len")
    horizon = horizon or (info or {}).get("horizon")
    if context_len is None or horizon is None:
        raise EvaluationError(f"{ckpt} does not record its training window: pass --context-len and --horizon")
    w = load_window(data, int(context_len), int(horizon), n, info, predictor.n_u, predictor.n_y, offset, seed,
                    predictor.inputs)
    check_arm(predictor, w.attrs, data)
    predictor.channels = (w.u_names, w.y_names)  # an arm with fewer joints than a multi-arm model: padded
    steps = parse_horizons(horizons_spec, w.horizon, w.dt)
    horizons = parse_range(sweep_horizon_spec, 1, w.horizon, "horizon")
    contexts = parse_range(sweep_context_spec, 1, w.context_len, "context")
    check_patch(predictor.patch, [w.context_len, *contexts])
    # Checked before the output folder is made: a refused --compare leaves nothing behind.
    others = {name: references.load_other(name, other, w, device) for name, other in (compare or {}).items()}
    with output_folder(out, "evaluation") as tmp:  # refused, locked, and written whole or not at all
        return _score_and_write(predictor, w, tmp, ckpt, data, baselines, steps, others, arx_orders,
                                arx_train_data, batch_size, offset, seed, info, compare, horizons, contexts, samples)


def _score_and_write(predictor, w: Window, out: str, ckpt: str, data: str, baselines, steps, others, arx_orders,
                     arx_train_data, batch_size: int, offset, seed: int, info, compare, horizons, contexts,
                     samples: int) -> dict:
    """Scores the model and the baselines on ``w`` and writes every output file into ``out``."""
    scores = score_windows(predictor, w, tuple(baselines), steps, others=others, arx_orders=arx_orders,
                           train_blocks=training_data.reader(ckpt, arx_train_data), batch_size=batch_size)
    result = scores.result
    result["meta"] = {"ckpt": ckpt, "data": data, **result["meta"], "offset": offset, "seed": seed,
                      **in_sample(info, data), **_smoothing(predictor), **_physics(predictor)}  # (before the sweeps)
    result["meta"]["baseline_notes"].update({name: {"ckpt": path} for name, path in (compare or {}).items()})
    # A result folder says what made it (command, commit, date, machine), as every result file does.
    result["provenance"] = provenance()
    result["sweeps"] = _sweeps(predictor, w, horizons, contexts, _baseline_preds(scores), batch_size, out)
    eval_plots.write_all(out, w.split()[1], scores.y, scores.preds, w.y_names, w.dt, samples, seed,
                         std=scores.std, steps=result["horizons"]["steps"], y_units=w.attrs.get("y_units"))
    _write_files(out, result)
    return result


def check_arm(predictor, attrs: dict, where: str) -> None:
    """Refuses data of one registered arm (a store's ``domain``) for a model trained on others.

    Only registered arms are compared: a model or store of real logs (``domain`` a user's
    name) may be another robot of the same kind, and a transfer between them is the user's
    choice. Checkpoints that predate the record of their arms are let through.

    Raises:
        EvaluationError: the message names both arms and ``where`` the data come from.
    """
    from robomorph.inference.predictor_checks import model_arms  # noqa: PLC0415  (torch only here)
    from robomorph.sim import arms as registry  # noqa: PLC0415

    arm = registry.of_store(attrs)
    trained = [a for a in model_arms(predictor) if a in registry.ARMS]
    if arm is not None and trained and arm.name not in trained:
        raise EvaluationError(f"{where} is of the {arm.name} but the model was trained on the {', '.join(trained)}: "
                              "its predictions would be of another robot's dynamics; use a model trained on the "
                              f"{arm.name} (or on stores of several arms including it)")


def _checked_predictor(ckpt: str, device: str | None, baselines, inputs: str | None, normalization: str | None,
                       physics: str | None = None):
    """The checkpoint's Predictor, once the baselines, inputs and normalization asked for fit it,
    predicting in the physics mode asked for (a hybrid model's)."""
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415  (torch only here)

    check_baselines(baselines)
    predictor = Predictor.from_checkpoint(ckpt, device=device)
    predictor.check_inputs(inputs)
    if normalization is not None and normalization != predictor.normalization:
        raise NormalizationError(f"{ckpt} was trained with normalization {predictor.normalization!r}, not "
                                 f"{normalization!r}: the normalization is fixed at training time (data.normalization)")
    predictor.use_physics(physics)
    return predictor


def _write_files(out: str, result: dict) -> None:
    write_csv(os.path.join(out, "metrics.csv"), result)
    write_horizons_csv(os.path.join(out, "horizons.csv"), result["horizons"], result.get("provenance"))
    write_table(os.path.join(out, "table.md"), result)
    write_json(os.path.join(out, "metrics.json"), result)


def _physics(predictor) -> dict:
    """``{"physics": how a hybrid predicted}`` (mode, observer, friction-mixture members and whether the mode
    uses the mixture, physics steps per sample after the first second, None: the default; the robots its std
    is the spread of, None: none drawn), else {} (a black-box model, or its decoder)."""
    if not getattr(predictor, "physics", None) or predictor.physics_mode == "none":
        return {}
    from robomorph.inference.hybrid import MIXED_MODES  # noqa: PLC0415
    from robomorph.inference.hybrid_std import debiasing, drawn_points, observing, springing  # noqa: PLC0415

    mixture = predictor.inputs == "command" and predictor.physics_mode in MIXED_MODES and predictor.physics_members > 1
    return {"physics": {"mode": predictor.physics_mode, "observer": observing(predictor), "springs": springing(predictor),
                        "debias": debiasing(predictor), "mixture": mixture,
                        "members": predictor.physics_members, "substeps": predictor.physics_substeps,
                        "points": drawn_points(predictor)}}


def _smoothing(predictor) -> dict:
    """``{"smoothing": tally}`` where the smoothed physics predicted (a copy), else {}."""
    # The hybrid exists once a physics mode has predicted (it is built on first use).
    tally = getattr(getattr(predictor, "_hybrid", None), "smoothing", None)
    return {"smoothing": copy.deepcopy(tally)} if tally and tally["windows"] else {}


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


def _baseline_preds(scores: Scores) -> dict:
    """Every source's predictions but the model's (the sweeps cut them to shorter horizons)."""
    return {name: p for name, p in scores.preds.items() if name != "model"}


def in_sample(info: dict | None, data: str) -> dict:
    """``{"in_sample": bool, "in_sample_store": the training store or None}``: whether ``data``
    is one of the checkpoint's training stores, by content fingerprint (a copy elsewhere
    counts) or holds any of their trajectories (a store of the training seed with more robots),
    or, for checkpoints that predate fingerprints, by path. Its scores then measure
    how well the model fits robots it was trained on, not how it generalizes."""
    from robomorph.data.fingerprints import recorded_match  # noqa: PLC0415

    info = info or {}
    match = recorded_match(data, list(info.get("stores") or []), info.get("store_fingerprints"), info.get("robot_hashes"))
    return {"in_sample": match is not None, "in_sample_store": match}


IN_SAMPLE_NOTE = ("in-sample: this store is one the model was trained on ({store}), so these scores include "
                  "robots it has seen; evaluate on held-out robots for generalization")


def default_out(ckpt: str, data: str) -> str:
    """``<run>/eval/<store name>`` for a checkpoint in ``<run>/checkpoints/`` (or a model folder in ``<run>/``)."""
    return RunDir.of_checkpoint(os.path.join(ckpt, "config.json") if os.path.isdir(ckpt) else ckpt).eval_dir(data)


def summary_text(res: dict, out: str, horizons: bool = True) -> str:
    """A few lines for the terminal: mean approach-1 scores of the model and the baselines,
    then (with ``horizons``) the RMS errors by horizon in physical units."""
    m, meta = res["approach1"]["mean"], res["meta"]
    lines = [f"{meta['n']} trajectories, context {meta['context_len']}, horizon {meta['horizon']}, "
             f"inputs {meta.get('inputs', 'total')} (approach 1 mean):"]
    if res.get("leaks_query_statistics"):
        lines.append(f"  normalization {meta.get('normalization')}: scores use the query outputs' statistics (the "
                     "paper's protocol), not those of a deployable model")
    if meta.get("in_sample"):
        lines.append("  " + IN_SAMPLE_NOTE.format(store=meta.get("in_sample_store")))
    lines.append(f"  {'model':18s} R2 {m['r2']['mean']:8.3f}  FIT {m['fit']['mean']:8.2f}  RMSE {m['rmse']['mean']:.4g}")
    notes = meta.get("baseline_notes", {})
    for b, r in res["baselines"].items():
        mb = r["approach1"]["mean"]
        lines.append(f"  {b:18s} R2 {mb['r2']['mean']:8.3f}  FIT {mb['fit']['mean']:8.2f}  RMSE {mb['rmse']['mean']:.4g}"
                     + (f"  ({note})" if (note := diverged_note(notes.get(b, {}), meta["n"])) else "")
                     + (f"  ({note})" if (note := cost_note(notes.get(b, {}))) else ""))
    lines += [f"  skipped {b}: {why}" for b, why in res["skipped_baselines"].items()]
    if note := smoothing_note(meta.get("smoothing")):
        lines.append(f"  {note}")
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

