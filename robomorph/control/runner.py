"""Many episodes: robots x controllers, seeded, in worker processes, with a progress bar.

Each (robot, controller) pair is one job. A job redraws its robot and reference from
``(seed, robot)`` alone and its planner's noise from ``(seed, robot, 1)``, so the results do
not depend on the number of workers or the order jobs finish in, and every controller meets
the same robot on the same reference.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from robomorph.control.dynamics import ControlError
from robomorph.control.mppi import MPPIConfig
from robomorph.control.references import TASKS

CONTROLLERS = ("osc", "mpc:model", "mpc:nominal_physics", "mpc:identified_physics", "mpc:true_physics")
DEFAULT_CONTROLLERS = ("osc", "mpc:model", "mpc:nominal_physics", "mpc:true_physics")
# Wider than training (multisine.yaml: masses +-10 %, damping 5-10, friction x0.5-1.5): the
# unknown payloads and worn joints a deployed controller meets.
UNCERTAINTY = {
    "training": {},
    "wide": {"mass_pct": 30.0, "damping": (3.0, 13.0), "frictionloss_scale": (0.3, 1.8)},
}


@dataclass(frozen=True)
class ControlConfig:
    """One comparison of controllers.

    Attributes:
        task: ``circle``, ``spiral`` or ``reach``.
        robots: held-out robots (each controller runs on every one).
        controllers: from :data:`CONTROLLERS`.
        seed: root seed of robots, references and planner noise.
        warmup: seconds under the catalogue OSC before the controller takes over (the
            first context; at least the model's context length).
        duration: seconds of tracking after the warm-up.
        uncertainty: ``wide`` (masses +-30 %, damping and friction outside the training
            ranges) or ``training`` (the training distribution).
        dt, substeps: frame period and physics steps per frame of the world.
        plan_substeps: physics steps per frame in the physics planners.
        context: context length of the in-context model [frames].
        reidentify: frames between the hybrid model's identifications (0: once).
        mpc: the MPPI planner's settings.
    """

    task: str = "circle"
    robots: int = 8
    controllers: tuple[str, ...] = DEFAULT_CONTROLLERS
    seed: int = 0
    warmup: float = 200 / 60
    duration: float = 6.0
    uncertainty: str = "wide"
    dt: float = 1 / 60
    substeps: int = 8
    plan_substeps: int = 2
    context: int = 200
    reidentify: int = 60
    mpc: MPPIConfig = field(default_factory=MPPIConfig)

    def __post_init__(self):
        if self.task not in TASKS:
            raise ControlError(f"--task {self.task!r} is not a control task: choose {', '.join(TASKS)}")
        unknown = [c for c in self.controllers if c not in CONTROLLERS]
        if unknown or not self.controllers:
            raise ControlError(f"--controllers: unknown {', '.join(map(repr, unknown)) or 'none given'}; "
                               f"choose from {', '.join(CONTROLLERS)}")
        twice = sorted({c for c in self.controllers if self.controllers.count(c) > 1})
        if twice:
            raise ControlError(f"--controllers names {', '.join(twice)} more than once: name each controller once")
        if self.uncertainty not in UNCERTAINTY:
            raise ControlError(f"--uncertainty {self.uncertainty!r}: choose {', '.join(UNCERTAINTY)}")
        if self.robots < 1:
            raise ControlError(f"--robots must be >= 1, got {self.robots}")
        if not (0 < self.warmup < np.inf and 0 < self.duration < np.inf):
            raise ControlError(f"--warmup and --duration must be finite and > 0 seconds, got {self.warmup} and "
                               f"{self.duration}")
        if self.seed < 0:
            raise ControlError(f"--seed must be >= 0, got {self.seed}")
        if self.plan_substeps < 1 or self.context < 1 or self.reidentify < 0:
            raise ControlError("plan_substeps and context must be >= 1, reidentify >= 0")

    @property
    def warmup_frames(self) -> int:
        return int(round(self.warmup / self.dt))

    @property
    def steps(self) -> int:
        return self.warmup_frames + int(round(self.duration / self.dt))

    def randomization(self):
        from robomorph.sim.randomize import RandomizationConfig  # noqa: PLC0415

        return dataclasses.replace(RandomizationConfig(), **UNCERTAINTY[self.uncertainty])


def draw_episode(cfg: ControlConfig, robot: int, max_draws: int = 50):
    """The robot's parameter vector and its reference (from ``(seed, robot)`` alone).

    Draws again (a new robot and reference from the next stream of ``(seed, robot)``) while the
    reference is out of the arm's comfortable reach (:func:`robomorph.control.references.reachable`):
    the same for every controller, decided by kinematics alone.
    """
    import mujoco  # noqa: PLC0415

    from robomorph.control.references import draw_reference, reachable  # noqa: PLC0415
    from robomorph.sim import panda  # noqa: PLC0415
    from robomorph.sim.osc import start_pose  # noqa: PLC0415
    from robomorph.sim.randomize import Randomizer  # noqa: PLC0415

    model = panda.build_model(cfg.substeps, cfg.dt, True)
    randomizer = Randomizer(model, cfg.randomization())
    nominal = model.body_mass.copy()
    for draw in range(max_draws):
        rng = np.random.default_rng(np.random.SeedSequence(cfg.seed, spawn_key=(robot, 0, draw)))
        params = randomizer.sample(rng)
        qinit = randomizer.split(params)["qinit"]
        model.body_mass[:] = nominal  # kinematics do not depend on the draw's physics
        pos, quat = start_pose(model, mujoco.MjData(model), qinit)
        ref = draw_reference(cfg.task, rng, pos, quat, cfg.warmup_frames, cfg.steps, cfg.dt)
        if reachable(model, ref, qinit):
            return params, ref
    raise ControlError(f"no reachable {cfg.task} reference in {max_draws} draws for robot {robot}")


def make_planner(cfg: ControlConfig, controller: str, params: np.ndarray, predictor=None):
    """The planner behind ``mpc:<name>`` (the hidden ``params`` reach ``true_physics`` only)."""
    from robomorph.control import dynamics as dyn  # noqa: PLC0415
    from robomorph.sim.recipe import Recipe  # noqa: PLC0415

    name = controller.split(":", 1)[1]
    # The planners' ranges and catalogue are the training recipe's (what an engineer assumes).
    recipe = Recipe()
    common = (controller, recipe.randomization, cfg.dt, cfg.plan_substeps)
    if name == "nominal_physics":
        return dyn.CataloguePlanner(*common)
    if name == "true_physics":
        return dyn.TruePlanner(controller, cfg.randomization(), cfg.dt, cfg.plan_substeps, hidden=params)
    if name == "identified_physics":
        return dyn.IdentifiedPlanner(*common, recipe=recipe)
    if predictor is None:
        raise ControlError("mpc:model needs --ckpt, a model trained in the command formulation")
    if predictor.physics and predictor.physics_mode != "none":
        return dyn.HybridPlanner(*common, predictor=predictor, context=cfg.context, reidentify=cfg.reidentify)
    return dyn.ModelPlanner(controller, predictor, cfg.context)


def run_job(cfg: ControlConfig, robot: int, controller: str, predictor=None):
    """One episode: :class:`robomorph.control.episode.EpisodeResult`."""
    from robomorph.control.episode import CatalogueOSC, Episode  # noqa: PLC0415
    from robomorph.control.mppi import MPPI  # noqa: PLC0415

    params, ref = draw_episode(cfg, robot)
    episode = Episode(params, ref, cfg.randomization(), cfg.dt, cfg.substeps)
    osc = CatalogueOSC(ref, episode.start, cfg.dt, cfg.substeps)
    episode.warm_up(osc)
    planner = mppi = None
    if controller != "osc":
        planner = make_planner(cfg, controller, params, predictor)
        rng = np.random.default_rng(np.random.SeedSequence(cfg.seed, spawn_key=(robot, 1)))
        mppi = MPPI(cfg.mpc, episode.limits, rng)
    try:
        result = episode.track(controller, osc, planner, mppi)
    finally:
        if planner is not None:
            planner.close()
    result.robot, result.task = robot, cfg.task
    for key in ("seconds", "identifications"):
        if hasattr(planner, key):
            result.notes[key] = getattr(planner, key)
    return result
