"""Inference API: a trained meta-model as a simulator of an unseen robot.

    from robomorph import Predictor
    pred = Predictor.from_checkpoint("results/runs/ms/checkpoints/best.ckpt")
    pred = Predictor.from_pretrained("model/")   # or a folder written by robomorph export
    y_query = pred.simulate(u_ctx, y_ctx, u_query)   # physical units in and out

This is what a model predictive controller calls: given a window of measured torques and outputs of the
robot at hand (the context) and candidate future torques, it returns the predicted outputs. Normalization is
handled inside (statistics stored in the checkpoint). Only ``robomorph.model`` and ``robomorph.core`` are needed.

A model trained with ``data.normalization: paper_window`` (the paper's protocol) rescales each window with the
mean and std of the very outputs it predicts; ``simulate`` refuses it unless the caller passes those statistics
explicitly (``y_query_stats``), which only an evaluation against recorded outputs can do.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterator

import numpy as np
import torch

from robomorph.core.errors import DeviceError, RoboMorphError
from robomorph.core.inputs import check_model_inputs
from robomorph.core.names import TODAYS_RECORD
from robomorph.core.normalizations import NormalizationError, leaks_query_statistics
from robomorph.inference import catalogue, residual
from robomorph.model.channels import arm_columns, pad, select
from robomorph.inference.checkpoint import CheckpointError, TrainedModel, load_trained
from robomorph.inference.hybrid_std import calibrated_rows, kind_calibrations, spread_points
from robomorph.inference.settings import HybridSettings

# Re-exported: the public names of what simulate checks live beside the checks.
from robomorph.inference.predictor_checks import (  # noqa: F401
    MAX_INPUT_STDS,
    PredictionError,
    all_finite,
    as_batch,
    check_hybrid_context,
    check_range,
    check_settings,
)


def resolve_device(device: str | torch.device | None) -> torch.device:
    """The torch device for ``--device`` (default: cuda when available), or a one-line
    :class:`DeviceError` for a name torch does not know or a device this machine lacks."""
    try:
        dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    except (RuntimeError, TypeError) as exc:
        raise DeviceError(f"--device {device!r} is not a device: {exc}; use cpu, cuda or cuda:N") from None
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise DeviceError(f"--device {device}: CUDA is not available on this machine (torch "
                              f"{torch.__version__}); use --device cpu")
        if dev.index is not None and dev.index >= count:
            raise DeviceError(f"--device {device}: this machine has {count} CUDA device(s), "
                              f"cuda:0..cuda:{count - 1}")
    elif dev.type == "mps" and not torch.backends.mps.is_available():
        raise DeviceError(f"--device {device}: MPS is not available on this machine; use --device cpu")
    elif dev.type not in ("cpu", "cuda", "mps"):
        raise DeviceError(f"--device {device}: robomorph runs on cpu, cuda or mps, not {dev.type}")
    return dev


class Predictor:
    """Wraps a :class:`TrainedModel` for inference on numpy or torch arrays.

    Attributes:
        model: the network with its normalization, in eval mode.
        n_u, n_y: channel counts the model expects.
        patch: steps per token; context lengths must be multiples of it.
        normalization: the protocol it was trained with (``train_stats`` or ``paper_window``).
        inputs: the input formulation it was trained on: ``total`` (total joint torque)
            or ``command`` (the command without the arm's gravity compensation).
        data_info: channel names, dt and the training window (None for checkpoints that predate it).
        has_std: the model has a Gaussian head (``simulate(..., return_std=True)`` works).
        calibration: the per-horizon scale of that std stored in the checkpoint by ``python -m
            robomorph.calibrate`` (a :class:`StdCalibration`), or None; ``simulate`` applies it.
        device: where it runs.
        max_input_std: ``simulate`` refuses torques further than this many training standard deviations
            from the training mean (default :data:`MAX_INPUT_STDS`; None: no check).
        limits: :meth:`from_arm`'s catalogue limits (:class:`~robomorph.inference.catalogue.ArmLimits`):
            ``simulate`` refuses torques beyond three times the arm's motor limits and context joint angles outside its
            joint ranges (wrong units, with no training statistics to tell); None (a trained model's): no check.
        physics: the physics backbone's record (parameter layout and generator recipe) of a model trained
            with ``--model.physics amortized`` or given a blend by ``robomorph calibrate --blend``, else None.
        settings: how it predicts, every knob of its hybrid included: one frozen
            :class:`~robomorph.inference.settings.HybridSettings`, its defaults from the checkpoint's record
            (mode ``regression`` for commands; for total torques ``blend`` when the model has one, else ``none``,
            its decoder). Change it with :meth:`configure`; the ``physics_*`` attributes of earlier releases
            are deprecated aliases of its fields.
        channels: ``(u_names, y_names)`` of an arm's arrays for a model of several arms (padded inside, its
            outputs alone returned: :mod:`robomorph.model.channels`); None: found by their widths.
        residual: a residual model's record of how its priors are made (:mod:`robomorph.inference.residual`:
            ``simulate`` runs that hybrid, :attr:`prior_predictor`, and adds the network's correction), else None.
    """

    def __init__(self, model: TrainedModel, device: str | torch.device | None = None, data_info: dict | None = None):
        self.device = resolve_device(device)
        self.max_input_std: float | None = MAX_INPUT_STDS
        self.limits = None  # a catalogue arm's torque and joint limits, checked instead (from_arm)
        self.model = model.to(self.device).eval()
        self.n_u, self.n_y, self.patch = model.config.n_u, model.config.n_y, model.config.patch
        self.normalization: str = model.normalizer.normalization
        self.data_info = data_info
        self.has_std = bool(getattr(model, "gaussian", False))
        # Checkpoints written before the command formulation were all trained on total torque.
        self.inputs: str = (data_info or {}).get("inputs", "total")
        self.physics = _backbone(model, data_info)
        self.channels = None
        self.residual = (data_info or {}).get("residual", {}) if getattr(model.config, "residual", False) else None
        self._prior_predictor = None
        self._settings = HybridSettings.of_record(self.physics, self.inputs, getattr(model, "blend", None))
        self._pool = None  # the hybrids (robomorph.inference.hybrid_split.HybridPool), built on first use
        self._stack = None  # a StackConfig: simulate stacks the model with kinematics (the ``stack`` setting)
        if self.physics:
            self.has_std = True  # the spread over robots around the estimate

    @property
    def prior_predictor(self) -> "Predictor":
        """A residual model's hybrid (built on first use), whose prediction its network corrects; change its
        settings with ``prior_predictor.configure`` only as the model's priors were made."""
        if self.residual is None:
            raise PredictionError("this model corrects no prior (it is not a residual model)")
        if self._prior_predictor is None:
            self._prior_predictor = residual.prior_predictor(type(self), self.residual)
        return self._prior_predictor

    @property
    def settings(self) -> HybridSettings:
        """How this Predictor predicts (frozen; :meth:`configure` replaces it)."""
        return self._settings

    def configure(self, settings: HybridSettings | None = None, /, **changes) -> "Predictor":
        """Replaces :attr:`settings` by ``settings`` (default: the current ones) with ``changes`` (names of
        :class:`~robomorph.inference.settings.HybridSettings`), validated as a whole; returns the Predictor.

            pred.configure(mode="refined", members=1)
            pred.configure(HybridSettings.from_key("regression@1~1/2+obs", pred.settings))

        Raises:
            PredictionError: an unknown name, a value out of its range, or a physics mode this model cannot
                predict in (no physics backbone; a network's mode asked of :meth:`from_arm`'s). Nothing changes
                then: the settings stay as they were, so the next call predicts as before."""
        if settings is not None and not isinstance(settings, HybridSettings):
            raise PredictionError(f"configure takes a HybridSettings (or names of its fields), got "
                                  f"{type(settings).__name__}")
        new = (settings or self._settings).replace(**changes)
        if new.mode != self._settings.mode:
            _checked_mode(self.physics, new.mode, "mode")
        catalogue.check_network_free(self, new.mode)
        if new.mode != self._settings.mode and new.mode != "none" and self.physics:
            from robomorph.inference.hybrid import check_mode  # noqa: PLC0415  (MuJoCo only when used)

            check_mode(self.model, new.mode)  # a parameter head or blend weights the model lacks: refused now
        self._settings = new
        return self

    @property
    def hybrids(self) -> tuple:
        """The hybrids built so far: the first (:meth:`hybrid`) and the workers beside it (``settings.workers``)."""
        return () if self._pool is None else tuple(self._pool.hybrids)

    @property
    def settings_in_effect(self) -> HybridSettings:
        """:attr:`settings` with the switches that do not apply to this model's formulation, mode or arm
        turned off (:meth:`HybridSettings.in_effect`): what its hybrid runs with and its calibrations are
        keyed by."""
        recipe = (self.physics or {}).get("recipe") or {}
        return self._settings.in_effect(self.inputs, recipe.get("gravity_compensation"))

    def hybrid(self, strict: bool = False):
        """The :class:`robomorph.inference.hybrid.Hybrid` of this model (built on first use) with the settings
        in effect; a :class:`PredictionError` for a model without a physics backbone. ``strict``: its std's
        points checked against the stored calibrations (:func:`robomorph.inference.hybrid_std.spread_points`;
        a mean needs none)."""
        return self._hybrids().first(self._hybrid_settings(strict))

    def _hybrids(self):
        from robomorph.inference.hybrid_split import HybridPool  # noqa: PLC0415  (MuJoCo only when used)

        if not self.physics:
            raise PredictionError("this model has no physics backbone (it was trained with --model.physics none)")
        self._pool = self._pool or HybridPool(self.model, self.physics, self.inputs)
        return self._pool

    def _hybrid_settings(self, strict: bool) -> HybridSettings:
        """The settings in effect, with the std's points resolved against the stored calibrations."""
        return self.settings_in_effect.replace(points=spread_points(self, strict))

    @property
    def smoothing(self) -> dict | None:
        """What mode ``smoothed`` did so far (:func:`robomorph.identification.smoother.new_report`'s tally:
        windows, stages, handovers), or None before this Predictor's hybrid smoothed any."""
        return None if self._pool is None else self._pool.smoothing

    @smoothing.setter
    def smoothing(self, report: dict) -> None:
        if self._pool is not None:
            self._pool.smoothing = report

    def check_inputs(self, inputs: str | None) -> None:
        """Refuses inputs of the other formulation than the one the model was trained on."""
        check_model_inputs(self.inputs, inputs)

    @property
    def calibration(self):
        """The stored std calibration of this physics mode (a hybrid's std depends on how the robot
        is identified), from windows that open their trajectory where there is one, or None."""
        return kind_calibrations(self)[0]

    def use_physics(self, mode: str | None, option: str = "--physics") -> None:
        """Predicts in physics mode ``mode`` (None: the default); refuses one it cannot predict in, naming
        ``option`` (the command's flag)."""
        if _checked_mode(self.physics, mode, option) is not None:
            self.configure(mode=mode)

    @contextlib.contextmanager
    def raw_std(self) -> Iterator["Predictor"]:
        """Within the block, ``simulate`` returns the Gaussian head's own standard deviation,
        without the stored calibration (what calibrating is fitted on)."""
        kept, settings = self.model.calibrations, self._settings
        # The spread the stored calibrations scale (or the one chosen): what a calibration fitted here records.
        if self.physics and settings.points is None:
            self._settings = settings.replace(points=spread_points(self))
        self.model.calibrations = {}
        try:
            yield self
        finally:
            self.model.calibrations, self._settings = kept, settings

    @property
    def stack(self):
        """The stacking setting: a :class:`robomorph.inference.stacking.StackConfig` under which :meth:`simulate`
        returns this model stacked with kinematic extrapolation by the context backtest (its std measured on the
        robot's own record), or None (the default): the model's own prediction. Set it to a ``StackConfig``, True
        (the default config) or False/None. ``robomorph evaluate --stacked auto`` turns it on for recordings of a real
        robot, where it wins (``results/benchmarks/stacking.md``), and off on simulated stores, where the model
        predicts 10-30 times better than kinematics beyond the backtest's reach and the stack cannot know it."""
        return self._stack

    @stack.setter
    def stack(self, value) -> None:
        from robomorph.inference.stacking import StackConfig  # noqa: PLC0415

        if value is True:
            value = StackConfig()
        elif value is False:
            value = None
        if value is not None and not isinstance(value, StackConfig):
            raise PredictionError(f"stack takes a StackConfig, True, False or None, got {type(value).__name__}")
        self._stack = value

    def _simulate_stacked(self, u_ctx, y_ctx, u_query, inputs, return_std: bool, at_rest, anchor):
        """:meth:`simulate` under the ``stack`` setting: the model (its plain prediction, on every fold's context and
        the whole one) stacked with the kinematic candidates; a trajectory's start (``at_rest``, ``anchor``) is every
        fold's too, since the folds keep the context's first samples."""
        from robomorph.inference.stacking import StackedPredictor  # noqa: PLC0415

        self.check_inputs(inputs)

        def plain(u, y, uq):
            return np.asarray(self.simulate(u, y, uq, inputs=inputs, at_rest=at_rest, anchor=anchor, stacked=False),
                              dtype=np.float64)

        stack = StackedPredictor.of(self, self._stack, model=plain)
        out = stack.simulate(u_ctx, y_ctx, u_query, return_std=return_std)
        out = [torch.as_tensor(np.asarray(t)) for t in (out if return_std else (out,))]
        return _outputs(u_query, out, return_std)

    def stacked(self, config=None):
        """This model stacked with kinematic extrapolation by the context backtest
        (:class:`robomorph.inference.stacking.StackedPredictor`): its ``simulate(u_ctx, y_ctx, u_query,
        return_std=...)`` follows, step by step, what worked on the robot's own recent past, and its std is measured
        there. ``config``: a :class:`robomorph.inference.stacking.StackConfig`."""
        from robomorph.inference.stacking import StackedPredictor  # noqa: PLC0415

        return StackedPredictor.of(self, config)

    def identify_from(self, u, y, config=None):
        """This hybrid identified over the robot's training recordings (a user's identification run), adapted per
        context and corrected in acceleration space: a :class:`robomorph.inference.recordings.RecordingsPredictor`,
        whose ``simulate(u_ctx, y_ctx, u_query)`` predicts with that robot. ``u``, ``y``: lists of (T, n_u) and
        (T, n_y) recordings in this model's formulation (or (N, T, ...) arrays of windows); ``config``: a
        :class:`robomorph.inference.recordings.RecordingsConfig`. Never give it the windows it will be scored on."""
        from robomorph.inference.recordings import RecordingsPredictor  # noqa: PLC0415  (MuJoCo only when used)

        return RecordingsPredictor(self, u, y, config)

    def check(self, u_ctx, y_ctx, config=None):
        """Backtests this model and the kinematic candidates on the context alone: a
        :class:`robomorph.inference.stacking.ContextCheck` (``print(check.summary())``: per horizon, which won and by
        how much); warns when the model explains the context worse than holding its last sample at every step."""
        return self.stacked(config).check(u_ctx, y_ctx)

    @property
    def leaks_query_statistics(self) -> bool:
        """True when this model's predictions need the query outputs' statistics (``paper_window``)."""
        return leaks_query_statistics(self.normalization)

    @classmethod
    def from_checkpoint(cls, path: str, device: str | torch.device | None = None) -> "Predictor":
        """Loads a checkpoint written by ``robomorph fit``, or a model folder written by
        ``robomorph export`` (clear errors for bad files; nothing stored in them is run)."""
        model, info = load_trained(path)
        return cls(model, device, info)

    @classmethod
    def from_arm(cls, arm: str = "panda", recipe: str | None = None, device=None, inputs: str = "command",
                 calibrated: bool = True, **overrides) -> "Predictor":
        """A catalogue arm's command hybrid, untrained: a Predictor with no network
        (:mod:`robomorph.inference.catalogue` holds what it is built from).

        Args:
            arm: a name of :data:`robomorph.sim.arms.ARMS`.
            recipe: the generator recipe whose physics step, gravity compensation and randomization ranges the
                data follow (a shipped name such as ``multisine`` or a YAML path; default the generator's defaults).
            device: where tensors are returned (the simulation runs on the CPU).
            inputs: ``command`` or ``total`` (see :func:`~robomorph.inference.catalogue.arm_record`).
            calibrated: scale the std by the arm's shipped calibration where one applies (module docstring);
                False: the raw spread (what a calibration is fitted on).
            overrides: recipe fields changed, e.g. ``dt=0.01``.

        Raises:
            NoNetworkError: an arm that is not registered, a ``robot`` override naming another arm than
                ``arm``, or ``calibrated`` other than True or False.
            ConfigError: a recipe field out of its range (``dt`` above a second, ...).
        """
        # Validated whole before anything is built (issue 61): robot="ur5e" used to win over the arm in silence.
        if "robot" in overrides and overrides["robot"] != arm:
            raise catalogue.NoNetworkError(f"robot={overrides['robot']!r} names another arm than {arm!r}: give the "
                                           f"arm once, as the first argument (Predictor.from_arm({overrides['robot']!r}))")
        if not isinstance(calibrated, bool):
            raise catalogue.NoNetworkError(f"calibrated must be True or False, got {calibrated!r}")
        info = catalogue.arm_record(arm, recipe, inputs, **overrides)
        model = catalogue.NoNetwork(len(info["u_names"]), len(info["y_names"]))
        if calibrated:
            model.calibrations = catalogue.shipped_calibrations(info)
        pred = cls(model, device, info)
        # The record a trained command hybrid carries, set here: a model without a parameter head takes no
        # backbone from its record (Predictor.__init__), and this one has no model at all.
        pred.physics, pred.has_std = info["physics"], True
        pred.configure(mode="regression", **TODAYS_RECORD)
        pred.max_input_std = None  # no training statistics to compare the inputs with: the catalogue's limits
        pred.limits = catalogue.ArmLimits.of(info["arm"])
        return pred

    @classmethod
    def from_pretrained(cls, path: str, device: str | torch.device | None = None) -> "Predictor":
        """Loads an inference-only model folder written by ``robomorph export``
        (``model.safetensors`` + ``config.json``), or a model shipped with the package by its bare name
        (:mod:`robomorph.model.pretrained`: offline); a training checkpoint is read as well.

        Raises:
            CheckpointError: the folder is missing (a bare name no shipped model has: the shipped ones
                are named), incomplete, altered, or of another format.
        """
        from robomorph.model import pretrained  # noqa: PLC0415

        found = pretrained.resolve(path)
        if not os.path.exists(found) and found == os.fspath(path) and os.sep not in found and "/" not in found:
            raise CheckpointError(f"{path} is neither a model folder nor a shipped model; the package ships "
                                  f"{', '.join(pretrained.available()) or 'none'}")
        return cls.from_checkpoint(found, device)

    def _check_output(self, y: torch.Tensor, inputs: list[torch.Tensor]) -> None:
        """Refuses non-finite predictions instead of handing them on without a word."""
        rows = [] if all_finite(y) else torch.nonzero((~torch.isfinite(y)).flatten(1).any(1)).flatten().tolist()
        if not rows:
            return
        stats = self.model.normalizer
        scale = max(float((inputs[k].abs() / stats.u_std).nan_to_num(nan=0.0).max()) for k in (0, 2))
        raise PredictionError(
            f"the model's predictions are non-finite (NaN or inf) for batch rows {rows[:10]}: the inputs reach "
            f"{scale:.3g} training standard deviations, far outside what the model was trained on; check their "
            "units and scale (the checkpoint expects the training data's)")

    @torch.no_grad()
    def simulate(self, u_ctx, y_ctx, u_query, y_query_stats=None, inputs: str | None = None,
                 return_std: bool = False, at_rest=None, anchor=None, prior=None, stacked: bool | None = None):
        """Predicts the outputs over the query horizon.

        Args:
            u_ctx: (Tc, n_u) or (B, Tc, n_u) context inputs, numpy or torch.
            y_ctx: (Tc, n_y) or (B, Tc, n_y) context outputs.
            u_query: (Th, n_u) or (B, Th, n_u) future inputs.
            y_query_stats: only for a ``paper_window`` model, and required there: ``(mean, std)``
                over time of the query outputs, (n_y,) or (B, n_y) each. This is information
                about the answer: scores obtained with it are not those of a deployable model.
            inputs: which formulation the torques are (``total`` or ``command``); when
                given, a mismatch with the training formulation is refused.
            return_std: also return the predicted standard deviation (models trained with
                ``gaussian: true`` only), recalibrated by horizon when the checkpoint carries a calibration
                (a hybrid's: the spread over robots around its estimate, ``settings.points``, by window kind).
            at_rest, anchor: hybrid models only: bool or (B,) bools, the context opens its trajectory (default
                False); (B, 7) where each robot started (its springs' rest pose; default: the first context sample).
                A residual model hands them to its hybrid.
            prior: residual models only: the hybrid's prediction (Th, n_y) or (B, Th, n_y) made already (that of
                :attr:`prior_predictor` on the same arrays); default: computed here.
            stacked: stack the model with kinematic extrapolation by the context backtest (True), or predict with the
                model alone (False); default: the :attr:`stack` setting. Stacked, the std comes from the backtest.

        Returns:
            y_query (Th, n_y) or (B, Th, n_y), the same kind (numpy/torch) as ``u_query``;
            with ``return_std``, ``(mean, std)``, both in the outputs' physical units.

        Raises:
            NormalizationError: ``y_query_stats`` missing for a ``paper_window`` model, given
                for another, or of the wrong shape.
            InputsError: ``inputs`` names the other formulation.
            PredictionError: arrays of the wrong shape or length (empty, a context that is not a
                multiple of the patch, longer than the positional tables, mismatched batches),
                non-finite inputs, torques further than ``max_input_std`` training standard
                deviations from the training mean, or non-finite predictions.
            CheckpointError: ``return_std`` for a model without a Gaussian head.
        """
        if (self._stack is not None) if stacked is None else stacked:
            if y_query_stats is not None or prior is not None:
                raise PredictionError("a stacked prediction takes neither y_query_stats nor prior: pass stacked=False")
            return self._simulate_stacked(u_ctx, y_ctx, u_query, inputs, return_std, at_rest, anchor)
        self.check_inputs(inputs)
        hybrid = bool(self.physics) and self._settings.mode != "none"
        if return_std and not (self.has_std if hybrid else getattr(self.model, "gaussian", False)):
            raise CheckpointError("this model has no Gaussian head, so it predicts no standard deviation; "
                                  "train one with --model.gaussian true --model.loss nll, or drop return_std")
        tensors, single, cols = self._arm_batch((u_ctx, y_ctx, u_query))
        check_range(self, *tensors)
        if hybrid and y_query_stats is not None:
            raise NormalizationError("a hybrid model uses no query statistics: drop y_query_stats")
        stats = None if hybrid else self._query_stats(y_query_stats, len(tensors[0]))
        if hybrid:
            check_hybrid_context(tensors[0].shape[1])
        try:
            if hybrid:
                mean, std = self._hybrids().predict(self._hybrid_settings(return_std), tensors, return_std, at_rest,
                                                    anchor)
                mean, std = (None if t is None else torch.as_tensor(t) for t in (mean, std))
                std = None if std is None else calibrated_rows(self, std, at_rest)
            else:
                if prior is not None and self.residual is None:
                    raise PredictionError("prior: this model corrects no prior (it is not a residual model); drop it")
                if self.residual is not None:
                    prior = residual.query_prior(self, tensors, prior, at_rest, anchor)
                mean, std = self.model.forward_dist_raw(*tensors, stats, prior=prior)
                std = std if std is None or self.calibration is None else self.calibration.apply(std)
        except RoboMorphError:
            raise
        except ValueError as exc:  # the network's shape and length checks: the caller's arrays
            raise PredictionError(str(exc)) from None
        mean, std = select(mean, cols), select(std, cols)
        self._check_output(mean, tensors)
        return _outputs(u_query, [t[0] if single else t for t in (mean, std) if t is not None], return_std)

    def _arm_batch(self, arrays) -> tuple[list[torch.Tensor], bool, tuple | None]:
        """:func:`as_batch` of an arm's arrays, padded to the model's channels when it has fewer
        (a model of several arms), and their columns there (None: the model's own channels).
        The Predictor's settings are checked first (:func:`check_settings`): every simulate comes here."""
        check_settings(self)
        cols = arm_columns(self.model.config.channel_mask, self.data_info, arrays, (self.n_u, self.n_y), self.channels)
        widths = (self.n_u, self.n_y) if cols is None else (len(cols[0]), len(cols[1]))
        tensors, single = as_batch(arrays, (*widths, widths[0]), self.device)
        return (tensors if cols is None else pad(tensors, cols, self.n_u, self.n_y)), single, cols

    def _query_stats(self, y_query_stats, batch: int):
        """Checks ``y_query_stats`` against the predictor's normalization; (mean, std) tensors (B, n_y) or None."""
        if not self.leaks_query_statistics:
            if y_query_stats is not None:
                raise NormalizationError(f"this model was trained with normalization {self.normalization!r}, which "
                                         "uses no query statistics: drop y_query_stats")
            return None
        if y_query_stats is None:
            raise NormalizationError(
                "this model was trained with normalization 'paper_window' (the paper's protocol): it rescales each "
                "window with the mean and std of the outputs it is asked to predict, which a deployed model cannot "
                "know. Pass y_query_stats=(mean, std) of the query outputs "
                "(robomorph.core.normalizations.query_output_stats(y_query)) to score it as the paper did, or train "
                "with data.normalization=train_stats for a model you can deploy")
        if len(y_query_stats) != 2:
            raise NormalizationError("y_query_stats must be a pair (mean, std) of the query outputs")
        out = []
        for name, v in zip(("mean", "std"), y_query_stats):
            t = torch.as_tensor(np.asarray(v) if not isinstance(v, torch.Tensor) else v, dtype=torch.float32,
                                device=self.device)
            t = t.unsqueeze(0) if t.dim() == 1 else t
            if t.shape not in ((1, self.n_y), (batch, self.n_y)) or not all_finite(t):
                raise NormalizationError(f"y_query_stats {name} must be finite, ({self.n_y},) or ({batch}, {self.n_y}); "
                                         f"got {tuple(t.shape)}")
            out.append(t.expand(batch, self.n_y))
        return tuple(out)


def _checked_mode(physics: dict | None, mode: str | None, option: str) -> str | None:
    """``mode`` once a model with backbone record ``physics`` can predict in it (None stays None)."""
    from robomorph.inference.hybrid import MODES  # noqa: PLC0415

    if mode is not None and mode != "none" and not physics:
        raise PredictionError(f"{option} {mode}: this model has no physics backbone (trained with --model.physics "
                              "none, e.g. on real logs without a catalogue robot); drop the option")
    if mode is not None and mode not in (*MODES, "none"):
        raise PredictionError(f"{option} {mode!r}: choose none or one of {', '.join(MODES)}")
    return mode


def _backbone(model: TrainedModel, data_info: dict | None) -> dict | None:
    """The physics backbone's record of a model trained with a parameter head, or of one whose blend brought it."""
    blend = getattr(model, "blend", None)
    return ((data_info or {}).get("physics") if model.config.n_params else None) \
        or (blend.physics if blend is not None else None) or None


def _deprecated_alias(name: str):
    """``Predictor.physics_<name>``: the settings' ``name``, read and set with a DeprecationWarning (one release)."""
    attr = f"physics_{name}"

    def warn() -> None:
        warnings.warn(f"Predictor.{attr} is deprecated: read predictor.settings.{name}, set it with "
                      f"predictor.configure({name}=...)", DeprecationWarning, stacklevel=3)

    def get(self):
        warn()
        return getattr(self._settings, name)

    def set_(self, value):
        warn()
        self.configure(**{name: value})

    return property(get, set_, doc=f"Deprecated: :attr:`settings`.{name}.")


for _name in ("mode", "samples", "members", "points", "substeps", "observer", "springs", "debias", "candidates",
              "workers"):
    setattr(Predictor, f"physics_{_name}", _deprecated_alias(_name))


def _outputs(u_query, out: list[torch.Tensor], return_std: bool):
    """The prediction (and std) as the caller gave ``u_query``: numpy of its float type, or torch on its device."""
    if isinstance(u_query, torch.Tensor):
        out = [t.to(u_query.device, u_query.dtype) for t in out]
    else:
        dtype = getattr(u_query, "dtype", None)
        kind = dtype if dtype is not None and np.issubdtype(dtype, np.floating) else np.float32
        out = [t.cpu().numpy().astype(kind) for t in out]
    return tuple(out) if return_std else out[0]
