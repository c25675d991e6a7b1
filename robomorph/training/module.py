"""The LightningModule: loss, optimizer, schedule, logging and transfer initialization.

The network is the plain :class:`robomorph.model.transformer.MetaModel`; normalization (statistics of
the training split, carried in the checkpoint) is a :class:`Normalizer` beside it. Batches
arrive in physical units from :class:`robomorph.data.datamodule.RoboMorphDataModule`.
"""

from __future__ import annotations

import math
from typing import Literal

import lightning.pytorch as L
import torch

from robomorph.core import metrics
from robomorph.core.errors import RoboMorphError
from robomorph.core.names import (
    FREEZE_MODES,
    LOSSES,
    LR,
    NORMALIZATIONS,
    TEST_FIT,
    TEST_LOSS,
    TEST_R2,
    TRAIN_LOSS,
    VAL_FIT,
    VAL_LOSS,
    VAL_R2,
)
from robomorph.core.normalizations import check_normalization
from robomorph.model.checkpoint import (
    DATA_INFO_KEY,
    TrainedModel,
    model_config,
    predict_normalized_dist,
)
from robomorph.model.normalization import Normalizer, query_stats
from robomorph.model.transformer import MetaModel, ModelConfig
from robomorph.sim.backbone import BackboneError
from robomorph.training.data_record import check_channels, data_info
from robomorph.training.losses import ModelOptionError, check_loss, elementwise_loss, horizon_weights, whole_patches
from robomorph.training.optim import lr_factor as _lr_factor
from robomorph.training.optim import optimizers
from robomorph.training.pretrained import apply_freeze, start_from

# The parameter head's outputs: the Panda's identifiable parameters (robomorph.sim.backbone).
N_PHYSICAL = 29
TRAIN_PARAM_RMSE = "train/param_rmse"

# Constructor arguments that the data decide: robomorph fit links them from the datamodule.
FROM_DATA = ("n_u", "n_y", "context_len")
# Checkpoint entry holding the trainer's max_steps, so a resume can say how the schedule changes.
SCHEDULE_KEY = "robomorph_schedule"


class ModelSettingsError(ModelOptionError):
    """Model or optimizer settings that cannot work; the message names the ``--model.`` flag."""


class MetaModule(L.LightningModule):
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
            :mod:`robomorph.model.hybrid`; needs simulated Panda stores that record
            ``params``) or ``auto`` (``amortized`` in the command formulation when every
            training store can have it, else ``none`` with a note: imported real logs have no
            catalogue robot, and total torques make any simulation diverge within seconds).
        param_weight: weight of the parameter head's Gaussian NLL in the loss.
        decoder_loss: also train the black-box decoder (false: the parameter head alone, whose
            training steps then skip the decoder; the decoder stays untrained).
        n_params: set from ``physics`` (the Panda's 29 identifiable parameters); not a setting.
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
        init_ckpt: str | None = None,
        freeze: Literal[FREEZE_MODES] = "none",
        reinit_io: bool = False,
        normalization_from: Literal["source", "target"] = "target",
        physics: Literal["none", "amortized", "auto"] = "none",
        param_weight: float = 1.0,
        decoder_loss: bool = True,
        n_params: int | None = None,
    ):
        super().__init__()
        _check_physics(physics, param_weight, decoder_loss)
        check_loss(loss, gaussian, horizon_weight, horizon_tau)
        _check_training(freeze, normalization_from, lr, min_lr_ratio, warmup_steps, huber_delta)
        check_context(context_len, patch, max_context)
        check_normalization(normalization, recenter)
        self.save_hyperparameters()
        # The parameter head's width is the Panda's identifiable parameters, whatever the ranges.
        self.hparams.n_params = N_PHYSICAL if physics != "none" else 0
        self._physics_on = physics == "amortized"  # "auto" is decided by the data in setup
        self._layout: dict | None = None  # the parameter layout of the training stores (setup)
        self.net: MetaModel | None = None
        self.normalizer: Normalizer | None = None
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
                               integrate=h.integrate)
        # Outside the module tree, so the checkpoint keys stay ``net.*`` and ``normalizer.*``.
        self.__dict__["_trained"] = trained
        self.net, self.normalizer = trained.net, trained.normalizer
        self.register_buffer("stats_ready", torch.tensor(False))
        apply_freeze(self.net, self.hparams.freeze)

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is None:
            return
        check_channels(dm, self.hparams.n_u, self.hparams.n_y)
        if stage == "fit" or self.data_info is None:
            self.data_info = data_info(dm)
        if self.hparams.physics == "auto":
            from robomorph.sim.backbone import BackboneError as _Refused  # noqa: PLC0415

            try:
                if getattr(dm, "inputs", "total") != "command":
                    # Total torques pay gravity at the recorded state: a simulation diverges within
                    # seconds even with the true parameters (docs: the hybrid model).
                    raise _Refused("the hybrid predicts in the command formulation (--data.inputs command)")
                self._layout, self._physics_on = physics_layout(dm), True
            except _Refused as exc:
                self._physics_on = False
                if stage == "fit":
                    why = str(exc).split(";")[0].replace("--model.physics needs", "the hybrid needs")
                    print(f"note: --model.physics auto: {why}; training the black-box model alone")
        elif self.hparams.physics != "none":
            self._layout = physics_layout(dm)
        if self._physics_on:
            self.data_info = {**self.data_info, "physics": {**self._layout, "mode": "amortized"}}
            for name in ("train_set", "val_set", "test_set"):
                if getattr(dm, name, None) is not None:
                    getattr(dm, name).add_params()
        if stage == "fit" and self.hparams.init_ckpt and not self.resuming and not getattr(self, "_transferred", False):
            start_from(self, self.hparams.init_ckpt)
            self._transferred = True
        if not bool(self.stats_ready):
            # A resumed or transferred model keeps the statistics it was trained with.
            self.normalizer.set_stats(dm.stats)
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

    def _query_stats(self, batch: dict):
        """The batch's query-output statistics when the normalization uses them (the paper's leak), else None."""
        return query_stats(batch["y_query"]) if self.normalizer.uses_query_stats else None

    def _step(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        h, batch = self.hparams, whole_patches(batch, self.hparams.patch)
        qs = self._query_stats(batch)
        uc, yc, uq = self.normalizer.encode(batch["u_ctx"], batch["y_ctx"], batch["u_query"], qs)
        target = self.normalizer.encode_target(batch["y_query"], batch["y_ctx"], qs)
        loss, pred = torch.zeros((), device=uc.device), None
        if not self._physics_on or h.decoder_loss:
            pred, logvar = predict_normalized_dist(self.net, h.anchor, uc, yc, uq, h.integrate)
            weights = horizon_weights(target.shape[1], h.horizon_weight, h.horizon_tau, target.device)
            loss = (elementwise_loss(h.loss, pred, logvar, target, h.huber_delta) * weights[:, None]).mean()
        if self._physics_on:
            self._param_error = self._param_loss(batch, uc, yc)
            loss = loss + h.param_weight * self._param_error[0]
        return loss, pred, target

    def _param_loss(self, batch: dict, uc: torch.Tensor, yc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The parameter head's Gaussian NLL and RMS error, in unit coordinates (the context only)."""
        if "params" not in batch or self._layout is None:
            raise BackboneError("--model.physics amortized needs the robots' parameters in every batch: train on "
                                "simulated Panda stores that record params, or use --model.physics none")
        lay = self._layout
        index = torch.as_tensor(lay["index"], device=uc.device)
        low = torch.as_tensor(lay["low"], device=uc.device, dtype=torch.float64)
        high = torch.as_tensor(lay["high"], device=uc.device, dtype=torch.float64)
        half = (high - low) / 2
        # A collapsed range is known exactly: its target is the middle (0).
        target = torch.where(half > 0, (batch["params"][:, index] - (low + high) / 2) / half.clamp_min(1e-12), 0.0)
        mean, logvar = self.net.forward_params(uc, yc)
        target = target.to(mean.dtype)
        nll = 0.5 * (logvar + (target - mean) ** 2 * torch.exp(-logvar) + math.log(2 * math.pi))
        return nll.mean(), ((target - mean) ** 2).mean().sqrt()

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss, _, _ = self._step(batch)
        self.log(TRAIN_LOSS, loss, prog_bar=True, batch_size=len(batch["u_ctx"]))
        if self._physics_on:
            self.log(TRAIN_PARAM_RMSE, self._param_error[1], batch_size=len(batch["u_ctx"]))
        self.log(LR, self.trainer.optimizers[0].param_groups[0]["lr"], batch_size=len(batch["u_ctx"]))
        return loss

    def _eval_step(self, batch: dict, keys: tuple[str, str, str]) -> None:
        batch = whole_patches(batch, self.hparams.patch)
        loss, pred, _ = self._step(batch)
        n = len(batch["y_query"])
        if self._physics_on:
            self.log(keys[0].split("/")[0] + "/param_rmse", self._param_error[1], batch_size=n, sync_dist=True,
                     prog_bar=True)
        if pred is None:  # the parameter head alone: no sequence prediction to score here
            self.log(keys[0], loss, batch_size=n, sync_dist=True, prog_bar=keys[0] == VAL_LOSS)
            return
        y = batch["y_query"].double()
        yhat = self.normalizer.decode(pred, batch["y_ctx"], self._query_stats(batch)).double()
        n = len(y)
        self.log(keys[0], loss, batch_size=n, sync_dist=True, prog_bar=keys[0] == VAL_LOSS)
        # approach 1: per trajectory and channel over time, mean over channels, then over trajectories
        self.log(keys[1], metrics.r2(y, yhat).mean(-1).mean(), batch_size=n, sync_dist=True, prog_bar=True)
        self.log(keys[2], metrics.fit_index(y, yhat).mean(-1).mean(), batch_size=n, sync_dist=True)

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, (VAL_LOSS, VAL_R2, VAL_FIT))

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, (TEST_LOSS, TEST_R2, TEST_FIT))

    # ------------------------------------------------------------------ optimizer
    def configure_optimizers(self):
        return optimizers(self)


def _check_physics(physics: str, param_weight: float, decoder_loss: bool) -> None:
    if physics not in ("none", "amortized", "auto"):
        raise ModelSettingsError(f"--model.physics must be 'none', 'amortized' or 'auto', got {physics!r}")
    if not param_weight > 0 or not isinstance(decoder_loss, bool):
        raise ModelSettingsError("--model.param_weight must be > 0 and --model.decoder_loss true or false")


def physics_layout(dm) -> dict:
    """The parameter layout of the DataModule's stores, which must agree (one line otherwise).

    Raises:
        BackboneError: a store is not a simulated Panda store with params, or the stores'
            randomization ranges differ (the unit coordinates would mean different things).
    """
    from robomorph.sim.backbone import parameter_layout, same_layout  # noqa: PLC0415

    sources = dm._open()
    layouts = [parameter_layout(src.attrs) for src in sources]
    for src, lay in zip(sources[1:], layouts[1:]):
        if not same_layout(layouts[0], lay):
            raise BackboneError(f"{src.path} randomizes the parameters over other ranges than {sources[0].path}: "
                                "train the parameter head on stores of one recipe's ranges")
    return layouts[0]


def _check_training(freeze: str, normalization_from: str, lr: float, min_lr_ratio: float,
                    warmup_steps: int, huber_delta: float) -> None:
    """Refuses freeze, transfer and optimizer settings that cannot work, naming the flag
    (the loss: :func:`robomorph.training.losses.check_loss`)."""
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
