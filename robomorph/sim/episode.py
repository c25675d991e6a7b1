"""One attempt = one randomized robot and one task, fully determined by (recipe, index).

Both engines (threaded open-loop rollouts, worker processes for closed loops) redraw an
attempt from its index alone, so the arrays never depend on batch size, worker count or
shard layout.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.names import OPEN_LOOP_TASKS
from robomorph.sim import filters, osc
from robomorph.sim.closed_loop import simulate_closed_loop
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import Recipe
from robomorph.sim.signals import SIGNALS


def attempt_rng(seed: int, index: int) -> np.random.Generator:
    """The independent random stream of attempt ``index`` under root ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index,)))


@dataclass
class Draw:
    """What an attempt sampled before simulating."""

    index: int
    task: str
    params: np.ndarray
    qpos0: np.ndarray
    ctrl: np.ndarray | None  # (T, n) open-loop torques (None for OSC tasks)
    fm: float
    rng: np.random.Generator  # continues the attempt's stream (OSC paths are drawn from it)


@dataclass
class Outcome:
    """A simulated attempt: the reject reason, or the dataset row."""

    index: int
    task: str
    reason: str | None
    params: np.ndarray
    u: np.ndarray | None = None  # (T, n) total joint torque
    u_cmd: np.ndarray | None = None  # (T, n) the command, without the gravity compensation
    y: np.ndarray | None = None  # (T, 7 + n)
    target: np.ndarray | None = None  # (T, 3)
    fm: float = float("nan")
    kp: float = float("nan")


def build_model(recipe: Recipe) -> mujoco.MjModel:
    """The nominal model the recipe simulates."""
    return recipe.arm.build_model(recipe.substeps, recipe.dt, recipe.gravity_compensation == "true_model")


def is_open_loop(recipe: Recipe, task: str) -> bool:
    """Open-loop tasks go through mujoco.rollout unless gravity needs a feedback term."""
    return task in OPEN_LOOP_TASKS and recipe.gravity_compensation != "nominal_model"


def _choose_task(recipe: Recipe, rng: np.random.Generator) -> str:
    weights = recipe.task_weights
    names = list(weights)
    # A single task draws nothing, so its streams match those of older single-task stores.
    return names[0] if len(names) == 1 else str(rng.choice(names, p=list(weights.values())))


def draw_task(recipe: Recipe, index: int) -> str:
    """The task of attempt ``index`` (the first draw of its stream)."""
    return _choose_task(recipe, attempt_rng(recipe.seed, index))


def draw(recipe: Recipe, randomizer: Randomizer, index: int) -> Draw:
    """Samples task, physical parameters and open-loop signal of attempt ``index``."""
    rng = attempt_rng(recipe.seed, index)
    task = _choose_task(recipe, rng)
    params = randomizer.sample(rng)
    ctrl, fm = None, float("nan")
    if task in OPEN_LOOP_TASKS:
        # The Panda passes no gain, so its signals are the paper's, bit for bit.
        gain = None if recipe.robot == "panda" else recipe.arm.joint_gain
        ctrl, fm = SIGNALS[task](rng, recipe.steps, recipe.dt, recipe.signal, gain)
    return Draw(index, task, params, randomizer.split(params)["qinit"].copy(), ctrl, fm, rng)


def finish(recipe: Recipe, d: Draw, sens: np.ndarray, joint_range: np.ndarray, stride: int,
           target: np.ndarray | None = None, kp: float = float("nan"),
           added: Callable[[np.ndarray], np.ndarray] | None = None) -> Outcome:
    """Filters sensor data (at any rate) and turns a valid rollout into a dataset row.

    ``added(qpos)`` is the compensation the controller added to the command at each
    frame (``nominal_model``: the catalogue g(q)); it is taken off to give ``u_cmd``.
    """
    arm = recipe.arm
    reason = filters.check(sens, joint_range, recipe.filters, arm.limits)
    out = Outcome(d.index, d.task, reason, d.params, fm=d.fm, kp=kp)
    if reason is None:
        rows = sens[::stride]
        out.u, out.y = filters.to_outputs(rows)
        comp = None if added is None else np.stack([added(q) for q in rows[:, arm.layout.qpos]])
        out.u_cmd = filters.to_command(rows, comp)
        out.target = None if target is None else np.asarray(target, dtype=np.float32)
    return out


class NominalGravity:
    """g(q) of the un-randomized robot, added to a command (``nominal_model`` mode)."""

    def __init__(self, recipe: Recipe):
        self.model = recipe.arm.build_model(recipe.substeps, recipe.dt, gravity_compensation=False)
        self.data = mujoco.MjData(self.model)
        self.nj = recipe.arm.n_joint

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        self.data.qpos[:] = qpos
        self.data.qvel[:] = 0
        mujoco.mj_forward(self.model, self.data)
        # With zero velocity the bias force is gravity alone.
        return self.data.qfrc_bias[: self.nj].copy()


class ClosedLoopRunner:
    """Simulates attempts one at a time with Python in the loop (one per worker process)."""

    def __init__(self, recipe: Recipe):
        self.recipe = recipe
        self.model = build_model(recipe)
        self.randomizer = Randomizer(self.model, recipe.randomization, recipe.robot)
        self.data = mujoco.MjData(self.model)
        self.gravity = NominalGravity(recipe) if recipe.gravity_compensation == "nominal_model" else None

    def __call__(self, index: int) -> Outcome:
        r, d = self.recipe, draw(self.recipe, self.randomizer, index)
        self.randomizer.apply(self.model, d.params)
        target, kp = None, float("nan")
        nj, limits = r.arm.n_joint, r.arm.limits
        if d.ctrl is not None:
            signal = d.ctrl
            grav = self.gravity

            def controller(data, t):
                u = signal[t] + (grav(data.qpos[:nj]) if grav else 0.0)
                return np.clip(u, -limits, limits)

            sens = simulate_closed_loop(self.model, self.data, d.qpos0, r.steps, r.substeps, controller)
        else:
            path_cfg = r.circle if d.task == "circle" else r.spiral
            sens, target, kp = osc.simulate_osc(
                self.model, self.data, d.qpos0, d.task, d.rng, r.steps, r.substeps, r.dt, r.osc, path_cfg,
                extra_torque=self.gravity, torque_limits=limits,
            )
        # The controller added the catalogue g(q) at each frame-start state: recomputing it
        # from the recorded (float64) joints gives the very same values.
        return finish(r, d, sens, self.model.jnt_range[:nj], 1, target, kp, added=self.gravity)
