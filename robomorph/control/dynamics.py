"""What a model-predictive controller plans with: predictors of the arm under candidate torques.

Every planner answers the same question at each re-plan: given what has been measured so far
(the commands sent and the outputs recorded, the joint state now), what will the outputs be at
the next ``H`` frames under each of ``K`` candidate command sequences? Timing follows the
recording convention: row ``t`` holds the state at the start of frame ``t`` and the command
applied from it, so at frame ``f`` the measured rows are ``< f`` for commands and ``<= f`` for
outputs, and the candidates are the commands of frames ``f .. f+H-1``, which the outputs at
``f+1 .. f+H`` answer.

- :class:`PhysicsPlanner`: MuJoCo with a parameter vector, one threaded ``mujoco.rollout``
  over the candidates from the measured joint state (a lean copy of the arm, with the EE
  sensors, at ``plan_substeps`` physics steps per frame). Its parameters come from
  ``nominal_physics`` (the catalogue robot), ``identified_physics`` (fitted once to the
  warm-up's context by the rollout fit of :mod:`robomorph.identification.identify`), the in-context
  hybrid model (re-identified from the rolling context every ``reidentify`` frames), or
  ``true_physics`` (the hidden parameters: a ceiling, labelled as such, the only planner
  that reads them).
- :class:`ModelPlanner`: a black-box meta-model (a :class:`robomorph.inference.predictor.Predictor`
  without a physics backbone, or one configured with ``mode="none"``), context = the last
  ``context`` measured rows, query = the candidates.
"""

from __future__ import annotations

import mujoco
import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.identification.identify import lean_spec
from robomorph.sim import arms

# Every arm's output row opens with the EE position (3) and quaternion (4), then its n joints
# (Arm.y_names), so the joints start at the same column whatever the arm.
POSE = 7

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


class ControlError(RoboMorphError, ValueError):
    """A control setting or model that cannot work; the message says what to do."""


def planning_model(dt: float, substeps: int, robot: str = arms.DEFAULT_ROBOT) -> mujoco.MjModel:
    """The arm a planner simulates (``robot``, a name of :mod:`robomorph.sim.arms`): the same
    bodies, joints and motors (gravity compensated through the actuators, as the arm does), no
    meshes or contacts, and two sensors, the EE position and orientation, so a rollout returns
    ``y`` without a kinematics pass."""
    spec = lean_spec(substeps, dt, True, robot)
    for sensor_type in (mujoco.mjtSensor.mjSENS_FRAMEPOS, mujoco.mjtSensor.mjSENS_FRAMEQUAT):
        sensor = spec.add_sensor()
        sensor.type, sensor.objtype, sensor.objname = sensor_type, mujoco.mjtObj.mjOBJ_SITE, "ee"
    model = spec.compile()
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return model


class Measured:
    """What the controller has measured up to frame ``f`` (filled by the episode).

    Attributes:
        u: (T, n) commands sent (rows ``< f`` valid).
        y: (T, POSE + n) outputs recorded at frame starts (rows ``<= f`` valid).
        qpos, qvel: (n,) the joint state at the start of frame ``f`` (encoders).
        frame: ``f``.
        start: (n,) the joints where the episode started (at rest).
    """

    def __init__(self, steps: int, n: int, start: np.ndarray):
        self.u = np.zeros((steps, n))
        self.y = np.zeros((steps, POSE + n))
        self.qpos, self.qvel = np.zeros(n), np.zeros(n)
        self.frame = 0
        self.start = np.asarray(start, dtype=np.float64).copy()


class PhysicsPlanner:
    """Candidates simulated on MuJoCo with one parameter vector (``params`` order).

    Args:
        name: the controller's label.
        randomizer_cfg: the randomization ranges the parameter vectors follow (layout only).
        dt: frame period [s].
        plan_substeps: physics steps per frame in the planner (fewer than the arm's: a
            planner's model is coarser than the world, as in any MPC).
        nthread: rollout threads.
        reads_hidden: True only for ``true_physics``.
        robot: the arm simulated, a name of :mod:`robomorph.sim.arms` (its joints and the
            layout of ``params``).
    """

    def __init__(self, name: str, randomizer_cfg, dt: float, plan_substeps: int = 2, nthread: int = 1,
                 reads_hidden: bool = False, robot: str = arms.DEFAULT_ROBOT):
        from mujoco import rollout  # noqa: PLC0415

        from robomorph.sim.randomize import Randomizer  # noqa: PLC0415

        self.name, self.reads_hidden = name, reads_hidden
        self.arm = arms.get(robot)
        self.model = planning_model(dt, plan_substeps, robot)
        self.randomizer = Randomizer(self.model, randomizer_cfg, robot)
        self.ss, self.nj = int(plan_substeps), self.arm.n_joint
        self._datas = [mujoco.MjData(self.model) for _ in range(max(1, nthread))]
        self._pool = rollout.Rollout(nthread=nthread) if nthread > 1 else None
        self._x0 = np.zeros(mujoco.mj_stateSize(self.model, _STATE))
        self.params: np.ndarray | None = None
        self.reidentify = 0  # frames between identifications (0: never after the first)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()

    def set_params(self, params: np.ndarray) -> None:
        self.params = np.asarray(params, dtype=np.float64).copy()
        self.randomizer.apply(self.model, self.params)

    def identify(self, m: Measured) -> np.ndarray:
        """The parameter vector this planner uses from frame ``m.frame`` on (subclasses)."""
        raise NotImplementedError

    def observe(self, m: Measured, first: bool) -> None:
        """Called at every re-plan; (re-)identifies when due."""
        self._state = (m.qpos.copy(), m.qvel.copy())
        if first or (self.reidentify and m.frame % self.reidentify == 0):
            self.set_params(self.identify(m))

    def predict(self, torque: np.ndarray) -> np.ndarray:
        """(K, H, n) commands of frames f..f+H-1 -> (K, H, POSE + n) outputs at frames f+1..f+H."""
        k, nj, ss = len(torque), self.nj, self.ss
        d = self._datas[0]
        mujoco.mj_resetData(self.model, d)
        d.qpos[:nj], d.qvel[:nj] = self._state
        mujoco.mj_getState(self.model, d, self._x0, _STATE)
        control = np.repeat(np.asarray(torque, dtype=np.float64), ss, axis=1)
        # A rollout records each step's sensors as mj_step computed them, from the state before
        # the step: a frame's closing EE pose is read at the next step, so one more step (the
        # last command held) is simulated.
        control = np.concatenate([control, control[:, -1:]], axis=1)
        args = ([self.model] * k, self._datas, np.tile(self._x0, (k, 1)), control)
        if self._pool is not None:
            state, sens = self._pool.rollout(*args)
        else:
            from mujoco import rollout  # noqa: PLC0415

            state, sens = rollout.rollout(*args)
        ends = slice(ss - 1, -1, ss)  # the state after the last physics step of each frame
        read = slice(ss, None, ss)  # the sensors of that state (computed by the step after it)
        quat = sens[:, read, 3:POSE][..., [1, 2, 3, 0]]  # w x y z -> X Y Z W, as y holds it
        return np.concatenate([sens[:, read, :3], quat, state[:, ends, 1:1 + nj]], axis=2)


class CataloguePlanner(PhysicsPlanner):
    """``nominal_physics``: the catalogue robot, its springs anchored where the episode started."""

    def identify(self, m: Measured) -> np.ndarray:
        return self.randomizer.catalogue(m.start)


class TruePlanner(PhysicsPlanner):
    """``true_physics``: the robot's hidden parameters (a ceiling; no real controller has them)."""

    def __init__(self, *args, hidden: np.ndarray, **kwargs):
        super().__init__(*args, reads_hidden=True, **kwargs)
        self.hidden = np.asarray(hidden, dtype=np.float64)

    def identify(self, m: Measured) -> np.ndarray:
        return self.hidden


class IdentifiedPlanner(PhysicsPlanner):
    """``identified_physics``: the rollout fit of :mod:`robomorph.identification.identify` on the warm-up's
    context (the robot at rest at its start), bounded by the recipe's randomization ranges;
    fitted once, as an engineer identifies a robot from one recorded run."""

    def __init__(self, *args, recipe, **kwargs):
        super().__init__(*args, **kwargs)
        self.recipe = recipe
        self.seconds = 0.0

    def identify(self, m: Measured) -> np.ndarray:
        import time  # noqa: PLC0415

        from robomorph.identification.identify import Identifier  # noqa: PLC0415

        t0 = time.perf_counter()
        f = m.frame
        with Identifier(self.recipe, "command") as ident:
            fit = ident.fit(self.randomizer.catalogue(m.start), m.y[:f, POSE:], m.u[:f], np.zeros(self.nj))
        self.seconds += time.perf_counter() - t0
        return fit.params


class HybridPlanner(PhysicsPlanner):
    """The in-context hybrid model: its physics backbone identifies the robot from the last
    ``context`` measured rows (in the mode of the predictor's ``settings``), re-identified every
    ``reidentify`` frames as the context rolls on; the candidates are simulated with the result."""

    def __init__(self, *args, predictor, context: int, reidentify: int, **kwargs):
        super().__init__(*args, **kwargs)
        self.predictor, self.context = predictor, int(context)
        self.reidentify = int(reidentify)
        self.seconds, self.identifications = 0.0, 0

    def identify(self, m: Measured) -> np.ndarray:
        import time  # noqa: PLC0415

        import torch  # noqa: PLC0415

        t0 = time.perf_counter()
        f, c = m.frame, min(self.context, m.frame)
        u_ctx = torch.as_tensor(m.u[f - c:f][None], dtype=torch.float32)
        y_ctx = torch.as_tensor(m.y[f - c:f][None], dtype=torch.float32)
        params = self.predictor.hybrid().identify(u_ctx, y_ctx, self.predictor.settings.mode,
                                                  anchor=m.start[None])[0]
        self.seconds += time.perf_counter() - t0
        self.identifications += 1
        return params


class ModelPlanner:
    """A black-box meta-model: the candidates decoded on the last ``context`` measured rows."""

    reads_hidden = False

    def __init__(self, name: str, predictor, context: int):
        self.name, self.predictor = name, predictor
        patch = int(predictor.patch)
        self.context = int(context) // patch * patch
        self._ctx = None

    def close(self) -> None:
        pass

    def observe(self, m: Measured, first: bool) -> None:
        f = m.frame
        c = min(self.context, f // self.predictor.patch * self.predictor.patch)
        self._ctx = (m.u[f - c:f].astype(np.float32), m.y[f - c:f].astype(np.float32))

    def predict(self, torque: np.ndarray) -> np.ndarray:
        """Query rows f..f+H: the first predicted row (frame f) is measured already and dropped."""
        k = len(torque)
        u_ctx, y_ctx = (np.repeat(a[None], k, axis=0) for a in self._ctx)
        query = np.concatenate([torque, torque[:, -1:]], axis=1).astype(np.float32)
        return np.asarray(self.predictor.simulate(u_ctx, y_ctx, query, inputs="command"))[:, 1:]
