"""What ``fit`` shows while it trains: optimizer steps and time against the budget.

Lightning's own bar counts epochs ("Epoch 62"), which mean nothing here: the budget is
``trainer.max_steps`` optimizer steps and, optionally, the wall-clock cap
``trainer.max_time`` (Lightning's :class:`~lightning.pytorch.callbacks.Timer`). So:

- :class:`StepBar` replaces Lightning's bar: a tqdm bar of steps out of ``max_steps``
  with the last training loss and, under a wall-clock cap, the time used of it (on a
  terminal only, as tqdm decides, so logs do not fill with carriage returns); in a log, a
  line of steps and rate every few seconds instead (:mod:`robomorph.core.progress`).
- :class:`ValidationLines` prints one line per validation: step, validation loss and FIT,
  elapsed time (of the cap, when there is one), whether or not the bar is on.
- :func:`quiet_lightning` turns off what Lightning says besides: its tips (advertisements
  for a cloud logger), "GPU available" lines, the model-summary table (all logged at INFO)
  and deprecation warnings. ``fit --verbose`` keeps them.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
import warnings
from collections.abc import Iterator

import lightning.pytorch as L
from lightning.fabric.utilities.warnings import PossibleUserWarning
from lightning.pytorch.callbacks import ProgressBar, Timer
from tqdm.auto import tqdm

from robomorph.core.names import TRAIN_LOSS, VAL_FIT, VAL_LOSS
from robomorph.core.progress import Phase

# Loggers Lightning reports through (rank_zero_info and the model summary log under them).
LIGHTNING_LOGGERS = ("lightning.pytorch", "lightning.fabric", "pytorch_lightning", "lightning_fabric")


def clock(seconds: float) -> str:
    """``H:MM:SS`` (``M:SS`` under an hour) of a duration in seconds."""
    s = int(round(max(seconds, 0.0)))
    h, m, s = s // 3600, s // 60 % 60, s % 60
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Budget:
    """The trainer's budget: ``max_steps`` and the wall-clock cap of its Timer, if any."""

    def __init__(self, trainer: L.Trainer) -> None:
        self.max_steps = trainer.max_steps if trainer.max_steps and trainer.max_steps > 0 else None
        self.timer = next((cb for cb in trainer.callbacks if isinstance(cb, Timer)), None)
        self.started = time.monotonic()

    @property
    def cap(self) -> float | None:
        """The wall-clock cap in seconds, or None."""
        if self.timer is None:
            return None
        remaining = self.timer.time_remaining()
        return None if remaining is None else self.timer.time_elapsed() + remaining

    def elapsed(self) -> float:
        """Training time so far: the Timer's (which a resume restores) or this session's."""
        return self.timer.time_elapsed() if self.timer is not None else time.monotonic() - self.started

    def steps(self, step: int) -> str:
        return f"{step}/{self.max_steps}" if self.max_steps else str(step)

    def time(self) -> str:
        cap = self.cap
        return clock(self.elapsed()) + (f" of {clock(cap)}" if cap is not None else "")


def _scalar(metrics: dict, key: str) -> float | None:
    value = metrics.get(key)
    return None if value is None else float(value)


class ValidationLines(L.Callback):
    """One line per validation on stderr: step, val/loss, val/fit and elapsed time."""

    def __init__(self) -> None:
        self.lines: list[str] = []  # what was printed, for callers that want it back
        self.budget: Budget | None = None

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.budget = Budget(trainer)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero or self.budget is None:
            return
        metrics = trainer.callback_metrics
        shown = [f"{key} {value:.4g}" for key in (VAL_LOSS, VAL_FIT) if (value := _scalar(metrics, key)) is not None]
        line = (f"validation at step {self.budget.steps(trainer.global_step)}: {', '.join(shown) or 'no metrics'}"
                f" | elapsed {self.budget.time()}")
        self.lines.append(line)
        tqdm.write(line, file=sys.stderr)  # above the bar, which tqdm then redraws


# Steps between two updates of the bar's loss and time.
POSTFIX_EVERY = 10


class StepBar(ProgressBar):
    """A tqdm bar of optimizer steps (not epochs) against ``max_steps``."""

    def __init__(self) -> None:
        super().__init__()
        self.bar: tqdm | None = None
        # In a log, where tqdm draws nothing: a line every few seconds (not `self.log`: Lightning sets that
        # attribute of every callback to the module's log method).
        self.phase: Phase | None = None
        self.budget: Budget | None = None
        self._enabled = True

    def disable(self) -> None:
        self._enabled = False

    def enable(self) -> None:
        self._enabled = True

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.budget = Budget(trainer)
        if self._enabled and trainer.is_global_zero:
            # disable=None: tqdm draws only on a terminal.
            self.bar = tqdm(total=self.budget.max_steps, initial=trainer.global_step, unit="step", desc="training",
                            file=sys.stderr, dynamic_ncols=True, disable=None, leave=True)
            if self.bar.disable:  # not a terminal: minutes between validation lines would be silent
                self.phase = Phase("training", self.budget.max_steps, "step", initial=trainer.global_step)
                budget = self.budget
                self.phase.cap_left = lambda: None if budget.cap is None else budget.cap - budget.elapsed()
                self.phase.__enter__()

    def on_train_batch_end(self, trainer: L.Trainer, *args) -> None:
        if self.bar is None:
            return
        self.bar.update(trainer.global_step - self.bar.n)
        if self.phase is not None:
            self.phase.update(trainer.global_step - self.phase.n)
        # Reading the loss copies it to the host (a device sync on a GPU): only when the bar is
        # drawn, and every POSTFIX_EVERY steps, not in every training step.
        if self.bar.disable or self.bar.n % POSTFIX_EVERY:
            return
        loss = _scalar(trainer.callback_metrics, TRAIN_LOSS)
        post = {"loss": f"{loss:.4g}"} if loss is not None else {}
        if self.budget.cap is not None:
            post["time"] = self.budget.time()
        self.bar.set_postfix(post, refresh=False)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.close()

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        self.close()

    def close(self) -> None:
        if self.phase is not None:
            self.phase.__exit__(None, None, None)
            self.phase = None
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def progress_callbacks(bar: bool) -> list[L.Callback]:
    """The callbacks of :mod:`progress`: the bar only when the trainer's progress bar is on
    (Lightning refuses a progress-bar callback under ``enable_progress_bar false``)."""
    return [StepBar(), ValidationLines()] if bar else [ValidationLines()]


@contextlib.contextmanager
def quiet_lightning(verbose: bool) -> Iterator[None]:
    """Within the block, Lightning's INFO messages (tips, accelerator lines, the model
    summary) and deprecation warnings are off, unless ``verbose``; restored after."""
    if verbose:
        yield
        return
    loggers = [logging.getLogger(name) for name in LIGHTNING_LOGGERS]
    levels = [lg.level for lg in loggers]
    with warnings.catch_warnings():
        for category in (DeprecationWarning, FutureWarning, PossibleUserWarning):
            warnings.filterwarnings("ignore", category=category)
        for lg in loggers:
            lg.setLevel(logging.WARNING)
        try:
            yield
        finally:
            for lg, level in zip(loggers, levels):
                lg.setLevel(level)
