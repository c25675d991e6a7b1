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
from robomorph.sim.arms import ARMS, DEFAULT_ROBOT

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
        robot: the arm, a name of :mod:`robomorph.sim.arms` (``panda``, ``ur5e``, ``kinova3``,
            ...): the world, the catalogue OSC and the physics planners are built from its
            registry entry (joints, torque limits, outputs); a model must be trained on it.
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
    robot: str = DEFAULT_ROBOT
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
        if self.robot not in ARMS:
            raise ControlError(f"--robot {self.robot!r} is not a registered arm: choose {', '.join(ARMS)}")
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
        for flag, seconds in (("--warmup", self.warmup), ("--duration", self.duration)):
            # Both are counted in frames: under one frame the episode has no warm-up or no tracking.
            if int(round(seconds / self.dt)) < 1:
                raise ControlError(f"{flag} {seconds:g} s is shorter than one frame ({self.dt:.4g} s): give at "
                                   f"least {self.dt:.4g} s")
        if self.seed < 0:
            raise ControlError(f"--seed must be >= 0, got {self.seed}")
        if self.plan_substeps < 1 or self.context < 1 or self.reidentify < 0:
            raise ControlError("plan_substeps and context must be >= 1, reidentify >= 0")

    @property
    def arm(self):
        """The arm's registry entry (:class:`robomorph.sim.arms.Arm`)."""
        return ARMS[self.robot]

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
    from robomorph.sim.osc import start_pose  # noqa: PLC0415
    from robomorph.sim.randomize import Randomizer  # noqa: PLC0415

    model = cfg.arm.build_model(cfg.substeps, cfg.dt, True)
    randomizer = Randomizer(model, cfg.randomization(), cfg.robot)
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
    raise ControlError(f"no reachable {cfg.task} reference in {max_draws} draws for robot {robot} of the {cfg.robot}")


def make_planner(cfg: ControlConfig, controller: str, params: np.ndarray, predictor=None):
    """The planner behind ``mpc:<name>`` (the hidden ``params`` reach ``true_physics`` only)."""
    from robomorph.control import dynamics as dyn  # noqa: PLC0415
    from robomorph.sim.recipe import Recipe  # noqa: PLC0415

    name = controller.split(":", 1)[1]
    # The planners' ranges and catalogue are the training recipe's (what an engineer assumes),
    # for the arm controlled: a parameter vector's layout is the arm's.
    recipe = Recipe(robot=cfg.robot)
    common = (controller, recipe.randomization, cfg.dt, cfg.plan_substeps)
    if name == "nominal_physics":
        return dyn.CataloguePlanner(*common, robot=cfg.robot)
    if name == "true_physics":
        return dyn.TruePlanner(controller, cfg.randomization(), cfg.dt, cfg.plan_substeps, hidden=params,
                               robot=cfg.robot)
    if name == "identified_physics":
        return dyn.IdentifiedPlanner(*common, recipe=recipe, robot=cfg.robot)
    if predictor is None:
        raise ControlError("mpc:model needs --ckpt, a model trained in the command formulation")
    check_model_arm(predictor, cfg.robot)
    if predictor.physics and predictor.settings.mode != "none":
        return dyn.HybridPlanner(*common, predictor=predictor, context=cfg.context, reidentify=cfg.reidentify,
                                 robot=cfg.robot)
    return dyn.ModelPlanner(controller, predictor, cfg.context)


def model_arm(predictor) -> str | None:
    """The registered arm a model was trained on, or None where it does not say one (older
    checkpoints, real logs of an unregistered robot, several arms)."""
    from robomorph.inference.predictor_checks import model_arms  # noqa: PLC0415

    trained = [a for a in model_arms(predictor) if a in ARMS]
    return trained[0] if len(trained) == 1 else None


def check_model_arm(predictor, robot: str) -> None:
    """Refuses, in one line, a model that cannot plan for ``robot``: trained on another registered
    arm, or with inputs and outputs of another number of joints."""
    from robomorph.evaluation.evaluator import EvaluationError, check_arm  # noqa: PLC0415

    arm = ARMS[robot]
    try:
        check_arm(predictor, {"domain": robot}, "the controlled arm")
    except EvaluationError as exc:
        raise ControlError(str(exc)) from None
    n_u, n_y = len(arm.u_names), len(arm.y_names)
    if (predictor.n_u, predictor.n_y) != (n_u, n_y):
        raise ControlError(f"the model predicts {predictor.n_y} outputs from {predictor.n_u} inputs; the controlled "
                           f"arm, the {robot}, takes {n_u} torques and gives {n_y} outputs (EE pose and "
                           f"{arm.n_joint} joints)")


def run_job(cfg: ControlConfig, robot: int, controller: str, predictor=None):
    """One episode: :class:`robomorph.control.episode.EpisodeResult`."""
    from robomorph.control.episode import CatalogueOSC, Episode  # noqa: PLC0415
    from robomorph.control.mppi import MPPI  # noqa: PLC0415

    params, ref = draw_episode(cfg, robot)
    episode = Episode(params, ref, cfg.randomization(), cfg.dt, cfg.substeps, cfg.robot)
    osc = CatalogueOSC(ref, episode.start, cfg.dt, cfg.substeps, robot=cfg.robot)
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
