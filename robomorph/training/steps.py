"""What a training, validation or test step of the meta-model computes and logs.

A mixin of :class:`robomorph.training.module.MetaModule` (which holds the network, its
normalizer and its hyper-parameters): the loss on normalized outputs, weighted over the
horizon, plus the parameter head's loss for a hybrid model (:mod:`robomorph.training.physics`),
and the metrics logged at validation and test.
"""

from __future__ import annotations

import torch

from robomorph.core import metrics
from robomorph.core.names import LR, TEST_FIT, TEST_LOSS, TEST_R2, TRAIN_LOSS, VAL_FIT, VAL_LOSS, VAL_R2
from robomorph.inference.checkpoint import predict_normalized_dist
from robomorph.model.normalization import query_stats
from robomorph.training.compiling import CompiledStep, resolve_compile
from robomorph.training.losses import elementwise_loss, horizon_weights, masked_loss, whole_patches
from robomorph.training.physics import TRAIN_PARAM_RMSE, param_loss


class Steps:
    """The steps of :class:`robomorph.training.module.MetaModule` (see the module docstring)."""

    def _query_stats(self, batch: dict):
        """The batch's query-output statistics when the normalization uses them (the paper's leak), else None."""
        return query_stats(batch["y_query"]) if self.normalizer.uses_query_stats else None

    def _losses(self, batch: dict):
        """Loss, normalized prediction and target, and the parameter head's (NLL, RMS error) or None.

        No side effects, so that the training step can be compiled (:mod:`robomorph.training.compiling`).
        """
        h, batch = self.hparams, whole_patches(batch, self.hparams.patch)
        qs = self._query_stats(batch)
        uc, yc, uq = self.normalizer.encode(batch["u_ctx"], batch["y_ctx"], batch["u_query"], qs)
        target = self.normalizer.encode_target(batch["y_query"], batch["y_ctx"], qs)
        loss, pred, param_error = torch.zeros((), device=uc.device), None, None
        # A residual model's prior, normalized as the target: the network learns target - prior.
        prior = self.normalizer.encode_target(batch["prior_query"], batch["y_ctx"], qs) if self.net.cfg.residual else None
        if not self._physics_on or h.decoder_loss:
            pred, logvar = predict_normalized_dist(self.net, h.anchor, uc, yc, uq, h.integrate, prior,
                                                   self.trained_model.kinematic_points)
            weights = horizon_weights(target.shape[1], h.horizon_weight, h.horizon_tau, target.device)
            fit, goal = pred, target
            if prior is not None:
                # The loss in units of the prior's typical error at each step and channel: every step counts.
                scale = self.net.prior_scale[:target.shape[1]]
                fit, goal = (pred - prior) / scale, (target - prior) / scale
            if self.net.cfg.channel_mask:  # stores of several arms: absent outputs are NaN, skipped
                loss = masked_loss(h.loss, fit, logvar, goal, weights, h.huber_delta)
            else:
                loss = (elementwise_loss(h.loss, fit, logvar, goal, h.huber_delta) * weights[:, None]).mean()
        if self._physics_on:
            param_error = param_loss(self.net, self._layout, batch, uc, yc)
            loss = loss + h.param_weight * param_error[0]
        return loss, pred, target, param_error

    def _step(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        loss, pred, target, self._param_error = self._losses(batch)
        return loss, pred, target

    def _train_loss(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor | None]:
        """What a training step computes (and what ``--model.compile`` compiles): the loss and
        the parameter head's RMS error (None without one)."""
        loss, _, _, param_error = self._losses(batch)
        return loss, None if param_error is None else param_error[1]

    def _training_loss_fn(self):
        """The training step's loss function: compiled on first use where ``--model.compile``
        says so for this device, else :meth:`_train_loss` itself."""
        fn = self.__dict__.get("_compiled_step")
        if fn is None:
            varying = self._varying_windows()
            mode = resolve_compile(self.hparams.get("compile", "off"), self.device.type, varying)
            if mode is None:
                return self._train_loss
            step = CompiledStep(self._train_loss, mode, dynamic=varying)
            fn = self.__dict__["_compiled_step"] = step  # a plain attribute: not in the state dict
        return fn

    def _varying_windows(self) -> bool:
        """Whether the training windows' lengths vary from batch to batch (the datamodule's
        ``context_min`` / ``horizon_min``)."""
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        return dm is not None and (getattr(dm, "context_min", None) is not None
                                   or getattr(dm, "horizon_min", None) is not None)

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss, param_rmse = self._training_loss_fn()(batch)
        self.log(TRAIN_LOSS, loss, prog_bar=True, batch_size=len(batch["u_ctx"]))
        if param_rmse is not None:
            self.log(TRAIN_PARAM_RMSE, param_rmse, batch_size=len(batch["u_ctx"]))
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
        # approach 1: per trajectory and channel over time, mean over channels, then over trajectories;
        # channels a trajectory's arm lacks (NaN) are left out of its mean
        over_channels = torch.nanmean if self.net.cfg.channel_mask else torch.mean
        self.log(keys[1], over_channels(metrics.r2(y, yhat), -1).mean(), batch_size=n, sync_dist=True, prog_bar=True)
        self.log(keys[2], over_channels(metrics.fit_index(y, yhat), -1).mean(), batch_size=n, sync_dist=True)

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, (VAL_LOSS, VAL_R2, VAL_FIT))

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, (TEST_LOSS, TEST_R2, TEST_FIT))
