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
from robomorph.sim import filters, kinematics, osc, realism, realistic
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
    real: realism.Realization | None = None  # the realism terms' draws (None for a clean recipe)


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
    realism: np.ndarray | None = None  # the realism vector (robomorph.sim.realism.names)


def build_model(recipe: Recipe) -> mujoco.MjModel:
    """The nominal model the recipe simulates."""
    return recipe.arm.build_model(recipe.substeps, recipe.dt, recipe.gravity_compensation == "true_model")


def make_randomizer(model: mujoco.MjModel, recipe: Recipe) -> Randomizer:
    """The recipe's randomizer (drawing from ranges widened by ``realism.widen``)."""
    return Randomizer(model, recipe.randomization, recipe.robot, recipe.realism.widen)


def is_open_loop(recipe: Recipe, task: str) -> bool:
    """Open-loop tasks go through mujoco.rollout unless gravity needs a feedback term or a
    realism term needs Python at every physics step (:mod:`robomorph.sim.realistic`)."""
    return (task in OPEN_LOOP_TASKS and recipe.gravity_compensation != "nominal_model"
            and not recipe.realism.steps_in_python)


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
    real = None
    if recipe.realism.enabled:
        feedback = task == "multisine" and recipe.realism.feedback.enabled
        real = realism.draw(recipe.realism, realism.realism_rng(recipe.seed, index), recipe.arm.limits,
                            recipe.arm.joint_gain, fm, feedback)
    return Draw(index, task, params, randomizer.split(params)["qinit"].copy(), ctrl, fm, rng, real)


def _sense(recipe: Recipe, d: Draw, u: np.ndarray, y: np.ndarray, model: mujoco.MjModel | None,
           ) -> tuple[np.ndarray, np.ndarray]:
    """The logged (u, y) of a realistic attempt: sensor errors on the true values and, unless the
    log is resampled later (which recomputes it), the EE pose of the logged joints."""
    rng = np.random.default_rng(np.random.SeedSequence(recipe.seed, spawn_key=(d.index, 2)))
    tau, q = realism.sense(u.astype(np.float64), y[:, 7:].astype(np.float64), d.real, rng)
    pose = y[:, :7]
    noisy = d.real.encoder_noise > 0 or d.real.encoder_resolution > 0
    if noisy and recipe.realism.encoder.pose_from_joints and not recipe.realism.timing.log_physics_rate:
        pose = kinematics.ee_pose(q, model)
    return tau.astype(np.float32), np.concatenate([pose, q], axis=1).astype(np.float32)


def finish(recipe: Recipe, d: Draw, sens: np.ndarray, joint_range: np.ndarray, stride: int,
           target: np.ndarray | None = None, kp: float = float("nan"),
           added: Callable[[np.ndarray], np.ndarray] | None = None, command: np.ndarray | None = None,
           model: mujoco.MjModel | None = None) -> Outcome:
    """Filters sensor data (at any rate) and turns a valid rollout into a dataset row.

    ``added(qpos)`` is the compensation the controller added to the command at each
    frame (``nominal_model``: the catalogue g(q)); it is taken off to give ``u_cmd``.
    ``command`` (same rows as ``sens``), where given, is the logged command itself. With
    realism, the sensors' errors are put on ``u`` and ``y`` (``model``: the nominal
    kinematics the EE pose is recomputed with) and the realism vector is recorded. With
    ``realism.timing.log_physics_rate`` the rows stay at the physics rate (``stride`` 1):
    generation brings them to ``dt``.
    """
    arm = recipe.arm
    reason = filters.check(sens, joint_range, recipe.filters, arm.limits)
    out = Outcome(d.index, d.task, reason, d.params, fm=d.fm, kp=kp)
    if reason is None:
        rows = sens[::stride]
        out.u, out.y = filters.to_outputs(rows)
        if command is not None:
            out.u_cmd = np.asarray(command[::stride], dtype=np.float32)
        else:
            comp = None if added is None else np.stack([added(q) for q in rows[:, arm.layout.qpos]])
            out.u_cmd = filters.to_command(rows, comp)
        out.target = None if target is None else np.asarray(target, dtype=np.float32)
        if d.real is not None:
            out.u, out.y = _sense(recipe, d, out.u, out.y, model)
            out.realism = d.real.vector()
    return out


class NominalGravity:
    """g(q) of the un-randomized robot, added to a command (``nominal_model`` mode)."""

    def __init__(self, recipe: Recipe):
        self.model = recipe.arm.build_model(recipe.substeps, recipe.dt, gravity_compensation=False)
        self.data = mujoco.MjData(self.model)
        self.nj = recipe.arm.n_joint
        self._bias = np.empty(self.model.nv)

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        d.qvel[:] = 0
        # With zero velocity the bias force is gravity alone: the recursive Newton-Euler pass of a forward pass's
        # velocity stage, without its collision detection and constraints (the same numbers to the bit, at about
        # a thirtieth of the time: 3.7 against 123 us on the Panda, where the hybrid and the regression ask for
        # it at every frame of a context or a closed-loop horizon).
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, self._bias)
        return self._bias[: self.nj].copy()


class ClosedLoopRunner:
    """Simulates attempts one at a time with Python in the loop (one per worker process)."""

    def __init__(self, recipe: Recipe):
        self.recipe = recipe
        self.model = build_model(recipe)
        self.randomizer = make_randomizer(self.model, recipe)
        self.data = mujoco.MjData(self.model)
        self.gravity = NominalGravity(recipe) if recipe.gravity_compensation == "nominal_model" else None
        self.realistic = recipe.realism.steps_in_python
        if self.realistic:
            self.flange = realistic.Flange(self.model)
            self.flange_randomized = self.flange.body in set(self.randomizer.index.body_ids.tolist())
            self.comp = (realistic.Compensation(recipe.arm, recipe.substeps, recipe.dt)
                         if recipe.gravity_compensation == "nominal_model" else None)

    def _realistic(self, d: Draw) -> Outcome:
        r, nj = self.recipe, self.recipe.arm.n_joint
        base = self.flange.current(self.model) if self.flange_randomized else None
        self.flange.apply(self.model, d.real.payload_mass, d.real.payload_com, base)
        res = realistic.simulate(r, self.model, self.data, d, d.real, self.comp)
        stride = 1 if r.realism.timing.log_physics_rate else r.substeps
        return finish(r, d, res.sens, self.model.jnt_range[:nj], stride, res.target, res.kp,
                      command=res.command, model=self.model)

    def __call__(self, index: int) -> Outcome:
        r, d = self.recipe, draw(self.recipe, self.randomizer, index)
        self.randomizer.apply(self.model, d.params)
        if self.realistic:
            return self._realistic(d)
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
        return finish(r, d, sens, self.model.jnt_range[:nj], 1, target, kp, added=self.gravity, model=self.model)
