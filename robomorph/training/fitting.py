"""``python -m robomorph.fit``: train a meta-model (LightningCLI over :func:`fit`).

    python -m robomorph.fit --data.stores data/ms.zarr --run ms-small
    python -m robomorph.fit --config configs/my.yaml --model.d_model 64 --trainer.max_steps 500
    python -m robomorph.fit --print_config

Each run writes ``<runs_dir>/<run>/``: ``config.yaml`` (the resolved configuration),
``checkpoints/last.ckpt`` and ``checkpoints/best.ckpt`` (lowest ``val/loss``), a CSV log
``logs/metrics.csv`` and a wandb run (offline unless ``--wandb online``). Re-running with
the same ``--run`` resumes from ``last.ckpt`` at the same step, optimizer and schedule.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import sys
import time
import warnings
from typing import Any

import torch
from lightning.pytorch.callbacks import LearningRateMonitor
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.loggers import WandbLogger
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch.utilities.exceptions import SIGTERMException

from robomorph.core.atomic import write_text
from robomorph.core.errors import DeviceError, StoppedBySignal, UsageError
from robomorph.core.locks import exclusive
from robomorph.core.names import VAL_LOSS, check_plain_name
from robomorph.core.rundir import RunDir
from robomorph.data.datamodule import RoboMorphDataModule
from robomorph.inference.checkpoint import load_checkpoint_file
from robomorph.training import preflight
from robomorph.training.callbacks import BestAndLast, FinalValidation, SaveOnSigterm
from robomorph.training.checkpoints import AtomicCheckpointIO, ResumableCSVLogger, prune_log
from robomorph.training.module import FROM_DATA, SCHEDULE_KEY, MetaModule, schedule_change
from robomorph.training.pretrained import inherited_channels
from robomorph.training.progress import progress_callbacks, quiet_lightning

_RUN_ENV = "ROBOMORPH_RUN_NAME"  # shared with DDP worker processes, which re-run this script


@dataclasses.dataclass
class FitResult:
    """What a finished :func:`fit` leaves behind."""

    run_dir: str
    best_ckpt: str | None
    last_ckpt: str | None
    metrics: dict[str, float]
    global_step: int
    val_step: int | None = None  # the step of the validation that ``metrics`` reports


def _default_precision() -> str:
    if torch.cuda.is_available() and torch.cuda.is_bf16_supported():
        return "bf16-mixed"
    return "32-true"


TRAINER_DEFAULTS: dict[str, Any] = {
    "max_steps": 2000,
    "val_check_interval": 200,
    "check_val_every_n_epoch": None,  # validate by steps, across epoch boundaries
    "gradient_clip_val": 1.0,
    "log_every_n_steps": 10,
    "num_sanity_val_steps": 0,
}


class RoboMorphCLI(LightningCLI):
    """LightningCLI with a run directory, automatic resume, loggers and checkpoints."""

    extra_callbacks: tuple = ()  # callback objects from Python callers (benchmarks, sweeps)

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument("--run", type=str | None, default=None,
                            help="run name: outputs go to <runs_dir>/<run>/ (default: a timestamp)")
        parser.add_argument("--runs_dir", type=str, default="results/runs")
        parser.add_argument("--ckpt_path", type=str | None, default=None,
                            help="checkpoint to resume from; 'last' = this run's last.ckpt "
                                 "(the default whenever the run already has one)")
        parser.add_argument("--wandb", type=str, default=os.environ.get("WANDB_MODE", "offline"),
                            help="offline (default: no account needed), online, or disabled")
        parser.add_argument("--project", type=str, default="robomorph", help="wandb project")
        parser.add_argument("--group", type=str | None, default=None, help="wandb group (e.g. a sweep study)")
        parser.add_argument("--verbose", type=bool, default=False,
                            help="also show Lightning's own messages: tips, accelerator lines, deprecation "
                                 "warnings and the model summary")
        # One setting, two users: the data records it, the model's normalizer applies it.
        parser.link_arguments("data.recenter", "model.recenter")
        parser.link_arguments("data.normalization", "model.normalization")
        # The data decide the model's widths and context: read from the instantiated
        # datamodule (its stores' metadata) and passed to the model's constructor.
        for name in FROM_DATA:
            parser.link_arguments(f"data.{name}", f"model.{name}", apply_on="instantiate")

    def before_instantiate_classes(self) -> None:
        # Fine-tuning a model of several arms: the run keeps its channel set (and so its
        # architecture) when the stores fit in it; see pretrained.inherited_channels.
        data, model = self.config.data, self.config.model
        if data.channels is None and data.stores:
            stores = [data.stores] if isinstance(data.stores, str) else list(data.stores)
            data.channels = inherited_channels(model.init_ckpt, model.reinit_io, stores, data.inputs)

    def run_dir(self) -> RunDir:
        cfg = self.config
        name = check_plain_name(cfg.run or os.environ.get(_RUN_ENV) or time.strftime("run-%Y%m%d-%H%M%S"), "--run")
        os.environ[_RUN_ENV] = name
        return RunDir.named(cfg.runs_dir, name)

    def instantiate_trainer(self, **kwargs: Any):
        # The folder is made by fit() once the pre-flight checks pass, not here: a refused
        # fit leaves nothing behind.
        cfg, run = self.config, self.run_dir()
        self.rundir = run  # the run folder this fit writes (RunDir)
        ckpt_dir = run.checkpoints
        callbacks = [
            # The file names are RunDir's: best.ckpt, and Lightning's last.ckpt.
            BestAndLast(dirpath=ckpt_dir, filename="best", monitor=VAL_LOSS, mode="min", save_top_k=1,
                            save_last=True, auto_insert_metric_name=False, enable_version_counter=False),
            LearningRateMonitor(logging_interval="step"),
            FinalValidation(),
            SaveOnSigterm(ckpt_dir),
        ]
        trainer_cfg = self._get(self.config_init, "trainer", default={})
        # Steps against the budget, not epochs: ours replaces Lightning's bar (on unless disabled).
        callbacks += progress_callbacks(trainer_cfg.get("enable_progress_bar") is not False)
        kwargs["callbacks"] = list(trainer_cfg.get("callbacks") or []) + callbacks + list(self.extra_callbacks)
        kwargs["default_root_dir"] = run.path
        kwargs["logger"] = _loggers(run, cfg)
        kwargs["plugins"] = [AtomicCheckpointIO()]
        if trainer_cfg.get("precision") is None:
            kwargs["precision"] = _default_precision()
        # Lightning speaks while the trainer is built (tips, accelerators) and while it fits:
        # quiet from here until fit() closes this stack.
        self.quiet = contextlib.ExitStack()
        self.quiet.enter_context(quiet_lightning(bool(cfg.verbose)))
        try:
            return super().instantiate_trainer(**kwargs)
        except BaseException:
            self.quiet.close()
            raise


class QuietWandbLogger(WandbLogger):
    """Lightning's WandbLogger without the ``anonymous`` setting it always passes to ``wandb.init``.

    Lightning sends ``anonymous=None`` when not asked for it; wandb (0.19 and later) warns
    that "The anonymous setting has no effect" for any value given, None included, on every
    fit. The setting does nothing, so leaving it out changes nothing but the warning.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if self._wandb_init.get("anonymous") is None:
            self._wandb_init.pop("anonymous", None)


def _loggers(run: RunDir, cfg) -> list:
    # save_dir + name "logs" + no version: the CSV log is RunDir's logs/metrics.csv.
    loggers: list = [ResumableCSVLogger(save_dir=run.path, name=os.path.basename(run.logs), version="")]
    if cfg.wandb != "disabled":
        os.environ.setdefault("WANDB_SILENT", "true")
        run_id = None
        if os.path.exists(run.wandb_id):
            with open(run.wandb_id, encoding="utf-8") as f:
                run_id = f.read().strip()
        logger = QuietWandbLogger(save_dir=run.path, project=cfg.project, name=run.name,
                             group=cfg.group, id=run_id, resume="allow" if run_id else None, mode=cfg.wandb)
        loggers.append(logger)
    return loggers


def _save_wandb_id(trainer, run: RunDir) -> None:
    for logger in trainer.loggers:
        if isinstance(logger, WandbLogger) and trainer.is_global_zero:
            write_text(run.wandb_id, logger.version or "")


def _finish_wandb(trainer) -> None:
    """Closes the wandb run so the next fit() in this process starts its own."""
    for logger in trainer.loggers:
        if isinstance(logger, WandbLogger) and trainer.is_global_zero:
            import wandb  # noqa: PLC0415

            wandb.finish()


def _callback(trainer, cls):
    return next(cb for cb in trainer.callbacks if isinstance(cb, cls))


def _announce_resume(cli: RoboMorphCLI, run: RunDir, ckpt_path: str) -> None:
    """Says where the run resumes and, when ``max_steps`` changed, how the schedule changes."""
    ckpt = load_checkpoint_file(ckpt_path)
    step = ckpt["global_step"]
    prune_log(run.metrics_csv, step)
    print(f"resuming {run.path} from {ckpt_path} (step {step})", file=sys.stderr)
    old_max = ckpt.get(SCHEDULE_KEY, {}).get("max_steps", _configured_max_steps(run))
    change = schedule_change(ckpt["hyper_parameters"], old_max, cli.model.hparams, cli.trainer.max_steps, step)
    if change:
        print(change, file=sys.stderr)


def _configured_max_steps(run: RunDir) -> int | None:
    """``trainer.max_steps`` of the run's config.yaml (checkpoints older than SCHEDULE_KEY)."""
    import yaml  # noqa: PLC0415

    try:
        with open(run.config) as f:
            return int(yaml.safe_load(f)["trainer"]["max_steps"])
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        return None


def _resume_path(cli: RoboMorphCLI, run: RunDir) -> str | None:
    run.check_resume_point()  # a folder or unreadable file there is no "new run"
    last = run.last_ckpt
    asked = cli.config.ckpt_path
    if asked == "last" or (asked is None and os.path.isfile(last)):
        return last if os.path.isfile(last) else None
    return asked


def build_cli(args: list[str] | dict | None = None, callbacks: list | None = None) -> RoboMorphCLI:
    """Parses arguments (list, dict or sys.argv) and instantiates data, model and trainer."""
    cls = type("RoboMorphCLIWithCallbacks", (RoboMorphCLI,), {"extra_callbacks": tuple(callbacks or ())})
    if args is not None:
        # Called as a function (tests, sweeps, demo): the caller's own command line is not ours.
        warnings.filterwarnings("ignore", message="LightningCLI's args parameter is intended")
    # "Seed set to N" would precede any one-line error of a bad command; the seed is in config.yaml.
    seed_log = logging.getLogger("lightning.fabric.utilities.seed")
    level = seed_log.level
    seed_log.setLevel(logging.WARNING)
    try:
        return cls(
            MetaModule, RoboMorphDataModule, run=False, args=args, trainer_defaults=TRAINER_DEFAULTS,
            save_config_callback=None, seed_everything_default=0,
            parser_kwargs={"prog": "python -m robomorph.fit", "description": __doc__.split("\n")[0]},
        )
    finally:
        seed_log.setLevel(level)


def fit(args: list[str] | dict | None = None, callbacks: list | None = None) -> FitResult:
    """Trains (or resumes) one run; the function sweeps and tests call.

    Args:
        args: CLI arguments as a list (``["--data.stores", "x.zarr"]``) or a nested dict
            (``{"data": {"stores": "x.zarr"}, "trainer": {"max_steps": 10}}``).
        callbacks: extra Lightning callback objects (e.g. a sweep's pruning callback).
    """
    with lightning_refusals():
        cli = build_cli(args, callbacks)
        with cli.quiet, _run_lock(cli):
            return _fit(cli)


@contextlib.contextmanager
def lightning_refusals():
    """Lightning's refusal of a configuration (an accelerator this machine lacks, an unknown
    profiler) as the package's one-line error: the user's flags, whoever called fit() (the
    fit door, a sweep's trial, reproduce, the demo)."""
    try:
        yield
    except MisconfigurationException as exc:
        kind = DeviceError if "accelerator" in str(exc) or "backend" in str(exc) else UsageError
        raise kind(f"--trainer: {exc}") from exc


def _run_lock(cli: RoboMorphCLI):
    """One writer per run folder (two would mix their logs and configs). DDP workers re-run
    this script: the launching process (global rank 0) holds the lock for them all."""
    return exclusive(cli.rundir.path, "run folder") if cli.trainer.is_global_zero else contextlib.nullcontext()


def _fit(cli: RoboMorphCLI) -> FitResult:
    run, trainer, module = cli.rundir, cli.trainer, cli.model
    ckpt = _resume_path(cli, run)
    _preflight(cli, ckpt)
    module.resuming = ckpt is not None
    created = not os.path.isdir(run.path)
    os.makedirs(run.path, exist_ok=True)
    try:
        if trainer.is_global_zero:
            if ckpt:
                _announce_resume(cli, run, ckpt)
            # Written only now: a refused resume keeps the configuration its checkpoints belong to.
            cli.parser.save(cli.config, run.config, overwrite=True, multifile=False)
        try:
            with warnings.catch_warnings():
                # A run's checkpoint and log folders hold its earlier steps when it resumes, by design: Lightning's
                # "directory ... exists and is not empty" would say otherwise on every re-run.
                warnings.filterwarnings("ignore", message=r".*directory .* exists and is not empty")
                trainer.fit(module, datamodule=cli.datamodule, ckpt_path=ckpt)
        except SIGTERMException:
            saver = _callback(trainer, SaveOnSigterm)
            raise StoppedBySignal(run.path, saver.path, saver.saved_step) from None
        finally:
            _save_wandb_id(trainer, run)
            _finish_wandb(trainer)
    except BaseException:
        _remove_if_empty(run, created)
        raise
    cb = trainer.checkpoint_callback
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1}
    best, last = run.best_ckpt, run.last_ckpt
    return FitResult(run_dir=run.path, best_ckpt=best if os.path.isfile(best) else (cb.best_model_path or None),
                     last_ckpt=last if os.path.isfile(last) else None, metrics=metrics,
                     global_step=trainer.global_step, val_step=_callback(trainer, FinalValidation).last_val_step)


def _preflight(cli: RoboMorphCLI, ckpt: str | None) -> int:
    """Every check that can fail before training (data, shapes, budget, checkpoints); the
    step of the resumed checkpoint (0 for a new run)."""
    trainer, module, dm = cli.trainer, cli.model, cli.datamodule
    preflight.check_budget(trainer)
    dm.setup("fit")  # idempotent: the trainer's own call then finds it done
    preflight.check_windows(module, dm)
    if ckpt:
        return preflight.check_resume(module, dm, ckpt)
    preflight.check_init(module)
    return 0


def _remove_if_empty(run: RunDir, created: bool) -> None:
    """A run folder this call made and that holds no checkpoint goes again: a failed fit
    leaves no husk for the next ``--run`` of that name to trip over."""
    if created and not os.path.isfile(run.last_ckpt):
        shutil.rmtree(run.path, ignore_errors=True)


def final_line(result: FitResult) -> str:
    """The run's last line: the step reached and the validation it reports, with its step."""
    shown = ", ".join(f"{k}={v:.4g}" for k, v in sorted(result.metrics.items()) if k.startswith("val/"))
    if result.val_step is None or not shown:
        return f"{result.run_dir}: step {result.global_step}, no validation in this session"
    return f"{result.run_dir}: step {result.global_step}, validation at step {result.val_step}: {shown}"
