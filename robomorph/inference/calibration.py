"""Recalibrating a Gaussian head's standard deviation by horizon, after training.

A head trained with its negative log-likelihood is calibrated on average over the training
windows, not at every horizon: on held-out robots it grows over-confident as the horizon
lengthens (the 60-minute runs of the README: ±1σ covers 68 % of the truth at the first
step, 44-52 % from 1 s on). The classic remedy for regression uncertainties is a
post-hoc scale of the predicted spread fitted on held-out data (std or "temperature"
scaling, Levi et al. 2022; Kuleshov et al. 2018 in its quantile form). Here the scale
depends on the query step and the output channel, because the miscalibration does:

    std_calibrated[h, c] = s(h, c) * std[h, c]

``s`` is stored at log-spaced knot steps and interpolated linearly in log step between
them (the error of a rollout grows roughly like a power of the horizon); before the first
knot and after the last it is held constant, so any query length can be predicted. The
mean prediction is untouched.

Two estimators of ``s`` at a knot, over the windows and the steps of the knot's band:

- ``nll``: ``sqrt(mean(z^2))`` with ``z = (y - mean) / std``, the scale that
  minimises the Gaussian negative log-likelihood;
- ``quantile``: the 68.27 % quantile of ``|z|``, the scale that puts exactly that share of
  the calibration data inside ±1σ (heavier tails then show at ±2σ);
- ``coverage``: the scale whose ±1σ and ±2σ coverages are together nearest to a Gaussian's
  (68.27 % and 95.45 %), each miss measured in units of its tolerance (:data:`COVERAGE_TOLERANCE`,
  5 and 3 points) and the larger one minimized: errors with heavier tails than a Gaussian's
  cannot meet both levels with one scale, and ``nll`` then over-covers ±1σ (measured on the
  blend of a total-torque model: 75-79 % inside ±1σ over the first second) while ``quantile``
  under-covers ±2σ. The scale lies between the two single-level answers. ``robomorph
  calibrate``'s default: measured against ``nll`` on the 60-minute black-box model (largest
  mean miss 2.5 against 4.0 points) and on the total-torque blend (largest miss 1.5 against
  6.6), ``results/benchmarks/calibration.csv`` and the hybrid docs.

- ``power``: ``coverage`` with one more degree of freedom, a power of the spread about its
  median ``r`` over the knot's calibration windows, ``s * r * (std / r) ** p``, with ``p`` from
  :data:`POWERS` chosen, like the scale, for the smaller larger miss. Heavy tails in ``z`` come
  from windows whose spread is too small for their errors beside others whose spread is too
  large; ``p < 1`` narrows the spread's range across windows. Measured on the hybrid
  (``regression``, 256 calibration robots, 256 held-out ones, command formulation, windows from
  the start, ``results/benchmarks/calibration_hybrid.csv``): the joints' ±1σ / ±2σ coverage at
  steps 1/15/60/300/800 is 71.9-73.0 / 92.5-93.7 %, inside the goal bands (68 ± 5 / 95 ± 3 %) at
  every step, against 70.7-75.3 / 89.9-92.6 % for ``coverage`` (inside at one step); the mean miss
  over all steps fell from 6.1 / 4.4 to 4.9 / 2.2 points. In an offline trial with 64
  calibration robots neither method met the bands (the fitted powers follow the noise), so
  below :data:`POWER_MIN_WINDOWS` windows ``p`` stays 1. ``p`` is 1 too where a power does not
  help, and the calibration is then ``coverage``'s. ``robomorph calibrate``'s default.

Stored in a checkpoint under :data:`CALIBRATION_KEY` as plain lists, with where it was
fitted, so a reader can tell the validation split from a test store.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from robomorph.core.errors import RoboMorphError

# Checkpoint entry holding the calibration (a dict of plain lists and strings).
CALIBRATION_KEY = "robomorph_std_calibration"
METHODS = ("nll", "quantile", "coverage", "power")
# The robots a hybrid's std is the spread of (robomorph.inference.hybrid_std): what a calibration scales.
POINTS = ("columns", "draws", "observed")
# The powers of the spread that ``power`` chooses from (1: the spread as predicted).
POWERS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
# Fewer calibration windows than this: ``power`` keeps the spread's power at 1 (``coverage``'s
# scale): on 64 windows the fitted powers followed the noise (module docstring).
POWER_MIN_WINDOWS = 128
# Share of a Gaussian inside ±1σ (what the ``quantile`` method aims at) and inside ±2σ.
ONE_SIGMA = math.erf(1 / math.sqrt(2))
TWO_SIGMA = math.erf(2 / math.sqrt(2))
# How far the ±1σ and ±2σ coverages may stray (the goals of the hybrid issue): ``coverage`` weighs misses by them.
COVERAGE_TOLERANCE = (0.05, 0.03)
# Knots per decade of query steps: a step of 1.47x between knots follows the curvature of
# the measured miscalibration while pooling enough steps per knot at short horizons.
KNOTS_PER_DECADE = 6
# Predicted standard deviations below this (normalized) floor are treated as this, so a
# degenerate channel cannot send z to infinity.
_STD_FLOOR = 1e-12


class CalibrationError(RoboMorphError, ValueError):
    """A calibration that cannot be fitted, applied or read (the message says why)."""


def knot_steps(horizon: int, per_decade: int = KNOTS_PER_DECADE) -> np.ndarray:
    """Increasing, distinct, log-spaced query steps from 1 to ``horizon`` (both included)."""
    if horizon < 1:
        raise CalibrationError(f"the calibration horizon must be >= 1 step, got {horizon}")
    count = max(2, int(round(per_decade * math.log10(horizon))) + 1) if horizon > 1 else 1
    return np.unique(np.round(np.logspace(0, math.log10(horizon), count)).astype(np.int64))


@dataclasses.dataclass(frozen=True)
class StdCalibration:
    """Per-step, per-channel multipliers of a predicted standard deviation.

    Attributes:
        knots: (K,) increasing query steps (1 = the first predicted step).
        scale: (K, n_y) positive multipliers at those steps.
        method: one of :data:`METHODS` (how ``scale`` was estimated).
        source: where it was fitted (store, split, windows, ...), and the coverage on those
            windows before and after; shown to readers, not used in computing.
        power, reference: (K, n_y) each, ``power`` only: the spread's power ``p`` and the
            median spread ``r`` it is taken about (``s * r * (std / r) ** p``); None: ``p`` = 1.
        points: a hybrid's: the robots its std was the spread of (:data:`POINTS`,
            :mod:`robomorph.inference.hybrid_std`); None: no draws (a decoder, a smoother), or ``draws`` before the choice.
    """

    knots: tuple[int, ...]
    scale: tuple[tuple[float, ...], ...]
    method: str = "nll"
    source: dict = dataclasses.field(default_factory=dict)
    power: tuple[tuple[float, ...], ...] | None = None
    reference: tuple[tuple[float, ...], ...] | None = None
    points: str | None = None

    def __post_init__(self) -> None:
        if self.points is not None and self.points not in POINTS:
            raise CalibrationError(f"unknown spread points {self.points!r}; choose from {list(POINTS)}")
        scale = np.asarray(self.scale, dtype=np.float64)
        check_knot_table(self.knots, scale, "calibration", "scale", CalibrationError)
        if not (np.isfinite(scale).all() and (scale > 0).all()):
            raise CalibrationError("calibration scales must be finite and positive")
        if self.method not in METHODS:
            raise CalibrationError(f"unknown calibration method {self.method!r}; choose from {list(METHODS)}")
        if (self.power is None) != (self.reference is None):
            raise CalibrationError("a calibration's power and reference spread come together: fit it again")
        if self.power is not None:
            power, ref = np.asarray(self.power, dtype=np.float64), np.asarray(self.reference, dtype=np.float64)
            for name, table in (("power", power), ("reference", ref)):
                check_knot_table(self.knots, table, "calibration", name, CalibrationError)
            if power.shape != scale.shape or not (np.isfinite(power).all() and (power > 0).all()
                                                  and np.isfinite(ref).all() and (ref > 0).all()):
                raise CalibrationError("calibration powers and reference spreads must be finite, positive and "
                                       "shaped like the scales")

    @property
    def n_y(self) -> int:
        return len(self.scale[0])

    def factors(self, horizon: int) -> np.ndarray:
        """(horizon, n_y) multipliers for query steps 1..horizon (log-log interpolation, flat outside)."""
        return np.exp(interp_log_step(self.knots, np.log(np.asarray(self.scale, dtype=np.float64)), horizon))

    def powers(self, horizon: int) -> np.ndarray:
        """(horizon, n_y) the spread's powers for query steps 1..horizon (ones without a power)."""
        if self.power is None:
            return np.ones((horizon, self.n_y))
        return interp_log_step(self.knots, np.asarray(self.power, dtype=np.float64), horizon)

    def scaled(self, std: np.ndarray) -> np.ndarray:
        """(..., H, n_y) ``std`` recalibrated at steps 1..H: times the factors, about the reference
        spread to the power (``power`` calibrations)."""
        std = np.asarray(std, dtype=np.float64)
        if std.shape[-1] != self.n_y:
            raise CalibrationError(f"the calibration has {self.n_y} channels, the prediction {std.shape[-1]}")
        factors = self.factors(std.shape[-2])
        if self.power is None:
            return std * factors
        ref = np.exp(interp_log_step(self.knots, np.log(np.asarray(self.reference, dtype=np.float64)), std.shape[-2]))
        return factors * ref * (np.maximum(std, 0.0) / ref) ** self.powers(std.shape[-2])

    def apply(self, std: torch.Tensor) -> torch.Tensor:
        """``std`` (B, H, n_y) recalibrated at steps 1..H (:meth:`scaled`)."""
        if std.shape[-1] != self.n_y:
            raise CalibrationError(f"the calibration has {self.n_y} channels, the prediction {std.shape[-1]}")
        if self.power is None:
            return std * torch.as_tensor(self.factors(std.shape[-2]), dtype=std.dtype, device=std.device)
        return torch.as_tensor(self.scaled(std.detach().cpu().numpy()), dtype=std.dtype, device=std.device)

    def to_dict(self) -> dict:
        doc = {"knots": [int(k) for k in self.knots], "scale": [[float(v) for v in row] for row in self.scale],
               "method": self.method, "source": dict(self.source)}
        if self.power is not None:
            doc["power"] = [[float(v) for v in row] for row in self.power]
            doc["reference"] = [[float(v) for v in row] for row in self.reference]
        if self.points is not None:
            doc["points"] = self.points
        return doc

    @classmethod
    def from_dict(cls, doc: dict) -> "StdCalibration":
        try:
            table = lambda key: None if doc.get(key) is None else tuple(tuple(float(v) for v in r) for r in doc[key])  # noqa: E731
            return cls(tuple(int(k) for k in doc["knots"]), table("scale"), str(doc.get("method", "nll")),
                       dict(doc.get("source") or {}), table("power"), table("reference"), doc.get("points"))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, CalibrationError):
                raise
            raise CalibrationError(f"unreadable std calibration ({type(exc).__name__}: {exc}): fit it again "
                                   "with python -m robomorph.calibrate") from exc


def calibration_key(calibration: StdCalibration) -> str:
    """Where a model keeps a calibration: its physics mode, with ``/moving`` for a hybrid mode's
    fitted on windows that do not open their trajectory (``calibrate --offset random``). A hybrid
    knows which windows open theirs (``at_rest``) and applies each kind's to its own; a black-box
    model has one calibration whatever its windows."""
    src = calibration.source
    mode = mode_key(str(src.get("physics_mode", "none")), **{name: bool(src.get(name)) for _, name in SPREAD_SWITCHES})
    start = calibration.source.get("offset", "start") in ("start", 0)
    return mode if mode == "none" or start else f"{mode}/moving"


# The hybrid's switches that change its spread, as (flag in a calibration key, HybridSettings field), in key order:
# ``+obs`` horizons from the observer's velocity (another spread near the start), ``+springs`` the joints' springs
# fitted (another late in the horizon), ``+debias`` the regression's bias taken off (other errors), and the
# identification terms of robomorph.inference.settings (offsets, friction beyond the box, a payload, denoising).
SPREAD_SWITCHES = (("obs", "observer"), ("springs", "springs"), ("debias", "debias"), ("offsets", "offsets"),
                   ("coulomb", "coulomb"), ("payload", "payload"), ("denoise", "denoise"))


def mode_key(mode: str, **switches: bool) -> str:
    """A physics mode's calibration key: the mode, then ``+flag`` for each of :data:`SPREAD_SWITCHES` on in
    ``switches`` (named as HybridSettings' fields); the decoder's std (``none``), which none of them touches, has
    none."""
    if mode == "none":
        return mode
    return mode + "".join(f"+{flag}" for flag, name in SPREAD_SWITCHES if switches.get(name))


def read_calibrations(entry: dict | None) -> dict[str, StdCalibration]:
    """The calibrations stored under :data:`CALIBRATION_KEY`, by :func:`calibration_key`: one
    calibration (every checkpoint calibrated once, and those written before modes were kept apart),
    or ``{"by_mode": {key: calibration}}`` for a hybrid calibrated in several modes or kinds."""
    if not entry:
        return {}
    if not isinstance(entry, dict):
        raise CalibrationError("unreadable std calibration (not a mapping): fit it again with python -m robomorph.calibrate")
    docs = list(entry["by_mode"].values()) if isinstance(entry.get("by_mode"), dict) else [entry]
    cals = [StdCalibration.from_dict(d) for d in docs]
    return {calibration_key(c): c for c in cals}


def calibrations_entry(calibrations: dict[str, StdCalibration]) -> dict | None:
    """What :func:`read_calibrations` reads back (None when there is none): one mode stays in the
    single-calibration layout that every earlier checkpoint has."""
    if not calibrations:
        return None
    if len(calibrations) == 1:
        return next(iter(calibrations.values())).to_dict()
    return {"by_mode": {key: c.to_dict() for key, c in sorted(calibrations.items())}}


def check_knot_table(knots, values: np.ndarray, what: str, name: str, error: type[Exception]) -> None:
    """Refuses (with ``error``) knots that are not increasing steps >= 1, or ``values`` that are
    not (knots, n_y): the checks of every per-step table stored at knots."""
    k = np.asarray(knots)
    if k.ndim != 1 or len(k) == 0 or (k < 1).any() or (np.diff(k) <= 0).any():
        raise error(f"{what} knots must be increasing steps >= 1, got {list(knots)}")
    if values.ndim != 2 or values.shape[0] != len(k):
        raise error(f"{what} {name} must be (knots={len(k)}, n_y), got shape {values.shape}")


def interp_log_step(knots, values: np.ndarray, horizon: int) -> np.ndarray:
    """(horizon, n_y) of (K, n_y) ``values`` at ``knots`` for steps 1..horizon: linear in log
    step between knots, held flat outside them."""
    log_k = np.log(np.asarray(knots, dtype=np.float64))
    log_h = np.log(np.arange(1, horizon + 1, dtype=np.float64))
    return np.stack([np.interp(log_h, log_k, values[:, c]) for c in range(values.shape[1])], axis=1)


def end_dense_knots(horizon: int, per_decade: int = KNOTS_PER_DECADE) -> np.ndarray:
    """Knots as dense at the horizon's end as at its start: :func:`knot_steps` over the first half,
    mirrored onto the second. For errors that change fastest near the end, as a smoother's do (its
    last steps have no later torque to pin them), where log-spaced knots pool the last steps with
    many earlier ones of smaller error. Horizons under 4 steps: :func:`knot_steps`."""
    if horizon < 4:
        return knot_steps(horizon, per_decade)
    head = knot_steps(horizon, per_decade)
    head = head[head <= horizon // 2]
    tail = horizon + 1 - head[::-1]
    return np.concatenate([head, tail[tail > head[-1]]])


def step_bands(knots: np.ndarray, horizon: int) -> list[np.ndarray]:
    """The 0-based step indices pooled for each knot: steps nearer to it than to its
    neighbours in log step (the bands tile 1..horizon)."""
    log_k = np.log(knots.astype(np.float64))
    edges = np.exp(np.concatenate([[-np.inf], (log_k[1:] + log_k[:-1]) / 2, [np.inf]]))
    steps = np.arange(1, horizon + 1)
    return [np.flatnonzero((steps >= lo) & (steps < hi)) for lo, hi in zip(edges[:-1], edges[1:])]


def fit(y: np.ndarray, mean: np.ndarray, std: np.ndarray, method: str = "nll",
        knots: np.ndarray | None = None, source: dict | None = None, end: bool = False,
        points: str | None = None) -> StdCalibration:
    """Fits the per-step, per-channel scales on windows whose truth is known.

    Args:
        y, mean, std: (N, H, n_y) true outputs, predicted means and predicted standard
            deviations (physical units; only their ratios matter).
        method: one of :data:`METHODS` (module docstring).
        knots: query steps to fit at (default :func:`knot_steps` of H).
        source: provenance stored with it.
        end: knots as dense at the horizon's end as at its start (:func:`end_dense_knots`; ``knots``
            must then be None). The knots are stored, so the calibration applies as any other.
        points: the robots ``std`` was the spread of (a hybrid's; recorded, see :class:`StdCalibration`).
    """
    if method not in METHODS:
        raise CalibrationError(f"unknown calibration method {method!r}; choose from {list(METHODS)}")
    y, mean, std = (np.asarray(a, dtype=np.float64) for a in (y, mean, std))
    if y.ndim != 3 or y.shape != mean.shape or y.shape != std.shape:
        raise CalibrationError(f"y, mean and std must be (N, H, n_y) of one shape, got {y.shape}, {mean.shape}, "
                               f"{std.shape}")
    n, horizon, _ = y.shape
    if n < 2:
        raise CalibrationError(f"calibrating needs at least 2 windows with known outputs, got {n}")
    if end and knots is not None:
        raise CalibrationError("end-dense knots are placed by the fit: pass knots or end, not both")
    if end:
        knots = end_dense_knots(horizon)
    knots = knot_steps(horizon) if knots is None else np.asarray(knots, dtype=np.int64)
    if knots.max() > horizon:
        raise CalibrationError(f"calibration knot {int(knots.max())} lies beyond the horizon {horizon}")
    err, std = np.abs(y - mean), np.maximum(std, _STD_FLOOR)
    rows, powers, refs = [], [], []
    for band in step_bands(knots, horizon):
        eb, sb = (a[:, band].reshape(-1, y.shape[-1]) for a in (err, std))
        zb = eb / sb
        if method == "nll":
            s = np.sqrt(np.mean(zb ** 2, axis=0))
        elif method == "quantile":
            s = np.quantile(zb, ONE_SIGMA, axis=0)
        elif method == "coverage":
            s = np.array([_two_level_scale(zb[:, c])[0] for c in range(zb.shape[1])])
        else:
            powers_of = POWERS if n >= POWER_MIN_WINDOWS else (1.0,)
            s, p, r = zip(*(_power_and_scale(eb[:, c], sb[:, c], powers_of) for c in range(zb.shape[1])))
            s = np.asarray(s)
            powers.append(p)
            refs.append(r)
        # A channel the model predicts exactly (z = 0 everywhere) keeps its spread.
        rows.append(np.where(np.isfinite(s) & (s > 0), s, 1.0))
    table = lambda t: tuple(tuple(float(v) for v in r) for r in t) if t else None  # noqa: E731
    return StdCalibration(tuple(int(k) for k in knots), table(rows), method, dict(source or {}), table(powers),
                          table(refs), points)


def _power_and_scale(err: np.ndarray, std: np.ndarray, powers=POWERS) -> tuple[float, float, float]:
    """``(scale, power, reference)`` of one channel at one knot: the power of ``powers`` (the
    nearest to 1 among equals) whose best scale misses the two levels least."""
    ref = float(np.median(std))
    if not (np.isfinite(ref) and ref > 0):
        return _two_level_scale(err / std)[0], 1.0, 1.0
    best = None
    for p in sorted(powers, key=lambda p: abs(p - 1.0)):
        scale, miss = _two_level_scale(err / (ref * (std / ref) ** p))
        if best is None or miss < best[0] - 1e-12:
            best = (miss, scale, p)
    return best[1], best[2], ref


def _two_level_scale(z: np.ndarray) -> tuple[float, float]:
    """The scale of ``|z|`` whose larger miss of a Gaussian's ±1σ and ±2σ coverage (in tolerances) is
    least, and that miss."""
    one, two = float(np.quantile(z, ONE_SIGMA)), float(np.quantile(z, TWO_SIGMA)) / 2
    if not (one > 0 and two > 0):
        return (one if one > 0 else two), float("inf")
    grid = np.geomspace(min(one, two), max(one, two), 64)
    zs = np.sort(z)
    cover = lambda k: np.searchsorted(zs, k * grid, side="right") / len(zs)  # noqa: E731
    miss = band_miss(cover(1.0), cover(2.0))
    best = int(np.argmin(miss))
    return float(grid[best]), float(miss[best])


def band_miss(one, two) -> np.ndarray:
    """How far ±1σ / ±2σ coverages (shares, arrays or lists of one shape) are from a Gaussian's, the larger
    of the two misses in units of its tolerance (:data:`COVERAGE_TOLERANCE`): 1 or less is inside both bands
    (68.3 ± 5 % and 95.4 ± 3 %)."""
    tol1, tol2 = COVERAGE_TOLERANCE
    return np.maximum(np.abs(np.asarray(one, dtype=np.float64) - ONE_SIGMA) / tol1,
                      np.abs(np.asarray(two, dtype=np.float64) - TWO_SIGMA) / tol2)


def outside_bands(one: list[float], two: list[float]) -> list[int]:
    """The indices of the steps whose ±1σ / ±2σ coverages (shares) leave the bands (:func:`band_miss` over 1)."""
    return [int(i) for i in np.flatnonzero(band_miss(one, two) > 1.0 + 1e-9)]
