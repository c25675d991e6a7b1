"""The physics backbone of the hybrid model: robots given by parameter vectors, simulated over windows.

A meta-model with a parameter head (``--model.physics amortized``) reads a context and
predicts the physical parameters of the robot that produced it; this module turns those
parameters into a prediction of the horizon, the way ``identified_physics`` does with a
fitted vector (:mod:`robomorph.evaluation.identified`), but for a whole batch at once and
with no optimization:

1. the context is simulated open loop from its first sample with each window's
   parameters (``mujoco.rollout``; the formulation's feedback evaluated at the recorded
   states as :mod:`robomorph.identification.identify` does), which gives the joint velocity at the
   last context sample: in the command formulation that velocity follows the context's
   dynamics better than a finite-difference estimate (measured for ``identified_physics``);
2. from the measured joint positions at the last context sample and that velocity, the
   horizon is simulated under the query torques, at the recipe's physics step for its first
   second and at a coarser one after (:data:`COARSE_STEP`); the end-effector pose is the
   catalogue kinematics of the simulated joint angles (link geometry is not randomized).

Step 2 runs in one threaded ``mujoco.rollout`` call where the formulation needs no state
feedback inside the horizon (the command on an arm that compensates its own gravity through
the actuators, and torques on an arm without compensation); otherwise (total torques with
``true_model`` compensation, commands with ``nominal_model``) each window is simulated
closed loop by :class:`robomorph.evaluation.physics.NominalPhysics` with the same vector.

The parameters a head predicts are those :class:`robomorph.identification.identify.ParameterSpace`
names for the recipe (a mass per link; damping, armature and friction loss per joint), in
its unit coordinates (-1 and 1 at the randomization bounds); the rest keep the catalogue's
values. :func:`parameter_layout` gives the layout a checkpoint records, so a Predictor
rebuilds the backbone without the store.
"""

from __future__ import annotations

import mujoco
import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.sim.kinematics import SiteKinematics

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
# Many horizons of one robot from one state (a planner's candidates): ``exact`` rollouts, or ``tangent``
# (:mod:`robomorph.identification.tangent`: one exact rollout and a linear model about it, dry friction corrected).
CANDIDATES = ("exact", "tangent")


class BackboneError(RoboMorphError, ValueError):
    """A physics option that cannot work on these data; the message says what to do."""


def parameter_layout(attrs: dict) -> dict:
    """What a parameter head predicts for robots of a store (JSON-able, saved in checkpoints).

    Raises:
        BackboneError: the store is not a simulated store of a registered arm with its generator
            config and per-robot parameters (imported real logs have no parameters to learn
            from: train the black-box model on them, or predict with ``Predictor.from_arm``).
    """
    from robomorph.core.config import from_dict  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.identification.identify import KINDS, ParameterSpace, lean_model  # noqa: PLC0415
    from robomorph.sim.randomize import Randomizer, param_names  # noqa: PLC0415
    from robomorph.sim.recipe import Recipe  # noqa: PLC0415

    arm = arms.of_store(attrs)
    if arm is None or not isinstance(attrs.get("config"), dict) \
            or list(attrs.get("param_names", [])) != param_names(arm.name):
        raise BackboneError("--model.physics needs simulated stores of a registered arm that record each robot's "
                            f"parameters (this store: domain {attrs.get('domain')!r}, "
                            f"{'with' if attrs.get('param_names') else 'without'} params); "
                            "train the black-box model on it with --model.physics none")
    recipe = from_dict(Recipe, attrs["config"], "store config")
    model = lean_model(recipe.substeps, recipe.dt, recipe.gravity_compensation == "true_model", recipe.robot)
    randomizer = Randomizer(model, recipe.randomization, recipe.robot)
    space = ParameterSpace.of(randomizer, recipe.randomization, KINDS)
    return {"recipe": dict(attrs["config"]), "names": list(space.names), "index": space.index.tolist(),
            "low": space.low.tolist(), "high": space.high.tolist()}


def same_layout(a: dict, b: dict) -> bool:
    """Whether two stores' parameter layouts agree (names and bounds)."""
    return a["names"] == b["names"] and np.allclose(a["low"], b["low"]) and np.allclose(a["high"], b["high"])


def to_unit(layout: dict, params: np.ndarray) -> np.ndarray:
    """(..., P) full parameter vectors -> (..., n) the predicted entries in unit coordinates."""
    lo, hi = np.asarray(layout["low"]), np.asarray(layout["high"])
    return (np.asarray(params)[..., layout["index"]] - (lo + hi) / 2) / ((hi - lo) / 2)


# The physics step of a horizon after its first second, by default [s]. Measured on 32 held-out
# robots with their true parameters (Panda recipe, 60 Hz; results/benchmarks/horizon_step.csv):
# 4 physics steps per sample instead of the generator's 8 move the horizon by 0.06 and 0.08 mrad
# at 5 and 13.3 s, a few percent of what identification leaves, for 37 % fewer physics steps over
# a 200 + 800 window; on 64 held-out robots `regression` scored 1.799 / 3.985 mrad there against
# 1.796 / 3.981, the same to four digits before (results/benchmarks/hybrid.md). Everywhere
# coarse, the first steps would move too (0.0025 and 0.034 mrad at steps 1 and 15, about a
# sixth of the error there); 2 physics steps per sample moved 5 s by 0.22 mrad.
COARSE_STEP = 1 / 240
# Context samples simulated for the observer's velocity (:func:`observed_velocity`): from a five-point
# central difference 12 samples before the end. On 256 held-out robots the horizons equal, to 4 digits
# at steps 1 to 800, those from the whole context simulated (tails of 6 to 60 alike), and the single
# robot (`regression~1/2+obs`) costs 21 % less per window (64 windows, interleaved medians: 23.8 -> 18.8 ms
# from random offsets, 28.0 -> 21.3 from the start).
OBSERVED_TAIL = 12
# The observer's start velocity is replaced by the recorded joints' own finite difference (a cubic through the last
# samples) where the two differ by more than this [rad/s] on some joint: the identified robot's simulation of the
# context has then left the record too far for the residual's velocity to correct it. Measured on 16 held-out robots
# under catalogue gravity compensation: one window's observer 1.02 rad/s off (its simulated context 2.9), the finite
# difference 0.0004; the first step's joint RMS there 5.2 mrad. Clean contexts differ by far less (OBSERVER_GUARD_NOTE).
OBSERVER_GUARD = 0.05


def coarse_substeps(recipe) -> int:
    """Physics steps per sample after the first second by default: a step of about
    :data:`COARSE_STEP`, never finer than the recipe's own."""
    return max(1, min(int(recipe.substeps), round(float(recipe.dt) / COARSE_STEP)))


class PhysicsBackbone:
    """Simulates windows of robots given as parameter vectors (reusable; :meth:`close` when done).

    Args:
        layout: :func:`parameter_layout` of the training stores (as recorded in a checkpoint).
        inputs: ``total`` or ``command``: the formulation of the torques given.
        nthread: rollout threads (0: one per core).
        substeps: physics steps per sample of the open-loop horizon after its first
            :attr:`FINE_STEPS` (None: :func:`coarse_substeps`, 4 for the Panda recipe's 8; the
            recipe's own re-enacts the generator to the bit throughout). The context and the
            first second keep the recipe's step: there the prediction is most precise, and a
            coarse step's error is largest against it. Closed-loop horizons (the commands of an
            arm compensating its gravity with its catalogue model, whose g(q) is added at each
            frame start) take the same coarse step after their first second.

    ``observe`` (settable; default: the layout's ``observer``, absent and so False in records written
    before 2026-11-26): commands start the horizon from :func:`observed_velocity` instead of the
    simulated context's own end velocity.
    """

    # Query steps simulated at the recipe's physics step before ``substeps`` takes over (1 s at 60 Hz).
    FINE_STEPS = 60

    def __init__(self, layout: dict, inputs: str, nthread: int = 0, substeps: int | None = None):
        import os  # noqa: PLC0415

        from robomorph.core.config import from_dict  # noqa: PLC0415
        from robomorph.identification.identify import Identifier, IdentifyConfig  # noqa: PLC0415
        from robomorph.sim.recipe import Recipe  # noqa: PLC0415

        self.layout, self.inputs = layout, inputs
        self.recipe = from_dict(Recipe, layout["recipe"], "model's recipe")
        self.substeps = int(self.recipe.substeps)
        self.coarse = substeps  # the physics steps per sample after FINE_STEPS
        nthread = nthread or os.cpu_count() or 1
        self.ident = Identifier(self.recipe, inputs, IdentifyConfig(nthread=nthread))
        self.index = np.asarray(layout["index"], dtype=np.int64)
        self.low, self.high = np.asarray(layout["low"]), np.asarray(layout["high"])
        if list(self.ident.space.names) != list(layout["names"]):
            raise BackboneError(f"the model's parameter layout does not match this version's {self.recipe.robot}: "
                                "re-train it")
        self.dt = float(self.recipe.dt)
        # Without state feedback inside the horizon, the horizon is one open-loop rollout.
        self.open_loop = self.ident.engine.feedback is None
        self._closed = None  # per thread (lean model, data, catalogue gravity) for the formulations with feedback
        self._kinematics = SiteKinematics(self.ident.model, "ee")
        self.observe = bool(layout.get("observer", False))
        self.candidates = "exact"

    @property
    def coarse(self) -> int:
        """Physics steps per sample of horizons after :attr:`FINE_STEPS` (settable; None: the default)."""
        return self._coarse

    @coarse.setter
    def coarse(self, substeps: int | None) -> None:
        if substeps is not None and (isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1):
            raise BackboneError(f"physics substeps must be a positive integer (physics steps per sample), got {substeps!r}")
        self._coarse = int(substeps or coarse_substeps(self.recipe))

    @property
    def candidates(self) -> str:
        """How many horizons of one robot from one state are simulated: ``exact`` or ``tangent`` (settable)."""
        return self._candidates

    @candidates.setter
    def candidates(self, how: str) -> None:
        if how not in CANDIDATES:
            raise BackboneError(f"candidate physics must be one of {list(CANDIDATES)}, got {how!r}")
        self._candidates = how

    def close(self) -> None:
        self.ident.close()

    def __enter__(self) -> "PhysicsBackbone":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def catalogue(self, qinit: np.ndarray) -> np.ndarray:
        """(P,) the catalogue robot's full vector with its springs anchored at ``qinit``."""
        return self.ident.randomizer.catalogue(qinit)

    def full_params(self, unit: np.ndarray, qinit: np.ndarray) -> np.ndarray:
        """(N, n) unit coordinates and (N, 7) spring anchors -> (N, P) full vectors (clipped to the bounds)."""
        z = np.clip(np.asarray(unit, dtype=np.float64), -1.0, 1.0)
        out = np.stack([self.catalogue(q) for q in np.asarray(qinit, dtype=np.float64)])
        out[:, self.index] = (self.low + self.high) / 2 + z * (self.high - self.low) / 2
        return out

    def context_velocity(self, params: np.ndarray, q_ctx: np.ndarray, torque_ctx: np.ndarray,
                         qvel_start: np.ndarray, kick: tuple[int, float] | None = None) -> np.ndarray:
        """(N, 7) joint velocity at each context's last sample, from which the horizon starts.

        Commands: each robot simulated over its context from the first sample (its velocity
        ``qvel_start``), which follows the context's dynamics better than a finite difference;
        total torques: the finite-difference estimate (the context simulation drifts with g(q)
        in the torque, as ``identified_physics`` found). ``kick``: :func:`observed_velocity`'s."""
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415
        from robomorph.identification.identify import ContextProblem  # noqa: PLC0415

        if self.inputs != "command":
            return estimate_velocity(q_ctx, self.dt)
        if self.open_loop:
            # All contexts in threaded batches: the rollouts of the fit's problem (ContextProblem), to the bit.
            nj = q_ctx.shape[2]
            s0, v0 = _context_start(q_ctx, qvel_start, self.observe, self.dt)
            states = self.frame_states(params, q_ctx[:, s0], v0,
                                       np.asarray(torque_ctx, dtype=np.float64)[:, s0:-1], fine=True)
            end = states[:, -1, 1 + nj:1 + 2 * nj]  # state: time, qpos, qvel
            return observed_velocity(end, q_ctx[:, s0:] - states[..., 1:1 + nj], self.dt, kick, q_ctx) \
                if self.observe else end
        # Closed loop (the arm's compensation by its catalogue model, evaluated at the recorded states): the whole
        # context, not the observer's tail as open loop. On the realistic recipe's noisy contexts the tail's start
        # moved single windows' horizons by up to 1.6 mrad in the first second (8 held-out robots), where the
        # friction mixture, which re-enacts whole contexts, moved none: a window predicted alone and in a batch
        # would differ.
        out, residual = self.context_rollouts(params, q_ctx, torque_ctx, qvel_start)
        return observed_velocity(out, residual, self.dt, kick, q_ctx) if self.observe else out

    def context_rollouts(self, params: np.ndarray, q_ctx: np.ndarray, torque_ctx: np.ndarray,
                         qvel_start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(qvel_end (N, nj), residual (N, T - 1, nj))`` of each robot simulated over its whole context from its
        first sample as the fit's :class:`robomorph.identification.identify.ContextProblem` simulates one (the
        formulation's feedback evaluated at the recorded states, so open loop), all windows in threaded batches
        of the engine's models: the velocity at the last sample, and the recorded joints less the simulated ones
        at rows 1.. (non-finite rows as the problem reads them). One problem a window gave the same numbers, one
        rollout at a time on one thread."""
        from robomorph.identification.identify import ContextProblem  # noqa: PLC0415

        ident, space = self.ident, self.ident.space
        n, t_all, nj = q_ctx.shape
        models = ident.engine.models
        qvel_end, residual = np.empty((n, nj)), np.empty((n, t_all - 1, nj))
        for s in range(0, n, len(models)):
            rows = range(s, min(s + len(models), n))
            problems = [ContextProblem(ident, params[b], q_ctx[b], torque_ctx[b], np.asarray(qvel_start[b]))
                        for b in rows]
            ctrl = []
            for model, problem in zip(models, problems):
                # Through unit coordinates and back, as a problem's own rollout sets its robot.
                p = problem.params(space.to_unit(problem.base[space.index]))
                ident.randomizer.apply(model, p)
                ctrl.append(problem.control(np.asarray(ident.randomizer.split(p)["mass"])[None])[0])
            control = np.ascontiguousarray(np.repeat(np.stack(ctrl), ident.substeps, axis=1))
            x0 = np.stack([p.x0 for p in problems])
            state = np.empty((len(rows), problems[0].nstep, x0.shape[1]))
            ident.engine.rollout(models[:len(rows)], x0, control, state=state)
            qsim = state[:, problems[0].rows, 1:1 + nj]  # FULLPHYSICS: time, qpos, qvel, ...
            residual[rows.start:rows.stop] = -np.nan_to_num(qsim - q_ctx[rows.start:rows.stop, 1:], nan=10.0,
                                                            posinf=10.0, neginf=-10.0)
            nv0 = 1 + ident.model.nq
            qvel_end[rows.start:rows.stop] = state[:, -1, nv0:nv0 + nj]
        return qvel_end, residual

    def simulate(self, params: np.ndarray, q_ctx: np.ndarray, torque_ctx: np.ndarray, torque_query: np.ndarray,
                 qvel_start: np.ndarray, quat_last: np.ndarray | None = None,
                 qvel_end: np.ndarray | None = None) -> np.ndarray:
        """Predicts the horizon of each window with its own parameter vector.

        Args:
            params: (N, P) full parameter vectors (:meth:`full_params`).
            q_ctx: (N, Tc, 7) recorded joint positions of the contexts.
            torque_ctx: (N, Tc, 7) their torques in this formulation.
            torque_query: (N, H, 7) the query torques (``torque_query[k]`` applied from query step k).
            qvel_start: (N, 7) joint velocity at each context's first sample.
            quat_last: (N, 4) the last context quaternion (X Y Z W), whose sign the prediction keeps.
            qvel_end: (N, 7) the velocity at the last context sample, when already known
                (default: :meth:`context_velocity`).

        Returns:
            (N, H, 14) outputs at query steps 1..H (EE position, EE quaternion X Y Z W, joints).
        """

        params = np.asarray(params, dtype=np.float64)
        q_ctx = np.asarray(q_ctx, dtype=np.float64)
        torque_ctx = np.asarray(torque_ctx, dtype=np.float64)
        n = len(params)
        torque = frame_torques(torque_ctx, torque_query)
        if qvel_end is None:
            qvel_end = self.context_velocity(params, q_ctx, torque_ctx, qvel_start)
        if self.open_loop and self.candidates == "tangent" and n > 1 and all(
                np.all(a == a[:1]) for a in (params, q_ctx[:, -1], qvel_end)):  # one robot from one state
            from robomorph.identification.tangent import candidate_joints  # noqa: PLC0415

            q = candidate_joints(self, params[0], q_ctx[0, -1], qvel_end[0], torque)
        elif self.open_loop:
            q = self.frame_states(params, q_ctx[:, -1], qvel_end, torque)[..., 1:1 + q_ctx.shape[2]]  # time, qpos, ...
        else:
            q = self._closed_loops(params, q_ctx[:, -1], qvel_end, torque)
        return signed(self.outputs(q), quat_last)[:, 1:]  # row 0: the last context sample

    def frame_states(self, params: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray, torque: np.ndarray,
                     fine: bool = False) -> np.ndarray:
        """(N, F + 1, S) full physics states (``mjSTATE_FULLPHYSICS``) at the starts of F open-loop frames (row 0:
        the start): :meth:`segments`' physics steps, or with ``fine`` the recipe's throughout (as contexts are simulated)."""
        ident, nj = self.ident, qpos0.shape[1]
        m, d = ident.model, ident.engine.scratch
        frames = torque.shape[1]
        size = mujoco.mj_stateSize(m, _STATE)
        out = np.empty((len(params), frames + 1, size))
        models = ident.engine.models
        for s in range(0, len(params), len(models)):
            group = range(s, min(s + len(models), len(params)))
            ms = models[:len(group)]
            x = out[group.start:group.stop, 0]
            for k, (model, b) in enumerate(zip(ms, group)):
                ident.randomizer.apply(model, params[b])
                mujoco.mj_resetData(model, d)
                d.qpos[:nj], d.qvel[:nj] = qpos0[b], qvel0[b]
                mujoco.mj_getState(model, d, x[k], _STATE)
            try:
                for first, last, ss in [(0, frames, self.substeps)] if fine else self.segments(frames):
                    for model in ms:
                        model.opt.timestep = self.dt / ss
                    control = np.repeat(torque[group.start:group.stop, first:last], ss, axis=1)
                    state = np.empty((len(group), (last - first) * ss, size))
                    ident.engine.rollout(ms, np.ascontiguousarray(out[group.start:group.stop, first]), control, state=state)
                    rows = np.arange(1, last - first + 1) * ss - 1  # after the last physics step of each frame
                    out[group.start:group.stop, first + 1:last + 1] = state[:, rows]
            finally:
                for model in ms:
                    model.opt.timestep = m.opt.timestep  # the recipe's, which the context's simulations use
        return out

    def outputs(self, q: np.ndarray) -> np.ndarray:
        """(..., T, 7) joint positions -> (..., T, 14) y (catalogue kinematics: link geometry is not randomized)."""
        from robomorph.sim.filters import continuous_quaternion  # noqa: PLC0415

        pos, quat = self._kinematics(q)
        quat = continuous_quaternion(quat)
        return np.concatenate([pos, quat[..., [1, 2, 3, 0]], q], axis=-1)

    def _closed_loops(self, params: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray, torque: np.ndarray
                      ) -> np.ndarray:
        """(N, F + 1, 7) joint positions of each robot simulated closed loop (state feedback in the formulation),
        on the engine's threads: robots of a batch (windows, a friction mixture's members) side by side."""
        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

        n = len(params)
        workers = self._closed_workers(min(n, self.ident.engine.rollout.nthread))
        if len(workers) == 1:
            return np.stack([self._closed_loop(workers[0], params[b], qpos0[b], qvel0[b], torque[b]) for b in range(n)])
        # MuJoCo's steps release the GIL: each thread takes the next robot on its own lean model and data.
        with ThreadPoolExecutor(len(workers)) as pool:
            chunks = [range(w, n, len(workers)) for w in range(len(workers))]
            done = pool.map(lambda w: [self._closed_loop(workers[w], params[b], qpos0[b], qvel0[b], torque[b])
                                       for b in chunks[w]], range(len(workers)))
            out = np.empty((n, torque.shape[1] + 1, qpos0.shape[1]))
            for w, rows in enumerate(done):
                out[list(chunks[w])] = rows
        return out

    def _closed_workers(self, count: int) -> list:
        """``count`` (model, data, controller's gravity) of the lean arm for closed-loop horizons, built on first use.

        The lean arm (:func:`robomorph.identification.identify.lean_model`: no meshes, sensors or contacts) steps
        a contact-free motion to the bit as the full one does, at a quarter of its time (15 against 57 us per
        physics step on the Panda); a horizon's robot never touches anything the generator would have kept."""
        import copy  # noqa: PLC0415

        recipe = self.recipe
        self._closed = self._closed or []
        while len(self._closed) < max(1, count):
            model = copy.deepcopy(self.ident.model)
            grav = _LeanGravity(self.ident.model) if self.inputs == "command" \
                and recipe.gravity_compensation == "nominal_model" else None
            self._closed.append((model, mujoco.MjData(model), grav))
        return self._closed[:max(1, count)]

    def _closed_loop(self, worker: tuple, params: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray,
                     torque: np.ndarray) -> np.ndarray:
        """(F + 1, 7) joint positions at the frame starts of one robot simulated closed loop (the recording
        convention of :func:`robomorph.sim.closed_loop.simulate_closed_loop`, the last frame's start included)."""
        from robomorph.sim.closed_loop import diverged, formulation_controller, reset_to  # noqa: PLC0415

        model, data, grav = worker
        nj, frames = len(qpos0), len(torque)
        self.ident.randomizer.apply(model, params)
        control = formulation_controller(torque, self.inputs, self.recipe.gravity_compensation == "true_model", nj,
                                         grav)
        out = np.empty((frames + 1, nj))
        reset_to(model, data, qpos0, qvel0)
        timestep, rest = model.opt.timestep, self.substeps - 1
        try:
            for t in range(frames):
                # After FINE_STEPS frames the coarse step, each frame's duration kept.
                if t == self.FINE_STEPS and self.coarse != self.substeps:
                    model.opt.timestep, rest = timestep * self.substeps / self.coarse, self.coarse - 1
                out[t] = data.qpos[:nj]  # the frame's start
                mujoco.mj_step1(model, data)
                data.ctrl[:] = control(data, t)
                mujoco.mj_step2(model, data)
                if rest:
                    mujoco.mj_step(model, data, nstep=rest)
                if diverged(data):  # as the generator's closed loop: the frame where it was seen on
                    out[t:] = np.nan
                    return out
            out[frames] = data.qpos[:nj]
        finally:
            model.opt.timestep = timestep
        return out

    def segments(self, frames: int) -> list[tuple[int, int, int]]:
        """``(first, last, substeps)`` of the open-loop horizon's stretches: :attr:`PhysicsBackbone.FINE_STEPS` frames
        at the recipe's step, the rest at ``coarse`` (empty stretches left out)."""
        fine = frames if self.coarse == self.substeps else min(frames, self.FINE_STEPS)
        return [(a, b, ss) for a, b, ss in ((0, fine, self.substeps), (fine, frames, self.coarse)) if b > a]


class _LeanGravity:
    """g(q) of the catalogue robot on its lean arm (the Newton-Euler pass of
    :class:`robomorph.sim.episode.NominalGravity`, the same numbers to the bit), one per thread."""

    def __init__(self, catalogue_model: mujoco.MjModel):
        import copy  # noqa: PLC0415

        self.model = copy.deepcopy(catalogue_model)
        self.data = mujoco.MjData(self.model)
        self._bias = np.empty(self.model.nv)

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        m, d = self.model, self.data
        d.qpos[:len(qpos)], d.qvel[:] = qpos, 0.0
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, self._bias)
        return self._bias[:len(qpos)].copy()


def _context_start(q_ctx: np.ndarray, qvel_start: np.ndarray, observe: bool, dt: float) -> tuple[int, np.ndarray]:
    """(sample, (N, nj) velocity) from which open-loop contexts are simulated: their first sample, or for the
    observer, whose velocity does not depend on where the simulation starts (the residual's velocity takes up
    the start's error), :data:`OBSERVED_TAIL` samples before the end at a five-point central difference
    (error of order dt^4, against dt^2 for three points). A context too short for it is simulated whole."""
    s = q_ctx.shape[1] - 1 - OBSERVED_TAIL
    if not observe or s < 2:
        return 0, np.asarray(qvel_start, dtype=np.float64)
    return s, (q_ctx[:, s - 2] - 8 * q_ctx[:, s - 1] + 8 * q_ctx[:, s + 1] - q_ctx[:, s + 2]) / (12 * dt)


def observed_velocity(qvel_end: np.ndarray, residual: np.ndarray, dt: float,
                      kick: tuple[int, float] | None = None, recorded: np.ndarray | None = None) -> np.ndarray:
    """(N, 7) a simulated context's end velocity corrected as an observer would: plus the velocity, at the last
    sample, of ``residual`` (N, T, 7), the recorded joint positions less the simulated ones (a cubic through the
    last samples). The simulation's velocity drifts over a context; the recorded positions show by how much.
    ``kick``: (joint, size), that joint's velocity moved further by ``size`` times the correction there (the std's
    ``observed`` points, :func:`robomorph.inference.hybrid_spread.observed_spread`: its size says how far the
    simulated context had drifted, and so how uncertain the start is).
    Measured on 256 held-out robots (``results/benchmarks/hybrid_observer.md``, single robot): the first step's
    joint error 0.0150 -> 0.0054 mrad from the start, 0.0164 -> 0.0066 from random offsets; 0.25 s 6-11 % lower;
    1 s and later within 1 %."""
    from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415

    added = estimate_velocity(np.asarray(residual, dtype=np.float64), dt)
    out = np.asarray(qvel_end, dtype=np.float64) + added
    if recorded is not None:  # (N, T, 7) the recorded joints: where the observer strays, their finite difference
        direct = estimate_velocity(np.asarray(recorded, dtype=np.float64), dt)
        strayed = np.abs(out - direct).max(axis=1) > OBSERVER_GUARD
        out[strayed] = direct[strayed]
    if kick is not None:
        out[:, kick[0]] += kick[1] * np.abs(added[:, kick[0]])
    return out


def frame_torques(torque_ctx: np.ndarray, torque_query: np.ndarray) -> np.ndarray:
    """(N, H, 7) the torques of frames c-1 .. c+H-2 from the last context sample: the last context
    torque, then the query's (``torque_query[k]`` is applied from query step k + 1)."""
    torque_ctx = np.asarray(torque_ctx, dtype=np.float64)
    h = np.shape(torque_query)[1]
    return np.concatenate([torque_ctx[:, -1:], np.asarray(torque_query, dtype=np.float64)[:, :h - 1]
                           if h > 1 else torque_ctx[:, :0]], axis=1)


def signed(y: np.ndarray, quat_last: np.ndarray | None) -> np.ndarray:
    """Outputs (N, T, 14) whose row 0 is the last context sample, their quaternions flipped (in
    place) where row 0's disagrees in sign with ``quat_last`` (N, 4; None: left as they are)."""
    if quat_last is not None:
        flip = np.einsum("nk,nk->n", y[:, 0, 3:7], np.asarray(quat_last)) < 0
        y[flip, :, 3:7] *= -1.0
    return y
