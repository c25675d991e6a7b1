"""One closed-loop episode: a randomized arm, a warm-up under the catalogue OSC, then a controller.

The arm is the generator's domain of a registered arm (:mod:`robomorph.sim.arms`: meshes,
contacts, sensors, its joints and torque limits) with a parameter vector applied; it
compensates its own gravity through its actuators (the command formulation, as a
torque-controlled arm does). The episode owns the world: controllers see only what an
encoder and a torque sensor report (:class:`robomorph.control.dynamics.Measured`), never the
model the world simulates, except ``true_physics`` which is handed the hidden vector.

An episode fails, and stops, at the first frame that has a contact, a joint within
``joint_margin`` of its limit, or a diverged state.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import mujoco
import numpy as np

from robomorph.control.dynamics import POSE, Measured
from robomorph.control.mppi import MPPI, Goal
from robomorph.control.references import Reference
from robomorph.sim import arms
from robomorph.sim.closed_loop import diverged, reset_to
from robomorph.sim.osc import OSCConfig, OSCController

JOINT_MARGIN = 0.02  # rad: closer to a limit than this ends the episode


@dataclass
class EpisodeResult:
    """What one controller did on one robot (arrays over frames ``0..frames-1``)."""

    controller: str
    robot: int
    task: str
    ee: np.ndarray  # (T, 3) EE positions at frame starts
    ref: np.ndarray  # (T, 3) the reference
    torque: np.ndarray  # (T, n) commands sent
    warmup: int
    frames: int  # frames run (less than T when it failed)
    failure: str | None = None
    replan_ms: list[float] = field(default_factory=list)
    saturated: int = 0  # frames of the tracking phase with a command at a torque limit
    notes: dict = field(default_factory=dict)

    @property
    def error_mm(self) -> np.ndarray:
        """(frames - warmup,) EE distance to the reference over the tracking phase [mm]."""
        w, n = self.warmup, self.frames
        return 1e3 * np.linalg.norm(self.ee[w:n] - self.ref[w:n], axis=1)


class CatalogueOSC:
    """The generator's OSC computed on the catalogue robot from the measured joint state
    (``robot``: the arm's registry name)."""

    def __init__(self, ref: Reference, start: np.ndarray, dt: float, substeps: int, kp: float = 10.0,
                 robot: str = arms.DEFAULT_ROBOT):
        from robomorph.sim.randomize import RandomizationConfig, Randomizer  # noqa: PLC0415

        arm = arms.get(robot)
        self.model = arm.build_model(substeps, dt, True)
        catalogue = Randomizer(self.model, RandomizationConfig(), robot)
        catalogue.apply(self.model, catalogue.catalogue(start))
        self.data = mujoco.MjData(self.model)
        self.osc = OSCController(self.model, ref.pos, ref.vel, ref.acc, ref.quat, start, kp, OSCConfig(),
                                 torque_limits=arm.limits)

    def __call__(self, qpos: np.ndarray, qvel: np.ndarray, t: int) -> np.ndarray:
        self.data.qpos[:], self.data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.model, self.data)
        return self.osc(self.data, t).copy()


class Episode:
    """The world of one episode (reset per controller: every controller meets the same robot).

    Args:
        params: the robot's parameter vector (:func:`robomorph.sim.randomize.param_names`).
        ref: the reference, warm-up included.
        randomizer_cfg: the ranges ``params`` was drawn from (its layout).
        dt, substeps: frame period and physics steps per frame of the world.
        robot: the arm, a name of :mod:`robomorph.sim.arms` (its joints, torque limits, sensors
            and the layout of ``params``).
    """

    def __init__(self, params: np.ndarray, ref: Reference, randomizer_cfg, dt: float = 1 / 60, substeps: int = 8,
                 robot: str = arms.DEFAULT_ROBOT):
        from robomorph.sim.randomize import Randomizer  # noqa: PLC0415

        self.ref, self.dt, self.substeps = ref, float(dt), int(substeps)
        self.arm = arm = arms.get(robot)
        self.nj, self.sens = arm.n_joint, arm.layout
        self.model = arm.build_model(substeps, dt, True)
        self.randomizer = Randomizer(self.model, randomizer_cfg, robot)
        self.params = np.asarray(params, dtype=np.float64)
        self.randomizer.apply(self.model, self.params)
        self.start = self.randomizer.split(self.params)["qinit"].copy()
        self.data = mujoco.MjData(self.model)
        self.limits = arm.limits
        self.joint_range = self.model.jnt_range[:self.nj].copy()
        self.m = Measured(ref.steps, self.nj, self.start)
        self.frame = 0
        self.failure: str | None = None

    def set_hidden(self, params: np.ndarray) -> None:
        """Changes the robot's physical parameters in place (tests: nothing but true_physics may notice)."""
        self.params = np.asarray(params, dtype=np.float64)
        self.randomizer.apply(self.model, self.params)

    def reset(self) -> None:
        reset_to(self.model, self.data, self.start)
        self.frame, self.failure = 0, None
        self.m = Measured(self.ref.steps, self.nj, self.start)
        self.ee = np.zeros((self.ref.steps, 3))

    def _measure(self) -> None:
        """Frame start: position and velocity stages, then the sensors into ``Measured``."""
        f, d, m, lay = self.frame, self.data, self.m, self.sens
        mujoco.mj_step1(self.model, d)
        s = d.sensordata
        quat = s[lay.ee_quat][[1, 2, 3, 0]]
        if f and np.dot(quat, m.y[f - 1, 3:POSE]) < 0:  # signs kept continuous, as the stores keep them
            quat = -quat
        m.y[f] = np.concatenate([s[lay.ee_pos], quat, s[lay.qpos]])
        m.qpos[:], m.qvel[:] = d.qpos[:self.nj], d.qvel[:self.nj]
        m.frame = f
        self.ee[f] = s[lay.ee_pos]

    def _apply(self, u: np.ndarray) -> None:
        """Sends the command of this frame and simulates the frame; flags a failure."""
        d = self.data
        d.ctrl[:] = np.clip(u, -self.limits, self.limits)
        self.m.u[self.frame] = d.ctrl
        mujoco.mj_step2(self.model, d)
        if self.substeps > 1:
            mujoco.mj_step(self.model, d, nstep=self.substeps - 1)
        self.frame += 1
        q = d.qpos[:self.nj]
        if diverged(d) or not np.all(np.isfinite(q)):
            self.failure = "diverged"
        elif d.sensordata[self.sens.contacts] > 0:
            self.failure = "contact"
        elif np.any(q < self.joint_range[:, 0] + JOINT_MARGIN) or np.any(q > self.joint_range[:, 1] - JOINT_MARGIN):
            self.failure = "joint_limit"

    def warm_up(self, osc: CatalogueOSC) -> None:
        """Frames ``0..warmup-1`` under the catalogue OSC (the first context)."""
        self.reset()
        while self.frame < self.ref.warmup and self.failure is None:
            self._measure()
            self._apply(osc(self.m.qpos, self.m.qvel, self.frame))

    def goal(self, horizon: int) -> Goal:
        f, ref = self.frame, self.ref
        rows = np.minimum(np.arange(f + 1, f + 1 + horizon), ref.steps - 1)
        return Goal(ref.pos[rows], ref.quat[[1, 2, 3, 0]], self.m.qpos.copy(), self.start, self.dt,
                    self.joint_range)

    def plan(self, planner, mppi: MPPI, first: bool) -> np.ndarray:
        """Re-plans at the current frame (measured already): the commands of the next ``replan`` frames."""
        planner.observe(self.m, first)
        return mppi.step(planner.predict, self.goal(mppi.cfg.horizon))

    def track(self, controller: str, osc: CatalogueOSC, planner=None, mppi: MPPI | None = None) -> EpisodeResult:
        """Frames ``warmup..T-1`` under the controller (``osc``: the catalogue OSC goes on)."""
        out = EpisodeResult(controller, -1, "", self.ee, self.ref.pos, self.m.u, self.ref.warmup, self.frame,
                            self.failure)
        if self.failure is not None:
            return out
        queue: list[np.ndarray] = []
        while self.frame < self.ref.steps and self.failure is None:
            self._measure()
            if planner is None:
                u = osc(self.m.qpos, self.m.qvel, self.frame)
            else:
                if not queue:
                    t0 = time.perf_counter()
                    if self.frame == self.ref.warmup:
                        mppi.reset(self.m.u[self.frame - 1])
                    queue = list(self.plan(planner, mppi, self.frame == self.ref.warmup))
                    out.replan_ms.append(1e3 * (time.perf_counter() - t0))
                u = queue.pop(0)
            self._apply(u)
            out.saturated += int(np.any(np.abs(self.m.u[self.frame - 1]) >= self.limits - 1e-9))
        out.frames, out.failure = self.frame, self.failure
        return out
