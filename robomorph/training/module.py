"""The LightningModule: loss, optimizer, schedule, logging and transfer initialization.

The network is the plain :class:`robomorph.model.transformer.MetaModel`; normalization (statistics of
the training split, carried in the checkpoint) is a :class:`Normalizer` beside it. Batches
arrive in physical units from :class:`robomorph.data.datamodule.RoboMorphDataModule`.
"""

from __future__ import annotations

from typing import Literal

import lightning.pytorch as L
import torch

from robomorph.core.errors import RoboMorphError
from robomorph.core.names import (
    EXTRAPOLATIONS,
    FREEZE_MODES,
    LOSSES,
    NORMALIZATIONS,
    TODAYS_RECORD,
)
from robomorph.core.normalizations import check_normalization
from robomorph.inference.checkpoint import (
    DATA_INFO_KEY,
    TrainedModel,
    check_extrapolation,
    model_config,
)
from robomorph.model.normalization import Normalizer
from robomorph.model.transformer import MetaModel, ModelConfig
from robomorph.training.compiling import COMPILE_MODES, check_compile
from robomorph.training.data_record import check_channels, data_info
from robomorph.training.losses import ModelOptionError, check_loss
from robomorph.training.optim import lr_factor as _lr_factor
from robomorph.training.optim import clip_fused, optimizers
from robomorph.training.physics import N_PHYSICAL, check_physics, resolve_physics
from robomorph.training.pretrained import apply_freeze, start_from
from robomorph.training.steps import Steps

# Constructor arguments that the data decide: robomorph fit links them from the datamodule.
FROM_DATA = ("n_u", "n_y", "context_len", "channel_mask", "residual")
# Checkpoint entry holding the trainer's max_steps, so a resume can say how the schedule changes.
SCHEDULE_KEY = "robomorph_schedule"


class ModelSettingsError(ModelOptionError):
    """Model or optimizer settings that cannot work; the message names the ``--model.`` flag."""


class MetaModule(Steps, L.LightningModule):
    """Trains a :class:`MetaModel` to predict y over the horizon from a context of (u, y).

    Args:
        n_u, n_y: channel counts. ``robomorph fit`` links them from the datamodule's
            stores; a module built without them cannot train or predict.
        context_len: the training context in steps (linked from the datamodule as well);
            checked against ``patch`` and ``max_context`` when given.
        d_model, n_head, n_layer, n_layer_dec, dropout, bias, patch, max_context, max_horizon:
            the network; defaults and meaning in :class:`robomorph.model.transformer.ModelConfig`
            (the CPU-sized model: d 128, 4 + 4 layers, 4 heads, patches of 10 steps).
        n_init: last context steps given to the decoder as initial-condition tokens (0 = off).
        gaussian: the head also predicts a log-variance per step and channel.
        loss: ``huber``, ``mse`` or ``nll`` (Gaussian NLL, needs ``gaussian``), on normalized outputs.
        huber_delta: Huber transition point in normalized units.
        horizon_weight, horizon_tau: query step t weighs ``1 + horizon_weight * exp(-t / horizon_tau)``
            in the loss, rescaled to mean 1 (0: uniform), so the first steps count more.
        lr: peak learning rate (AdamW).
        min_lr_ratio: the cosine decays to ``lr * min_lr_ratio``.
        warmup_steps: linear warmup length.
        decay_steps: cosine length (default: the trainer's ``max_steps``).
        weight_decay: AdamW weight decay on matrices (not on biases, norms, embeddings).
        betas: AdamW betas.
        recenter: subtract the context mean of each trajectory (context-only statistics).
        normalization: ``train_stats`` (training-split statistics) or ``paper_window`` (the
            paper's protocol: each window z-scored over context and query; its predictions use
            the query outputs' statistics). Linked from ``data.normalization`` by ``robomorph.fit``.
        anchor: the network predicts the deviation from the last context output, which
            is added back (a context value: nothing of the query leaks). The prediction
            then starts where the robot is instead of having to locate it first.
        integrate: the network predicts per-step changes summed from the last context output.
        extrapolate: ``velocity``: the network predicts the correction to constant-velocity
            extrapolation from the last context sample (``y[-1] + k v`` at query step ``k``, ``v``
            fitted to the last ``velocity_points`` context samples), so an untrained or zeroed
            network predicts what the ``constant_velocity`` baseline does and the first steps start
            on the arm's motion; with ``integrate`` the correction is summed twice from per-step
            accelerations, so the first step's is small whatever the context (the shipped model's form);
            ``none`` (default): as ``anchor`` and ``integrate`` say.
        velocity_points: context samples the velocity is fitted to with ``extrapolate velocity``
            (2, the default: the last backward difference, the ``constant_velocity`` baseline's;
            up to 6 as :func:`robomorph.core.velocity.estimate_velocity`, a cubic over them).
        init_ckpt: start from this checkpoint's (or model folder's) weights and normalization (transfer).
        freeze: ``none``, ``encoder`` or ``all_but_head``.
        reinit_io: when the checkpoint's n_u / n_y differ, re-initialize the input
            embeddings and the head instead of failing.
        normalization_from: with ``init_ckpt``, where the normalization statistics come
            from: ``target`` (default), this run's training data; ``source``, the
            checkpoint's (same channels only: with new channels they come from the data).
        physics: ``none`` (the black-box model), ``amortized`` (a parameter head learns each
            robot's physical parameters from the context, targets the store's ``params``, and
            the Predictor simulates the robot identified from the context: the hybrid model,
            :mod:`robomorph.inference.hybrid`; needs simulated Panda stores that record
            ``params``) or ``auto`` (``amortized`` in the command formulation when every
            training store can have it, else ``none`` with a note: imported real logs have no
            catalogue robot, and total torques make any simulation diverge within seconds).
        param_weight: weight of the parameter head's Gaussian NLL in the loss.
        decoder_loss: also train the black-box decoder (false: the parameter head alone, whose
            training steps then skip the decoder; the decoder stays untrained).
        n_params: set from ``physics`` (the Panda's 29 identifiable parameters); not a setting.
        channel_mask: some training stores lack some of the run's channels (arms with fewer
            joints): the network reads which are absent and the loss skips them
            (:class:`robomorph.model.architecture.ModelConfig`); linked from the datamodule.
        compile: how the training step runs: ``auto`` (compiled with CUDA graphs on a CUDA
            device, eager on a CPU), ``off``, or a ``torch.compile`` mode (``default``,
            ``reduce-overhead``, ``max-autotune``); see :mod:`robomorph.training.compiling`.
            It changes the speed of training, not the model or its checkpoint.
        residual: the network learns the correction of a physics prior (prior stores,
            :mod:`robomorph.data.priors`): its decoder reads the prior's query prediction and its output
            is added to it (:mod:`robomorph.inference.residual`); linked from the datamodule.
    """

    def __init__(
        self,
        n_u: int | None = None,
        n_y: int | None = None,
        context_len: int | None = None,
        # The architecture's defaults are ModelConfig's, defined there once.
        d_model: int = ModelConfig.d_model,
        n_head: int = ModelConfig.n_head,
        n_layer: int = ModelConfig.n_layer,
        n_layer_dec: int | None = ModelConfig.n_layer_dec,
        dropout: float = ModelConfig.dropout,
        bias: bool = ModelConfig.bias,
        patch: int = ModelConfig.patch,
        max_context: int = ModelConfig.max_context,
        max_horizon: int = ModelConfig.max_horizon,
        n_init: int = ModelConfig.n_init,
        gaussian: bool = ModelConfig.gaussian,
        loss: Literal[LOSSES] = "huber",
        huber_delta: float = 1.0,
        horizon_weight: float = 0.0,
        horizon_tau: float = 60.0,
        lr: float = 1e-3,
        min_lr_ratio: float = 0.1,
        warmup_steps: int = 200,
        decay_steps: int | None = None,
        weight_decay: float = 0.0,
        betas: tuple[float, float] = (0.9, 0.95),
        recenter: bool = False,
        normalization: Literal[NORMALIZATIONS] = "train_stats",
        anchor: bool = False,
        integrate: bool = False,
        extrapolate: Literal[EXTRAPOLATIONS] = "none",
        velocity_points: int = 2,
        init_ckpt: str | None = None,
        freeze: Literal[FREEZE_MODES] = "none",
        reinit_io: bool = False,
        normalization_from: Literal["source", "target"] = "target",
        physics: Literal["none", "amortized", "auto"] = "none",
        param_weight: float = 1.0,
        decoder_loss: bool = True,
        n_params: int | None = None,
        channel_mask: bool = False,
        compile: Literal[COMPILE_MODES] = "auto",
        residual: bool = False,
    ):
        super().__init__()
        if residual and (anchor or integrate or physics == "amortized"):
            raise ModelSettingsError("a residual model (prior stores) corrects the prior's prediction: it goes with "
                                     "neither --model.anchor, --model.integrate nor --model.physics amortized")
        _check_extrapolation(extrapolate, velocity_points, anchor, integrate, residual)
        check_physics(physics, param_weight, decoder_loss)
        check_loss(loss, gaussian, horizon_weight, horizon_tau)
        _check_training(freeze, normalization_from, lr, min_lr_ratio, warmup_steps, huber_delta, compile)
        check_context(context_len, patch, max_context)
        check_normalization(normalization, recenter)
        self.save_hyperparameters()
        self.hparams.n_params = 0 if residual else _n_params(physics, channel_mask)
        self._physics_on, self._layout = physics == "amortized", None  # set by setup from the data
        self.net, self.normalizer = None, None  # MetaModel and Normalizer, built by _build
        # Set by robomorph.fit when it resumes a run: the checkpoint then supplies the
        # weights, so init_ckpt (possibly gone by now) must not be read again.
        self.resuming = False
        # What the model was trained on (channel names, dt, window lengths): saved in the
        # checkpoint so evaluation can check a store against it and take its defaults.
        self.data_info: dict | None = None
        if n_u is not None and n_y is not None:
            self._build(n_u, n_y)

    # ----------------------------------------------------------------- construction
    @property
    def model_config(self) -> ModelConfig:
        return self.config_for(self.hparams.n_u, self.hparams.n_y)

    def config_for(self, n_u: int, n_y: int) -> ModelConfig:
        """The network's validated configuration for ``n_u`` inputs and ``n_y`` outputs (:func:`settings_config`)."""
        return settings_config({**dict(self.hparams), "n_u": n_u, "n_y": n_y})

    def _build(self, n_u: int, n_y: int) -> None:
        h = self.hparams
        trained = TrainedModel(self.model_config, recenter=h.recenter, anchor=h.anchor, normalization=h.normalization,
                               integrate=h.integrate, extrapolate=h.extrapolate, velocity_points=h.velocity_points)
        # Outside the module tree, so the checkpoint keys stay ``net.*`` and ``normalizer.*``.
        self.__dict__["_trained"] = trained
        self.net, self.normalizer = trained.net, trained.normalizer
        self.register_buffer("stats_ready", torch.tensor(False))
        apply_freeze(self.net, self.hparams.freeze)

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is None:
            return
        check_channels(dm, self.hparams.n_u, self.hparams.n_y, self.hparams.get("channel_mask", False))
        if bool(getattr(dm, "residual", False)) != bool(self.hparams.get("residual", False)):
            raise ModelSettingsError("a residual model trains on prior stores (robomorph priors) and only there: "
                                     f"the data {'are' if getattr(dm, 'residual', False) else 'are not'} prior stores, "
                                     f"--model.residual is {self.hparams.get('residual', False)} (robomorph fit links it)")
        if stage == "fit" or self.data_info is None:
            self.data_info = data_info(dm)
            if getattr(dm, "prior", None) is not None:
                # What the Predictor needs to make the same prior at inference (robomorph.inference.residual).
                self.data_info = {**self.data_info, "residual": dm.prior}
        self._physics_on, self._layout = resolve_physics(self.hparams.physics if self.hparams.n_params else "none",
                                                         dm, stage)
        if self._physics_on:
            # The hybrid's switches as a model trained today records them (robomorph.inference.settings.TODAYS_RECORD,
            # where each one's measurement is cited); older records lack the newer ones and predict as before.
            self.data_info = {**self.data_info, "physics": {**self._layout, "mode": "amortized", **TODAYS_RECORD}}
        if stage == "fit" and self.hparams.init_ckpt and not self.resuming and not getattr(self, "_transferred", False):
            start_from(self, self.hparams.init_ckpt)
            self._transferred = True
        if not bool(self.stats_ready):
            # A resumed or transferred model keeps the statistics it was trained with.
            self.normalizer.set_stats(dm.stats)
            if self.net.cfg.residual:
                set_prior_scale(self.net, dm.prior_error, dm.stats.y_std)
            self.stats_ready.fill_(True)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.data_info is not None:
            checkpoint[DATA_INFO_KEY] = self.data_info
        if self._trainer is not None:
            checkpoint[SCHEDULE_KEY] = {"max_steps": int(self.trainer.max_steps)}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.data_info = checkpoint.get(DATA_INFO_KEY, self.data_info)

    @property
    def trained_model(self) -> TrainedModel:
        """The network and normalization being trained, as the :class:`TrainedModel` that
        ``Predictor.from_checkpoint`` loads (same tensors): ``Predictor(module.trained_model)``."""
        if self.net is None:
            raise RoboMorphError("the model has no n_u/n_y yet: pass them (robomorph fit links them from the data)")
        return self.__dict__["_trained"]

    # --------------------------------------------------------------------- forward
    def forward(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                y_query_stats=None) -> torch.Tensor:
        """Predicts y over the query horizon, in physical units (the Predictor's computation).

        ``y_query_stats`` (mean, std of the query outputs, (B, n_y) each) is needed, and used,
        only under ``normalization="paper_window"``.
        """
        return self.trained_model.forward_dist_raw(u_ctx, y_ctx, u_query, y_query_stats)[0]

    def forward_dist(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, y_query_stats=None
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean and standard deviation (None without a Gaussian head), both in physical units."""
        return self.trained_model.forward_dist_raw(u_ctx, y_ctx, u_query, y_query_stats)

    # ------------------------------------------------------------------ optimizer
    def configure_optimizers(self):
        return optimizers(self)

    def configure_gradient_clipping(self, optimizer, gradient_clip_val=None, gradient_clip_algorithm=None) -> None:
        if not clip_fused(self, optimizer, gradient_clip_val, gradient_clip_algorithm):
            super().configure_gradient_clipping(optimizer, gradient_clip_val, gradient_clip_algorithm)


def set_prior_scale(net: MetaModel, error: "np.ndarray", y_std: "np.ndarray") -> None:
    """A residual network's ``prior_scale``: the prior's RMS error (horizon, n_y) per step and channel, in
    normalized outputs, held at its last step beyond the training horizon and floored (a channel the prior
    gets exactly right still divides the loss)."""
    scale = torch.as_tensor(error / y_std, dtype=net.prior_scale.dtype).clamp_min(1e-6)
    n = min(len(scale), len(net.prior_scale))
    with torch.no_grad():
        net.prior_scale[:n] = scale[:n]
        net.prior_scale[n:] = scale[n - 1]


def _n_params(physics: str, channel_mask: bool) -> int:
    """The parameter head's width: the Panda's identifiable parameters, whatever the ranges; none
    for ``auto`` over stores of several arms (the head is the Panda's: the black-box model then)."""
    return N_PHYSICAL if physics == "amortized" or (physics == "auto" and not channel_mask) else 0


def _check_extrapolation(extrapolate: str, velocity_points: int, anchor: bool, integrate: bool, residual: bool) -> None:
    """Refuses ``--model.extrapolate`` settings that cannot work, naming the flags: the kinematic anchor
    replaces the last-output anchor and the summed changes, and a residual model corrects its prior instead."""
    try:
        check_extrapolation(extrapolate, velocity_points)
    except ValueError as exc:
        raise ModelSettingsError(f"--model.{exc}") from None
    if extrapolate != "none" and (anchor or residual):
        raise ModelSettingsError(f"--model.extrapolate {extrapolate} already starts the prediction from the last context "
                                 "output: set --model.anchor false (and it goes with no residual model, which corrects "
                                 "its prior instead)")


def _check_training(freeze: str, normalization_from: str, lr: float, min_lr_ratio: float,
                    warmup_steps: int, huber_delta: float, compile: str = "auto") -> None:
    """Refuses freeze, transfer, optimizer and compile settings that cannot work, naming the flag
    (the loss: :func:`robomorph.training.losses.check_loss`)."""
    check_compile(compile)
    if freeze not in FREEZE_MODES:
        raise ModelSettingsError(f"--model.freeze must be one of {FREEZE_MODES}, got {freeze!r}")
    if normalization_from not in ("source", "target"):
        raise ModelSettingsError(f"--model.normalization_from must be 'source' or 'target', got {normalization_from!r}")
    for name, value, ok in (("lr", lr, lr > 0), ("min_lr_ratio", min_lr_ratio, 0 <= min_lr_ratio <= 1),
                            ("warmup_steps", warmup_steps, warmup_steps >= 0),
                            ("huber_delta", huber_delta, huber_delta > 0)):
        if not ok:
            raise ModelSettingsError(f"--model.{name} {value} is out of range: need lr > 0, "
                                     "0 <= min_lr_ratio <= 1, warmup_steps >= 0, huber_delta > 0")


def settings_config(hparams: dict) -> ModelConfig:
    """:func:`model_config` of a module's hyper-parameters, its errors naming the ``--model.`` flags.

    Raises:
        ModelSettingsError: shapes that cannot work (e.g. ``n_head`` not dividing ``d_model``).
    """
    try:
        return model_config(hparams)
    except ValueError as exc:
        raise ModelSettingsError(f"{str(exc).replace('ModelConfig.', '--model.')}") from exc


def check_context(context_len: int | None, patch: int, max_context: int) -> None:
    """The encoder needs whole patches and a positional table that covers the context.

    Raises:
        ModelSettingsError: naming the ``--data.context_len`` and ``--model.`` flags to change.
    """
    if context_len is None:
        return
    if context_len % patch:
        lower, upper = context_len - context_len % patch, context_len - context_len % patch + patch
        hint = f"use {upper}" if lower < 1 else f"use {lower} or {upper}"
        raise ModelSettingsError(f"--data.context_len {context_len} is not a multiple of --model.patch {patch} "
                                 f"(steps per token): {hint}, or another patch")
    if context_len > max_context:
        raise ModelSettingsError(f"--data.context_len {context_len} exceeds --model.max_context {max_context} (the "
                                 f"positional table's length): raise --model.max_context to at least {context_len}")


def schedule_change(old_hparams: dict, old_max_steps: int | None, new_hparams, new_max_steps: int,
                    step: int) -> str | None:
    """One line on how a resume at ``step`` changes the run, or None when nothing changes.

    The cosine runs over ``decay_steps`` or, by default, ``max_steps``: resuming with another
    ``max_steps`` then stretches or shrinks the rest of it, and the learning rate jumps.
    """
    if old_max_steps is None or old_max_steps == new_max_steps:
        return None

    def total(h, max_steps: int) -> int:
        return h.get("decay_steps") or (max_steps if max_steps > 0 else 10_000)

    old_total, new_total = total(old_hparams, old_max_steps), total(new_hparams, new_max_steps)
    head = f"max_steps {old_max_steps} -> {new_max_steps}, resuming at step {step}"
    if old_total == new_total:
        return f"{head}: the learning-rate schedule is unchanged (decay_steps {new_total})"
    lrs = [h["lr"] * _lr_factor(step, h["warmup_steps"], t, h["min_lr_ratio"])
           for h, t in ((old_hparams, old_total), (new_hparams, new_total))]
    return (f"{head}: the cosine learning-rate decay now ends at step {new_total} instead of {old_total} "
            f"(lr at step {step}: {lrs[0]:.3g} -> {lrs[1]:.3g}); pin --model.decay_steps to keep it")
