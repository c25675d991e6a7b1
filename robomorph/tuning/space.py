"""Search spaces as data: ``sweeps/<space>.yaml`` read, validated and turned into trials.

A space file::

    name: architecture-cpu                 # default study name
    objective: {metric: val/r2, direction: maximize}
    budget: {max_steps: 3000, max_time: "00:00:20:00"}   # per trial (trainer limits)
    sampler: {name: tpe, seed: 0, n_startup_trials: 5}   # tpe | random | grid
    pruner: {name: median, n_startup_trials: 2, n_warmup_steps: 500}   # median | none
    base:                                  # fit() arguments shared by every trial
      config: datamodules/train_cpu.yaml   # optional LightningCLI config file
      data: {stores: data/ms.zarr}
    params:                                # dotted fit() argument -> distribution
      model.n_layer: {choices: [2, 4, 6]}
      model.lr: {low: 1.0e-4, high: 3.0e-3, log: true}
      model.d_model: {low: 64, high: 192, step: 64}      # ints when low/high/step are ints
    transfer: {init_ckpt: results/runs/pre/checkpoints/best.ckpt, steps: 2000}  # optional

A parameter ``transfer.regime`` (choices from :data:`robomorph.training.transfer.REGIMES`) picks
the transfer-learning regime of each trial. With ``objective.data`` set, the objective is
the evaluation metric on that store (approach 1 mean, e.g. ``r2`` or ``fit``) instead of
a validation metric logged by training.

Each space tunes one model: a Gaussian head is trained with ``nll`` and ``nll`` needs the
head, so a space whose choices would pair them otherwise is refused. The ``budget`` is
each trial's trainer limits and wins over the base's config file (``train_cpu.yaml``
asks for 20,000 steps; a space's ``budget.max_steps`` is what its trials train); giving
a limit in both ``budget`` and ``base.trainer`` is refused. ``--set`` overrides
(:func:`robomorph.tuning.runner.with_overrides`) win over both.
"""

from __future__ import annotations

import inspect
import os
from dataclasses import dataclass, field
from typing import Any

from robomorph.core.config import load_yaml
from robomorph.core.errors import RoboMorphError
from robomorph.core.names import METRICS, REGIMES, check_plain_name
from robomorph.core.overrides import merge, unflatten
from robomorph.core.recipes import locate

SAMPLERS = ("tpe", "random", "grid")
PRUNERS = ("median", "none")
SECTIONS = ("data", "model", "trainer", "transfer")
EVAL_METRICS = METRICS  # an evaluation objective takes one of the evaluation's metrics


class SpaceError(RoboMorphError, ValueError):
    """A search space that cannot be run; the message names the field and the fix."""


@dataclass(frozen=True)
class Param:
    """One searched fit() argument: categorical (``choices``) or numeric (``low``, ``high``)."""

    name: str
    choices: tuple | None = None
    low: float | None = None
    high: float | None = None
    step: float | None = None
    log: bool = False

    @property
    def is_int(self) -> bool:
        return all(isinstance(v, int) and not isinstance(v, bool) for v in (self.low, self.high, self.step or 1))

    def suggest(self, trial) -> Any:
        if self.choices is not None:
            return trial.suggest_categorical(self.name, list(self.choices))
        if self.is_int:
            return trial.suggest_int(self.name, self.low, self.high, step=self.step or 1, log=self.log)
        return trial.suggest_float(self.name, self.low, self.high, step=self.step, log=self.log)


@dataclass(frozen=True)
class Space:
    """A validated search space (see the module docstring for the file format)."""

    name: str
    metric: str
    direction: str
    params: tuple[Param, ...]
    base: dict = field(default_factory=dict)
    budget: dict = field(default_factory=dict)
    sampler: dict = field(default_factory=lambda: {"name": "tpe"})
    pruner: dict = field(default_factory=lambda: {"name": "median"})
    eval_data: str | None = None
    transfer: dict = field(default_factory=dict)
    overrides: dict = field(default_factory=dict)  # nested fit() arguments from the command line (--set)

    def suggest(self, trial) -> dict[str, Any]:
        """Draws every parameter of ``trial``: ``{dotted name: value}``."""
        return {p.name: p.suggest(trial) for p in self.params}

    def grid(self) -> dict[str, list]:
        """The search space of the grid sampler (categorical parameters only)."""
        return {p.name: list(p.choices) for p in self.params}

    def fit_args(self, values: dict[str, Any], run: str, runs_dir: str) -> dict:
        """The nested fit() arguments of one trial (``transfer.*`` values left out).

        Later layers win: the base's config file, the base, the budget (so a config file's
        ``trainer.max_steps`` never outlasts the space's), the command line's overrides,
        the trial's values.
        """
        args = merge(self.base_args(), {"trainer": self.budget})
        args = merge(args, self.overrides)
        args = merge(args, unflatten({k: v for k, v in values.items() if not k.startswith("transfer.")}))
        args.update(run=run, runs_dir=runs_dir)
        return args

    def base_args(self) -> dict:
        """The base's config file (a path or a shipped recipe's name) with the base over it."""
        base = dict(self.base)
        config = base.pop("config", None)
        return merge(load_yaml(locate(config, "datamodules")), base) if config else merge(base, None)

    def check(self, where: str = "space") -> Space:
        """Refuses a space whose trials would train a model other than the one it tunes:
        ``nll`` without the Gaussian head (refused by the model anyway), or a Gaussian head
        trained with ``mse``/``huber`` (its variance head never learns). Returns ``self``."""
        model = merge(self.base_args().get("model"), self.overrides.get("model"))
        searched = {p.name: p.choices for p in self.params}
        defaults = _model_defaults()
        losses = searched.get("model.loss") or (model.get("loss", defaults["loss"]),)
        heads = searched.get("model.gaussian") or (model.get("gaussian", defaults["gaussian"]),)
        for loss in losses:
            for gaussian in heads:
                if (loss == "nll") != bool(gaussian):
                    fix = ("search nll with model.gaussian true" if gaussian else "set model.gaussian true for nll")
                    raise SpaceError(f"{where}: a trial would train model.loss {loss} with model.gaussian "
                                     f"{str(bool(gaussian)).lower()}: the Gaussian head needs the nll loss, and nll "
                                     f"needs the head ({fix}, or drop the mismatched choice)")
        return self

    def check_inputs(self) -> None:
        """The pre-trained checkpoint a transfer space starts from exists (before any trial)."""
        regimes = next((p.choices for p in self.params if p.name == "transfer.regime"), ()) or ()
        ckpt = self.transfer.get("init_ckpt")
        if set(regimes) & {"zero_shot", "finetune"} and not os.path.isfile(str(ckpt)):
            raise SpaceError(f"transfer.init_ckpt {ckpt} does not exist: pre-train it first (the command is in the "
                             "space file's header) or pass --set transfer.init_ckpt=PATH")


def _model_defaults() -> dict[str, Any]:
    from robomorph.training.module import MetaModule  # noqa: PLC0415  (heavy; only when validating)

    return {k: v.default for k, v in inspect.signature(MetaModule.__init__).parameters.items()}


def _known_args() -> dict[str, set[str]]:
    import lightning.pytorch as L  # noqa: PLC0415  (heavy; only when validating)

    from robomorph.data.datamodule import RoboMorphDataModule  # noqa: PLC0415
    from robomorph.training.module import FROM_DATA, MetaModule  # noqa: PLC0415

    def names(fn):
        return set(inspect.signature(fn).parameters) - {"self"}

    return {"data": names(RoboMorphDataModule.__init__), "model": names(MetaModule.__init__) - set(FROM_DATA),
            "trainer": names(L.Trainer.__init__), "transfer": {"regime", "freeze", "lr"}}


def _param(name: str, spec: Any, known: dict[str, set[str]]) -> Param:
    section, _, leaf = name.partition(".")
    if section not in SECTIONS or not leaf:
        raise SpaceError(f"parameter {name!r}: name it <section>.<argument> with section one of {SECTIONS}")
    if leaf not in known[section]:
        raise SpaceError(f"unknown parameter {name!r}: {section} has no argument {leaf!r} "
                         f"(see python -m robomorph.fit --print_config)")
    if not isinstance(spec, dict):
        raise SpaceError(f"parameter {name!r}: give {{choices: [...]}} or {{low: .., high: ..}}, got {spec!r}")
    unknown = set(spec) - {"choices", "low", "high", "step", "log"}
    if unknown:
        raise SpaceError(f"parameter {name!r}: unknown keys {sorted(unknown)}")
    if "choices" in spec:
        choices = spec["choices"]
        if not isinstance(choices, list) or not choices:
            raise SpaceError(f"parameter {name!r}: choices must be a non-empty list")
        return Param(name, choices=tuple(choices))
    if "low" not in spec or "high" not in spec:
        raise SpaceError(f"parameter {name!r}: numeric parameters need low and high")
    low, high, step, log = spec["low"], spec["high"], spec.get("step"), bool(spec.get("log", False))
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high)):
        raise SpaceError(f"parameter {name!r}: low and high must be numbers")
    if low > high:
        raise SpaceError(f"parameter {name!r}: low {low} > high {high}")
    if log and (low <= 0 or step is not None):
        raise SpaceError(f"parameter {name!r}: a log scale needs low > 0 and no step")
    return Param(name, low=low, high=high, step=step, log=log)


def parse_space(data: dict, where: str = "space") -> Space:
    """Validates a space given as a dict (the parsed YAML)."""
    if not isinstance(data, dict):
        raise SpaceError(f"{where}: expected a mapping at the top level")
    unknown = set(data) - {"name", "objective", "budget", "sampler", "pruner", "base", "params", "transfer"}
    if unknown:
        raise SpaceError(f"{where}: unknown keys {sorted(unknown)}")
    objective = data.get("objective") or {}
    metric, direction = objective.get("metric"), objective.get("direction")
    if not metric or direction not in ("minimize", "maximize"):
        raise SpaceError(f"{where}: objective needs a metric and direction minimize|maximize, got {objective!r}")
    if objective.get("data") and metric not in EVAL_METRICS:
        raise SpaceError(f"{where}: an evaluation objective takes a metric from {EVAL_METRICS}, got {metric!r}")
    budget, base_trainer = data.get("budget") or {}, (data.get("base") or {}).get("trainer") or {}
    both = sorted(set(budget) & set(base_trainer))
    if both:
        raise SpaceError(f"{where}: {', '.join(f'budget.{k} and base.trainer.{k}' for k in both)} are both set: "
                         "keep the budget's (the per-trial limits) and drop the other")
    params = data.get("params")
    if not isinstance(params, dict) or not params:
        raise SpaceError(f"{where}: params must map at least one parameter to its distribution")
    known = _known_args()
    parsed = tuple(_param(k, v, known) for k, v in params.items())
    sampler = {"name": "tpe", **(data.get("sampler") or {})}
    pruner = {"name": "median", **(data.get("pruner") or {})}
    if sampler["name"] not in SAMPLERS:
        raise SpaceError(f"{where}: sampler must be one of {SAMPLERS}, got {sampler['name']!r}")
    if sampler["name"] == "grid" and any(p.choices is None for p in parsed):
        raise SpaceError(f"{where}: the grid sampler needs choices for every parameter")
    if pruner["name"] not in PRUNERS:
        raise SpaceError(f"{where}: pruner must be one of {PRUNERS}, got {pruner['name']!r}")
    regime = next((p for p in parsed if p.name == "transfer.regime"), None)
    if regime is not None:
        bad = set(regime.choices or ()) - set(REGIMES)
        if regime.choices is None or bad:
            raise SpaceError(f"{where}: transfer.regime takes choices from {REGIMES}")
        if set(regime.choices) & {"zero_shot", "finetune"} and not (data.get("transfer") or {}).get("init_ckpt"):
            raise SpaceError(f"{where}: zero_shot and finetune start from transfer.init_ckpt; name the "
                             "pre-trained checkpoint there")
    study = check_plain_name(str(data.get("name") or "sweep"), f"{where}: name")  # it names folders
    return Space(name=study, metric=metric, direction=direction, params=parsed,
                 base=data.get("base") or {}, budget=budget, sampler=sampler, pruner=pruner,
                 eval_data=objective.get("data"), transfer=data.get("transfer") or {}).check(where)


def load_space(path: str) -> Space:
    """Reads and validates a space: a path, or a shipped space's name (``ci``, ``sweeps/ci.yaml``)."""
    path = locate(path, "sweeps")
    return parse_space(load_yaml(path), where=path)
