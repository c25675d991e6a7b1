"""Every prediction checked on its own context: the context backtest, horizon-wise stacking and an honest std.

The context is a record of this very robot. :class:`StackedPredictor` splits it: each *fold* keeps the context up to
a cut and predicts the samples after it, with every candidate on the same samples (hold, constant velocity, constant
acceleration, and a model where one is given: the hybrid, the black box, any ``simulate``-like callable). From the
folds' errors, step by step:

- **Weights per horizon step.** A softmin over the candidates' pooled log mean square errors (a candidate
  ``temperature`` worse in log MSE gets ``1/e`` of the weight) whose prior is a robust default, hotter where fewer
  folds reach the step (``evidence`` folds' worth of prior). The default is kinematic: constant velocity fading into
  hold with time constant ``default_tau`` seconds. Smooth in every input: no argmin decides a prediction.
- **Beyond the backtest's reach** (the context minus its shortest fold), the last step's weights fade into the
  default as ``K / k``: a short-horizon choice is never carried to long horizons without evidence.
- **The std** of the stacked prediction at step ``k``: the weighted mean square of the candidates' backtest errors per
  channel (an upper bound of the combination's own error, by convexity), smoothed over neighbouring steps; beyond the
  reach it grows as ``(k / K) ** p`` with ``p`` fitted on the reach's second half (clipped to ``[0.5, 2]``). It is
  measured on the robot's own record: no simulation in the loop.

The model is backtested on ``model_folds`` folds only (each costs one prediction: the default one keeps the whole
stack within twice the plain prediction); its pooled error is transferred through its ratio to constant velocity on
those folds, so candidates are compared on the same samples. :class:`ContextCheck` says per horizon which candidate
won on the context and by how much, and warns when the model does not explain the context at all (another input
formulation, wrong units, another arm): its backtest error above hold's at every step.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.inference.kinematics import KINEMATIC

# Relative floor of a channel's scale in the pooled error (a joint that never moved in the context weighs as a
# channel moving by this share of the busiest channel's spread).
_SCALE_FLOOR = 1e-3
# Normalized RMS errors below this are ties (a context at rest); the softmin's prior gives every candidate this share
# beside the default's weights, so that evidence can still pick it.
_TIE_FLOOR, _OPEN_SHARE = 1e-6, 0.2
# A model's query prediction further from constant velocity's than this many times the gap the backtest measured
# between them loses its weight (a Gaussian gate: :meth:`StackedPredictor._gated`).
_GATE = 3.0


class StackingError(RoboMorphError, ValueError):
    """Settings or arrays the context backtest cannot work with."""


@dataclass(frozen=True)
class StackConfig:
    """How the context is backtested and the candidates stacked.

    Attributes:
        min_context: the share of the context every fold keeps (the rest is what the folds predict).
        folds: cut points for the kinematic candidates (free to backtest).
        model_folds: cut points for the model (each costs one of its predictions); 0: the model is not stacked.
        temperature: the softmin's temperature over log mean square errors.
        evidence: folds' worth of prior at each step: the softmin's temperature is ``temperature (1 + evidence /
            folds reaching the step)``.
        default_tau: seconds over which the default's constant velocity fades into hold.
        smooth: the relative half-width of the window over which per-step errors are pooled (``k/(1+s)`` to
            ``k (1+s)``): a step's vote is its neighbours' too.
        warn: warn (``warnings.warn``) when the model explains the context worse than hold at every step.
    """

    min_context: float = 0.5
    folds: int = 16
    model_folds: int = 1
    temperature: float = 0.5
    evidence: float = 2.0
    default_tau: float = 3.0
    smooth: float = 0.25
    warn: bool = True

    def __post_init__(self) -> None:
        bad = []
        if not 0.1 <= self.min_context <= 0.9:
            bad.append(f"min_context {self.min_context} (0.1 to 0.9)")
        if not 1 <= self.folds <= 64:
            bad.append(f"folds {self.folds} (1 to 64)")
        if not 0 <= self.model_folds <= self.folds:
            bad.append(f"model_folds {self.model_folds} (0 to folds)")
        for name in ("temperature", "default_tau"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                bad.append(f"{name} {value} (a finite number > 0)")
        for name in ("evidence", "smooth"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                bad.append(f"{name} {value} (a finite number >= 0)")
        if bad:
            raise StackingError("stacking settings out of range: " + "; ".join(bad))


@dataclass
class ContextCheck:
    """What the backtest found on a batch of contexts.

    Attributes:
        names: the candidates, kinematic first, then the model (``model``) where there is one.
        dt: the sample time [s].
        rmse: (B, C, K) each window's pooled normalized RMS error of each candidate at backtest steps 1..K.
        weights: (B, C, H) the stacked prediction's weights at each query step (or the backtest's K steps).
        folds: the cut points of the kinematic folds, and of each model's (by name).
        explained: per model, (B,) False where its backtest error is above hold's at every step.
    """

    names: list[str]
    dt: float
    rmse: np.ndarray
    weights: np.ndarray
    folds: tuple[list[int], dict]
    explained: dict
    notes: list[str] = field(default_factory=list)

    @property
    def reach(self) -> int:
        """The backtest's longest step (K)."""
        return self.rmse.shape[2]

    def winners(self, step: int) -> tuple[str, float]:
        """The candidate with the lowest median (over windows) backtest error at 1-based ``step`` (capped at the
        reach), and how much lower it is than the runner-up (a ratio >= 1)."""
        k = min(step, self.reach) - 1
        med = np.nanmedian(self.rmse[:, :, k], axis=0)
        order = np.argsort(med)
        second = med[order[1]] if len(order) > 1 else med[order[0]]
        return self.names[int(order[0])], float(second / max(med[order[0]], 1e-300))

    def summary(self, steps: list[int] | None = None) -> str:
        """A table: per reported step, each candidate's median backtest error relative to constant velocity's,
        the winner, and the stacked prediction's mean weights."""
        reach = self.reach
        steps = sorted({s for s in (steps or _default_steps(reach, self.dt)) if 1 <= s <= reach})
        ref = self.names.index("constant_velocity")
        models = "; ".join(f"{k}: {v}" for k, v in self.folds[1].items()) or "no model"
        lines = [f"context backtest: {len(self.rmse)} window(s), folds at {self.folds[0]} ({models}), reach {reach} "
                 f"steps ({reach * self.dt:.3g} s)",
                 "step  time[s]  " + "  ".join(f"{n[:12]:>12s}" for n in self.names) + "  winner (by)"]
        for s in steps:
            med = np.nanmedian(self.rmse[:, :, s - 1], axis=0)
            rel = med / max(med[ref], 1e-300)
            name, by = self.winners(s)
            lines.append(f"{s:4d}  {s * self.dt:7.3g}  " + "  ".join(f"{r:12.3g}" for r in rel)
                         + f"  {name} ({by:.2f}x)")
        lines.append("(errors relative to constant velocity's, median over windows; weights: "
                     + ", ".join(f"{n} {w:.2f}" for n, w in zip(self.names, self.weights[:, :, 0].mean(0)))
                     + " at step 1)")
        for name, ok in self.explained.items():
            if not ok.all():
                lines.append(f"WARNING: {name} explains {int((~ok).sum())} of {len(ok)} context(s) worse than hold at "
                             "every step: another input formulation (total torques to a command model?), other units, "
                             "or another arm")
        lines.extend(self.notes)
        return "\n".join(lines)


def _default_steps(reach: int, dt: float) -> list[int]:
    return [1] + [int(round(t / dt)) for t in (0.05, 0.1, 0.25, 0.5, 1.0, 2.0) if round(t / dt) > 1] + [reach]


Model = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class StackedPredictor:
    """Models (or none) stacked with kinematic extrapolation by the context backtest.

    Args:
        model: ``f(u_ctx, y_ctx, u_query) -> (B, H, n_y)`` (a :class:`robomorph.inference.predictor.Predictor`'s
            ``simulate``, any callable alike), named ``model``; or several, ``{name: f}`` or ``{name: (f, folds)}``
            (a cheap one, a per-context ARX, can afford as many folds as the kinematic candidates); or None: the
            kinematic candidates alone.
        dt: the sample time [s] (the default's fading is in seconds).
        config: :class:`StackConfig`.
        patch: the model's context lengths must be multiples of this (a Predictor's ``patch``).
        min_model_context: the shortest context the model is given in a fold.
        decide_on: the output channels whose errors set the weights (indices; default every channel): an arm's
            joint angles, which :meth:`of` picks from the model's channel names.
    """

    def __init__(self, model: Model | dict | None, dt: float, config: StackConfig | None = None, patch: int = 1,
                 min_model_context: int = 3, decide_on=None):
        if not (math.isfinite(dt) and dt > 0):
            raise StackingError(f"dt must be a finite number of seconds > 0, got {dt}")
        # name -> (callable, folds): one model is "model" on ``config.model_folds`` folds
        self.dt, self.config = float(dt), config or StackConfig()
        models = {} if model is None else (dict(model) if isinstance(model, dict) else {"model": model})
        self.models = {}
        for name, entry in models.items():
            fn, folds = entry if isinstance(entry, tuple) else (entry, self.config.model_folds)
            if name in KINEMATIC or not callable(fn) or not 0 <= int(folds) <= 64:
                raise StackingError(f"candidate {name!r}: give a callable (and 0 to 64 folds) under a name other "
                                    f"than {', '.join(KINEMATIC)}")
            self.models[name] = (fn, int(folds))
        self.patch, self.min_model_context = max(1, int(patch)), int(min_model_context)
        # The channels whose errors set the weights (the joint angles of an arm: an end-effector quaternion's channels
        # outvoted them on the Kinova-format logs), every channel where None.
        self.decide_on = None if decide_on is None else np.asarray(list(decide_on), dtype=int)
        self.last_check: ContextCheck | None = None
        self.learned: dict | None = None  # name -> (H,) prior weights from training recordings (:meth:`learn`)
        self.learned_mse: dict | None = None

    @classmethod
    def of(cls, predictor, config: StackConfig | None = None, model: Model | None = None) -> "StackedPredictor":
        """A :class:`robomorph.inference.predictor.Predictor` stacked: its plain ``simulate`` (never its stacked one,
        whatever its ``stack`` setting), or ``model`` in its place, with its rate, patch and joint channels."""
        dt = float((predictor.data_info or {}).get("dt", 0) or 0)
        if not dt > 0:
            raise StackingError("this model records no sample time (data_info dt): build "
                                "StackedPredictor(predictor.simulate, dt=...) with the logs' rate")
        # The channels it predicts: an arm's own where a model of several arms was given fewer (``channels``).
        channels = getattr(predictor, "channels", None)
        names = list((channels[1] if channels else None) or (predictor.data_info or {}).get("y_names") or [])
        joints = [i for i, n in enumerate(names) if n.startswith("q")] or None
        if model is None:
            def model(u, y, uq):
                return predictor.simulate(u, y, uq, stacked=False)
        return cls(model, dt, config, getattr(predictor, "patch", 1), decide_on=joints)

    @property
    def names(self) -> list[str]:
        return list(KINEMATIC) + list(self.models)

    # ------------------------------------------------------------------ the backtest
    def _cuts(self, t: int) -> tuple[list[int], dict[str, list[int]]]:
        """The kinematic folds' cut points, and each model's (the first at the shortest context it may read, the
        others spread toward the context's end)."""
        cfg = self.config
        lo = max(3, int(math.ceil(cfg.min_context * t)))
        if t - lo < 1:
            raise StackingError(f"a context of {t} samples leaves nothing to backtest: give at least "
                                f"{int(math.ceil(4 / (1 - cfg.min_context)))} samples")
        kin = sorted({int(round(c)) for c in np.linspace(lo, t - 1, cfg.folds)})
        first = int(math.ceil(max(lo, self.min_model_context) / self.patch) * self.patch)
        span = list(range(first, t, self.patch))
        models = {}
        for name, (_, folds) in self.models.items():
            picks = np.linspace(0, len(span) - 1, folds + 1)[:-1] if folds > 1 else [0] * folds
            models[name] = sorted({span[int(round(i))] for i in picks}) if span else []
        return kin, models

    def _fold_errors(self, fn: Model, u: np.ndarray, y: np.ndarray, cuts: list[int], reach: int,
                     scale: np.ndarray) -> np.ndarray:
        """(F, B, K, n_y) squared errors (normalized by ``scale``) of ``fn`` on each fold; NaN past a fold's end."""
        t = y.shape[1]
        out = np.full((len(cuts), len(y), reach, y.shape[2]), np.nan)
        for f, c in enumerate(cuts):
            h = min(reach, t - c)
            pred = np.asarray(fn(u[:, :c], y[:, :c], u[:, c:c + h]), dtype=np.float64)
            out[f, :, :h] = ((pred[:, :h] - y[:, c:c + h]) / scale[:, None]) ** 2
        return out

    def check(self, u_ctx, y_ctx) -> ContextCheck:
        """Backtests every candidate on the contexts (B, Tc, n_u) and (B, Tc, n_y) alone; the weights are those of
        the backtest's own steps."""
        return self._backtest(*self._arrays(u_ctx, y_ctx), horizon=None)[0]

    def _arrays(self, u_ctx, y_ctx):
        u, y = (np.asarray(getattr(a, "numpy", lambda: a)(), dtype=np.float64) for a in (u_ctx, y_ctx))
        if u.ndim == 2:
            u, y = u[None], y[None]
        if u.ndim != 3 or y.ndim != 3 or u.shape[:2] != y.shape[:2]:
            raise StackingError(f"contexts must be (B, T, n_u) and (B, T, n_y) with the same B and T, got "
                                f"{u.shape} and {y.shape}")
        if not (np.isfinite(u).all() and np.isfinite(y).all()):
            raise StackingError("the context holds NaN or inf: clean or cut the log before predicting")
        return u, y

    def _backtest(self, u: np.ndarray, y: np.ndarray, horizon: int | None):
        cfg = self.config
        t = y.shape[1]
        kin_cuts, model_cuts = self._cuts(t)
        reach = t - kin_cuts[0]
        spread = y.std(axis=1)  # (B, n_y): each channel's spread in this context
        scale = np.maximum(spread, _SCALE_FLOOR * spread.max(axis=1, keepdims=True) + 1e-12)
        names = list(KINEMATIC)
        errs = [self._fold_errors(fn, u, y, kin_cuts, reach, scale) for fn in KINEMATIC.values()]
        # The weights' score of a fold: its squared error over the deciding channels in one scale (the window's median
        # spread of them), so that channels that barely move (whose normalized errors are their noise) do not
        # outvote the moving ones.
        pick = slice(None) if self.decide_on is None else self.decide_on
        common = np.median(scale[:, pick], axis=1)  # (B,)

        def fold_scores(err: np.ndarray) -> np.ndarray:  # (F, B, K, n_y) -> (F, B, K)
            return (err * (scale[None, :, None] / common[None, :, None, None]) ** 2)[..., pick].mean(axis=3)

        notes, explained = [], {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # steps no fold reaches stay NaN
            # Per candidate and channel, the mean square over folds (B, K, n_y): the std's; and the weights' score, the
            # folds' arithmetic mean as the judge pools its windows (a geometric mean, which one fold's spike sways
            # less, cost 1.8x at 0.25 s on the UR5: the folds where a candidate blows up are what matters).
            per_ch = [np.nanmean(e, axis=0) for e in errs]
            score = [np.nanmean(fold_scores(e), axis=0) for e in errs]  # (B, K) each
            for name, (fn, _) in self.models.items():
                cuts = model_cuts[name]
                if not cuts:
                    notes.append(f"{name} was not backtested (no fold: folds 0 or too short a context); not stacked")
                    continue
                try:
                    err = self._fold_errors(fn, u, y, cuts, reach, scale)
                except (RoboMorphError, ValueError) as exc:  # one that cannot read a fold's shorter context (an ARX
                    notes.append(f"{name} was not backtested ({exc}); not stacked")  # with more coefficients)
                    continue
                # Transferred through its ratio to constant velocity on the model's own folds (the same samples),
                # the log ratio shrunk toward none by its evidence: n folds reaching a step keep n / (n + evidence)
                # of it (one fold of a model is a noisy vote; a per-context ARX that won there lost on the query).
                cv_err = self._fold_errors(KINEMATIC["constant_velocity"], u, y, cuts, reach, scale)
                reaching = np.array([sum(c + k < t for c in cuts) for k in range(reach)], dtype=np.float64)
                keep = reaching / (reaching + cfg.evidence)
                ratio = np.nanmean(err, axis=0) / np.maximum(np.nanmean(cv_err, axis=0), 1e-30)
                per_ch.append(per_ch[1] * np.exp(keep[None, :, None] * np.log(np.maximum(ratio, 1e-30))))
                ratio = np.nanmean(fold_scores(err), axis=0) / np.maximum(np.nanmean(fold_scores(cv_err), axis=0), 1e-30)
                score.append(score[1] * np.exp(keep[None] * np.log(np.maximum(np.nan_to_num(ratio, nan=1.0), 1e-30))))
                names.append(name)
                # Explained at all? Its own folds' error against hold's there, unshrunk, at every step it reached.
                held = np.nanmean(self._fold_errors(KINEMATIC["hold"], u, y, cuts, reach, scale), axis=0)
                mine = np.nanmean(err, axis=0)
                reached = reaching > 0
                explained[name] = ~np.all(mine[:, reached].mean(axis=2) > held[:, reached].mean(axis=2), axis=1)
        per_ch = _fill_steps(np.stack(per_ch, axis=1))  # (B, C, K, n_y)
        mse = _pool_steps(_fill_steps(np.stack(score, axis=1)[..., None])[..., 0], cfg.smooth)  # (B, C, K)
        counts = np.array([sum(c + k < t for c in kin_cuts) for k in range(reach)], dtype=np.float64)
        h = reach if horizon is None else horizon
        # One weight set per window, from every deciding channel's error in that one scale: the moving joints decide
        # (weights of each channel's own were noisier: 1.14x the best kinematic bar at 0.25 s on the Kinova, not 1.00).
        pooled = np.moveaxis(_pool_steps(np.moveaxis(per_ch, 3, 2), cfg.smooth), 2, 3)  # (B, C, K, n_y): the std's
        weights = self._weights(mse, counts, h, names)
        for name, ok in explained.items():
            if cfg.warn and not ok.all():
                warnings.warn(f"{name} explains {int((~ok).sum())} of {len(ok)} context(s) worse than holding the last "
                              "sample at every backtest step: check the input formulation (total torques to a command "
                              "model?), the units, or the arm", stacklevel=3)
        check = ContextCheck(names, self.dt, np.sqrt(mse), weights, (kin_cuts, model_cuts), explained, notes)
        self.last_check = check
        return check, pooled, scale

    def _weights(self, mse: np.ndarray, counts: np.ndarray, horizon: int, names: list[str]) -> np.ndarray:
        """(B, C, H) the stacking weights at query steps 1..H, from the pooled mean square errors ``mse`` (B, C, K)."""
        cfg = self.config
        b, c, reach = mse.shape
        default = self._default(c, horizon, names)  # (C, H)
        # Errors below the floor are ties (a context at rest: every candidate is exact there), and ties go to the
        # default: the softmin's prior is the default with a share for every candidate.
        floor = _TIE_FLOOR ** 2
        log = np.log(mse + floor)
        prior = (1 - _OPEN_SHARE) * self._default(c, reach, names) + _OPEN_SHARE / c  # (C, K)
        # Shrunk toward the prior by the evidence: fewer folds at a step, a hotter softmin (``evidence`` folds'
        # worth of prior doubles the temperature where ``evidence`` folds reach). A candidate far worse than the best
        # keeps no weight, however little evidence there is.
        temperature = cfg.temperature * (1 + cfg.evidence / np.maximum(counts, 1e-9))  # (K,)
        soft = prior[None] * np.exp(-(log - log.min(axis=1, keepdims=True)) / temperature)
        soft /= soft.sum(axis=1, keepdims=True)
        k_in = min(horizon, reach)
        w = np.empty((b, c, horizon))
        w[:, :, :k_in] = soft[:, :, :k_in]
        if horizon > reach:
            # Past the reach, with no evidence: the kinematic candidates' weights fade into the default as K / k, the
            # models' as (K / k)^4 (a per-context ARX that wins over the reach may diverge soon after it: 1.3e5 mrad
            # at 5 s on the UR5, where its last weights were carried as K / k).
            last = w[:, :, reach - 1]  # (B, C)
            fade = reach / np.arange(reach + 1, horizon + 1)  # (H - K,)
            fast = (np.arange(c) >= len(KINEMATIC)) & (self.learned is None)  # a learned prior knows the models
            kept = np.where(fast[:, None], fade ** 4, fade)  # (C, H - K)
            carried = kept[None] * last[:, :, None]
            w[:, :, reach:] = carried + (1 - carried.sum(axis=1, keepdims=True)) * default[None, :, reach:]
        return w

    def _default(self, n: int, horizon: int, names: list[str] | None = None) -> np.ndarray:
        """(C, H) the prior weights: those learned on the arm's training recordings (:meth:`learn`) where there are,
        else constant velocity fading into hold over ``default_tau`` seconds and nothing on the others."""
        t = np.arange(1, horizon + 1) * self.dt
        out = np.zeros((n, horizon))
        out[1] = np.exp(-t / self.config.default_tau)
        out[0] = 1 - out[1]
        if self.learned is None or names is None:
            return out
        learned = np.zeros((n, horizon))
        for i, name in enumerate(names):
            if name in self.learned:
                row = self.learned[name]
                learned[i] = row[np.minimum(np.arange(horizon), len(row) - 1)]  # its last step carried on
        total = learned.sum(axis=0, keepdims=True)
        return np.where(total > 0, learned / np.maximum(total, 1e-300), out)

    def learn(self, u, y, context_len: int, max_windows: int = 512, models: dict | None = None) -> "StackedPredictor":
        """Learns the prior weights from windows of the arm's own training recordings, (N, Tc + H, n_u) and
        (N, Tc + H, n_y), never from a test window: every candidate predicts each window's query from its
        context, and each step's weights are the softmin (``temperature``) of the candidates' mean square errors
        pooled over all of them. These replace the kinematic default, inside the backtest's reach as the softmin's
        prior and beyond it as what the weights fade into: pooled evidence says what works at long horizons, where
        one context cannot. ``models``: the models run on those windows (``{name: f or (f, folds)}``, default all;
        one left out, a costly hybrid, gets no prior weight and can still win on its context's evidence). Returns
        self."""
        u, y = self._arrays(u, y)
        if not 3 <= context_len < y.shape[1]:
            raise StackingError(f"context_len {context_len} must leave a query in windows of {y.shape[1]} samples")
        u, y = u[:max_windows], y[:max_windows]
        uc, yc, uq, yq = u[:, :context_len], y[:, :context_len], u[:, context_len:], y[:, context_len:]
        pick = slice(None) if self.decide_on is None else self.decide_on
        spread = np.maximum(np.median(yc.std(axis=1)[:, pick], axis=1), 1e-12)[:, None, None]  # one scale per window
        mse = {}
        chosen = self.models if models is None else {n: (e if isinstance(e, tuple) else (e, 1)) for n, e in models.items()}
        candidates = {**KINEMATIC, **{n: fn for n, (fn, _) in chosen.items()}}
        for name, fn in candidates.items():
            try:
                pred = np.asarray(fn(uc, yc, uq), dtype=np.float64)
            except RoboMorphError:
                continue
            with np.errstate(over="ignore", invalid="ignore"):
                err = np.nan_to_num(((pred - yq) / spread) ** 2, nan=1e30, posinf=1e30)
            mse[name] = err[..., pick].mean(axis=(0, 2))  # (H,): over windows, as the judge pools them (a blow-up counts)
        log = np.log(np.stack(list(mse.values())) + _TIE_FLOOR ** 2)
        w = np.exp(-(log - log.min(axis=0, keepdims=True)) / self.config.temperature)
        w /= w.sum(axis=0, keepdims=True)
        self.learned = {name: w[i] for i, name in enumerate(mse)}
        self.learned_mse = mse
        return self

    # ------------------------------------------------------------------ the prediction
    def simulate(self, u_ctx, y_ctx, u_query, return_std: bool = False):
        """The stacked prediction (B, H, n_y) of the query, and with ``return_std`` its std from the backtest.

        The model (where given) predicts from the whole context once more; the kinematic candidates are free."""
        u, y = self._arrays(u_ctx, y_ctx)
        uq = np.asarray(getattr(u_query, "numpy", lambda: u_query)(), dtype=np.float64)
        uq = uq[None] if uq.ndim == 2 else uq
        single = np.ndim(u_ctx) == 2
        horizon = uq.shape[1]
        check, per_ch, scale = self._backtest(u, y, horizon)
        preds = [fn(u, y, uq) for fn in KINEMATIC.values()]
        preds += [np.asarray(self.models[name][0](u, y, uq), dtype=np.float64) for name in check.names[len(KINEMATIC):]]
        preds = np.stack(preds, axis=1)  # (B, C, H, n_y)
        check.weights = self._gated(check, preds, scale)
        mean = np.einsum("bch,bchy->bhy", check.weights, preds)
        if not return_std:
            return mean[0] if single else mean
        std = self._std(per_ch, check.weights, scale, horizon)
        return (mean[0], std[0]) if single else (mean, std)

    def _gated(self, check: ContextCheck, preds: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """The weights with each model's weight at a step scaled by how plausible its query prediction is there: a
        prediction further from constant velocity's than ``_GATE`` times the backtest says they differ keeps
        ``exp(-d^2 / 2)`` of its weight (d in those units), the rest going to the others in proportion. A per-context
        ARX that backtested well can still diverge on the query: 7 % of its weight cost 6x at the UR5's first step."""
        w = check.weights
        n_kin = len(KINEMATIC)
        if w.shape[1] == n_kin:
            return w
        b, c, h = w.shape
        pick = slice(None) if self.decide_on is None else self.decide_on
        common = np.median(scale[:, pick], axis=1)[:, None, None]  # the backtest's one scale (B, 1, 1)
        rmse = check.rmse  # (B, C, K)
        reach = rmse.shape[2]
        k = np.arange(1, h + 1)
        # The backtest's expected gap between a model and constant velocity, past the reach grown as (k / K)^2.
        at = np.minimum(k, reach) - 1
        grow = np.maximum(k / reach, 1.0) ** 2
        gates = np.ones_like(w)
        for m in range(n_kin, c):
            gap = np.sqrt(np.mean(((preds[:, m] - preds[:, 1]) / common)[..., pick] ** 2, axis=2))  # (B, H)
            expected = np.hypot(rmse[:, m, at], rmse[:, 1, at]) * grow
            gates[:, m] = np.exp(-0.5 * (gap / np.maximum(_GATE * expected, 1e-30)) ** 2)
        gated = w * gates
        lost = (w - gated).sum(axis=1, keepdims=True)
        rest = gated.sum(axis=1, keepdims=True)
        return gated * (1 + lost / np.maximum(rest, 1e-30))

    def _std(self, pooled: np.ndarray, weights: np.ndarray, scale: np.ndarray, horizon: int) -> np.ndarray:
        """(B, H, n_y): the weighted mean square of the candidates' backtest errors, then grown past the reach."""
        b, c, reach, n_y = pooled.shape
        k_in = min(horizon, reach)
        var = np.einsum("bck,bcky->bky", weights[:, :, :k_in], pooled[:, :, :k_in])
        std = np.sqrt(var) * scale[:, None]
        if horizon <= reach:
            return std
        # Past the reach: a power of the step, fitted on the reach's second half (per window and channel).
        full = np.sqrt(np.einsum("bck,bcky->bky", weights[:, :, :reach], pooled)) * scale[:, None]
        ks = np.arange(max(1, reach // 2), reach + 1)
        lk = np.log(ks)
        ls = np.log(np.maximum(full[:, ks - 1], 1e-30))
        slope = ((lk - lk.mean())[None, :, None] * (ls - ls.mean(axis=1, keepdims=True))).sum(1) / max(
            float(((lk - lk.mean()) ** 2).sum()), 1e-30)
        p = np.clip(np.nan_to_num(slope, nan=1.0), 0.5, 2.0)  # (B, n_y)
        steps = np.arange(reach + 1, horizon + 1)
        grown = full[:, -1:] * (steps[None, :, None] / reach) ** p[:, None]
        return np.concatenate([std, grown], axis=1)


def _fill_steps(per_ch: np.ndarray) -> np.ndarray:
    """Steps no fold reached (NaN) take the last reached step's value."""
    out = per_ch.copy()
    for k in range(1, out.shape[2]):
        gap = np.isnan(out[:, :, k])
        out[:, :, k][gap] = out[:, :, k - 1][gap]
    return np.nan_to_num(out, nan=0.0)


def _pool_steps(x: np.ndarray, smooth: float) -> np.ndarray:
    """(..., K) the mean over steps ``k/(1+s)`` to ``k (1+s)`` of each step (a step's vote is its neighbours' too)."""
    if smooth <= 0:
        return x
    reach = x.shape[-1]
    csum = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1)], axis=-1)
    k = np.arange(1, reach + 1)
    # The window's ends rounded inward: the first steps stay alone (their errors grow fastest).
    lo = np.clip(np.ceil(k / (1 + smooth)).astype(int), 1, reach)
    hi = np.clip(np.floor(k * (1 + smooth)).astype(int), 1, reach)
    return (csum[..., hi] - csum[..., lo - 1]) / (hi - lo + 1)
