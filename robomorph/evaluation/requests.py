"""What ``evaluate``, ``calibrate`` and ``calibrate --blend`` are asked to do: one frozen config each.

    from robomorph.evaluation.evaluator import evaluate
    from robomorph.evaluation.requests import EvaluateConfig
    res = evaluate(EvaluateConfig(data="data/ms_test.zarr", ckpt="runs/ms/checkpoints/best.ckpt"))
    res = evaluate(EvaluateConfig(data="data/ms_test.zarr", arm="panda", context_len=200, horizon=400))

Each config is validated on construction (as :class:`robomorph.control.runner.ControlConfig` is):
a value that cannot work is refused in one line that names its command-line option, before
anything is read. What only the data can tell (a window longer than the store's trajectories,
a horizon spec beyond the horizon) is checked where the data are read. The doors
(:mod:`robomorph.evaluate`, :mod:`robomorph.calibrate`) build these from their options and
call one function; scripts and tests build them directly.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from robomorph.core.names import INPUTS, NORMALIZATIONS, PHYSICS_MODES, RECORDED_SWITCHES
from robomorph.core.rundir import RunDir
from robomorph.evaluation.baselines import BASELINES
from robomorph.evaluation.sources import check_baselines
from robomorph.evaluation.windows import EvaluationError, WindowError, check_counts, parse_offset

# ``--physics``: a hybrid mode, or ``none`` (the decoder alone); None keeps the model's default.
PHYSICS_CHOICES = (*PHYSICS_MODES, "none")
# When evaluate stacks the model with kinematics (EvaluateConfig.stacked).
STACKED_CHOICES = ("auto", "on", "off")


def _choice(error: type[Exception], option: str, value, choices) -> None:
    """Refuses ``value`` (None passes: the default) unless it is one of ``choices``."""
    if value is not None and value not in choices:
        raise error(f"{option} {value!r}: choose one of {', '.join(choices)}")


def _whole(error: type[Exception], option: str, value, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise error(f"{option} must be a whole number >= {low}, got {value!r}")


def _window(error: type[Exception], cfg) -> None:
    """The checks every request shares: the counts, the window's start and the seed."""
    for name in ("context_len", "horizon", "n", "batch_size"):
        value = getattr(cfg, name)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise error(f"--{name.replace('_', '-')} must be a whole number, got {value!r}")
    try:
        check_counts(context_len=cfg.context_len, horizon=cfg.horizon, n=cfg.n, batch_size=cfg.batch_size)
        # Stored parsed (a frozen field set once, on construction): "0" and "start" are one offset.
        object.__setattr__(cfg, "offset", parse_offset(cfg.offset))
    except (EvaluationError, WindowError) as exc:
        raise error(str(exc)) from None
    _whole(error, "--seed", cfg.seed, 0)



@dataclass(frozen=True)
class EvaluateConfig:
    """One evaluation: a model on a store, beside the baselines (:func:`robomorph.evaluation.evaluator.evaluate`).

    Attributes:
        data: the store evaluated on (``.zarr``).
        ckpt: a checkpoint written by ``robomorph fit`` or a folder written by ``robomorph export``.
        arm: instead of ``ckpt``, a registered arm whose catalogue hybrid, untrained, is evaluated
            (:meth:`robomorph.inference.predictor.Predictor.from_arm`, built with the store's recipe).
            Exactly one of ``ckpt`` and ``arm``.
        out: the output folder (None: ``<run>/eval/<store name>``, or ``results/catalogue/<arm>/eval/<store
            name>`` for an arm).
        context_len, horizon: the window in steps (None: the checkpoint's training window; an arm has
            none, so both are needed with ``arm``).
        n: only the first ``n`` trajectories (None: all).
        baselines: from :data:`robomorph.evaluation.baselines.BASELINES`, ``OPT_IN`` and ``CEILINGS``.
        sweep_horizon_spec, sweep_context_spec: horizons and context lengths swept (``200:800:50``,
            ``20,40``; None: no sweep).
        batch_size: windows predicted at once.
        device: ``cpu``, ``cuda``, ... (None: cuda when available).
        samples: sample trajectories plotted.
        arx_orders: the ARX baselines' output and input lags ``(na, nb)``.
        seed: picks the plotted samples and the random offsets.
        normalization: when given, the normalization the checkpoint must have been trained with.
        horizons_spec: the steps of the per-horizon errors (None: first step, 0.25 s, 1 s, 5 s, the end).
        offset: where each window starts: ``start``, ``random`` (seeded) or a step (stored parsed).
        inputs: when given, the input formulation the checkpoint must have been trained on; with ``arm``,
            the formulation its hybrid takes (None: ``command``).
        arx_train_data: stores ``arx_train`` is fitted on, whole (empty: the checkpoint's training split).
        compare: ``(name, checkpoint)`` pairs scored beside the baselines (a mapping is accepted too).
        physics: a hybrid's physics mode (None: the model's default).
        stacked: ``auto`` (the default): the model's predictions stacked with kinematic extrapolation by the context
            backtest on recordings of a real robot (an ingested store), where that wins, and the model alone on
            simulated stores; ``on`` or ``off``: always or never
            (:attr:`robomorph.inference.predictor.Predictor.stack`).
    """

    data: str
    ckpt: str | None = None
    arm: str | None = None
    out: str | None = None
    context_len: int | None = None
    horizon: int | None = None
    n: int | None = None
    baselines: tuple[str, ...] = BASELINES
    sweep_horizon_spec: str | None = None
    sweep_context_spec: str | None = None
    batch_size: int = 64
    device: str | None = None
    samples: int = 3
    arx_orders: tuple[int, int] = (2, 2)
    seed: int = 0
    normalization: str | None = None
    horizons_spec: str | None = None
    offset: str | int = "start"
    inputs: str | None = None
    arx_train_data: tuple[str, ...] = ()
    compare: tuple[tuple[str, str], ...] = ()
    physics: str | None = None
    stacked: str = "auto"

    def __post_init__(self):
        if (self.ckpt is None) == (self.arm is None):
            raise EvaluationError("give --ckpt (a trained model) or --robot (a catalogue arm's untrained hybrid), "
                                  f"exactly one of them; got {'both' if self.ckpt else 'neither'}")
        if not self.data:
            raise EvaluationError("--data: give the store to evaluate on (.zarr)")
        # Tuples, so the config stays what it was built as (a caller's list changed later changes nothing).
        for name in ("baselines", "arx_train_data", "arx_orders"):
            object.__setattr__(self, name, tuple(getattr(self, name) or ()))
        compare = self.compare.items() if isinstance(self.compare, dict) else (self.compare or ())
        object.__setattr__(self, "compare", tuple((str(k), str(v)) for k, v in compare))
        check_baselines(self.baselines)
        _window(EvaluationError, self)
        _whole(EvaluationError, "--plot-trajectories", self.samples, 0)
        if len(self.arx_orders) != 2 or any(isinstance(v, bool) or not isinstance(v, int) or v < 1
                                            for v in self.arx_orders):
            raise EvaluationError(f"--arx-orders takes two whole numbers na,nb >= 1, got {self.arx_orders}")
        _choice(EvaluationError, "--normalization", self.normalization, NORMALIZATIONS)
        _choice(EvaluationError, "--inputs", self.inputs, INPUTS)
        _choice(EvaluationError, "--physics", self.physics, PHYSICS_CHOICES)
        _choice(EvaluationError, "--stacked", self.stacked, STACKED_CHOICES)
        names = [name for name, _ in self.compare]
        if len(set(names)) != len(names):
            raise EvaluationError(f"--compare names {sorted({x for x in names if names.count(x) > 1})} more than "
                                  "once: give each checkpoint its own name")
        if self.arm is not None:
            self._check_arm()

    def _check_arm(self) -> None:
        """What an untrained catalogue hybrid can be asked: its arm registered, its window given."""
        from robomorph.sim import arms  # noqa: PLC0415  (MuJoCo: only for an arm)

        if self.arm not in arms.ARMS:
            raise EvaluationError(f"--robot {self.arm!r} is not a registered arm: choose one of {', '.join(arms.names())}")
        if self.context_len is None or self.horizon is None:
            raise EvaluationError(f"--robot {self.arm}: a catalogue hybrid records no training window: pass "
                                  "--context-len and --horizon")
        if self.normalization not in (None, "train_stats"):
            raise EvaluationError(f"--normalization {self.normalization}: a catalogue hybrid has no network to "
                                  "have been trained with it; drop the option")

    @property
    def out_dir(self) -> str:
        """``out``, else ``<run>/eval/<store name>`` (:func:`default_out`), or for an arm
        ``results/catalogue/<arm>/eval/<store name>``."""
        if self.out:
            return self.out
        if self.arm is not None:
            return RunDir(os.path.join("results", "catalogue", self.arm)).eval_dir(self.data)
        return default_out(self.ckpt, self.data)

    @property
    def model(self) -> str:
        """What is evaluated, as the messages and ``metrics.json`` name it: the checkpoint, or ``arm:<name>``."""
        return self.ckpt if self.ckpt is not None else f"arm:{self.arm}"


def default_out(ckpt: str, data: str) -> str:
    """``<run>/eval/<store name>`` for a checkpoint in ``<run>/checkpoints/`` (or a model folder in ``<run>/``)."""
    return RunDir.of_checkpoint(os.path.join(ckpt, "config.json") if os.path.isdir(ckpt) else ckpt).eval_dir(data)


@dataclass(frozen=True)
class CalibrateConfig:
    """One std calibration (:func:`robomorph.evaluation.calibrating.calibrate`).

    Attributes:
        ckpt: a checkpoint (or model folder) with a Gaussian head, or a hybrid.
        data: a store of held-out robots (None: the fit's validation split, read back from its stores).
        out: where the calibrated checkpoint is written (None: the checkpoint, in place).
        n: at most this many windows.
        context_len, horizon: the window (None: the checkpoint's training window).
        offset, seed: where each window starts (``start``, ``random`` seeded by ``seed``, or a step).
        method: ``power``, ``coverage``, ``nll`` or ``quantile`` (:data:`robomorph.inference.calibration.METHODS`).
        batch_size: windows predicted at once.
        device: ``cpu``, ``cuda``, ... (None: cuda when available).
        horizons_spec: the steps the report shows (evaluate's ``--horizons``).
        physics: a hybrid's physics mode to calibrate (None: its default mode).
        observer, springs, debias, payload, coulomb, denoise: a hybrid's switches
            (:data:`robomorph.core.names.RECORDED_SWITCHES`) set in its record before fitting (None: as recorded);
            each setting keeps its own calibrations.
        points: the robots a hybrid's std is the spread of: ``columns``, ``draws`` or ``observed`` (None: as stored).
    """

    ckpt: str
    data: str | None = None
    out: str | None = None
    n: int | None = None
    context_len: int | None = None
    horizon: int | None = None
    offset: str | int = "start"
    seed: int = 0
    method: str = "power"
    batch_size: int = 64
    device: str | None = None
    horizons_spec: str | None = None
    physics: str | None = None
    observer: bool | None = None
    points: str | None = None
    springs: bool | None = None
    debias: bool | None = None
    payload: bool | None = None
    coulomb: bool | None = None
    denoise: bool | None = None

    def __post_init__(self):
        # Here, not at the top: the calibration's names bring torch, which evaluate's parsing does without.
        from robomorph.inference.calibration import METHODS, POINTS, CalibrationError  # noqa: PLC0415

        if not self.ckpt:
            raise CalibrationError("--ckpt: give the checkpoint (or model folder) to calibrate")
        _window(CalibrationError, self)
        _choice(CalibrationError, "--method", self.method, METHODS)
        _choice(CalibrationError, "--physics", self.physics, PHYSICS_CHOICES)
        _choice(CalibrationError, "--points", self.points, POINTS)
        for name in RECORDED_SWITCHES:
            if getattr(self, name) not in (None, True, False):
                raise CalibrationError(f"--{name} takes on or off, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class BlendConfig:
    """One fit of the physics/decoder blend (:func:`robomorph.evaluation.calibrating.blend`).

    Attributes:
        ckpt, data, out, n, context_len, horizon, offset, seed, device, horizons_spec: as :class:`CalibrateConfig`.
        batch_size: windows predicted at once (each runs a simulation: 16 by default).
        physics: the physics prediction blended, ``smoothed`` (needs a Gaussian head) or ``regression``
            (None: ``smoothed`` where the model has a Gaussian head, else ``regression``).
    """

    ckpt: str
    data: str | None = None
    out: str | None = None
    n: int | None = None
    context_len: int | None = None
    horizon: int | None = None
    offset: str | int = "start"
    seed: int = 0
    batch_size: int = 16
    device: str | None = None
    horizons_spec: str | None = None
    physics: str | None = None

    def __post_init__(self):
        from robomorph.inference.blending import PHYSICS_MODES  # noqa: PLC0415  (torch: as CalibrateConfig)
        from robomorph.inference.calibration import CalibrationError  # noqa: PLC0415

        if not self.ckpt:
            raise CalibrationError("--ckpt: give the checkpoint (or model folder) to fit a blend for")
        _window(CalibrationError, self)
        _choice(CalibrationError, "--blend-physics", self.physics, PHYSICS_MODES)


def as_request(cls, config, args: tuple, kwargs: dict, what: str):
    """The ``cls`` request a function was called with: ``config`` itself, or one built from the keyword call
    of earlier releases (``evaluate(ckpt, data, out, n=...)``; see :func:`legacy`).

    Raises:
        TypeError: a config given with other arguments beside it.
    """
    if isinstance(config, cls):
        if args or kwargs:
            raise TypeError(f"{what}(config) takes the {cls.__name__} alone: set the other values in it")
        return config
    return legacy(cls, (config, *args), kwargs, what)


def legacy(cls, args: tuple, kwargs: dict, what: str):
    """A config from the keyword call that came before it (``evaluate(ckpt, data, out, n=...)``), with a
    :class:`DeprecationWarning`: kept one release for the callers outside this room."""
    import warnings  # noqa: PLC0415

    # Pointing at the caller of evaluate/calibrate/blend (through as_request), whose call is to change.
    warnings.warn(f"{what}(ckpt, data, ...) with arguments is deprecated: pass one {cls.__name__}",
                  DeprecationWarning, stacklevel=4)
    names = [f.name for f in dataclasses.fields(cls)]
    if cls is EvaluateConfig:  # its old order: ckpt, data, out, then the rest as the fields follow
        names = ["ckpt", "data", "out", *[n for n in names if n not in ("ckpt", "data", "out", "arm")]]
    if len(args) > len(names):
        raise TypeError(f"{what}() takes at most {len(names)} positional arguments ({len(args)} given)")
    return cls(**dict(zip(names, args)), **kwargs)


__all__ = ["PHYSICS_CHOICES", "BlendConfig", "CalibrateConfig", "EvaluateConfig", "as_request", "default_out", "legacy"]
