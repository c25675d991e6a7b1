"""``python -m robomorph.sweep``: Optuna studies over fit() arguments, one run per trial.

    python -m robomorph.sweep sweeps/architecture_cpu.yaml --n-trials 20
    python -m robomorph.sweep sweeps/architecture_cpu.yaml --n-trials 20 --storage postgresql://u:p@host/db
    python -m robomorph.sweep summary --study-name architecture-cpu

Every trial is a full :func:`robomorph.training.fitting.fit` writing ``<runs_dir>/<study>-t<NNNN>/``
(recorded in the trial's user attributes with its metrics). The validation metric is
reported to the pruner at every validation, at step granularity (Optuna's stock Lightning
callback reports epochs). ``--n-trials`` is the study's total of finished trials: several
workers (processes or machines) sharing the storage stop together, and re-running the
command continues the study. Storage is SQLite in ``results/sweeps/optuna.db`` by default
(no server; local worker processes share it), or any SQLAlchemy URL. Workers send a
heartbeat: the trial of a worker that died is marked failed by the next worker and
retried with the same parameters, resuming the dead trial's run directory.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import logging
import os
import sys
import time

import lightning.pytorch as L
import numpy as np
import optuna

from robomorph.core.config import yaml_value
from robomorph.core.errors import RoboMorphError
from robomorph.core.overrides import merge, unflatten
from robomorph.core.rundir import RunDir
from robomorph.tuning.space import Space, SpaceError
from robomorph.tuning.storage import open_storage

STATES_DONE = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)


class StepPruning(L.Callback):
    """Reports ``metric`` at every validation with ``trainer.global_step`` as the step."""

    def __init__(self, trial: optuna.Trial, metric: str):
        self.trial, self.metric = trial, metric
        self.values: list[float] = []
        self.pruned_at: int | None = None

    def on_validation_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking or self.metric not in trainer.callback_metrics:
            return
        value = float(trainer.callback_metrics[self.metric])
        self.values.append(value)
        self.trial.report(value, step=trainer.global_step)
        if self.trial.should_prune():
            # Stop cleanly (checkpoints and logs stay consistent), raise after fit returns.
            self.pruned_at = trainer.global_step
            trainer.should_stop = True


class PerTrialSeedSampler(optuna.samplers.BaseSampler):
    """A sampler re-made for every trial with a seed derived from (study seed, trial number).

    Workers started together each hold a sampler seeded with the space's seed: their random
    streams are identical, so trial k of one worker drew exactly the parameters of trial k'
    of the other (duplicated trials, fANOVA on duplicates). Trial numbers are unique across
    the workers of one storage, so seeding by them gives every trial its own stream, and a
    re-run of the study draws the same parameters for the same trial numbers.
    """

    def __init__(self, make, seed: int | None):
        self._make, self._seed = make, seed
        self._inner = make(seed)

    def _trial_seed(self, number: int) -> int | None:
        if self._seed is None:
            return None
        return int(np.random.SeedSequence(self._seed, spawn_key=(number,)).generate_state(1)[0])

    def before_trial(self, study, trial) -> None:
        self._inner = self._make(self._trial_seed(trial.number))
        self._inner.before_trial(study, trial)

    def infer_relative_search_space(self, study, trial):
        return self._inner.infer_relative_search_space(study, trial)

    def sample_relative(self, study, trial, search_space):
        return self._inner.sample_relative(study, trial, search_space)

    def sample_independent(self, study, trial, param_name, param_distribution):
        return self._inner.sample_independent(study, trial, param_name, param_distribution)

    def after_trial(self, study, trial, state, values) -> None:
        self._inner.after_trial(study, trial, state, values)

    def reseed_rng(self) -> None:
        self._inner.reseed_rng()


def _sampler(space: Space) -> optuna.samplers.BaseSampler:
    cfg = dict(space.sampler)
    name, seed = cfg.pop("name"), cfg.pop("seed", None)
    if name == "grid":
        grid = space.grid()
        return PerTrialSeedSampler(lambda s: optuna.samplers.GridSampler(grid, seed=s), seed)
    if name == "random":
        return PerTrialSeedSampler(lambda s: optuna.samplers.RandomSampler(seed=s), seed)
    # constant_liar: TPE treats the trials other workers are running as (bad) results, so
    # concurrent workers do not all propose the neighbourhood of the same best trial.
    cfg.setdefault("constant_liar", True)
    return PerTrialSeedSampler(lambda s: optuna.samplers.TPESampler(seed=s, **cfg), seed)


def _pruner(space: Space) -> optuna.pruners.BasePruner:
    cfg = dict(space.pruner)
    if cfg.pop("name") == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(**cfg)


def open_study(space: Space, storage=None, study_name: str | None = None) -> optuna.Study:
    """Creates or loads the study (several workers may call this at once)."""
    storage = storage if storage is not None else open_storage(None)
    name = study_name or space.name
    for attempt in range(5):
        try:
            return optuna.create_study(storage=storage, study_name=name, direction=space.direction,
                                       sampler=_sampler(space), pruner=_pruner(space), load_if_exists=True)
        except Exception:  # noqa: BLE001  (two workers creating the schema at the same instant)
            if attempt == 4:
                raise
            time.sleep(0.5 + attempt)
    raise AssertionError("unreachable")


def _run_name(trial: optuna.Trial, study_name: str) -> str:
    # A retried trial carries the user attributes of the trial it replaces, its run
    # directory included: it resumes that run instead of starting over.
    previous = trial.user_attrs.get("run_dir")
    return os.path.basename(previous) if previous else f"{study_name}-t{trial.number:04d}"


def make_objective(space: Space, study_name: str, runs_dir: str, wandb: str = "offline"):
    """The objective: one fit() per trial (plus an evaluation when the space asks for one)."""
    from robomorph.training.fitting import fit  # noqa: PLC0415

    def objective(trial: optuna.Trial) -> float:
        values = space.suggest(trial)
        run = _run_name(trial, study_name)
        layout = RunDir.named(runs_dir, run)
        trial.set_user_attr("run_dir", layout.path)
        regime = values.get("transfer.regime")
        args = _regime_args(space, values, regime, run, runs_dir, wandb, study_name)
        pruning = StepPruning(trial, space.metric)
        ckpt = space.transfer.get("init_ckpt")
        if args is not None:
            result = fit(args, callbacks=[pruning])
            trial.set_user_attr("metrics", result.metrics)
            trial.set_user_attr("global_step", result.global_step)
            if pruning.pruned_at is not None:
                raise optuna.TrialPruned(f"pruned at step {pruning.pruned_at}")
            ckpt = result.best_ckpt
        if space.eval_data:
            return _evaluate(trial, space, ckpt, layout.eval_dir("sweep"))
        # The run's CSV log (pruned to the resumed step) records every validation, also those
        # of a dead worker whose trial this retry resumed: a resume already at its budget
        # validates no more. This process's own reports stand in when there is no log.
        best = _best(logged_values(layout.path, space.metric) or pruning.values, space.direction)
        if best is None:
            raise RuntimeError(f"trial {trial.number} logged no {space.metric!r}: validate at least once "
                               "(trainer.val_check_interval below the step budget)")
        return best

    return objective


def logged_values(run_dir: str, metric: str) -> list[float]:
    """The values of ``metric`` in a run's ``logs/metrics.csv`` (empty when none were logged)."""
    path = RunDir(run_dir).metrics_csv
    if not os.path.isfile(path):
        return []
    with open(path, newline="") as f:
        return [float(r[metric]) for r in csv.DictReader(f) if r.get(metric) not in (None, "")]


def _best(values: list[float], direction: str) -> float | None:
    if not values:
        return None
    return max(values) if direction == "maximize" else min(values)


def _regime_args(space: Space, values: dict, regime: str | None, run: str, runs_dir: str, wandb: str,
                 group: str) -> dict | None:
    args = space.fit_args(values, run, runs_dir)
    args.update(wandb=wandb, group=group)
    if regime is None:
        return args
    from robomorph.training.transfer import regime_overrides  # noqa: PLC0415

    # Learning rate and freezing are the fine-tuning's own settings; scratch keeps the base's.
    tuned = regime == "finetune"
    over = regime_overrides(regime, space.transfer.get("init_ckpt"), int(space.transfer.get("steps", 1000)),
                            lr=values.get("transfer.lr", space.transfer.get("lr")) if tuned else None,
                            freeze=values.get("transfer.freeze", space.transfer.get("freeze", "none")) if tuned else "none")
    return None if over is None else merge(args, over)


def _evaluate(trial: optuna.Trial, space: Space, ckpt: str | None, out: str) -> float:
    from robomorph.evaluation.evaluator import evaluate  # noqa: PLC0415
    from robomorph.evaluation.requests import EvaluateConfig  # noqa: PLC0415

    if not ckpt:
        raise RuntimeError("nothing to evaluate: the trial trained no checkpoint and the space names no init_ckpt")
    res = evaluate(EvaluateConfig(data=space.eval_data, ckpt=ckpt, out=out, baselines=(), samples=0))
    trial.set_user_attr("eval", {m: v["mean"] for m, v in res["approach1"]["mean"].items()})
    return float(res["approach1"]["mean"][space.metric]["mean"])


def run_sweep(space: Space, n_trials: int, storage=None, study_name: str | None = None,
              runs_dir: str = "results/runs", wandb: str = "offline") -> optuna.Study:
    """Runs trials until the study holds ``n_trials`` finished (complete or pruned) trials."""
    space.check_inputs()
    study = open_study(space, storage, study_name)
    done = len(study.get_trials(deepcopy=False, states=STATES_DONE))
    if done >= n_trials:
        print(f"study {study.study_name!r} already has {done} finished trials (asked {n_trials})", file=sys.stderr)
        return study
    stop = optuna.study.MaxTrialsCallback(n_trials, states=STATES_DONE)
    objective = make_objective(space, study.study_name, runs_dir, wandb)
    # n_trials bounds this worker; the callback stops every worker at the study's total.
    with _told_once():
        study.optimize(objective, n_trials=n_trials, callbacks=[stop], catch=(RuntimeError,), gc_after_trial=True)
    return study


class _NotUserErrors(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and isinstance(record.exc_info[1], RoboMorphError))


@contextlib.contextmanager
def _told_once():
    """Optuna logs the traceback of the error that failed a trial, then re-raises it; a
    :class:`RoboMorphError` (the user's setting, the same for every trial) stops the sweep
    and the door tells it in one line, so optuna's copy is left out."""
    quiet = _NotUserErrors()
    handlers = logging.getLogger("optuna").handlers
    for h in handlers:
        h.addFilter(quiet)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(quiet)


def with_overrides(space: Space, pairs: list[str]) -> Space:
    """``space`` with ``KEY=VALUE`` pairs (dotted keys, YAML values) set: ``transfer.*`` keys in
    its transfer settings, any other in the fit() arguments of every trial, over the base and
    the budget (``--set trainer.max_steps=5`` shortens every trial)."""
    flat, transfer = {}, dict(space.transfer)
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or "." not in key:
            raise SpaceError(f"--set takes section.argument=value, got {pair!r}")
        if key.startswith("transfer."):
            transfer[key.removeprefix("transfer.")] = yaml_value(value, f"--set {key}")
        else:
            flat[key] = yaml_value(value, f"--set {key}")
    return dataclasses.replace(space, overrides=merge(space.overrides, unflatten(flat)), transfer=transfer).check()
