"""``python -m robomorph.evaluate``: a trained meta-model, or a catalogue arm's untrained hybrid, beside the baselines.

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

import numpy as np

from robomorph.core.atomic import write_json
from robomorph.core.errors import RoboMorphError
from robomorph.core.locks import output_folder
from robomorph.core.normalizations import NormalizationError
from robomorph.core.progress import Phase, progress
from robomorph.core.results import provenance
from robomorph.evaluation import plots as eval_plots
from robomorph.evaluation import references, training_data
from robomorph.evaluation.horizons import horizon_markdown, parse_horizons
from robomorph.evaluation.requests import EvaluateConfig, as_request, default_out  # noqa: F401  (default_out: re-exported)
from robomorph.evaluation.scoring import Scores, score_windows
from robomorph.evaluation.tables import (cost_note, diverged_note, smoothing_note, write_csv, write_horizons_csv,
                                         write_table)

# Window, EvaluationError and parse_range re-exported: callers import them from here.
from robomorph.evaluation.windows import (  # noqa: F401
    EvaluationError,
    Window,
    check_patch,
    load_window,
    parse_offset,
    parse_range,
    recipe_note,
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


def evaluate(config: EvaluateConfig, *args, **kwargs) -> dict:
    """Evaluates a checkpoint (or a catalogue arm's untrained hybrid) on a store and writes every output
    file into ``config.out_dir``.

    ``arx_train`` is fitted on the checkpoint's training split (read back from its stores),
    or on the whole of the ``arx_train_data`` stores when given (an arm has no training split).
    ``compare`` names other checkpoints scored beside the baselines on the same data. The
    checkpoint is read once: the model and the training split both come from that one record.

    Args:
        config: the request (:class:`robomorph.evaluation.requests.EvaluateConfig`, validated when built).
            The call of earlier releases, ``evaluate(ckpt, data, out, n=..., ...)``, still works with a
            :class:`DeprecationWarning`, its arguments named as the config's fields.

    Returns:
        The ``metrics.json`` content.
    """
    cfg = as_request(EvaluateConfig, config, args, kwargs, "evaluate")
    predictor, record = _checked_predictor(cfg)
    info = predictor.data_info
    context_len = cfg.context_len or (info or {}).get("context_len")
    horizon = cfg.horizon or (info or {}).get("horizon")
    if context_len is None or horizon is None:
        raise EvaluationError(f"{cfg.ckpt} does not record its training window: pass --context-len and --horizon")
    w = load_window(cfg.data, int(context_len), int(horizon), cfg.n, predictor.data_info, predictor.n_u,
                    predictor.n_y, cfg.offset, cfg.seed, predictor.inputs)
    check_arm(predictor, w.attrs, cfg.data)
    predictor.stack = stacks(cfg.stacked, w.attrs)
    predictor.channels = (w.u_names, w.y_names)  # an arm with fewer joints than a multi-arm model: padded
    steps = parse_horizons(cfg.horizons_spec, w.horizon, w.dt)
    horizons = parse_range(cfg.sweep_horizon_spec, 1, w.horizon, "horizon")
    contexts = parse_range(cfg.sweep_context_spec, 1, w.context_len, "context")
    check_patch(predictor.patch, [w.context_len, *contexts])
    # Checked before the output folder is made: a refused --compare leaves nothing behind.
    others = {name: references.load_other(name, other, w, cfg.device) for name, other in cfg.compare}
    for other in others.values():  # compared like for like: stacked when the evaluated model is
        other.stack = predictor.stack
    train_blocks = training_data.reader(record, list(cfg.arx_train_data) or None, predictor.inputs,
                                        "a catalogue arm's hybrid" if cfg.arm else "the checkpoint")
    # Another arm's stores refused here, and the evaluated store itself noted: an ARX fitted on the robots it
    # is scored on (0.048 against 0.12 mrad on the probe's) is no reference.
    arx_in_sample = training_data.check_stores(list(cfg.arx_train_data), cfg.data, w.attrs, w.y_names, len(w.u_names)) \
        if set(cfg.baselines) & set(ARX_TRAINED) else None
    with output_folder(cfg.out_dir, "evaluation") as tmp:  # refused, locked, and written whole or not at all
        return _score_and_write(predictor, w, tmp, cfg, steps, others, train_blocks, info, horizons, contexts,
                                arx_in_sample)


# The baselines fitted on training data (--arx-train-data, else the checkpoint's training split).
ARX_TRAINED = ("arx_train", "accel_arx_train")


def _score_and_write(predictor, w: Window, out: str, cfg: EvaluateConfig, steps, others, train_blocks, info,
                     horizons, contexts, arx_in_sample: str | None = None) -> dict:
    """Scores the model and the baselines on ``w`` and writes every output file into ``out``; ``arx_in_sample``:
    the --arx-train-data store that is the evaluated one (its ARX baselines noted in-sample)."""
    scores = score_windows(predictor, w, cfg.baselines, steps, others=others, arx_orders=cfg.arx_orders,
                           train_blocks=train_blocks, batch_size=cfg.batch_size)
    result = scores.result
    if note := recipe_note(predictor.physics, w.attrs):  # a hybrid of another gravity-compensation recipe
        result["meta"]["recipe_note"] = note
    for name in ARX_TRAINED:
        if arx_in_sample and name in result["meta"]["baseline_notes"]:
            result["meta"]["baseline_notes"][name].update(in_sample=True, in_sample_store=arx_in_sample)
    result["meta"] = {"ckpt": cfg.model, "data": cfg.data, **result["meta"], "offset": cfg.offset, "seed": cfg.seed,
                      **in_sample(info, cfg.data), **_smoothing(predictor), **_physics(predictor)}  # (before the sweeps)
    result["meta"]["context_check"] = context_check(predictor, w)
    result["meta"]["stacked"] = predictor.stack is not None
    if cfg.arm:  # what was evaluated, beside the "arm:<name>" that stands for the checkpoint
        result["meta"]["catalogue_arm"] = cfg.arm
    result["meta"]["baseline_notes"].update({name: {"ckpt": path} for name, path in cfg.compare})
    # A result folder says what made it (command, commit, date, machine), as every result file does.
    result["provenance"] = provenance()
    result["sweeps"] = _sweeps(predictor, w, horizons, contexts, _baseline_preds(scores), cfg.batch_size, out)
    # Matplotlib takes tens of seconds on a loaded machine: a phase of its own, so nothing is silent.
    with Phase("plots", total=None, unit="figure"):
        eval_plots.write_all(out, w.split()[1], scores.y, scores.preds, w.y_names, w.dt, cfg.samples, cfg.seed,
                             std=scores.std, steps=result["horizons"]["steps"], y_units=w.attrs.get("y_units"))
    _write_files(out, result)
    return result


# Windows whose contexts the evaluation backtests (one extra prediction of the model on each: cheap beside the scoring).
CHECK_WINDOWS = 16


def context_check(predictor, w: Window) -> dict:
    """The context backtest (:meth:`robomorph.inference.predictor.Predictor.check`) on the first windows' contexts:
    per step, the model's median backtest error relative to constant velocity's, the winner, and how many contexts the
    model explains worse than hold at every step (another formulation, other units, another arm)."""
    import warnings  # noqa: PLC0415

    from robomorph.inference.stacking import StackedPredictor  # noqa: PLC0415

    u_ctx, y_ctx, _, _ = w.split()
    n = min(CHECK_WINDOWS, len(u_ctx))
    try:
        # A model's fold is one more prediction of it: a phase that reports while it runs, as every other.
        with warnings.catch_warnings(), Phase("context check", total=None, unit="context"):
            warnings.simplefilter("ignore")  # said once, in the summary line, not per window
            joints = [i for i, name in enumerate(w.y_names) if name.startswith("q")] or None
            def plain(u, y, uq):  # the model's own prediction, stacked or not in the scoring
                return predictor.simulate(u, y, uq, stacked=False)

            check = StackedPredictor(plain, w.dt, patch=predictor.patch, decide_on=joints).check(u_ctx[:n], y_ctx[:n])
    except RoboMorphError as exc:
        return {"windows": 0, "note": f"not run: {exc}"}
    names = check.names
    if "model" not in names:
        return {"windows": n, "note": "; ".join(check.notes) or "the model was not backtested"}
    steps = sorted({1, max(1, check.reach // 4), max(1, check.reach // 2), check.reach})
    m, cv = names.index("model"), names.index("constant_velocity")
    rel = {int(k): float(np.nanmedian(check.rmse[:, m, k - 1] / np.maximum(check.rmse[:, cv, k - 1], 1e-300)))
           for k in steps}
    return {"windows": n, "steps": steps, "model_over_constant_velocity": rel,
            "winner": {int(k): check.winners(k)[0] for k in steps},
            "unexplained": int((~check.explained["model"]).sum())}


def stacks(choice: str, attrs: dict) -> bool:
    """Whether ``evaluate --stacked choice`` stacks the model on a store with ``attrs``: ``auto`` on recordings of a
    real robot (a store ``robomorph ingest`` wrote), where the stack never loses to kinematics by more than a few
    percent and the models alone lose to them (``results/benchmarks/stacking.md``), and not on simulated stores,
    where the model predicts 10-30 times better than kinematics past the backtest's reach (1.67 s of a 200-sample
    context at 60 Hz) and the stack, with no evidence there, fades into them (CHANGELOG, issue 62)."""
    return choice == "on" or (choice == "auto" and attrs.get("task") == "ingested")


def context_check_note(check: dict | None) -> str | None:
    """The summary's line of :func:`context_check`."""
    if not check:
        return None
    if "note" in check:
        return f"context check: {check['note']}"
    rel = ", ".join(f"step {k} {r:.3g}" for k, r in check["model_over_constant_velocity"].items())
    line = (f"context check ({check['windows']} contexts backtested on themselves): model / constant velocity {rel}; "
            f"winners {', '.join(f'{k}: {v}' for k, v in check['winner'].items())}")
    if check["unexplained"]:
        line += (f". WARNING: the model explains {check['unexplained']} of {check['windows']} contexts worse than hold "
                 "at every step: another input formulation, other units, or another arm?")
    return line


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


def _checked_predictor(cfg: EvaluateConfig):
    """The Predictor asked for, once the inputs and normalization asked for fit it, predicting in the physics
    mode asked for (a hybrid model's); and the checkpoint's record without its weights (None for an arm): what
    the training split is read back from, so the file is read once."""
    from robomorph.inference.checkpoint import trained_of  # noqa: PLC0415  (torch only here)
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415
    from robomorph.model.files import read_model  # noqa: PLC0415

    if cfg.arm:
        predictor, record = _arm_predictor(cfg), None
    else:
        record = read_model(cfg.ckpt)
        model, info = trained_of(record, cfg.ckpt)
        predictor = Predictor(model, cfg.device, info)  # as Predictor.from_checkpoint builds it
        record = {k: v for k, v in record.items() if k != "state_dict"}  # the weights live in the model now
    predictor.check_inputs(cfg.inputs)
    if cfg.normalization is not None and cfg.normalization != predictor.normalization:
        raise NormalizationError(f"{cfg.ckpt} was trained with normalization {predictor.normalization!r}, not "
                                 f"{cfg.normalization!r}: the normalization is fixed at training time "
                                 "(data.normalization)")
    predictor.use_physics(cfg.physics)
    if cfg.arm:
        from robomorph.inference.catalogue import check_network_free  # noqa: PLC0415

        check_network_free(predictor)  # a mode that reads a network: refused before any folder is made
    return predictor, record


def _arm_predictor(cfg: EvaluateConfig):
    """The catalogue hybrid of ``cfg.arm`` built with the recipe the store records (its physics step, gravity
    compensation and randomization ranges), once the store is a simulation of that arm; for a real log in the
    arm's layout (``ingest --layout ARM``, ``ingest --rosbag --layout ARM``), the arm at the log's rate with no
    gravity compensation of its own, driven by the logged total torque (:func:`robomorph.evaluation.physics.recipe_of`)."""
    from robomorph.data.store import open_store  # noqa: PLC0415
    from robomorph.evaluation.physics import recipe_of  # noqa: PLC0415
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415

    attrs = dict(open_store(cfg.data, allow_incomplete=True).attrs)
    logged = attrs.get("task") == "ingested" and attrs.get("arm") is not None
    if logged:
        arm, recipe = arms.ARMS.get(str(attrs["arm"])), recipe_of(attrs).to_dict()
    else:
        arm, recipe = arms.of_store(attrs), attrs.get("config")
    if arm is None or not isinstance(recipe, dict):
        raise EvaluationError(f"--robot {cfg.arm}: {cfg.data} is not a store simulated from a registered arm's recipe "
                              f"nor a log in a registered arm's layout (domain {attrs.get('domain')!r}): the catalogue "
                              "hybrid needs the recipe its data follow; ingest logs with --layout ARM, or evaluate a "
                              "model trained on these data with --ckpt")
    if arm.name != cfg.arm:
        raise EvaluationError(f"--robot {cfg.arm}: {cfg.data} is of the {arm.name}; its hybrid would predict another "
                              f"robot's dynamics: use --robot {arm.name}")
    inputs = cfg.inputs or ("total" if logged else "command")  # a log's torque is the total one
    if inputs == "command" and "u_cmd" not in open_store(cfg.data, allow_incomplete=True).arrays:
        raise EvaluationError(f"--robot {cfg.arm}: {cfg.data} holds no u_cmd (the command formulation the catalogue "
                              "hybrid takes by default): regenerate the store, or pass --inputs total")
    # The recipe's fields as the store records them (its robot included): the hybrid a store of it would train.
    return Predictor.from_arm(cfg.arm, device=cfg.device, inputs=inputs, **recipe)


def _write_files(out: str, result: dict) -> None:
    write_csv(os.path.join(out, "metrics.csv"), result)
    write_horizons_csv(os.path.join(out, "horizons.csv"), result["horizons"], result.get("provenance"))
    write_table(os.path.join(out, "table.md"), result)
    write_json(os.path.join(out, "metrics.json"), result)


def _physics(predictor) -> dict:
    """``{"physics": how a hybrid predicted}`` (mode, observer, friction-mixture members and whether the mode
    uses the mixture, physics steps per sample after the first second, None: the default; the robots its std
    is the spread of, None: none drawn), else {} (a black-box model, or its decoder)."""
    if not getattr(predictor, "physics", None) or predictor.settings.mode == "none":
        return {}
    from robomorph.inference.hybrid import MIXED_MODES  # noqa: PLC0415
    from robomorph.inference.hybrid_std import drawn_points  # noqa: PLC0415

    s = predictor.settings_in_effect
    mixture = predictor.inputs == "command" and s.mode in MIXED_MODES and s.members > 1
    return {"physics": {"mode": s.mode, "observer": s.observer, "springs": s.springs, "debias": s.debias,
                        "mixture": mixture, "members": s.members, "substeps": s.substeps,
                        "points": drawn_points(predictor), "key": s.key}}


def _smoothing(predictor) -> dict:
    """``{"smoothing": tally}`` where the smoothed physics predicted (a copy), else {}."""
    tally = getattr(predictor, "smoothing", None)  # None before its hybrid smoothed (and for baselines)
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


def arx_in_sample_note(note: dict) -> str | None:
    """The line that says a baseline was fitted on the store it is scored on (``in_sample`` of its notes)."""
    if not note.get("in_sample"):
        return None
    return (f"in-sample: fitted on {note.get('in_sample_store')}, which holds the robots it is scored on; pass "
            "--arx-train-data stores of other robots for a reference")


IN_SAMPLE_NOTE = ("in-sample: this store is one the model was trained on ({store}), so these scores include "
                  "robots it has seen; evaluate on held-out robots for generalization")


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
    if meta.get("recipe_note"):
        lines.append("  " + meta["recipe_note"])
    lines.append(f"  {'model':18s} R2 {m['r2']['mean']:8.3f}  FIT {m['fit']['mean']:8.2f}  RMSE {m['rmse']['mean']:.4g}")
    notes = meta.get("baseline_notes", {})
    for b, r in res["baselines"].items():
        mb = r["approach1"]["mean"]
        lines.append(f"  {b:18s} R2 {mb['r2']['mean']:8.3f}  FIT {mb['fit']['mean']:8.2f}  RMSE {mb['rmse']['mean']:.4g}"
                     + (f"  ({note})" if (note := diverged_note(notes.get(b, {}), meta["n"])) else "")
                     + (f"  ({note})" if (note := cost_note(notes.get(b, {}))) else ""))
    lines += [f"  {b}: {note}" for b in res["baselines"] if (note := arx_in_sample_note(notes.get(b, {})))]
    lines += [f"  skipped {b}: {why}" for b, why in res["skipped_baselines"].items()]
    if note := smoothing_note(meta.get("smoothing")):
        lines.append(f"  {note}")
    if note := context_check_note(meta.get("context_check")):
        lines.append(f"  {note}")
    if meta.get("stacked"):
        lines.append("  model: stacked with hold, constant velocity and constant acceleration by each window's context "
                     "backtest, its std measured there (--stacked; off: the model alone)")
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

