"""``python -m robomorph.calibrate``: rescale a Gaussian head's standard deviation by horizon.

    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt          # the fit's validation split
    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt --data data/ms_val.zarr
    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt --remove
    python -m robomorph.calibrate --ckpt runs/ms/checkpoints/best.ckpt --blend    # physics early, decoder late

Predicts the validation windows of the checkpoint (the robots its DataModule held out for
validation, read back from its stores; or a held-out store given with ``--data``) with the
head's own standard deviation, fits the per-step, per-channel scale of
:mod:`robomorph.inference.calibration` on them, and stores it in the checkpoint (atomically, in
place or into ``--out``). From then on ``Predictor.simulate(..., return_std=True)``,
``evaluate`` and the dashboard use the recalibrated spread; the mean prediction does not
change. A training store given whole as ``--data`` is refused: the model has seen those
robots, and its errors there are smaller than on robots it has not seen.

``--blend`` fits, on the same windows, the per-step weights of the model's physics prediction
against its decoder's (:mod:`robomorph.inference.blending`) and stores them (with the physics
backbone's record, for a model trained without one): a total-torque model then predicts
with the blend by default. Calibrate its std afterwards with a plain run.
"""

from __future__ import annotations

import copy
import os
import time
from dataclasses import replace

import numpy as np

from robomorph.core.atomic import check_replaceable
from robomorph.core.names import RECORDED_SWITCHES
from robomorph.evaluation import training_data
from robomorph.evaluation.horizons import error_curve, groups_for, parse_horizons
from robomorph.evaluation.requests import BlendConfig, CalibrateConfig, as_request
from robomorph.evaluation.scoring import Predictions, score_windows
from robomorph.evaluation.tables import POINTS_TEXT
from robomorph.evaluation.windows import EvaluationError, Window, check_patch, load_window, recipe_note, start_joints
from robomorph.inference.calibration import (CALIBRATION_KEY, POWER_MIN_WINDOWS, CalibrationError, SPREAD_SWITCHES,
                                         calibration_key, calibrations_entry, fit, outside_bands, read_calibrations)


def _read(ckpt: str, device: str | None, need_std: bool = True) -> tuple:
    """The checkpoint's Predictor and its record, from one read of the file (the record is what is written
    back, with the calibration or the blend added)."""
    from robomorph.inference.checkpoint import trained_of  # noqa: PLC0415  (torch only here)
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415
    from robomorph.model.files import read_model  # noqa: PLC0415  (a checkpoint or a model folder)

    record = read_model(ckpt)
    model, info = trained_of(record, ckpt)
    # As Predictor.from_checkpoint builds it, with its own copy of the data record: the switches a calibration
    # writes into the record reach the Predictor through its settings only, as they did with two reads.
    predictor = Predictor(model, device, copy.deepcopy(info))
    if need_std and not predictor.has_std:
        raise CalibrationError(f"{ckpt} has no Gaussian head, so it predicts no standard deviation to calibrate; "
                               "train one with --model.gaussian true --model.loss nll")
    return predictor, record


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
    # By content when the fit recorded fingerprints: a copy of a training store is one too.
    from robomorph.data.fingerprints import recorded_match  # noqa: PLC0415
    from robomorph.model.files import DATA_INFO_KEY  # noqa: PLC0415

    info = ckpt_dict.get(DATA_INFO_KEY) or {}
    if recorded_match(data, stores, info.get("store_fingerprints"), info.get("robot_hashes")) is not None:
        raise CalibrationError(f"{data} is a training store of this checkpoint, or holds its robots (same content): "
                               "the model has seen them, "
                               "so its errors there understate those on new robots; drop --data to use the fit's "
                               "validation split, or give a store of other robots")
    return [(data, None)], "whole"


def _windows(predictor, sources, n, context_len, horizon, offset, seed) -> Window:
    """The windows of all sources, as one window set (the attributes of the last store)."""
    parts = []
    left = n
    for path, rows in sources:
        if left is not None and left <= 0:
            break
        w = load_window(path, context_len, horizon, left, predictor.data_info, predictor.n_u, predictor.n_y, offset,
                        seed, predictor.inputs, rows=rows)
        parts.append(w)
        left = None if left is None else left - len(w.u)
    if len(parts) == 1:
        return parts[0]
    joined = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("u", "y", "params", "starts", "y_first")}
    return replace(parts[-1], **joined)


def _fitting_windows(ckpt: str, predictor, sources, split: str, n, context_len, horizon, offset, seed: int,
                     what: str) -> tuple[Window, dict]:
    """The windows a calibration or a blend is fitted on (the checkpoint's training window by
    default), and the provenance they are stored with; ``what`` names a window in the refusal."""
    info = predictor.data_info or {}
    context_len, horizon = context_len or info.get("context_len"), horizon or info.get("horizon")
    if context_len is None or horizon is None:
        raise EvaluationError(f"{ckpt} does not record its training window: pass --context-len and --horizon")
    check_patch(predictor.patch, [int(context_len)])
    w = _windows(predictor, sources, n, int(context_len), int(horizon), offset, seed)
    if len(w.u) < 2:
        raise CalibrationError(f"only {len(w.u)} {what}: pass --data with a store of more robots")
    source = {"data": [p for p, _ in sources], "split": split, "n": int(len(w.u)), "context_len": int(context_len),
              "horizon": int(horizon), "offset": offset, "seed": int(seed), "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    if note := recipe_note(predictor.physics, w.attrs):  # kept with the calibration, printed with the report
        source["recipe_note"] = note
    return w, source


def calibrate(config: CalibrateConfig, *args, **kwargs) -> dict:
    """Fits the calibration and writes the checkpoint with it to ``config.out`` (default: in place).

    Each physics mode of a hybrid keeps its own calibration (a hybrid's std depends on how the robot is
    identified), and so does each setting of its observer, springs and debiasing, and each window kind:
    windows from the start, and windows that do not open their trajectory (``offset`` random or a step).
    Calibrating one leaves the others' in place.

    Args:
        config: the request, its fields documented there (:class:`robomorph.evaluation.requests.CalibrateConfig`);
            the call of earlier releases, ``calibrate(ckpt, data, ...)``, still works with a DeprecationWarning.

    Returns:
        A report: the calibration's provenance, and the ±1σ/±2σ coverage of the calibration
        windows before and after at the reported steps.
    """
    from robomorph.inference.hybrid_std import drawn_points  # noqa: PLC0415

    c = as_request(CalibrateConfig, config, args, kwargs, "calibrate")
    predictor, ckpt_dict, changed = _calibrated_predictor(c)
    sources, split = _sources(ckpt_dict, c.data)
    w, source = _fitting_windows(c.ckpt, predictor, sources, split, c.n, c.context_len, c.horizon, c.offset, c.seed,
                                 "calibration window")
    if getattr(predictor, "physics", None) and c.offset != "start":
        w = moving_windows(w, c.offset)
        source["n"] = int(len(w.u))
    horizon = source["horizon"]
    steps = parse_horizons(c.horizons_spec, horizon, w.dt)
    with predictor.raw_std():
        before = score_windows(predictor, w, (), steps, batch_size=c.batch_size)
        points = drawn_points(predictor)  # the spread fitted on (the stored calibrations' or the one chosen)
    mean, std = before.preds["model"], before.std
    source["normalization"] = predictor.normalization
    if getattr(predictor, "physics", None):
        # A hybrid's std depends on how it identifies the robot: the calibration is that mode's.
        s = predictor.settings_in_effect
        source.update(physics_mode=s.mode, **{name: getattr(s, name) for _, name in SPREAD_SWITCHES})
    cal = fit(before.y, mean, std, c.method, source=source, end=dense_at_end(predictor), points=points)
    after = score_windows(Predictions(mean, cal.scaled(std)), w, (), steps)
    report = _report(c.ckpt, c.out, cal, w.dt, horizon, steps, before, after)
    if changed:  # said, since every later prediction of the checkpoint changes with them
        report["defaults_changed"] = changed
    ckpt_dict[CALIBRATION_KEY] = calibrations_entry({**read_calibrations(ckpt_dict.get(CALIBRATION_KEY)),
                                                     calibration_key(cal): cal})
    _write(ckpt_dict, c.out or c.ckpt)
    return report


def dense_at_end(predictor) -> bool:
    """Whether a calibration of ``predictor`` places its knots as dense at the horizon's end as at its start
    (:func:`robomorph.inference.calibration.end_dense_knots`): every hybrid prediction. Log-spaced knots give the last
    one a band on its left only (the last sixth of the horizon), whose errors are smaller than the last step's
    wherever they grow, the scale then held flat to the end. A smoothed horizon's errors grow fastest there (no
    later torque pins its last steps); a forward simulation's keep growing. Measured on the command hybrid
    (``regression+obs``, ``power`` fitted on 768 robots, scored on 1,024 others): the joints' ±2σ coverage at the
    last step rose from 92.0 to 92.8 % from random offsets and from 91.6 to 91.9 % from the start, the earlier
    steps within 0.3 points (a screening: ``results/benchmarks/spread_knots_{random,start}.md`` at commit 3704ae7, CHANGELOG)."""
    return bool(getattr(predictor, "physics", None))


def _report(ckpt: str, out: str | None, cal, dt: float, horizon: int, steps: list[int], before, after) -> dict:
    """What a calibration did: its record and the windows' coverage and NLL before and after (kept in it too)."""
    factors, powers = cal.factors(horizon), cal.powers(horizon)
    report = {"ckpt": ckpt, "out": out or ckpt, "calibration": cal.to_dict(), "steps": steps,
              "seconds": [s * dt for s in steps],
              "before": before.result["horizons"]["calibration"]["all"],
              "after": after.result["horizons"]["calibration"]["all"],
              "nll": {"before": before.result["calibration"]["nll"]["all"],
                      "after": after.result["calibration"]["nll"]["all"]},
              "scale": [float(np.median(factors[s - 1])) for s in steps],
              "power": None if cal.power is None else [float(np.median(powers[s - 1])) for s in steps],
              # Unchanged by the calibration: a positive scale and power keep each channel's ranking of the windows.
              "skill": before.result["horizons"]["skill"]["all"]}
    cal.source["coverage"] = {"steps": steps, "before": report["before"], "after": report["after"]}
    return report


def _calibrated_predictor(c: CalibrateConfig) -> tuple:
    """The predictor to calibrate, set up as asked, the checkpoint's record, and the default switches changed
    (``["payload off"]``): the switches asked for (:data:`robomorph.core.names.RECORDED_SWITCHES`) written into its
    physics record (refused where they cannot apply, or where the calibrated mode does not use them)."""
    from robomorph.model.files import DATA_INFO_KEY  # noqa: PLC0415

    predictor, ckpt_dict = _read(c.ckpt, c.device)
    predictor.use_physics(c.physics)
    predictor.configure(points=c.points)
    record = (ckpt_dict.get(DATA_INFO_KEY) or {}).get("physics") if predictor.model.config.n_params else None
    gravity = ((predictor.physics or {}).get("recipe") or {}).get("gravity_compensation")
    changed: list[str] = []
    for name in RECORDED_SWITCHES:
        on = getattr(c, name)
        if on is None:
            continue
        if not record or (predictor.inputs != "command" and name not in ("payload", "coulomb")):
            raise CalibrationError(f"--{name} needs a {'' if name in ('payload', 'coulomb') else 'command-formulation '}"
                                   "model trained with --model.physics amortized")
        # The switch is the checkpoint's default for every mode: one the calibrated mode does not use would change
        # the model's default predictions and calibrate nothing (--physics none --payload off moved them 2.8e-4 rad).
        if not getattr(predictor.settings.replace(**{name: True}).in_effect(predictor.inputs, gravity), name):
            raise CalibrationError(f"--{name} {'on' if on else 'off'}: physics mode {predictor.settings.mode} does not "
                                   f"use the {name} switch, so it would change the checkpoint's default predictions "
                                   "and no calibration; drop it, or calibrate a mode that uses it (--physics regression)")
        if bool(record.get(name, False)) != bool(on):
            changed.append(f"{name} {'on' if on else 'off'}")
        record[name] = bool(on)
        predictor.configure(**{name: bool(on)})
    return predictor, ckpt_dict, changed


def moving_windows(w: Window, offset) -> Window:
    """The windows that do not open their trajectory: what a hybrid's calibration from ``offset``
    (random or a step) is for. Those that drew the start are the other kind's."""
    rows = w.starts > 0
    if rows.sum() < 2:
        raise CalibrationError(f"--offset {offset}: {int(rows.sum())} of {len(rows)} windows start after their "
                               f"trajectory's first step (context {w.context_len} + horizon {w.horizon} steps leave "
                               "little room): shorten --horizon, or give a store of longer trajectories")
    return w.rows(rows)


def blend(config: BlendConfig, *args, **kwargs) -> dict:
    """Fits the physics/decoder blend (:mod:`robomorph.inference.blending`) and writes the checkpoint
    with it to ``config.out`` (default: in place); the request is a
    :class:`robomorph.evaluation.requests.BlendConfig` (the call of earlier releases, ``blend(ckpt, ...)``,
    still works with a :class:`DeprecationWarning`). Its ``physics``: the physics prediction blended
    (:data:`robomorph.inference.blending.PHYSICS_MODES`; ``smoothed`` needs a model with a Gaussian head;
    None: ``smoothed`` where it has one, else ``regression``).

    Returns:
        A report: where it was fitted, the weights and the joints' RMS error of the physics,
        the decoder and the blend on the fitting windows at the reported steps.
    """
    from robomorph.evaluation.sources import predict  # noqa: PLC0415
    from robomorph.inference.blending import BLEND_KEY, HorizonBlend, fit_blend  # noqa: PLC0415

    c = as_request(BlendConfig, config, args, kwargs, "blend")
    ckpt, batch_size = c.ckpt, c.batch_size
    predictor, ckpt_dict = _read(ckpt, c.device, need_std=False)
    if predictor.leaks_query_statistics:
        raise CalibrationError(f"{ckpt} rescales each window with its query outputs (paper_window): a blend needs a "
                               "model that can be deployed; train with data.normalization=train_stats")
    sources, split = _sources(ckpt_dict, c.data)
    layout = _blend_layout(predictor, sources[0][0])
    w, source = _fitting_windows(ckpt, predictor, sources, split, c.n, c.context_len, c.horizon, c.offset, c.seed,
                                 "window to fit a blend on")
    u_ctx, y_ctx, u_q, y_q = w.split()
    rest = w.starts == 0 if len(w.starts) == len(w.u) else None
    predictor.configure(mode="none")
    anchor = start_joints(w)  # where each robot started, as the scoring path gives it
    decoder = predict(predictor, u_ctx, y_ctx, u_q, batch_size, "decoder", at_rest=rest)
    # The physics alone: a blend that weights it fully (the decoder where a simulation diverged).
    gaussian = bool(getattr(predictor.model, "gaussian", False))
    physics = c.physics or ("smoothed" if gaussian else "regression")
    if physics == "smoothed" and not gaussian:
        raise CalibrationError(f"{ckpt} has no Gaussian head, which the smoothed physics weighs its decoder by: "
                               "use --blend-physics regression")
    predictor.model.blend = HorizonBlend((1,), (tuple([1.0] * predictor.n_y),), physics=layout, physics_mode=physics)
    predictor.physics, predictor.has_std = layout, False  # the blend brings the backbone
    predictor.configure(mode="blend")
    sim = predict(predictor, u_ctx, y_ctx, u_q, batch_size, "physics", at_rest=rest, anchor=anchor)
    own = (predictor.data_info or {}).get("physics") and predictor.model.config.n_params  # its record has it
    fitted = fit_blend(y_q, sim, decoder, source=source, layout=None if own else layout, physics_mode=physics)
    steps = parse_horizons(c.horizons_spec, source["horizon"], w.dt)
    mixed = fitted.combine(sim, decoder)[0]
    joints = next(g for g in groups_for(w.y_names) if g.name == "joints")
    rms = {k: [float(error_curve(y_q, v, joints)[s - 1]) for s in steps]
           for k, v in (("physics", sim), ("decoder", decoder), ("blend", mixed))}
    fitted.source["joint_rms_mrad"] = {"steps": steps, **rms}
    fitted.source["gated_windows"] = int(fitted.gated(sim, decoder)[:, -1].sum())
    ckpt_dict[BLEND_KEY] = fitted.to_dict()
    _write(ckpt_dict, c.out or ckpt)
    weights = fitted.weights(source["horizon"])[:, list(joints.channels)]
    return {"ckpt": ckpt, "out": c.out or ckpt, "blend": fitted.to_dict(), "steps": steps,
            "seconds": [s * w.dt for s in steps], "weight": [float(np.mean(weights[s - 1])) for s in steps],
            "rms": rms}


def _blend_layout(predictor, store: str) -> dict:
    """The model's physics backbone, or for a model trained without one its store's (simulated
    Panda stores that record each robot's parameters)."""
    from robomorph.data.store import open_store  # noqa: PLC0415
    from robomorph.identification.backbone import BackboneError, parameter_layout  # noqa: PLC0415

    if predictor.physics:
        return predictor.physics
    try:
        return parameter_layout(dict(open_store(store).attrs))
    except BackboneError:
        raise CalibrationError(f"--blend needs a physics backbone, and {store} is not a simulated Panda store that "
                               "records each robot's parameters (real logs have no catalogue robot to simulate): "
                               "keep the decoder alone") from None


def blend_text(report: dict) -> str:
    """The terminal summary of :func:`blend`."""
    from robomorph.core.results import markdown_table  # noqa: PLC0415

    src, r = report["blend"]["source"], report["rms"]
    rows = [[s, f"{t:.3g}", f"{report['weight'][i]:.2f}", f"{r['physics'][i]:.4g}", f"{r['decoder'][i]:.4g}",
             f"{r['blend'][i]:.4g}"] for i, (s, t) in enumerate(zip(report["steps"], report["seconds"]))]
    return "\n".join([
        f"physics/decoder blend fitted on {src['n']} windows of {', '.join(src['data'])} "
        f"({'validation split' if src['split'] == 'val' else 'whole store'}), context {src['context_len']}, "
        f"horizon {src['horizon']}; gate {report['blend']['gate']:g} x the decoder's RMS error "
        f"({src['gated_windows']} of {src['n']} windows gated before the end: their physics' weight lowered or gone)",
        markdown_table(["step", "seconds", "physics weight (joints)", "physics [mrad]", "decoder [mrad]",
                        "blend [mrad]"], rows),
        "(joint RMS error on the fitting windows themselves; score it on a test store with robomorph evaluate; "
        "calibrate the blend's std with a plain robomorph calibrate)",
        *([f"note: {src['recipe_note']}"] if src.get("recipe_note") else []),
        f"written: {report['out']}"])


def remove(ckpt: str, out: str | None = None, physics: str | None = None) -> bool:
    """Drops the stored calibrations, or with ``physics`` that mode's only (writing ``out``, default
    in place); False when there was none."""
    from robomorph.model.files import read_model  # noqa: PLC0415  (a checkpoint or a model folder)

    ckpt_dict = read_model(ckpt)
    kept = read_calibrations(ckpt_dict.pop(CALIBRATION_KEY, None))
    # Both window kinds of a mode, with and without the observer.
    dropped = [k for k in kept if physics is None or k.split("/")[0].partition("+")[0] == physics]
    had = bool(dropped)
    kept = {k: c for k, c in kept.items() if k not in dropped}
    if kept:
        ckpt_dict[CALIBRATION_KEY] = calibrations_entry(kept)
    if had or (out and os.path.abspath(out) != os.path.abspath(ckpt)):
        _write(ckpt_dict, out or ckpt)
    return had


def _write(ckpt_dict: dict, path: str) -> None:
    """The checkpoint (or model folder), written whole or not at all, in the format it was read in."""
    from robomorph.model.files import write_model  # noqa: PLC0415

    if not os.path.isdir(path):  # a model folder's own writer guards what it replaces
        check_replaceable(path, "checkpoint", "--out")  # never a page, a log or a store's file
    write_model(ckpt_dict, path)


def report_text(report: dict) -> str:
    """The terminal summary: where it was fitted, and the coverage before and after."""
    from robomorph.core.results import markdown_table  # noqa: PLC0415

    src = report["calibration"]["source"]
    secs = report.get("seconds") or [None] * len(report["steps"])
    b, a = report["before"], report["after"]
    power, skill = report.get("power"), report.get("skill")
    rows = [[s, "" if t is None else f"{t:.3g}", f"{report['scale'][i]:.3g}",
             *([f"{power[i]:.3g}"] if power else []), f"{b['1sigma'][i]:.1%}",
             f"{a['1sigma'][i]:.1%}", f"{b['2sigma'][i]:.1%}", f"{a['2sigma'][i]:.1%}",
             *(["" if skill[i] is None else f"{skill[i]:.2f}"] if skill else [])]
            for i, (s, t) in enumerate(zip(report["steps"], secs))]
    lines = [f"std calibration ({report['calibration']['method']}) fitted on {src['n']} windows of "
             f"{', '.join(src['data'])} ({'validation split' if src['split'] == 'val' else 'whole store'}), "
             f"context {src['context_len']}, horizon {src['horizon']}"
             + ("" if src.get("offset", "start") == "start" else f", windows from offset {src['offset']}")
             + (f", physics mode {src['physics_mode']}" if src.get("physics_mode") else "")
             + (" with the observer's start velocity" if src.get("observer") else "")
             + (", the springs fitted" if src.get("springs") else "") + (", its bias taken off" if src.get("debias") else "")
             + (", offsets fitted" if src.get("offsets") else "")
             + (", friction beyond the box" if src.get("coulomb") else "") + (", a payload fitted" if src.get("payload") else "")
             + (", the context's noise smoothed" if src.get("denoise") else "")
             + (f", std over {POINTS_TEXT[p]}" if (p := report["calibration"].get("points")) in POINTS_TEXT else ""),
             markdown_table(["step", "seconds", "scale (median over channels)", *(["power (median)"] if power else []),
                             "±1σ before", "±1σ after", "±2σ before", "±2σ after",
                             *(["spread-error rank corr."] if skill else [])], rows)]
    if src.get("recipe_note"):
        lines.append(f"note: {src['recipe_note']}")
    if report.get("defaults_changed"):
        lines.append(f"note: the checkpoint's default switches are now {', '.join(report['defaults_changed'])}: "
                     "its default predictions change with them")
    missed = outside_bands(a["1sigma"], a["2sigma"])
    if missed:
        lines.append(_tails_note(report, missed))
    if report["calibration"]["method"] == "power" and src["n"] < POWER_MIN_WINDOWS:
        lines.append(f"the spread's power stays 1 (a scale alone) on fewer than {POWER_MIN_WINDOWS} windows: "
                     "pass --data with a store of more held-out robots to fit it")
    if "nll" in report:
        lines.append(f"mean Gaussian NLL per value over the horizon: {report['nll']['before']:.4g} before, "
                     f"{report['nll']['after']:.4g} after")
    lines.append("(coverage on the calibration windows themselves; ideal 68.3 % / 95.4 %; score it on a test "
                 "store with robomorph.evaluate)")
    lines.append(f"written: {report['out']}")
    return "\n".join(lines)


def _tails_note(report: dict, missed: list[int]) -> str:
    """Why the calibration windows themselves leave a band after the fit: heavy tails, and how well the
    spread ranks the windows by their errors (:func:`robomorph.evaluation.horizons.spread_skill`)."""
    steps = ", ".join(str(report["steps"][i]) for i in missed)
    skill = [v for i, v in enumerate(report.get("skill") or []) if i in missed and v is not None]
    ranked = "" if not skill else (f"; the spread ranks the windows by their errors with a rank correlation of "
                                   f"{min(skill):.2f}-{max(skill):.2f} there, and a scale common to all windows "
                                   "cannot widen only those whose spread is too small for their errors")
    return (f"at step(s) {steps} the errors are heavier-tailed than a Gaussian's: no scale of this spread puts both "
            f"±1σ and ±2σ within 68.3 ± 5 % / 95.4 ± 3 % of these windows{ranked}")
