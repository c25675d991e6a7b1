"""Physics early, the network late: a per-horizon blend of the two predictions of one model.

In the paper's total-torque formulation the torques hold gravity paid at the *recorded*
state, so a simulation of the identified robot is excellent for the first second and then
diverges (any deviation meets uncompensated gravity and grows about tenfold every 57 steps;
see the physics notes). The black-box decoder is the other way round: worse than physics at
the first step, bounded over the whole horizon. Neither is best everywhere, and which one is
better depends on the query step and the channel, not on the window. The blend

    y(h, c) = w(h, c) * physics(h, c) + (1 - w(h, c)) * decoder(h, c)

uses the least-squares weight of each step band and channel, fitted on held-out windows
whose truth is known (``robomorph calibrate --blend``):

    w = clip( sum (d - y)(d - p) / sum (d - p)^2 , 0, 1 )     with p physics, d decoder

the weight that minimizes the blend's squared error (it accounts for correlated errors,
which inverse-variance weighting does not). Weights are stored at the log-spaced knot steps
of :mod:`robomorph.inference.calibration` and interpolated linearly in log step between them.

A few simulations leave the trajectory early (within a second or two), while the weights
still trust the physics: their errors are small on average and ruinous in those windows (one
of 16 measured fell to R^2 -68 on a quaternion channel). So each window carries a *gate*:
once its physics has departed from its decoder by more than ``gate`` times the decoder's
typical error there (the RMS error of the decoder at that step and channel on the fitting
windows), the physics' weight falls, to none at :data:`GATE_RAMP` times that departure, and
does not come back for the rest of the window; where the physics is not finite the rest of
the window is the decoder's. ``gate`` is chosen on the fitting windows, from :data:`GATES`, as
the one with the best mean R^2 (approach 1). A blend of the smoothed physics has none (see
:func:`fit_blend`).

The blend's standard deviation, for independent errors, is
``sqrt(w^2 std_physics^2 + (1 - w)^2 std_decoder^2)``; ``robomorph calibrate`` then rescales it
by horizon as it does any other std.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.core.metrics import r2
from robomorph.inference.calibration import check_knot_table, interp_log_step, knot_steps, step_bands

# Checkpoint entry holding the blend (a dict of plain lists and strings).
BLEND_KEY = "robomorph_physics_blend"
# The gates tried when fitting (multiples of the decoder's RMS error; inf: no gate).
GATES = (3.0, 5.0, 10.0, 20.0, 50.0, float("inf"))
# The physics' share of its weight falls linearly from whole to none while its departure from the decoder grows
# from ``gate`` to GATE_RAMP times ``gate`` decoder RMS errors (:meth:`HorizonBlend.kept`). A cut at ``gate`` itself
# handed a window's whole horizon from its physics to its decoder when a nudge of its context carried the departure
# across: one of the kept test windows sat at 0.977 of its gate, and a 1e-6-relative nudge of the context moved its
# prediction by 8.5 % (issue 61). Below the gate nothing changed; a simulation that leaves goes far past twice it.
GATE_RAMP = 2.0
# The physics predictions a blend can weigh against the decoder (the hybrid's modes of those names).
PHYSICS_MODES = ("smoothed", "regression")


class BlendError(RoboMorphError, ValueError):
    """A blend that cannot be fitted, applied or read (the message says why)."""


@dataclasses.dataclass(frozen=True)
class HorizonBlend:
    """Per-step, per-channel weights of the physics prediction (the decoder gets the rest).

    Attributes:
        knots: (K,) increasing query steps (1 = the first predicted step).
        weight: (K, n_y) weights in [0, 1] at those steps.
        decoder_rms: (K, n_y) the decoder's RMS error there (what the gate is measured in);
            None: no gate.
        gate: a window's physics is dropped from the first step it departs from the decoder by
            more than this many ``decoder_rms`` (inf: never).
        physics_mode: which physics prediction is blended: ``smoothed``, the identified robot's
            horizon smoothed against the decoder (:mod:`robomorph.identification.smoother`), or
            ``regression``, its simulation forward from the context (blends fitted before there
            was a choice).
        source: where it was fitted (store, windows, errors before and after); for readers.
        physics: the physics backbone's record (:func:`robomorph.identification.backbone.parameter_layout`)
            when the model was trained without one (a black-box model of simulated stores);
            None when its own data record has it.
    """

    knots: tuple[int, ...]
    weight: tuple[tuple[float, ...], ...]
    source: dict = dataclasses.field(default_factory=dict)
    physics: dict | None = None
    decoder_rms: tuple[tuple[float, ...], ...] | None = None
    gate: float = float("inf")
    physics_mode: str = "regression"

    def __post_init__(self) -> None:
        if self.physics_mode not in PHYSICS_MODES:
            raise BlendError(f"a blend's physics must be one of {PHYSICS_MODES}, got {self.physics_mode!r}")
        weight = np.asarray(self.weight, dtype=np.float64)
        check_knot_table(self.knots, weight, "blend", "weights", BlendError)
        if not (np.isfinite(weight).all() and (weight >= 0).all() and (weight <= 1).all()):
            raise BlendError("blend weights must lie in [0, 1]")
        if not self.gate > 0:
            raise BlendError(f"the blend's gate must be > 0, got {self.gate}")
        if self.decoder_rms is not None:
            rms = np.asarray(self.decoder_rms, dtype=np.float64)
            if rms.shape != weight.shape or not (np.isfinite(rms).all() and (rms >= 0).all()):
                raise BlendError(f"the blend's decoder_rms must be finite, >= 0 and shaped as its weights {weight.shape}")

    @property
    def n_y(self) -> int:
        return len(self.weight[0])

    def weights(self, horizon: int) -> np.ndarray:
        """(horizon, n_y) physics weights at query steps 1..horizon (linear in log step, flat outside)."""
        return interp_log_step(self.knots, np.asarray(self.weight, dtype=np.float64), horizon)

    def kept(self, physics: np.ndarray, decoder: np.ndarray) -> np.ndarray:
        """(B, H) in [0, 1]: the share of its weight each window's physics keeps at each step under the gate.

        1 while the physics has stayed within ``gate`` decoder RMS errors of the decoder on every channel, 0 from
        :data:`GATE_RAMP` times that on, linear between, in the farthest departure so far (a simulation that left
        does not come back); 0 from its first step that is not finite. Continuous in both predictions."""
        physics = np.asarray(physics, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            ratio = np.zeros(physics.shape[:-1])
            if self.decoder_rms is not None and np.isfinite(self.gate):
                log_rms = np.log(np.maximum(np.asarray(self.decoder_rms), 1e-12))
                rms = np.exp(interp_log_step(self.knots, log_rms, physics.shape[-2]))
                ratio = (np.abs(physics - decoder) / (self.gate * rms[None])).max(axis=-1)
            # Not finite (the physics, or the ratio through a decoder that is not): dropped from there on.
            ratio = np.where(np.isfinite(physics).all(axis=-1) & ~np.isnan(ratio), ratio, np.inf)
            farthest = np.maximum.accumulate(ratio, axis=-1)
            return np.clip((GATE_RAMP - farthest) / (GATE_RAMP - 1.0), 0.0, 1.0)

    def gated(self, physics: np.ndarray, decoder: np.ndarray) -> np.ndarray:
        """(B, H) bools: the steps of each window from which its physics loses weight to the gate (:meth:`kept`)."""
        return self.kept(physics, decoder) < 1.0

    def combine(self, physics: np.ndarray, decoder: np.ndarray, physics_std: np.ndarray | None = None,
                decoder_std: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """The blended mean (B, H, n_y) and, given both stds, the blended std."""
        physics, decoder = np.asarray(physics, dtype=np.float64), np.asarray(decoder, dtype=np.float64)
        if physics.shape != decoder.shape or physics.shape[-1] != self.n_y:
            raise BlendError(f"blend of {self.n_y} channels given physics {physics.shape} and decoder {decoder.shape}")
        ok = np.isfinite(physics)
        w = self.kept(physics, decoder)[..., None] * self.weights(physics.shape[-2])[None]
        mean = w * np.where(ok, physics, 0.0) + (1 - w) * decoder
        if physics_std is None or decoder_std is None:
            return mean, None
        sp = np.where(ok & np.isfinite(physics_std), physics_std, 0.0)
        return mean, np.sqrt((w * sp) ** 2 + ((1 - w) * np.asarray(decoder_std, dtype=np.float64)) ** 2)

    def to_dict(self) -> dict:
        return {"knots": [int(k) for k in self.knots], "weight": [[float(v) for v in r] for r in self.weight],
                "source": dict(self.source), "physics": self.physics, "gate": float(self.gate),
                "decoder_rms": None if self.decoder_rms is None else [[float(v) for v in r] for r in self.decoder_rms],
                "physics_mode": self.physics_mode}

    @classmethod
    def from_dict(cls, doc: dict) -> "HorizonBlend":
        try:
            return cls(tuple(int(k) for k in doc["knots"]), tuple(tuple(float(v) for v in r) for r in doc["weight"]),
                       dict(doc.get("source") or {}), doc.get("physics"),
                       None if doc.get("decoder_rms") is None else tuple(tuple(float(v) for v in r)
                                                                        for r in doc["decoder_rms"]),
                       float(doc.get("gate", float("inf"))), str(doc.get("physics_mode", "regression")))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, BlendError):
                raise
            raise BlendError(f"unreadable physics blend ({type(exc).__name__}: {exc}): fit it again with "
                             "robomorph calibrate --blend") from exc


def fit_blend(y: np.ndarray, physics: np.ndarray, decoder: np.ndarray, knots: np.ndarray | None = None,
              source: dict | None = None, layout: dict | None = None, physics_mode: str = "regression"
              ) -> HorizonBlend:
    """Fits the least-squares weights on windows whose truth is known.

    Args:
        y, physics, decoder: (N, H, n_y) true outputs and the two predictions (physics may
            hold non-finite values where a simulation diverged: the decoder stands in there,
            as in :meth:`HorizonBlend.combine`).
        knots: query steps to fit at (default :func:`robomorph.inference.calibration.knot_steps`).
        source: provenance stored with it.
        layout: the physics backbone's record to store with it (:attr:`HorizonBlend.physics`).
        physics_mode: which physics prediction ``physics`` is (:attr:`HorizonBlend.physics_mode`).
    """
    y, physics, decoder = (np.asarray(a, dtype=np.float64) for a in (y, physics, decoder))
    if y.ndim != 3 or y.shape != physics.shape or y.shape != decoder.shape:
        raise BlendError(f"y, physics and decoder must be (N, H, n_y) of one shape, got {y.shape}, "
                         f"{physics.shape}, {decoder.shape}")
    if len(y) < 2:
        raise BlendError(f"fitting a blend needs at least 2 windows with known outputs, got {len(y)}")
    horizon = y.shape[1]
    knots = knot_steps(horizon) if knots is None else np.asarray(knots, dtype=np.int64)
    if knots.max() > horizon:
        raise BlendError(f"blend knot {int(knots.max())} lies beyond the horizon {horizon}")
    bands = step_bands(knots, horizon)
    rms = tuple(tuple(float(v) for v in np.sqrt(np.mean((decoder - y)[:, b] ** 2, axis=(0, 1)))) for b in bands)
    best = None
    # The smoothed physics is anchored to the decoder and cannot run away as a forward simulation
    # does; a gate in units of the decoder's in-distribution error would hand exactly the windows
    # whose decoder is off to the decoder (measured: multi-sine at 0.35 Hz, first step 1.94 mrad
    # with the gate, 0.065 without; none of 128 fitting windows was gated).
    for gate in (float("inf"),) if physics_mode == "smoothed" else GATES:
        # The weights of the windows and steps the gate leaves to physics, then the gate's R^2.
        probe = HorizonBlend(tuple(int(k) for k in knots), tuple((1.0,) * y.shape[-1] for _ in knots),
                             decoder_rms=rms, gate=gate)
        # The blend is d - w k (d - p) with k the share the gate leaves (:meth:`HorizonBlend.kept`): k (d - p), 0 where
        # the decoder stands alone, is what each band's weight multiplies.
        keep = probe.kept(physics, decoder)[..., None] * np.isfinite(physics)
        with np.errstate(invalid="ignore", over="ignore"):  # (a physics that is not finite is left out here)
            gap = np.where(keep > 0, keep * (decoder - physics), 0.0)
        rows = []
        for band in bands:
            g = gap[:, band].reshape(-1, y.shape[-1])
            e = (decoder - y)[:, band].reshape(-1, y.shape[-1])
            den = np.sum(g * g, axis=0)
            w = np.where(den > 0, np.sum(e * g, axis=0) / np.where(den > 0, den, 1.0), 0.0)
            rows.append(tuple(float(v) for v in np.clip(w, 0.0, 1.0)))
        blend = HorizonBlend(probe.knots, tuple(rows), dict(source or {}), layout, rms, gate, physics_mode)
        score = float(np.mean(r2(y, blend.combine(physics, decoder)[0])))
        if best is None or score > best[0]:
            best = (score, blend)
    return best[1]

