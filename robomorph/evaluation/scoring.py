"""The one scoring path: any predictor and chosen baselines on one set of windows.

    from robomorph.evaluation.scoring import score_windows
    from robomorph.evaluation.windows import load_window

    w = load_window("data/ms_test.zarr", 200, 800, None, pred.data_info, pred.n_u, pred.n_y)
    s = score_windows(pred, w, baselines=("hold", "nominal_physics"), steps="1,0.25s,1s,5s,end")
    s.result["approach1"]["mean"]["r2"]["mean"]     # the model's approach-1 R²
    s.at("model", "joints", 15)                     # joint RMS error [mrad] at step 15
    s.curve("hold", "ee_pos")                       # (H,) hold's EE position error [mm], step k at [k - 1]

``robomorph evaluate``, ``robomorph calibrate``, the demo, the training-time scoring of
the benchmarks and every benchmark script call :func:`score_windows`; nothing else computes
the errors, so the numbers agree wherever they are printed.

Step convention (as :mod:`robomorph.evaluation.horizons`): step ``k`` is 1-based, the
``k``-th predicted sample, ``k * dt`` after the last context sample; a time ``t`` is step
``round(t / dt)`` (0.25 s at 60 Hz: step 15; 5 s: step 300). ``curve(...)[k - 1]`` is step ``k``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from robomorph.core.normalizations import leaks_query_statistics
from robomorph.evaluation import metrics
from robomorph.evaluation.horizons import (
    Group,
    HorizonError,
    coverage_miss,
    error_curve,
    gaussian_nll,
    groups_for,
    horizon_report,
    parse_horizons,
)
from robomorph.evaluation.sources import gives_std, predict, run_baselines
from robomorph.evaluation.windows import Window, start_joints

MODEL = "model"


@dataclass
class Scores:
    """What :func:`score_windows` measured.

    Attributes:
        result: JSON-able: ``approach1``/``approach2`` of the model (when one was scored),
            ``baselines`` (the same per baseline and other source), ``skipped_baselines``,
            ``horizons`` (RMS errors at ``steps`` in physical units, ``below``: shares of
            steps where the model beats each source, ±1σ/±2σ coverage at ``steps``),
            ``calibration`` (with a std: ``nll`` and ``coverage_miss``), ``window_starts``
            and ``meta``. This is the ``metrics.json`` of ``robomorph evaluate`` less its
            sweeps and run information.
        preds: every source's (N, H, n_y) predictions (the model's under ``model``).
        std: the model's (N, H, n_y) standard deviation, or None.
        y: the (N, H, n_y) true query outputs.
        groups: the quantities errors are reported for (:func:`robomorph.evaluation.horizons.groups_for`).
    """

    result: dict
    preds: dict[str, np.ndarray]
    std: np.ndarray | None
    y: np.ndarray
    groups: list[Group]
    _curves: dict = field(default_factory=dict, repr=False)

    def group(self, quantity: str) -> Group:
        for g in self.groups:
            if g.name == quantity:
                return g
        raise KeyError(f"no quantity {quantity!r}; these windows have {[g.name for g in self.groups]}")

    def curve(self, source: str, quantity: str) -> np.ndarray:
        """(H,) RMS error over the windows at every step in the quantity's unit; index ``k - 1`` is step ``k``."""
        key = (source, quantity)
        if key not in self._curves:
            self._curves[key] = error_curve(self.y, self.preds[source], self.group(quantity))
        return self._curves[key]

    def at(self, source: str, quantity: str, step: int) -> float:
        """The RMS error at 1-based ``step`` (:meth:`curve` ``[step - 1]``)."""
        if not 1 <= step <= self.y.shape[1]:
            raise HorizonError(f"step {step} is outside the scored horizon 1..{self.y.shape[1]}")
        return float(self.curve(source, quantity)[step - 1])

    def summary(self, source: str = MODEL) -> dict:
        """Channel-mean ``r2``/``fit`` by approach 1 and ``r2_a2``/``fit_a2`` by approach 2 of a source."""
        res = self.result if source == MODEL else self.result["baselines"][source]
        a1, a2 = res["approach1"]["mean"], res["approach2"]["mean"]
        return {"r2": a1["r2"]["mean"], "fit": a1["fit"]["mean"], "r2_a2": a2["r2"], "fit_a2": a2["fit"]}


@dataclass
class Predictions:
    """Predictions already made, scored as the model: ``mean`` (N, >= H, n_y) and optionally
    ``std`` (the same shape), e.g. one prediction scored with several std calibrations."""

    mean: np.ndarray
    std: np.ndarray | None = None
    normalization: str | None = None


def resolve_steps(steps: str | Sequence[int] | None, horizon: int, dt: float) -> list[int]:
    """1-based steps from a ``--horizons`` text (:func:`parse_horizons`; None: its default) or a list of steps.

    Raises:
        HorizonError: a step outside ``1..horizon``.
    """
    if steps is None or isinstance(steps, str):
        return parse_horizons(steps, horizon, dt)
    out = sorted({int(k) for k in steps})
    if out and not (1 <= out[0] and out[-1] <= horizon):
        raise HorizonError(f"steps {out} must lie within 1..{horizon} (step k is k dt after the last context sample)")
    return out


def score_windows(predictor, windows: Window, baselines: Sequence[str] = ("hold",),
                  steps: str | Sequence[int] | None = None, *, others: dict | None = None,
                  arx_orders: tuple[int, int] = (2, 2), train_blocks=None, batch_size: int = 64,
                  score_std: bool = True) -> Scores:
    """Scores a predictor and baselines on the same windows.

    Args:
        predictor: anything with ``simulate(u_ctx, y_ctx, u_query)`` (a :class:`Predictor`, the model being
            trained, a stand-in), :class:`Predictions` already made, or None to score the baselines alone.
            When it gives a standard deviation, its calibration is scored too.
        windows: the context and query windows (:func:`robomorph.evaluation.windows.load_window`).
        baselines: names of :data:`robomorph.evaluation.baselines.BASELINES` (and
            ``identified_physics``, ``true_physics``); one that does not apply is skipped
            with its reason.
        steps: where the per-step errors are reported: 1-based steps or a ``--horizons``
            text such as ``"1,0.25s,1s,5s,end"`` (default that one); full curves are in
            :meth:`Scores.curve` either way.
        others: further sources scored like the baselines: name -> a predictor, or an
            (N, >= H, n_y) array of predictions already made (cut to the horizon).
        arx_orders: ``(na, nb)`` of ``arx`` and ``arx_train``.
        train_blocks: reads the training data for ``arx_train``
            (:func:`robomorph.evaluation.training_data.reader`).
        batch_size: trajectories per model call.
        score_std: score the model's standard deviation when it gives one (default); False predicts the means
            alone, for scores that read no std (a sweep's R² and FIT): a hybrid's std costs many more
            simulations than its mean.
    """
    w = windows
    u_ctx, y_ctx, u_q, y_q = w.split()
    y_q = y_q.astype(np.float64)
    steps = resolve_steps(steps, w.horizon, w.dt)
    preds, std, seconds = {}, None, None
    if isinstance(predictor, Predictions):
        preds[MODEL] = np.asarray(predictor.mean, dtype=np.float64)[:, :w.horizon]
        std = None if predictor.std is None else np.asarray(predictor.std, dtype=np.float64)[:, :w.horizon]
    elif predictor is not None:
        preds[MODEL], std, seconds = _model(predictor, w, y_q, batch_size, score_std)
    base, skipped, notes = run_baselines(w, tuple(baselines), arx_orders, train_blocks)
    for name, other in (others or {}).items():
        base[name] = (np.asarray(other, dtype=np.float64)[:, :w.horizon] if isinstance(other, np.ndarray)
                      else predict(other, u_ctx, y_ctx, u_q, batch_size, desc=name, y_query=y_q))
    preds.update(base)
    names, units = w.y_names, w.attrs.get("y_units")
    result = {}
    if MODEL in preds:
        result.update(_approaches(y_q, preds[MODEL], names))
    result.update({"baselines": {b: _approaches(y_q, p, names) for b, p in base.items()},
                   "skipped_baselines": skipped,
                   "horizons": horizon_report(y_q, preds, names, w.dt, steps, std, units),
                   "window_starts": w.starts.tolist(),
                   "meta": {**_meta(predictor, w, notes, std), "seconds_per_window": seconds}})
    groups = groups_for(names, units)
    if std is not None:
        result["calibration"] = _calibration(y_q, preds[MODEL], std, groups)
    if predictor is not None:
        # The paper's protocol scales each window with its query outputs' statistics: say so first.
        result["leaks_query_statistics"] = leaks_query_statistics(result["meta"]["normalization"])
    return Scores(result, preds, std, y_q, groups)


def _model(predictor, w: Window, y_q: np.ndarray, batch_size: int, score_std: bool):
    """The model's (N, H, n_y) means, its std (None: not asked for, or none given) and its cost per window [s]."""
    u_ctx, y_ctx, u_q, _ = w.split()
    at_rest = w.starts == 0 if len(w.starts) == len(u_ctx) else None  # the generator starts at rest
    # anchor: where each robot started, as the physics baselines are given it (sources.nominal_params)
    kwargs = {"y_query": y_q, "at_rest": at_rest, "anchor": start_joints(w)}
    with_std, t0 = score_std and gives_std(predictor, u_ctx, y_ctx, u_q, y_q), time.perf_counter()
    out = predict(predictor, u_ctx, y_ctx, u_q, batch_size, with_std=with_std, **kwargs)
    seconds = (time.perf_counter() - t0) / len(u_ctx)  # the model's cost per window, as identified physics' notes
    mean, std = out if with_std else (out, None)
    return mean, std, seconds


def _approaches(y: np.ndarray, yhat: np.ndarray, names: list[str]) -> dict:
    return {"approach1": metrics.approach1(y, yhat, names), "approach2": metrics.approach2(y, yhat, names)}


def _calibration(y: np.ndarray, mean: np.ndarray, std: np.ndarray, groups: list[Group]) -> dict:
    """Whole-horizon calibration: the mean NLL per value and the mean miss of the ±kσ coverage."""
    return {"nll": {"all": gaussian_nll(y, mean, std), **{g.name: gaussian_nll(y, mean, std, g.channels) for g in groups}},
            "coverage_miss": {"all": coverage_miss(y, mean, std),
                              **{g.name: coverage_miss(y, mean, std, g.channels) for g in groups}}}


def _meta(predictor, w: Window, notes: dict, std) -> dict:
    return {"context_len": w.context_len, "horizon": w.horizon, "n": len(w.u), "dt": w.dt, "y_names": w.y_names,
            "u_names": w.u_names, "device": str(getattr(predictor, "device", "")), "baseline_notes": notes,
            "domain": w.attrs.get("domain"), "task": w.attrs.get("task"),
            "normalization": getattr(predictor, "normalization", None), "std": std is not None, "inputs": w.inputs,
            "std_calibration": _calibration_meta(predictor) if std is not None else None}


def _calibration_meta(predictor) -> dict | None:
    """Where the stored std calibration was fitted (``robomorph.calibrate``), or None."""
    cal = getattr(predictor, "calibration", None)
    if cal is None:
        return None
    src = {k: v for k, v in cal.source.items() if k != "coverage"}
    return {"method": cal.method, **src}
