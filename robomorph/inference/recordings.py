"""The hybrid with a robot's own training recordings: identified once over all of them, adapted per context, corrected.

What a user with an identification run of their arm has beyond one context (issue 62 §2), three terms, each on top of
the one before (:class:`RecordingsPredictor`, from :meth:`robomorph.inference.predictor.Predictor.identify_from`):

1. **One identification over every recording** (``hybrid_train``): the hybrid's own regression
   (:meth:`robomorph.inference.hybrid.Hybrid.identify_recordings`, the solver a context's identification runs) fed
   with all the recordings' rows at once, constant torque offsets per joint beside the robot; every test window is
   then predicted by that one robot, nothing fitted on the window.
2. **Offsets adapted per context** (``+offsets``): a sensor's offset, a friction's asymmetry and an unknown
   payload's mean gravity drift from one recording to the next. Each context's mean torque residual under the
   identified robot is its own offset estimate; it is pulled toward the training one by a factor per joint learned
   on the training recordings alone (:func:`offset_gain`: how far the first part of a recording's residual predicts
   the rest's, least squares, within [0, 1]).
3. **A residual in acceleration space** (``+residual``): an acceleration per joint, linear in features of the
   joints, velocities and torques (:func:`features`), integrated twice along each predicted horizon and added to its
   joints (the end effector follows by the catalogue kinematics). It is fitted on the training recordings cut into
   windows, each predicted by the terms before it, to their horizons' joint errors (:class:`AccelResidual`: a
   correction that does not feed back into the simulated state has to be fitted on what it is added to), its ridge
   chosen by cross-validation over contiguous blocks of recordings; the strongest ridge is all but no correction,
   what it chooses where the correction does not carry over from one recording to another.

Nothing here reads a test window beyond its context: the recordings given are the only data anything is fitted on
(the benchmark gives the training split, :mod:`robomorph.data.public_logs`'s rule).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from robomorph.inference.predictor_checks import PredictionError

# Ridge strengths (per training row, on standardized features) the residual's cross-validation chooses among; the
# largest is close to no residual at all, so a residual that does not generalize across recordings is switched off.
RIDGES = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1e4)
# How the identification over all recordings is pulled toward the catalogue (RecordingsConfig.pull).
PULLS = ("context", "row")
# The velocity [rad/s] the Coulomb-like feature ``tanh(v / v0)`` saturates at.
COULOMB_VELOCITY = 0.05


class RecordingsError(PredictionError):
    """Training recordings that cannot identify the robot; the message says what to give."""


@dataclass(frozen=True)
class RecordingsConfig:
    """How the training recordings are used (validated on construction).

    Attributes:
        offsets: re-fit the torque offsets on each context, the training value as prior (:func:`offset_gain`).
        residual: learn and apply the acceleration-space residual (:class:`AccelResidual`).
        context: the context length [samples] the offsets' gain is learned for (each recording's first ``context``
            samples stand for a context, the rest for its horizon), and the residual's windows' context.
        horizon: the residual's training windows' horizon [samples] (the recordings are cut into windows of
            ``context + horizon``); the horizon the predictions will be asked for.
        folds: recordings' folds of the residual's cross-validation (fewer where there are fewer recordings).
        pull: the identification's pull toward the catalogue: ``context``, as strong in all as over one context of
            ``context`` samples (more recordings outweigh it); ``row``, the contexts' own pull per row of data.
        drift: each recording its own torque offsets in the identification (projected out of the solve), the
            training offsets their mean; False (the default): one offset over all recordings, solved for with the
            robot. Drifting offsets are what simulated recordings with an offset each need (tests), but on the real
            arms one offset predicted better (Kinova at 0.25 s / 1 s, offsets adapted: 78 / 402 mrad against
            140 / 777; UR5: 72.8 / 311 against 75.5 / 332).
    """

    offsets: bool = True
    residual: bool = True
    context: int = 200
    horizon: int = 200
    folds: int = 5
    pull: str = "context"
    drift: bool = False

    def __post_init__(self):
        for name in ("offsets", "residual", "drift"):
            if not isinstance(getattr(self, name), bool):
                raise RecordingsError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.pull not in PULLS:
            raise RecordingsError(f"pull must be one of {', '.join(PULLS)}, got {self.pull!r}")
        for name, low in (("context", 8), ("horizon", 1), ("folds", 2)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise RecordingsError(f"{name} must be a whole number >= {low}, got {value!r}")

    def replace(self, **changes) -> "RecordingsConfig":
        return dataclasses.replace(self, **changes)


def features(q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(..., 5 nj + 1) what the residual reads at a state: 1, sin q, cos q, v, tanh(v / v0), tau."""
    ones = np.ones(q.shape[:-1] + (1,))
    return np.concatenate([ones, np.sin(q), np.cos(q), v, np.tanh(v / COULOMB_VELOCITY), tau], axis=-1)


@dataclass
class AccelResidual:
    """A correction in acceleration space [rad/s^2] per joint, linear in :func:`features`, integrated twice along a
    predicted horizon (:meth:`shift`).

    Fitted on the horizons' joint errors of training windows (:meth:`fit`), not on each sample's acceleration error:
    the correction does not feed back into the simulated state, so what a sample's error asks of it is not what the
    horizon needs (measured on the Kinova: the per-sample fit, cross-validated to a tenth of the acceleration error's
    variance, took the test windows from 78 to 1600 mrad at 0.25 s)."""

    mean: np.ndarray  # (F,) the features' training mean (the constant's: 0)
    scale: np.ndarray  # (F,) their training std, floored (a feature that never moved is not divided by ~0)
    weights: np.ndarray  # (F, nj)
    ridge: float
    cv_error: dict  # {ridge: mean squared validation error of the horizons' joints [rad^2]}

    @classmethod
    def fit(cls, phi: np.ndarray, err: np.ndarray, groups: np.ndarray, dt: float, folds: int = 5) -> "AccelResidual":
        """Fitted on training windows' features ``phi`` (B, H, F) along their predicted horizons and their joints'
        errors ``err`` (B, H, nj) (recorded less predicted), the ridge chosen by cross-validation over ``groups``
        (B,) (a recording's windows stay together) among :data:`RIDGES`; the largest is all but no correction."""
        flat = phi.reshape(-1, phi.shape[-1])
        mean, scale = flat.mean(axis=0), flat.std(axis=0)
        mean[0], scale[0] = 0.0, 1.0
        scale = np.maximum(scale, 1e-6 * max(1.0, float(scale.max())))
        z = _integrated((phi - mean) / scale, dt).reshape(-1, phi.shape[-1])
        target = err.reshape(-1, err.shape[-1])
        rows = np.repeat(np.asarray(groups), phi.shape[1])
        ids = np.unique(rows)
        k = min(folds, len(ids))
        # Contiguous blocks of groups, not every k-th: neighbouring windows of a store often come from one recording,
        # and a fold that keeps its neighbours in training is told the answer (the Kinova's 60 training windows with
        # interleaved folds chose the weakest ridge, and the test windows' error at 1 s doubled).
        fold = np.searchsorted(ids, rows) * max(k, 1) // len(ids)
        errors = {}
        if k < 2:  # one recording: nothing to validate a correction on, so none (the strongest ridge)
            errors[RIDGES[-1]] = float("nan")
        for ridge in RIDGES if k >= 2 else ():
            sq = 0.0
            for f in range(k):
                tr = fold != f
                sq += float(((z[~tr] @ _ridge(z[tr], target[tr], ridge) - target[~tr]) ** 2).sum())
            errors[ridge] = sq / target.size
        best = min(errors, key=errors.get) if k >= 2 else RIDGES[-1]
        return cls(mean, scale, _ridge(z, target, best), best, errors)

    def shift(self, phi: np.ndarray, dt: float) -> np.ndarray:
        """(B, H, nj) the joints' correction along horizons whose features are ``phi`` (B, H, F)."""
        return _integrated((phi - self.mean) / self.scale, dt) @ self.weights


def _integrated(phi: np.ndarray, dt: float) -> np.ndarray:
    """An acceleration held over each step, integrated twice: step k's position change from steps 0..k-1's."""
    return np.cumsum(np.cumsum(phi, axis=1), axis=1) * dt * dt


def horizon_features(q_ctx: np.ndarray, q_pred: np.ndarray, uq: np.ndarray, dt: float) -> np.ndarray:
    """(B, H, F) :func:`features` along predicted horizons ``q_pred`` (B, H, nj) after contexts ``q_ctx`` (B, T, nj):
    at the state before each step (velocities by central differences), the torque ``uq`` over it."""
    q = np.concatenate([q_ctx[:, -2:], q_pred], axis=1)  # two context samples, the horizon
    v = (q[:, 2:] - q[:, :-2]) / (2 * dt)  # at the last context sample and every step but the last
    return features(q[:, 1:-1], v, uq)


def windows_of(us: list[np.ndarray], ys: list[np.ndarray], context: int, horizon: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Recordings cut into non-overlapping windows of ``context + horizon`` samples: ``(u, y, recording)`` (B, ...)."""
    cut = [(i, s) for i, a in enumerate(us) for s in range(0, len(a) - context - horizon + 1, context + horizon)]
    if not cut:
        raise RecordingsError(f"no recording holds one window of context {context} + horizon {horizon} samples for "
                              "the residual: give longer recordings, or RecordingsConfig(residual=False)")
    n = context + horizon
    return (np.stack([us[i][s:s + n] for i, s in cut]), np.stack([ys[i][s:s + n] for i, s in cut]),
            np.array([i for i, _ in cut]))


class KinematicResidual:
    """Constant-velocity extrapolation corrected by the acceleration residual, learned on the training recordings:
    the residual term for any arm, with no MJCF (``constant_velocity +residual`` in ``benchmarks/real_robots.py``).

    ``u``, ``y``: the recordings (lists of (T, n) arrays or (N, T, n) windows); ``joints``: the output columns the
    residual corrects (joint angles; the others are extrapolated alone); ``dt``: the sample time [s]; ``config``: a
    :class:`RecordingsConfig` (its ``context``, ``horizon`` and ``folds``)."""

    def __init__(self, u, y, joints: list[int], dt: float, config: RecordingsConfig | None = None):
        config = RecordingsConfig() if config is None else config
        if not isinstance(config, RecordingsConfig):
            raise RecordingsError(f"config must be a RecordingsConfig, got {type(config).__name__}")
        try:
            n_u, n_y = (np.shape(a[0])[-1] for a in (u, y))
        except (IndexError, TypeError, KeyError):
            raise RecordingsError("the residual takes the recordings' torques and outputs as two lists of (T, channels) "
                                  "arrays (or two (N, T, channels) arrays), at least one recording") from None
        us, ys = _pieces(u, y, n_u, n_y)
        if not joints or any(not 0 <= j < ys[0].shape[1] for j in joints):
            raise RecordingsError(f"joints must name output columns 0..{ys[0].shape[1] - 1}, got {joints!r}")
        if not dt > 0:
            raise RecordingsError(f"dt must be > 0 seconds, got {dt!r}")
        self.joints, self.dt, self.config = list(joints), float(dt), config
        wu, wy, groups = windows_of(us, ys, config.context, config.horizon)
        c = config.context
        base = self.simulate(wu[:, :c], wy[:, :c], wu[:, c:], residual=False)
        err = wy[:, c:, self.joints] - base[..., self.joints]
        self.residual = AccelResidual.fit(self._features(wy[:, :c], base, wu[:, c:]), err, groups, self.dt,
                                          config.folds)

    def _features(self, yc: np.ndarray, pred: np.ndarray, uq: np.ndarray) -> np.ndarray:
        return horizon_features(yc[..., self.joints], pred[..., self.joints], uq, self.dt)

    def simulate(self, u_ctx, y_ctx, u_query, residual: bool = True) -> np.ndarray:
        """(B, H, n_y) constant velocity from each context's last two samples, its joints corrected (``residual``)."""
        from robomorph.inference.kinematics import KINEMATIC  # noqa: PLC0415

        uc, yc, uq = (np.asarray(a, dtype=np.float64) for a in (u_ctx, y_ctx, u_query))
        out = np.asarray(KINEMATIC["constant_velocity"](uc, yc, uq), dtype=np.float64)
        if residual:
            out = out.copy()
            out[..., self.joints] += self.residual.shift(self._features(yc, out, uq), self.dt)
        return out


def _ridge(z: np.ndarray, y: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge solution, its pull per row scaled by the columns' mean square (the integrated features' size grows
    with the horizon: a ridge of 1 weighs the pull as much as the data)."""
    gram = z.T @ z
    pull = ridge * max(np.trace(gram) / z.shape[1], 1e-12) * np.eye(z.shape[1])
    return np.linalg.solve(gram + pull, z.T @ y)


def offset_gain(context_means: np.ndarray, horizon_means: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """(nj,) how far a context's own mean residual moves the offset from ``prior``: per joint, the least-squares
    factor by which the context's departure from the prior predicts the horizon's, within [0, 1] (0: the training
    offset alone; 1: the context's alone). ``context_means``, ``horizon_means``: (R, nj) per training recording."""
    dc, dh = context_means - prior, horizon_means - prior
    den = (dc * dc).sum(axis=0)
    gain = np.where(den > 0, (dc * dh).sum(axis=0) / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(gain, 0.0, 1.0)


def _pieces(u, y, n_u: int, n_y: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The recordings as lists of (T, n_u) and (T, n_y) arrays; a clear error for anything else."""
    if isinstance(u, np.ndarray) and u.ndim == 3:
        u = list(u)
    if isinstance(y, np.ndarray) and y.ndim == 3:
        y = list(y)
    if not isinstance(u, (list, tuple)) or not isinstance(y, (list, tuple)) or not u or len(u) != len(y):
        raise RecordingsError("identify_from takes the recordings' torques and outputs as two lists of (T, channels) "
                              "arrays of the same length (or two (N, T, channels) arrays), at least one recording")
    us, ys = [], []
    for i, (a, b) in enumerate(zip(u, y)):
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if a.ndim != 2 or b.ndim != 2 or a.shape[1] != n_u or b.shape[1] != n_y or len(a) != len(b):
            raise RecordingsError(f"recording {i}: torques {a.shape} and outputs {b.shape}; the arm takes (T, {n_u}) "
                                  f"and (T, {n_y}) of the same T")
        if len(a) < 8:
            raise RecordingsError(f"recording {i} has {len(a)} samples; each needs 8 or more")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise RecordingsError(f"recording {i} holds NaN or inf; clean or drop it")
        us.append(a)
        ys.append(b)
    return us, ys


class RecordingsPredictor:
    """A catalogue arm's hybrid identified over the robot's training recordings (:mod:`robomorph.inference.recordings`).

    Built by :meth:`robomorph.inference.predictor.Predictor.identify_from`. Attributes: ``params`` (P,) the identified
    robot, ``offsets`` (nj,) its training torque offsets [N m], ``gain`` (nj,) the per-context offsets' factor,
    ``residual`` the :class:`AccelResidual` (None without it), ``config``, ``recordings`` and ``samples`` (what it
    was fitted on)."""

    def __init__(self, predictor, u, y, config: RecordingsConfig | None = None):
        config = RecordingsConfig() if config is None else config
        if not isinstance(config, RecordingsConfig):
            raise RecordingsError(f"config must be a RecordingsConfig, got {type(config).__name__}")
        if not predictor.physics or predictor.settings.mode == "none":
            raise RecordingsError("identify_from needs a hybrid (Predictor.from_arm, or a model with a physics "
                                  "backbone in a physics mode)")
        self.predictor, self.config = predictor, config
        us, ys = _pieces(u, y, predictor.n_u, predictor.n_y)
        hybrid = predictor.hybrid()
        self.n_joint = nj = hybrid.n_joint
        qs = [b[:, 7:7 + nj] for b in ys]
        self.params, self.offsets = hybrid.identify_recordings(qs, us, config.context if config.pull == "context" else None,
                                                               config.drift)
        self.recordings, self.samples = len(us), int(sum(len(a) for a in us))
        # The solver identify_recordings just ran, kept: its data and inverse dynamics give the residuals, here and on
        # each context (a later context identification may build the hybrid another).
        self._regressor = reg = hybrid.regressor
        rows = []  # per recording: the torque its inner samples hold beyond the identified robot's
        for q, a in zip(qs, us):
            rows.append(reg.residual(self.params, reg.data(q, a, self._noise(hybrid, q))))
        self.gain = np.zeros(nj)
        if config.offsets:
            c = config.context
            long = [r for r in rows if len(r) > c + 8]
            if long:
                self.gain = offset_gain(np.stack([r[:c].mean(axis=0) for r in long]),
                                        np.stack([r[c:].mean(axis=0) for r in long]), self.offsets)
        self.residual = None
        if config.residual:
            self._learn_residual(us, ys, hybrid.backbone.dt)

    def _learn_residual(self, us: list[np.ndarray], ys: list[np.ndarray], dt: float) -> None:
        """The residual fitted on the recordings cut into windows of ``context + horizon`` samples, each predicted
        with the terms before it (the identified robot, the per-context offsets where on)."""
        c = self.config.context
        u, y, groups = windows_of(us, ys, c, self.config.horizon)
        pred = self.simulate(u[:, :c], y[:, :c], u[:, c:], residual=False)
        nj = self.n_joint
        err = y[:, c:, 7:7 + nj] - pred[..., 7:7 + nj]
        self.residual = AccelResidual.fit(self._features(pred, y[:, :c], u[:, c:], dt), err, groups, dt,
                                          self.config.folds)

    def _features(self, pred: np.ndarray, yc: np.ndarray, uq: np.ndarray, dt: float) -> np.ndarray:
        cols = slice(7, 7 + self.n_joint)
        return horizon_features(yc[..., cols], pred[..., cols], uq, dt)

    @staticmethod
    def _noise(hybrid, q: np.ndarray) -> float:
        from robomorph.identification.noise import encoder_noise  # noqa: PLC0415

        return encoder_noise(q) if hybrid.settings.denoise else 0.0

    def context_offsets(self, u_ctx: np.ndarray, y_ctx: np.ndarray) -> np.ndarray:
        """(B, nj) each context's offsets: the training ones moved by :attr:`gain` toward the context's own mean
        torque residual under the identified robot."""
        hybrid, reg = self.predictor.hybrid(), self._regressor
        if not self.gain.any():
            return np.repeat(self.offsets[None], len(u_ctx), axis=0)
        out = []
        for a, b in zip(u_ctx, y_ctx):
            q = b[:, 7:7 + self.n_joint]
            res = reg.residual(self.params, reg.data(q, a, self._noise(hybrid, q)))
            out.append(self.offsets + self.gain * (res.mean(axis=0) - self.offsets))
        return np.stack(out)

    def simulate(self, u_ctx, y_ctx, u_query, offsets: bool | None = None, residual: bool | None = None
                 ) -> np.ndarray:
        """(B, H, n_y) the identified robot's prediction of each horizon; ``offsets`` and ``residual`` (default: the
        config's) switch the per-context offsets and the acceleration residual on or off for this call."""
        uc, yc, uq = (np.asarray(a, dtype=np.float64) for a in (u_ctx, y_ctx, u_query))
        if uc.ndim == 2:
            return self.simulate(uc[None], yc[None], uq[None], offsets, residual)[0]
        offsets = self.config.offsets if offsets is None else offsets
        residual = self.config.residual if residual is None else residual
        if residual and self.residual is None:
            raise RecordingsError("this predictor learned no residual (RecordingsConfig(residual=False))")
        hybrid = self.predictor.hybrid()
        off = self.context_offsets(uc, yc) if offsets else self.offsets
        out = hybrid.simulate_identified(self.params, off, uc, yc, uq)
        return self._corrected(hybrid, out, yc, uq) if residual else out

    def _corrected(self, hybrid, out: np.ndarray, yc: np.ndarray, uq: np.ndarray) -> np.ndarray:
        """The residual's correction added to each predicted horizon's joints, the end effector following them."""
        from robomorph.identification.backbone import signed  # noqa: PLC0415

        nj, dt = self.n_joint, hybrid.backbone.dt
        shift = self.residual.shift(self._features(out, yc, uq, dt), dt)
        joints = np.concatenate([yc[:, -1:, 7:7 + nj], out[..., 7:7 + nj] + shift], axis=1)
        return signed(hybrid.backbone.outputs(joints), yc[:, -1, 3:7])[:, 1:]
