"""Every knob of the hybrid in one frozen, validated object: :class:`HybridSettings`.

A :class:`~robomorph.inference.predictor.Predictor` holds one (``pred.settings``), its defaults read
from the checkpoint's record (:meth:`HybridSettings.of_record`), and changes it only through
``pred.configure(**changes)``, which validates the whole new object before it replaces the old. The
hybrid and each of its workers receive the settings in effect (:meth:`HybridSettings.in_effect`:
the switches that do not apply to a formulation or a mode turned off), never attributes set one by
one from outside.

Two names come from it:

- :attr:`HybridSettings.key`, the settings that change a prediction in one line,
  ``MODE[@K][~M][/S][+obs][+springs][+debias][+tangent][+offsets][+coulomb][+payload][+denoise][+refineall]`` (K regression solves, M members of the
  friction mixture, S physics steps per sample after the first second), read back by
  :meth:`HybridSettings.from_key`: what benchmarks and tables name a setting by;
- :attr:`HybridSettings.calibration_key`, under which a model stores the std calibration of these
  settings (``regression+obs+springs+debias``): a hybrid's std depends on how the robot is identified.
"""

from __future__ import annotations

import dataclasses
import numbers
import os
from dataclasses import dataclass, field

from robomorph.core.names import PHYSICS_MODES, RECORDED_SWITCHES
from robomorph.inference.calibration import POINTS, SPREAD_SWITCHES, mode_key
from robomorph.inference.predictor_checks import PredictionError

# The modes a Predictor predicts in: the decoder alone (``none``) or a hybrid mode.
MODES = ("none", *PHYSICS_MODES)
# Many horizons on one context: exact rollouts, or tangent-linear about one
# (:mod:`robomorph.identification.tangent`).
CANDIDATES = ("exact", "tangent")
# The modes in which the regression identifies the robot without the parameter head's prior: where its
# own switches (the springs, the debiasing) apply.
_REGRESSING = ("regression", "refined", "blend", "smoothed")
_FLAGS = ("obs", "springs", "debias", "tangent", "offsets", "coulomb", "payload", "denoise", "refineall")


class SettingsError(PredictionError):
    """A hybrid setting out of its range; the message names it and what it takes."""


def default_workers() -> int:
    """Two where there are two cores or more: one hybrid's regression runs beside the other's rollouts
    (:mod:`robomorph.inference.hybrid_split`)."""
    return 2 if (os.cpu_count() or 1) >= 2 else 1


# The most each count may take. Far above anything that pays (members 9, samples 8, workers 2, iterations 3,
# refine_iters 3 to 8, substeps 8 to 16 by default) and below what exhausts memory or time before the first
# window: ``members=10**9`` used to be accepted here and fail only inside simulate.
LIMITS = {"samples": 1024, "members": 1024, "workers": 64, "iterations": 100, "refine_iters": 1000,
          "substeps": 1000}


def _whole(value, low: int, high: int | None = None) -> bool:
    return (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= low
            and (high is None or value <= high))


@dataclass(frozen=True)
class HybridSettings:
    """How a Predictor predicts: its mode and every knob of its hybrid.

    Attributes:
        mode: ``none`` (the decoder) or a physics mode (:data:`robomorph.core.names.PHYSICS_MODES`).
        samples: robots drawn for a std over random draws (``points="draws"``).
        members: robots of the friction mixture over the joints that held still in the context
            (:mod:`robomorph.identification.stiction`; commands); 1: the estimate alone (cheaper).
        points: the robots a hybrid's std is the spread of (:data:`robomorph.inference.calibration.POINTS`);
            None: those its stored calibration was fitted on, else ``observed`` with the observer,
            ``columns`` without (:mod:`robomorph.inference.hybrid_std`).
        substeps: physics steps per sample of the horizons after their first second (None:
            :func:`robomorph.identification.backbone.coarse_substeps`; the generator's re-enacts it throughout).
        observer: commands: horizons start from the observer's velocity
            (:func:`robomorph.identification.backbone.observed_velocity`).
        springs: commands: the regression fits the joints' springs too.
        debias: commands: the regression's bias, measured on the estimate's simulated context, taken off
            (:mod:`robomorph.inference.debias`).
        candidates: many horizons on one context: ``exact`` or ``tangent``.
        offsets: the regression identifies a constant torque per joint beside the robot (a sensor's offset, a
            friction's asymmetry, an unknown payload's mean gravity), and the horizon is simulated with it taken
            off the torques (:mod:`robomorph.identification.extra_terms`).
        coulomb: the regression's friction losses and damping may leave the randomization box (a real joint's
            Coulomb and viscous friction: :func:`robomorph.identification.extra_terms.friction_space`).
        payload: the regression's flange body may carry an unknown payload (its mass and centre of mass beyond
            the box: :func:`robomorph.identification.extra_terms.payload_space`), and where gravity is in the
            problem (total torques; commands to an arm compensating with its catalogue model) the links' centres
            of mass are fitted too.
        denoise: commands: the encoder noise measured in each context (:mod:`robomorph.identification.noise`)
            smooths the regression's differences and the horizon's start; a context measured noise-free
            predicts as without it.
        workers: hybrids that share a batch of many windows on threads (1: one does them all).
        iterations: solves of the regression, each linearized where the previous one landed.
        refine_iters: most cost evaluations of the ``refined`` mode's rollout fit.
        refine_all: the ``refined`` mode's rollout fit over every kind the regression identifies (link masses,
            damping, armature, friction losses) instead of the armature and friction losses alone: what pays on
            noisy contexts, where the regression's differences blur every parameter (with ``denoise``, 8 held-out
            robots at 1e-4 rad, ``refine_iters`` 8: 1.91 mrad at 1 s against 3.93 for the two kinds and 4.31 for the
            regression; 2.5 s per window).
        seed: the seed of the std's random draws (the same windows give the same std).
        smoother: how mode ``smoothed`` weighs physics and decoder (total torques): a
            :class:`robomorph.identification.smoother.SmootherConfig`; None: its defaults (kept as None so
            that a decoder's Predictor never imports MuJoCo).
    """

    mode: str = "none"
    samples: int = 8
    members: int = 9
    points: str | None = None
    substeps: int | None = None
    observer: bool = False
    springs: bool = False
    debias: bool = False
    candidates: str = "exact"
    offsets: bool = False
    coulomb: bool = False
    payload: bool = False
    denoise: bool = False
    workers: int = field(default_factory=default_workers)
    iterations: int = 3
    refine_iters: int = 3
    refine_all: bool = False
    seed: int = 0
    smoother: "SmootherConfig | None" = None  # noqa: F821  (imported only where given)

    def __post_init__(self):
        if self.mode not in MODES:
            raise SettingsError(f"mode {self.mode!r}: choose none or one of {', '.join(PHYSICS_MODES)}")
        for name in ("samples", "members", "workers", "iterations", "refine_iters"):
            if not _whole(getattr(self, name), 1, LIMITS[name]):
                raise SettingsError(f"{name} must be a whole number from 1 to {LIMITS[name]}, got "
                                    f"{getattr(self, name)!r}")
        if self.substeps is not None and not _whole(self.substeps, 1, LIMITS["substeps"]):
            raise SettingsError(f"substeps must be None or a whole number from 1 to {LIMITS['substeps']}, got "
                                f"{self.substeps!r}")
        if self.points is not None and self.points not in POINTS:
            raise SettingsError(f"points {self.points!r}: choose one of {', '.join(POINTS)} (or None: the "
                                "calibration's)")
        if self.candidates not in CANDIDATES:
            raise SettingsError(f"candidates must be one of {list(CANDIDATES)}, got {self.candidates!r}")
        for name in ("observer", "springs", "debias", "offsets", "coulomb", "payload", "denoise", "refine_all"):
            if not isinstance(getattr(self, name), bool):
                raise SettingsError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not _whole(self.seed, 0):
            raise SettingsError(f"seed must be a whole number >= 0, got {self.seed!r}")
        if self.smoother is not None:
            from robomorph.identification.smoother import SmootherConfig  # noqa: PLC0415  (MuJoCo only when used)

            if not isinstance(self.smoother, SmootherConfig):
                raise SettingsError(f"smoother must be a SmootherConfig or None, got {type(self.smoother).__name__}")

    @classmethod
    def of_record(cls, physics: dict | None, inputs: str, blend=None) -> "HybridSettings":
        """The defaults a checkpoint's record gives: the mode (``regression`` for commands; for total torques
        ``blend`` when the model has one, else ``none``: a total-torque simulation forward diverges within
        seconds) and the switches of :data:`robomorph.core.names.RECORDED_SWITCHES` as recorded (off in records written before them)."""
        if not physics:
            return cls()
        mode = "regression" if inputs == "command" else ("blend" if blend is not None else "none")
        return cls(mode=mode, **{name: bool(physics.get(name, False)) for name in RECORDED_SWITCHES})

    def replace(self, **changes) -> "HybridSettings":
        """A copy with ``changes``, validated; an unknown name is refused with the names there are."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise SettingsError(f"no hybrid setting {', '.join(unknown)}; the settings are "
                                f"{', '.join(f.name for f in dataclasses.fields(self))}")
        return dataclasses.replace(self, **changes)

    def in_effect(self, inputs: str, gravity_compensation: str | None = None) -> "HybridSettings":
        """These settings with the switches that do not apply turned off: the observer outside the command
        formulation; the springs and debiasing outside it too, and in modes whose robot is not the
        regression's alone (``learned``, ``fused``, ``none``); the debiasing on an arm that compensates its
        gravity with its catalogue model, where it measured worse (simulated kinova3, 4 robots, joint RMS at
        steps 1 / 15 / 60 / 300: 0.15 / 8.2 / 54 / 256 mrad with it, 0.055 / 2.1 / 10 / 57 without). The offsets
        and the wider friction in any mode whose robot is the regression's alone, in either formulation (a total
        torque's sensor has offsets too); the denoising with the commands' observer."""
        command = inputs == "command"
        regressing = command and self.mode in _REGRESSING
        alone = self.mode in _REGRESSING
        return dataclasses.replace(
            self, observer=self.observer and command, springs=self.springs and regressing,
            debias=self.debias and regressing and gravity_compensation != "nominal_model",
            offsets=self.offsets and alone, coulomb=self.coulomb and alone, payload=self.payload and alone,
            denoise=self.denoise and regressing)

    @property
    def calibration_key(self) -> str:
        """Where a model stores the std calibration of these settings (take it of :meth:`in_effect`'s):
        each switch of :data:`robomorph.inference.calibration.SPREAD_SWITCHES` on changes the spread; the
        decoder's is ``none``."""
        return mode_key(self.mode, **{name: getattr(self, name) for _, name in SPREAD_SWITCHES})

    @property
    def key(self) -> str:
        """The settings that change a prediction, in one line: ``MODE[@K][~M][/S][+obs][+springs][+debias][+tangent]
        [+offsets][+coulomb][+payload][+denoise][+refineall]``
        (the defaults left out), read back by :meth:`from_key`."""
        default = HybridSettings()
        out = self.mode
        out += f"@{self.iterations}" if self.iterations != default.iterations else ""
        out += f"~{self.members}" if self.members != default.members else ""
        out += f"/{self.substeps}" if self.substeps is not None else ""
        flags = {"obs": self.observer, "springs": self.springs, "debias": self.debias,
                 "tangent": self.candidates == "tangent", "offsets": self.offsets, "coulomb": self.coulomb,
                 "payload": self.payload, "denoise": self.denoise,
                 "refineall": self.refine_all and self.mode == "refined"}
        return out + "".join(f"+{flag}" for flag in _FLAGS if flags[flag])

    @classmethod
    def from_key(cls, key: str, base: "HybridSettings | None" = None) -> "HybridSettings":
        """The settings :attr:`key` names, the rest as in ``base`` (default: the defaults). A key names every
        switch it turns on, so those it leaves out are off."""
        spec, *flags = key.strip().split("+")
        if set(flags) - set(_FLAGS):
            raise SettingsError(f"{key!r}: the flags after '+' are {', '.join(_FLAGS)}, got "
                                f"{'+'.join(f for f in flags if f not in _FLAGS)!r}")
        spec, _, substeps = spec.partition("/")
        spec, _, members = spec.partition("~")
        mode, _, solves = spec.partition("@")
        try:
            numbers_ = {k: int(v) for k, v in (("iterations", solves), ("members", members), ("substeps", substeps))
                        if v}
        except ValueError:
            raise SettingsError(f"{key!r}: @K, ~M and /S take whole numbers, as in regression@3~9/4+obs") from None
        default = HybridSettings()
        base = base or default
        return base.replace(mode=mode, iterations=numbers_.get("iterations", default.iterations),
                            members=numbers_.get("members", default.members), substeps=numbers_.get("substeps"),
                            observer="obs" in flags, springs="springs" in flags, debias="debias" in flags,
                            candidates="tangent" if "tangent" in flags else "exact", offsets="offsets" in flags,
                            coulomb="coulomb" in flags, payload="payload" in flags, denoise="denoise" in flags,
                            refine_all="refineall" in flags)

