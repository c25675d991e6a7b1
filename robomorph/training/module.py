"""The LightningModule: loss, optimizer, schedule, logging and transfer initialization.

The network is the plain :class:`robomorph.model.transformer.MetaModel`; normalization (statistics of
the training split, carried in the checkpoint) is a :class:`Normalizer` beside it. Batches
arrive in physical units from :class:`robomorph.data.datamodule.RoboMorphDataModule`.
"""

from __future__ import annotations

import math
import os
from typing import Literal

import lightning.pytorch as L
import torch
import torch.nn.functional as F

from robomorph.core.errors import RoboMorphError
from robomorph.data.statistics import check_normalization
from robomorph.evaluation import metrics
from robomorph.model.normalization import Normalizer, query_stats
from robomorph.model.transformer import MetaModel, ModelConfig

# Log keys, defined once (namespaced as the lightning-hydra-template does).
TRAIN_LOSS, VAL_LOSS, VAL_R2, VAL_FIT, LR = "train/loss", "val/loss", "val/r2", "val/fit", "lr"
TEST_LOSS, TEST_R2, TEST_FIT = "test/loss", "test/r2", "test/fit"
FREEZE_MODES = ("none", "encoder", "all_but_head")
# Parameters of these layers depend on n_u / n_y; ``reinit_io`` re-initializes them.
IO_LAYERS = ("encoder.embed", "decoder.embed", "decoder.init_embed", "head")
LOSSES = ("huber", "mse", "nll")
# Per-step change of the normalized outputs that one unit of network output means with
# ``integrate``: of the order of the arm's per-step motion at 60 Hz (about 0.01 of a
# channel's standard deviation), so that an untrained network's random walk over 800 steps
# stays within a few standard deviations.
INTEGRATE_SCALE = 0.05
# Checkpoint entry holding what the model was trained on (see ``data_info``).
DATA_INFO_KEY = "robomorph_data"


def data_info(dm) -> dict:
    """Channel names, sample time and window lengths of a set-up DataModule (JSON-able)."""
    return {"u_names": list(dm.u_names), "y_names": list(dm.y_names), "dt": float(dm.dt),
            "context_len": int(dm.context_len), "horizon": int(dm.horizon),
            "stores": [str(s) for s in dm.stores], "inputs": str(getattr(dm, "inputs", "total"))}


class CheckpointError(RoboMorphError, RuntimeError):
    """A checkpoint is missing, corrupt, or does not fit the model asked for."""


class ModelOptionError(RoboMorphError, ValueError):
    """Model or loss options that do not fit together."""


def load_checkpoint_file(path: str) -> dict:
    """Reads a checkpoint with an error that says what is wrong with it."""
    if not os.path.isfile(path):
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001  (any unreadable file)
        raise CheckpointError(f"{path} is not a readable checkpoint (corrupt or truncated?): {exc}") from exc
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt or "hyper_parameters" not in ckpt:
        raise CheckpointError(f"{path} is not a RoboMorph/Lightning checkpoint (no state_dict/hyper_parameters)")
    return ckpt


class MetaModule(L.LightningModule):
    """Trains a :class:`MetaModel` to predict y over the horizon from a context of (u, y).

    Args:
        n_u, n_y: channel counts (filled in from the data when left unset).
        d_model, n_head, n_layer, n_layer_dec, dropout, bias, patch, max_context, max_horizon:
            the network (see :class:`robomorph.model.transformer.ModelConfig`). The defaults are the
            CPU-sized model: d 128, 4 + 4 layers, 4 heads, patches of 10 steps (13x faster
            per step than one token per step on 2 cores; ``benchmarks/train.py``).
        n_init: last context steps fed to the decoder as initial-condition tokens (0 = off;
            a multiple of ``patch``).
        gaussian: the head also predicts a log-variance per step and channel.
        loss: ``huber``, ``mse`` or ``nll`` (Gaussian negative log-likelihood, needs
            ``gaussian``), on normalized outputs.
        huber_delta: Huber transition point in normalized units.
        horizon_weight, horizon_tau: loss weight of query step t is
            ``1 + horizon_weight * exp(-t / horizon_tau)``, rescaled to mean 1 over the horizon
            (0 = uniform): the first steps, which a predictive controller uses most, count more.
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
        integrate: the network predicts per-step changes (scaled by ``INTEGRATE_SCALE``), summed
            from the last context output: the first predicted step is the last measured one
            plus one small change, so the prediction cannot jump away from the robot.
        init_ckpt: start from this checkpoint's weights and normalization (transfer).
        freeze: ``none``, ``encoder`` or ``all_but_head``.
        reinit_io: when the checkpoint's n_u / n_y differ, re-initialize the input
            embeddings and the head instead of failing.
    """

    def __init__(
        self,
        n_u: int | None = None,
        n_y: int | None = None,
        d_model: int = 128,
        n_head: int = 4,
        n_layer: int = 4,
        n_layer_dec: int | None = None,
        dropout: float = 0.0,
        bias: bool = True,
        patch: int = 10,
        max_context: int = 1024,
        max_horizon: int = 1024,
        n_init: int = 0,
        gaussian: bool = False,
        loss: Literal["huber", "mse", "nll"] = "huber",
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
        normalization: Literal["train_stats", "paper_window"] = "train_stats",
        anchor: bool = False,
        integrate: bool = False,
        init_ckpt: str | None = None,
        freeze: Literal["none", "encoder", "all_but_head"] = "none",
        reinit_io: bool = False,
    ):
        super().__init__()
        if loss not in LOSSES:
            raise ModelOptionError(f"loss must be one of {LOSSES}, got {loss!r}")
        if loss == "nll" and not gaussian:
            raise ModelOptionError("loss 'nll' needs the Gaussian head: set gaussian=true (--model.gaussian true)")
        if not horizon_weight >= 0 or not horizon_tau > 0:
            raise ModelOptionError(f"need horizon_weight >= 0 and horizon_tau > 0, got {horizon_weight}, {horizon_tau}")
        if freeze not in FREEZE_MODES:
            raise ValueError(f"freeze must be one of {FREEZE_MODES}, got {freeze!r}")
        if lr <= 0 or not 0 <= min_lr_ratio <= 1 or warmup_steps < 0 or huber_delta <= 0:
            raise ValueError("need lr > 0, 0 <= min_lr_ratio <= 1, warmup_steps >= 0, huber_delta > 0")
        check_normalization(normalization, recenter)
        self.save_hyperparameters()
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
        h = self.hparams
        # .get: checkpoints written before these options existed lack them (old behaviour).
        return ModelConfig(n_u=h.n_u, n_y=h.n_y, d_model=h.d_model, n_head=h.n_head, n_layer=h.n_layer,
                           n_layer_dec=h.n_layer_dec, dropout=h.dropout, bias=h.bias, patch=h.patch,
                           max_context=h.max_context, max_horizon=h.max_horizon, n_init=h.get("n_init", 0),
                           gaussian=h.get("gaussian", False))

    def _build(self, n_u: int, n_y: int) -> None:
        self.hparams.n_u, self.hparams.n_y = int(n_u), int(n_y)
        self.net = MetaModel(self.model_config)
        self.normalizer = Normalizer(n_u=n_u, n_y=n_y, recenter=self.hparams.recenter,
                                     normalization=self.hparams.get("normalization", "train_stats"))
        self.register_buffer("stats_ready", torch.tensor(False))
        self._apply_freeze()

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is None:
            return
        if self.net is None:
            self._build(dm.n_u, dm.n_y)
        elif (dm.n_u, dm.n_y) != (self.hparams.n_u, self.hparams.n_y):
            raise CheckpointError(
                f"the data has n_u={dm.n_u}, n_y={dm.n_y} but the model was built for "
                f"n_u={self.hparams.n_u}, n_y={self.hparams.n_y}"
            )
        if stage == "fit" or self.data_info is None:
            self.data_info = data_info(dm)
        if stage == "fit" and self.hparams.init_ckpt and not self.resuming and not getattr(self, "_transferred", False):
            self._transfer(self.hparams.init_ckpt)
            self._transferred = True
        if not bool(self.stats_ready):
            # A resumed or transferred model keeps the statistics it was trained with.
            self.normalizer.set_stats(dm.stats)
            self.stats_ready.fill_(True)

    def _transfer(self, path: str) -> None:
        ckpt = load_checkpoint_file(path)
        src = ckpt["hyper_parameters"]
        same_io = (src.get("n_u"), src.get("n_y")) == (self.hparams.n_u, self.hparams.n_y)
        theirs, ours = src.get("normalization", "train_stats"), self.hparams.get("normalization", "train_stats")
        if theirs != ours:
            raise CheckpointError(f"{path} was trained with normalization {theirs!r}, this run uses {ours!r}: "
                                  "transfer between the same protocol only (set data.normalization to match)")
        if not same_io and not self.hparams.reinit_io:
            raise CheckpointError(
                f"{path} was trained with n_u={src.get('n_u')}, n_y={src.get('n_y')}; this model has "
                f"n_u={self.hparams.n_u}, n_y={self.hparams.n_y}. Set reinit_io=true to re-initialize the "
                "input embeddings and the head (the rest transfers)."
            )
        state = {k: v for k, v in ckpt["state_dict"].items()
                 if same_io or not (k.startswith("normalizer.") or _is_io(k))}
        missing, unexpected = self.load_state_dict(state, strict=False)
        allowed_missing = [k for k in missing if not same_io and (k.startswith("normalizer.") or _is_io(k))]
        if set(missing) - set(allowed_missing) - {"stats_ready"} or unexpected:
            raise CheckpointError(
                f"{path} does not match this architecture (missing {sorted(set(missing) - set(allowed_missing))[:5]}, "
                f"unexpected {sorted(unexpected)[:5]}): use the same d_model, n_head, layers and patch"
            )
        if same_io:
            self.stats_ready.fill_(True)
        self._apply_freeze()

    def _apply_freeze(self) -> None:
        mode = self.hparams.freeze
        for name, p in self.net.named_parameters():
            if mode == "encoder":
                p.requires_grad = not name.startswith("enc")
            elif mode == "all_but_head":
                p.requires_grad = name.startswith("head")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.data_info is not None:
            checkpoint[DATA_INFO_KEY] = self.data_info

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.data_info = checkpoint.get(DATA_INFO_KEY, self.data_info)

    # --------------------------------------------------------------------- forward
    def forward(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor,
                y_query_stats=None) -> torch.Tensor:
        """Predicts y over the query horizon, in physical units.

        ``y_query_stats`` (mean, std of the query outputs, (B, n_y) each) is needed, and used,
        only under ``normalization="paper_window"``.
        """
        uc, yc, uq = self.normalizer.encode(u_ctx, y_ctx, u_query, y_query_stats)
        return self.normalizer.decode(self._predict(uc, yc, uq)[0], y_ctx, y_query_stats)

    def _query_stats(self, batch: dict):
        """The batch's query-output statistics when the normalization uses them (the paper's leak), else None."""
        return query_stats(batch["y_query"]) if self.normalizer.uses_query_stats else None

    def forward_dist(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, y_query_stats=None
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean and standard deviation (None without a Gaussian head), both in physical units."""
        uc, yc, uq = self.normalizer.encode(u_ctx, y_ctx, u_query, y_query_stats)
        mean, logvar = self._predict(uc, yc, uq)
        # Recentring and anchoring shift the outputs; only the z-score scales them.
        std = None if logvar is None else torch.exp(0.5 * logvar) * self.normalizer.decode_scale(
            y_ctx, y_query_stats, u_query.shape[1])
        return self.normalizer.decode(mean, y_ctx, y_query_stats), std

    def _predict(self, uc: torch.Tensor, yc: torch.Tensor, uq: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Normalized mean (B, Th, n_y) and log-variance (or None) from normalized inputs."""
        mean, logvar = self.net.forward_dist(uc, yc, uq)
        if self.hparams.get("integrate", False):
            # A running sum over steps <= t: causal, like the decoder it follows.
            mean = INTEGRATE_SCALE * mean.cumsum(dim=1)
        if self.hparams.get("anchor", False) or self.hparams.get("integrate", False):
            mean = mean + yc[:, -1:]
        return mean, logvar

    def horizon_weights(self, horizon: int) -> torch.Tensor:
        """Loss weight of each query step (horizon,), mean 1."""
        t = torch.arange(horizon, dtype=torch.float32, device=self.device)
        w = 1 + self.hparams.get("horizon_weight", 0.0) * torch.exp(-t / self.hparams.get("horizon_tau", 60.0))
        return w / w.mean()

    def _step(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        u_ctx, y_ctx = batch["u_ctx"], batch["y_ctx"]
        # Random context lengths need not be multiples of patch: the oldest steps go.
        drop = u_ctx.shape[1] % self.hparams.patch
        u_ctx, y_ctx = u_ctx[:, drop:], y_ctx[:, drop:]
        qs = self._query_stats(batch)
        uc, yc, uq = self.normalizer.encode(u_ctx, y_ctx, batch["u_query"], qs)
        target = self.normalizer.encode_target(batch["y_query"], y_ctx, qs)
        pred, logvar = self._predict(uc, yc, uq)
        loss = (self.elementwise_loss(pred, logvar, target) * self.horizon_weights(target.shape[1])[:, None]).mean()
        return loss, pred, target

    def elementwise_loss(self, pred: torch.Tensor, logvar: torch.Tensor | None, target: torch.Tensor) -> torch.Tensor:
        """Per step and channel loss (B, Th, n_y) on normalized outputs."""
        kind = self.hparams.loss
        if kind == "nll":
            return 0.5 * (logvar + (target - pred) ** 2 * torch.exp(-logvar) + math.log(2 * math.pi))
        if kind == "mse":
            return (pred - target) ** 2
        return F.huber_loss(pred, target, delta=self.hparams.huber_delta, reduction="none")

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss, _, _ = self._step(batch)
        self.log(TRAIN_LOSS, loss, prog_bar=True, batch_size=len(batch["u_ctx"]))
        self.log(LR, self.trainer.optimizers[0].param_groups[0]["lr"], batch_size=len(batch["u_ctx"]))
        return loss

    def _eval_step(self, batch: dict, keys: tuple[str, str, str]) -> None:
        loss, pred, _ = self._step(batch)
        y = batch["y_query"].double()
        drop = batch["y_ctx"].shape[1] % self.hparams.patch
        yhat = self.normalizer.decode(pred, batch["y_ctx"][:, drop:], self._query_stats(batch)).double()
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
        h = self.hparams
        params = [p for p in self.net.parameters() if p.requires_grad]
        if not params:
            raise ValueError("freeze left no trainable parameters")
        decay = [p for p in params if p.dim() >= 2 and not _is_embedding(self.net, p)]
        no_decay = [p for p in params if all(p is not q for q in decay)]
        groups = [{"params": decay, "weight_decay": h.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
        opt = torch.optim.AdamW(groups, lr=h.lr, betas=tuple(h.betas))
        total = h.decay_steps or (self.trainer.max_steps if self.trainer.max_steps > 0 else 10_000)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: _lr_factor(step, h.warmup_steps, total, h.min_lr_ratio))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def _lr_factor(step: int, warmup: int, total: int, floor: float) -> float:
    """Linear warmup to 1, cosine decay to ``floor`` at ``total``, then flat."""
    if step < warmup:
        return (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress))


def _is_io(key: str) -> bool:
    return any(key.startswith(f"net.{layer}.") for layer in IO_LAYERS)


def _is_embedding(net: torch.nn.Module, p: torch.Tensor) -> bool:
    return any(p is m.weight for m in net.modules() if isinstance(m, torch.nn.Embedding))
