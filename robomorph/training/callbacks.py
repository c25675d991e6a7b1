"""Callbacks every fit installs: checkpoints, a validation at the last step, SIGTERM saves.

- :class:`FinalValidation`: Lightning validates every ``val_check_interval`` steps, so a
  run of 250 steps validated at 200 would report (and choose ``best.ckpt`` from) a score 50
  steps old. This asks for one more validation at the last step and records the step of
  every validation, so the final report can name it.
- :class:`SaveOnSigterm`: a cluster scheduler stops a job with SIGTERM (then SIGKILL after
  a grace period). Lightning turns SIGTERM into an exception after the current batch; this
  saves ``last.ckpt`` (atomically, through the trainer's checkpoint IO) before the exception
  ends the run, so the same command resumes from the step reached.
"""

from __future__ import annotations

import os
import sys

import lightning.pytorch as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.utilities.exceptions import SIGTERMException


class BestAndLast(ModelCheckpoint):
    """``best.ckpt`` (lowest monitored value) and a ``last.ckpt`` written at *every* validation.

    Lightning 2.6 writes ``last.ckpt`` at a validation only when that validation also saved
    a top-k checkpoint, so after a validation that did not improve, ``last.ckpt`` lags (a
    resume would repeat those steps, and the last step's validation would not be saved).
    """

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_validation_end(trainer, pl_module)
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))


class FinalValidation(L.Callback):
    """Validates at ``max_steps`` and remembers the step of the last validation."""

    def __init__(self) -> None:
        self.last_val_step: int | None = None

    def on_train_batch_end(self, trainer: L.Trainer, *args) -> None:
        # should_stop at the last step makes the epoch loop validate now (when the step is
        # not already a regular validation step) instead of ending without a score.
        if 0 < trainer.max_steps <= trainer.global_step:
            trainer.should_stop = True

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self.last_val_step = int(trainer.global_step)


class SaveOnSigterm(L.Callback):
    """Saves ``<ckpt_dir>/last.ckpt`` when the run is stopped by SIGTERM."""

    def __init__(self, ckpt_dir: str) -> None:
        self.path = os.path.join(ckpt_dir, "last.ckpt")
        self.saved_step: int | None = None

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Lightning's SIGTERM handler is installed by now: from here a stop is saved.
        if trainer.is_global_zero:
            print(f"training from step {trainer.global_step} to {trainer.max_steps} "
                  "(SIGTERM saves last.ckpt and stops)", file=sys.stderr, flush=True)

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        if isinstance(exception, SIGTERMException):
            # Raised between batches (or inside validation): the weights, optimizer and step
            # counters agree, so the checkpoint resumes like one saved by ModelCheckpoint.
            trainer.save_checkpoint(self.path)
            self.saved_step = int(trainer.global_step)
