"""The generation recipe: what ``python -m robomorph.generate`` and ``datamodules/*.yaml`` hold."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

from robomorph.core.config import ConfigError, from_dict, load_yaml, to_dict
from robomorph.core.names import GRAVITY_MODES, OSC_TASKS, TASKS
from robomorph.core.overrides import merge
from robomorph.core.recipes import locate
from robomorph.sim import arms
from robomorph.sim.filters import FilterConfig
from robomorph.sim.osc import OSCConfig
from robomorph.sim.paths import CircleConfig, SpiralConfig
from robomorph.sim.randomize import RandomizationConfig
from robomorph.sim.realism import RealismConfig
from robomorph.sim.signals import SignalConfig


# The longest sample time a recipe takes [s]. The shipped recipes sample at 60 Hz and real arms log at 10 Hz
# to 1 kHz; a sample a second apart holds none of an arm's dynamics, and ``Predictor.from_arm(dt=1e9)``
# predicted poses of 6e5 m without a word.
MAX_DT = 1.0


@dataclass(frozen=True)
class Recipe:
    """Everything that decides a generated dataset (with the seed, it decides every array).

    Attributes:
        robot: the simulated arm, a name of :mod:`robomorph.sim.arms` (``panda``, ``ur5e``, ...).
        task: one task name, or a mixture ``{task: weight}`` drawn per trajectory.
        robots: valid trajectories to keep.
        steps: recorded samples per trajectory (T).
        seed: root seed; attempt ``i`` draws from ``SeedSequence(seed, spawn_key=(i,))``.
        dt: recorded sample time [s] (60 Hz as in the paper).
        substeps: physics steps per sample (dt / substeps is the physics step).
        gravity_compensation: ``true_model`` (g(q) of the randomized robot in the torque),
            ``nominal_model`` (g(q) of the catalogue robot: the randomized masses then
            show up as model error) or ``none``.
        chunk: trajectories per Zarr chunk, per rollout batch and per flush.
        max_attempts_factor: give up after ``robots * factor`` attempts.
        realism: the realism terms of :mod:`robomorph.sim.realism` (all off by default; the
            ``realistic`` recipe turns them on). Recorded in the store's ``config`` when any is on.
    """

    task: str | dict[str, float] = "multisine"
    robots: int = 256
    robot: str = arms.DEFAULT_ROBOT
    steps: int = 1000
    seed: int = 0
    dt: float = 1 / 60
    substeps: int = 8
    gravity_compensation: Literal[GRAVITY_MODES] = "true_model"
    chunk: int = 64
    max_attempts_factor: float = 20.0
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    signal: SignalConfig = field(default_factory=SignalConfig)
    osc: OSCConfig = field(default_factory=OSCConfig)
    circle: CircleConfig = field(default_factory=CircleConfig)
    spiral: SpiralConfig = field(default_factory=SpiralConfig)
    filters: FilterConfig = field(default_factory=FilterConfig)
    realism: RealismConfig = field(default_factory=RealismConfig)

    def __post_init__(self):
        for name in self.task_weights:
            if name not in TASKS:
                raise ValueError(f"unknown task {name!r}; choose from {list(TASKS)}")
        if any(w <= 0 for w in self.task_weights.values()):
            raise ValueError(f"task weights must be positive, got {self.task_weights}")
        for name in ("robots", "steps", "substeps", "chunk"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 < self.dt <= MAX_DT:
            raise ValueError(f"dt must be a sample time in seconds, > 0 and at most {MAX_DT:g}, got {self.dt}")
        if self.max_attempts_factor < 1:
            raise ValueError(f"max_attempts_factor must be >= 1, got {self.max_attempts_factor}")
        if self.gravity_compensation not in GRAVITY_MODES:
            raise ValueError(f"gravity_compensation must be one of {GRAVITY_MODES}")
        if self.robot not in arms.ARMS:
            raise ValueError(f"unknown robot {self.robot!r}; choose from {arms.names()}")

    @property
    def arm(self) -> arms.Arm:
        """The simulated arm's registry entry."""
        return arms.get(self.robot)

    @property
    def task_weights(self) -> dict[str, float]:
        """Task -> probability (a single task has weight 1)."""
        if isinstance(self.task, str):
            return {self.task: 1.0}
        total = sum(self.task.values())
        return {k: v / total for k, v in self.task.items()} if total > 0 else dict(self.task)

    @property
    def task_names(self) -> list[str]:
        return list(self.task_weights)

    @property
    def task_label(self) -> str:
        return "+".join(self.task_names)

    @property
    def has_osc(self) -> bool:
        return any(t in OSC_TASKS for t in self.task_names)

    def to_dict(self) -> dict[str, Any]:
        data = to_dict(self)
        # The Panda's recipes stay as they were written before arms had a name: stores and
        # checkpoints record this dict, and `reproduce` skips a store whose dict matches.
        if self.robot == arms.DEFAULT_ROBOT:
            del data["robot"]
        # A clean recipe's dict (and so its stores' attributes and fingerprints) stays as it was.
        if not self.realism.enabled:
            del data["realism"]
        return data


def load_recipe(path: str | None = None, overrides: dict[str, Any] | None = None) -> Recipe:
    """Builds a recipe from an optional YAML file (a path or a shipped recipe's name, see
    :func:`robomorph.core.recipes.locate`) and flag overrides (flags win)."""
    # A flag left unset (None) keeps the file's value.
    flags = {k: v for k, v in (overrides or {}).items() if v is not None}
    data = merge(load_yaml(locate(path, "datamodules")) if path else {}, flags)
    if "dt" in data and isinstance(data["dt"], int):
        data["dt"] = float(data["dt"])
    return from_dict(Recipe, data)


def replace(recipe: Recipe, **changes: Any) -> Recipe:
    """A validated copy with some fields changed."""
    try:
        return dataclasses.replace(recipe, **changes)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
