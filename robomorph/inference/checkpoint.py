"""Reading a trained model back from a checkpoint or a model folder, without the training code.

A checkpoint written by ``robomorph fit`` holds ``hyper_parameters`` (the architecture and
``n_u``/``n_y``), a ``state_dict`` with ``net.*`` (the :class:`MetaModel`) and
``normalizer.*`` (its :class:`Normalizer`) entries, and what the model was trained on under
:data:`DATA_INFO_KEY`; a folder written by ``robomorph export`` holds the same in
safetensors and JSON. Both are read by :mod:`robomorph.model.files`, which runs nothing
stored in them. :func:`load_trained` rebuilds the plain modules, so inference needs only
``robomorph.model`` and ``robomorph.core`` (no Lightning).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn

from robomorph.core.names import EXTRAPOLATIONS
from robomorph.core.velocity import velocity_weights
from robomorph.inference.blending import BLEND_KEY, BlendError, HorizonBlend
from robomorph.inference.calibration import CALIBRATION_KEY, CalibrationError, StdCalibration, calibration_key, read_calibrations

# The reader of model files; these names are imported from here by the rest of the package.
from robomorph.model.files import DATA_INFO_KEY, CheckpointError, load_checkpoint_file, read_model  # noqa: F401
from robomorph.model.normalization import Normalizer
from robomorph.model.transformer import MetaModel, ModelConfig

# State entries of the training wrapper that inference does not need.
_TRAINING_ONLY = ("stats_ready",)
# Per-step change of the normalized outputs that one unit of network output means with
# ``integrate``: of the order of the arm's per-step motion at 60 Hz (about 0.01 of a
# channel's standard deviation), so that an untrained network's random walk over 800 steps
# stays within a few standard deviations.
INTEGRATE_SCALE = 0.05
# Per-step acceleration of the normalized outputs that one unit of network output means with a kinematic
# anchor and ``integrate``: about 2 rad/s^2 at 60 Hz for a joint whose training std is 0.5 rad (the
# arms' accelerations are of the order of 1 to 10 rad/s^2), so that the first step's correction of an
# output of order 1 is a fraction of a mrad, the size of constant velocity's own first-step error.
ACCEL_SCALE = 1e-3


def model_config(hparams: dict) -> ModelConfig:
    """The architecture named by a model's hyper-parameters (absent fields take the defaults)."""
    names = {f.name for f in dataclasses.fields(ModelConfig)}
    return ModelConfig(**{k: v for k, v in hparams.items() if k in names})


def predict_normalized_dist(net: MetaModel, anchor: bool, uc: torch.Tensor, yc: torch.Tensor, uq: torch.Tensor,
                            integrate: bool = False, prior: torch.Tensor | None = None, velocity_points: int = 0
                            ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Normalized mean (B, Th, n_y) and log-variance (or None without a Gaussian head) from
    normalized inputs.

    With ``anchor`` the network predicts the deviation from the last context output, which is
    added back (a context value: nothing of the query leaks). With ``integrate`` it predicts
    per-step changes (scaled by :data:`INTEGRATE_SCALE`), summed from the last context output.
    With ``velocity_points`` (> 0) it predicts the correction to constant-velocity extrapolation
    from the last context output (:func:`kinematic_anchor`), so a zero output is ``y + v t``; with
    ``integrate`` as well, that correction is the double sum of per-step accelerations (scaled by
    :data:`ACCEL_SCALE`), so it starts at zero and grows as a motion does.
    A residual model (``prior``, the normalized prior prediction) predicts a correction in units of
    its ``prior_scale`` per step and channel, added to the prior.
    """
    mean, logvar = net.forward_dist(uc, yc, uq, prior)
    if prior is not None:
        return prior + mean * net.prior_scale[:mean.shape[1]], logvar
    if velocity_points:
        if integrate:
            # Per-step accelerations summed twice: the correction at step k is ACCEL_SCALE * sum_j (k - j + 1) a_j,
            # so the first step's is one output's ACCEL_SCALE, whatever the network makes of an unfamiliar context.
            mean = ACCEL_SCALE * mean.cumsum(dim=1).cumsum(dim=1)
        return mean + kinematic_anchor(yc, mean.shape[1], velocity_points), logvar
    if integrate:
        # A running sum over steps <= t: causal, like the decoder it follows.
        mean = INTEGRATE_SCALE * mean.cumsum(dim=1)
    if anchor or integrate:
        mean = mean + yc[:, -1:]
    return mean, logvar


def kinematic_anchor(yc: torch.Tensor, th: int, points: int) -> torch.Tensor:
    """Constant-velocity extrapolation (B, th, n_y) of the context outputs (B, Tc, n_y): ``y[-1] + k v``
    at query step ``k``, ``v`` per step from the last ``points`` samples (the fit of
    :func:`robomorph.core.velocity.estimate_velocity`; 2 points: the last backward difference, the
    ``constant_velocity`` baseline). Context values only, and linear in them, so it holds in normalized
    units as in physical ones."""
    w = torch.as_tensor(velocity_weights(yc.shape[1], points), dtype=yc.dtype, device=yc.device)  # (k,)
    v = torch.einsum("k,bkc->bc", w, yc[:, -len(w):])  # (B, n_y) per step
    k = torch.arange(1, th + 1, dtype=yc.dtype, device=yc.device)[None, :, None]  # (1, th, 1)
    return yc[:, -1:] + k * v[:, None]


def predict_normalized(net: MetaModel, anchor: bool, uc: torch.Tensor, yc: torch.Tensor,
                       uq: torch.Tensor, integrate: bool = False) -> torch.Tensor:
    """Normalized prediction (B, Th, n_y) from normalized inputs (the mean of a Gaussian head)."""
    return predict_normalized_dist(net, anchor, uc, yc, uq, integrate)[0]


def simulate(net: MetaModel, normalizer: Normalizer, anchor: bool, u_ctx: torch.Tensor,
             y_ctx: torch.Tensor, u_query: torch.Tensor, y_query_stats=None, integrate: bool = False,
             velocity_points: int = 0) -> torch.Tensor:
    """Predicts y over the query horizon in physical units: normalize, predict, decode.

    ``y_query_stats`` (mean, std of the query outputs) only under the ``paper_window`` protocol.
    """
    return simulate_dist(net, normalizer, anchor, u_ctx, y_ctx, u_query, y_query_stats, integrate,
                         velocity_points=velocity_points)[0]


def simulate_dist(net: MetaModel, normalizer: Normalizer, anchor: bool, u_ctx: torch.Tensor,
                  y_ctx: torch.Tensor, u_query: torch.Tensor, y_query_stats=None, integrate: bool = False,
                  prior: torch.Tensor | None = None, velocity_points: int = 0
                  ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Mean and standard deviation (None without a Gaussian head) in physical units; a residual
    model's ``prior`` (B, Th, n_y) in physical units, normalized here as the outputs are."""
    uc, yc, uq = normalizer.encode(u_ctx, y_ctx, u_query, y_query_stats)
    prior_n = None if prior is None else normalizer.encode_target(prior, y_ctx, y_query_stats)
    mean, logvar = predict_normalized_dist(net, anchor, uc, yc, uq, integrate, prior_n, velocity_points)
    # Recentring and anchoring shift the outputs; only the z-score scales them.
    std = None if logvar is None else torch.exp(0.5 * logvar) * normalizer.decode_scale(
        y_ctx, y_query_stats, u_query.shape[1])
    return normalizer.decode(mean, y_ctx, y_query_stats), std


class TrainedModel(nn.Module):
    """The network with the normalization it was trained with: physical units in and out.

    Its state has the same ``net.*`` and ``normalizer.*`` names as the training module's,
    so a checkpoint's ``state_dict`` loads into it directly.

    Args:
        config: the architecture.
        recenter: the normalizer subtracts each trajectory's context mean.
        anchor: predictions are offsets from the last context output.
        normalization: ``train_stats`` or ``paper_window`` (see :class:`Normalizer`).
        integrate: the network predicts per-step changes summed from the last context output.
        extrapolate: ``none``, or ``velocity``: the network predicts the correction to constant-velocity
            extrapolation from the last context output (:func:`kinematic_anchor`).
        velocity_points: with ``velocity``, the last context samples its velocity is fitted to.

    Attributes:
        gaussian: the network has a Gaussian head (:meth:`forward_dist` gives a std).
        calibrations: the per-horizon scales of that std fitted after training
            (``python -m robomorph.calibrate``), by physics mode and window kind (``none``: the decoder's).
        calibration: the decoder's, or None: applied by :meth:`forward_dist`.
        blend: the per-horizon weights of its physics prediction against its decoder's
            (``robomorph calibrate --blend``, :mod:`robomorph.inference.blending`), or None.
    """

    def __init__(self, config: ModelConfig, recenter: bool = False, anchor: bool = False,
                 normalization: str = "train_stats", integrate: bool = False, extrapolate: str = "none",
                 velocity_points: int = 2):
        super().__init__()
        check_extrapolation(extrapolate, velocity_points)
        self.config, self.anchor, self.integrate = config, bool(anchor), bool(integrate)
        self.extrapolate, self.velocity_points = extrapolate, int(velocity_points)
        self.gaussian = bool(config.gaussian)
        self.net = MetaModel(config)
        if self.kinematic_points:
            # An untrained correction is zero, as a residual model's: training starts from constant velocity
            # (a checkpoint's weights replace these).
            with torch.no_grad():
                self.net.head.weight.zero_()
                if self.net.head.bias is not None:
                    self.net.head.bias.zero_()
        self.calibrations: dict[str, StdCalibration] = {}
        self.blend = None
        self.normalizer = Normalizer(n_u=config.n_u, n_y=config.n_y, recenter=recenter, normalization=normalization)

    def forward(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                y_query_stats=None, prior: torch.Tensor | None = None) -> torch.Tensor:
        """(B, Tc, n_u), (B, Tc, n_y), (B, Th, n_u) in physical units -> (B, Th, n_y); a residual
        model's ``prior`` (B, Th, n_y) in physical units."""
        return self.forward_dist(u_ctx, y_ctx, u_query, y_query_stats, prior)[0]

    def forward_dist(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                     y_query_stats=None, prior: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean (B, Th, n_y) and standard deviation (or None without a Gaussian head), physical units;
        the standard deviation recalibrated by horizon when the model carries a calibration."""
        mean, std = self.forward_dist_raw(u_ctx, y_ctx, u_query, y_query_stats, prior)
        if std is not None and self.calibration is not None:
            std = self.calibration.apply(std)
        return mean, std

    def forward_dist_raw(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                         y_query_stats=None, prior: torch.Tensor | None = None
                         ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """:meth:`forward_dist` without the calibration: the head's own standard deviation."""
        return simulate_dist(self.net, self.normalizer, self.anchor, u_ctx, y_ctx, u_query, y_query_stats,
                             self.integrate, prior, self.kinematic_points)

    @property
    def kinematic_points(self) -> int:
        """Points of the kinematic anchor's velocity fit, 0 without one (what the predictors take)."""
        return self.velocity_points if self.extrapolate == "velocity" else 0

    @property
    def calibration(self) -> StdCalibration | None:
        """The decoder's std calibration (physics mode ``none``), or None."""
        return self.calibrations.get("none")

    def set_calibration(self, calibration: StdCalibration | None) -> None:
        """Attaches a std calibration under its :func:`calibration_key` (replacing the one there),
        checked against the model; None removes them all."""
        if calibration is None:
            self.calibrations = {}
            return
        if not self.gaussian and not self.config.n_params:
            raise CalibrationError("this model has no Gaussian head, so it has no standard deviation to calibrate")
        if calibration.n_y != self.config.n_y:
            raise CalibrationError(f"the calibration has {calibration.n_y} channels, the model {self.config.n_y}")
        self.calibrations = {**self.calibrations, calibration_key(calibration): calibration}


def check_extrapolation(extrapolate: str, velocity_points: int) -> None:
    """Refuses an unknown extrapolation or a velocity fit of fewer than 2 points (ValueError naming them)."""
    if extrapolate not in EXTRAPOLATIONS:
        raise ValueError(f"extrapolate must be one of {list(EXTRAPOLATIONS)}, got {extrapolate!r}")
    if isinstance(velocity_points, bool) or not isinstance(velocity_points, (int, np.integer)) or velocity_points < 2:
        raise ValueError(f"velocity_points must be an integer of at least 2 (2: the last backward difference), "
                         f"got {velocity_points!r}")


def _build(path: str, hp: dict, state: dict, device: torch.device | None = None) -> TrainedModel:
    """The model ``hp`` declares (on ``device``); on the meta device, refused unless every
    tensor of ``state`` has the shape the declared sizes give."""
    try:
        with torch.device(device or "cpu"):
            model = TrainedModel(model_config(hp), recenter=bool(hp.get("recenter", False)),
                                 anchor=bool(hp.get("anchor", False)),
                                 normalization=hp.get("normalization", "train_stats"),
                                 integrate=bool(hp.get("integrate", False)),
                                 # Absent from models written before the option: they predict as they did.
                                 extrapolate=hp.get("extrapolate", "none"),
                                 velocity_points=hp.get("velocity_points", 2))
    except (ValueError, TypeError) as exc:
        raise CheckpointError(f"{path} holds an invalid architecture: {exc}") from exc
    if device is not None:
        declared = {k: tuple(v.shape) for k, v in model.state_dict().items()}
        stored = {k: tuple(v.shape) for k, v in state.items() if hasattr(v, "shape")}
        wrong = sorted(k for k in declared.keys() | stored.keys() if declared.get(k) != stored.get(k))
        if wrong:
            k = wrong[0]
            raise CheckpointError(f"{path} does not match its own hyper-parameters: {len(wrong)} weights differ, "
                                  f"e.g. {k} is {stored.get(k, 'missing')} in the weights but "
                                  f"{declared.get(k, 'unknown')} by the declared sizes; export the model again")
    return model


def load_trained(path: str) -> tuple[TrainedModel, dict | None]:
    """Rebuilds the trained model of a checkpoint or of a model folder (``robomorph export``).

    Returns:
        ``(model in eval mode on the CPU, data info or None)``; the data info (channel names,
        dt, training window) is None for checkpoints written before it was recorded. A std
        calibration stored with the model is attached to it.

    Raises:
        CheckpointError: the file is missing, unreadable, refused as unsafe, or not a model
            written by ``fit``.
    """
    return trained_of(read_model(path), path)


def trained_of(ckpt: dict, path: str) -> tuple[TrainedModel, dict | None]:
    """:func:`load_trained` of a record :func:`read_model` read already (a command that needs the record too
    reads the file once); ``path`` names it in the errors. The record is not changed."""
    hp = ckpt["hyper_parameters"]
    if hp.get("n_u") is None or hp.get("n_y") is None:
        raise CheckpointError(f"{path} lacks n_u/n_y: it was not written by robomorph fit")
    state = {k: v for k, v in ckpt["state_dict"].items() if k not in _TRAINING_ONLY}
    _build(path, hp, state, torch.device("meta"))  # the declared sizes against the weights, allocating nothing
    model = _build(path, hp, state)
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(f"{path} does not match its own hyper-parameters: {exc}") from exc
    if ckpt.get(CALIBRATION_KEY) is not None:
        try:
            for cal in read_calibrations(ckpt[CALIBRATION_KEY]).values():
                model.set_calibration(cal)
        except CalibrationError as exc:
            raise CheckpointError(f"{path}: {exc}") from exc
    if ckpt.get(BLEND_KEY) is not None:
        try:
            model.blend = HorizonBlend.from_dict(ckpt[BLEND_KEY])
        except BlendError as exc:
            raise CheckpointError(f"{path}: {exc}") from exc
        if model.blend.n_y != model.config.n_y:
            raise CheckpointError(f"{path}: its physics blend has {model.blend.n_y} channels, the model "
                                  f"{model.config.n_y}: fit it again with robomorph calibrate --blend")
    return model.eval(), ckpt.get(DATA_INFO_KEY)
