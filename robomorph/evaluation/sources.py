"""The predictions a scoring compares: the model's (in batches) and the baselines' on a window set.

Any object with ``simulate(u_ctx, y_ctx, u_query)`` returning ``(N, H, n_y)`` can be the
predictor (a :class:`robomorph.inference.predictor.Predictor`, a stand-in in a test, another
checkpoint); ``return_std=True`` is asked for only when it accepts it.
"""

from __future__ import annotations

import copy
import inspect

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.core.normalizations import NormalizationError, query_output_stats
from robomorph.core.progress import Phase, progress
from robomorph.evaluation import references
from robomorph.evaluation.baselines import ARX, BASELINES, CEILINGS, KINEMATIC, OPT_IN, AccelARX
from robomorph.evaluation.windows import EvaluationError, Window, start_joints

# Windows a hybrid predicts at once in an evaluation: each takes a second or more on a loaded machine, so progress
# moves every few seconds (a batch of 32 showed "0/1 batch" for three minutes), and its two workers still share each.
HYBRID_BATCH = 8


def predict(predictor, u_ctx, y_ctx, u_query, batch_size: int, desc: str = "model", y_query=None,
            with_std: bool = False, at_rest=None, anchor=None):
    """The model's predictions in batches, with progress on stderr (:mod:`robomorph.core.progress`).

    ``y_query`` (the true outputs) is read only by a ``paper_window`` model, which needs
    their statistics (the paper's protocol); any other model never receives them.
    ``at_rest`` (N,) bools, the windows that open their trajectory, goes to a hybrid model
    (one with a physics backbone), whose simulation then starts at rest; ``anchor`` (N, 7), where
    each robot started (its springs' rest pose), goes to it too.

    Returns:
        (N, H, n_y) means, or with ``with_std`` the pair (means, standard deviations).
    """
    leaks = getattr(predictor, "leaks_query_statistics", False)
    if leaks and y_query is None:
        raise NormalizationError("a paper_window model needs the query outputs' statistics: pass y_query to predict()")
    means, stds = [], []
    # A hybrid takes them, and a residual model hands them to its hybrid.
    residual = getattr(predictor, "residual", None) is not None
    hybrid = getattr(predictor, "physics", None) or residual
    if residual or (hybrid and getattr(getattr(predictor, "settings", None), "mode", "none") != "none"):
        # A second or more a window on a loaded machine: smaller batches, so that progress moves.
        batch_size = min(batch_size, HYBRID_BATCH)
    with Phase(desc, len(u_ctx), "window") as phase:
        for s in range(0, len(u_ctx), batch_size):
            part = slice(s, s + batch_size)
            mean, std = _batch(predictor, u_ctx, y_ctx, u_query, part, y_query, with_std, at_rest, anchor, hybrid)
            means.append(mean)
            if with_std:
                stds.append(std)
            phase.update(len(mean))
    mean = np.concatenate(means).astype(np.float64)
    return (mean, np.concatenate(stds).astype(np.float64)) if with_std else mean


def _batch(predictor, u_ctx, y_ctx, u_query, part: slice, y_query, with_std: bool, at_rest, anchor, hybrid: bool):
    """One batch's (mean, std or None)."""
    kwargs = _extra(predictor, y_query, part, with_std)
    if at_rest is not None and hybrid:
        kwargs["at_rest"] = np.asarray(at_rest)[part]
    if anchor is not None and hybrid:
        kwargs["anchor"] = np.asarray(anchor)[part]
    out = predictor.simulate(u_ctx[part], y_ctx[part], u_query[part], **kwargs)
    return (out[0], out[1]) if with_std else (out, None)


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
    kept = copy.deepcopy(getattr(predictor, "smoothing", None))  # a hybrid's tally of smoothed windows
    try:
        params = inspect.signature(predictor.simulate).parameters
        if "return_std" not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            return False
        # A hybrid's one window can take seconds: reported like any other phase.
        with Phase("model (std probe)", total=1, unit="window") as phase:
            out = predictor.simulate(u_ctx[:1], y_ctx[:1], u_query[:1], **_extra(predictor, y_query, slice(0, 1), True))
            phase.update()
    except (NotImplementedError, RoboMorphError, ValueError, TypeError):
        return False
    finally:
        # The probe is not one of the windows: a hybrid's tally of smoothed windows forgets it.
        if getattr(predictor, "smoothing", None) is not None:
            from robomorph.identification.smoother import new_report  # noqa: PLC0415

            predictor.smoothing = kept or new_report()
    return isinstance(out, tuple) and len(out) == 2 and out[1] is not None


def check_baselines(names) -> None:
    """Refuses a baseline name that is not one of :data:`BASELINES`, :data:`OPT_IN` or :data:`CEILINGS`."""
    for name in names:
        if name not in BASELINES + OPT_IN + CEILINGS:
            raise EvaluationError(f"unknown baseline {name!r}; choose from {BASELINES + OPT_IN + CEILINGS}")


def run_baselines(w: Window, names: tuple[str, ...], arx_orders: tuple[int, int],
                  train_blocks=None) -> tuple[dict, dict, dict]:
    """Predictions of the baselines that apply, the reasons of those skipped, and notes.

    ``train_blocks``: a function returning the training data as ``(u, y)`` blocks (for
    ``arx_train``; see :mod:`robomorph.evaluation.training_data`).
    """
    check_baselines(names)
    u_ctx, y_ctx, u_q, _ = w.split()
    preds, skipped, notes = {}, {}, {}
    for name in names:
        if name in KINEMATIC:
            try:
                preds[name] = KINEMATIC[name](u_ctx, y_ctx, u_q).astype(np.float64)
            except ValueError as exc:  # a context too short to difference
                skipped[name] = str(exc)
        elif name in ("arx", "arx_train"):
            try:
                arx = ARX(*arx_orders) if name == "arx" else references.fit_arx_train(arx_orders, train_blocks)
                preds[name] = arx(u_ctx, y_ctx, u_q)
                notes[name] = {"na": arx.na, "nb": arx.nb, "diverged_held": arx.diverged}
                if name == "arx_train":
                    notes[name]["trajectories"] = arx.trajectories
            except ValueError as exc:  # too short a context, or no training data to read
                skipped[name] = str(exc)
        elif name in ("accel_arx", "accel_arx_train"):
            try:
                model = AccelARX() if name == "accel_arx" else references.fit_accel_arx_train(train_blocks)
                preds[name] = model(u_ctx, y_ctx, u_q)
                notes[name] = {"diverged_held": model.diverged}
                if name == "accel_arx_train":
                    notes[name]["trajectories"] = model.trajectories
            except ValueError as exc:  # too short a context, or no training data to read
                skipped[name] = str(exc)
        elif name in ("identified_physics", "identified_physics_springs"):
            from robomorph.evaluation.identified import config_of, predict_windows  # noqa: PLC0415
            from robomorph.evaluation.physics import NotApplicable  # noqa: PLC0415

            try:  # notes: the cost per window
                preds[name], notes[name] = predict_windows(w, config_of(name), anchors=nominal_params)
            except NotApplicable as exc:
                skipped[name] = str(exc)
        else:  # nominal_physics, true_physics
            from robomorph.evaluation.physics import NominalPhysics, NotApplicable, check_params  # noqa: PLC0415

            try:
                sim = NominalPhysics(w.attrs, inputs=w.inputs)
                if name == "true_physics":
                    check_params(w.attrs)
            except NotApplicable as exc:
                skipped[name] = str(exc)
                continue
            params = w.params if name == "true_physics" else nominal_params(sim, w)
            preds[name] = _batched(sim, u_ctx, y_ctx, u_q, name.replace("_", " "), params=params)
    return preds, skipped, notes


def nominal_params(sim, w: Window) -> np.ndarray | None:
    """Nominal parameters with the joint springs anchored where each robot started (its
    trajectory's first sample), as the generator anchored them; None (the simulator anchors
    at the context's first sample) when every window opens its trajectory, where they agree."""
    q = start_joints(w, sim.n_joint)  # NominalPhysics checked the arm's layout (q0..q{n-1} in y)
    return None if q is None else np.stack([sim.params(q0) for q0 in q])


def _batched(fn, u_ctx, y_ctx, u_q, desc: str, size: int = 16, params=None) -> np.ndarray:
    parts = [fn(u_ctx[s:s + size], y_ctx[s:s + size], u_q[s:s + size],
                params=None if params is None else params[s:s + size])
             for s in progress(range(0, len(u_ctx), size), desc, unit="batch")]
    return np.concatenate(parts).astype(np.float64)
