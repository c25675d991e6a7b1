"""Identification: the physical parameters of one robot, fitted to a context of its own motion.

    ident = Identifier(recipe, inputs="command")
    fit = ident.fit(base, q_ctx, torque_ctx, qvel0)   # base: the catalogue vector (param_names order)
    fit.params                                         # the full vector with the identified entries
    ident.close()

What is fitted (``IdentifyConfig.kinds``): a mass per link (the inertia scales with it, as
:class:`robomorph.sim.randomize.Randomizer` applies it), and damping, armature and friction loss per
joint; the centres of mass and the joint springs stay at the catalogue's (they barely move a joint
over a few seconds; the inertias were found unidentifiable from joint data alone). Each parameter
is bounded by the recipe's range, so one whose range is collapsed is known exactly and not fitted.

Method: bounded nonlinear least squares (scipy's trust-region reflective) of the simulated joint
positions against the context's, plus a pull toward the catalogue values (a weak Tikhonov term in
units of each parameter's half-range) that settles the directions the context cannot see. The
context is simulated open loop with ``mujoco.rollout`` from its first sample; a Jacobian is forward
differences, all its perturbed rollouts in one threaded call; the fit stops once it stops changing.

Formulations: the gravity compensation a formulation adds at each frame start
(``robomorph.evaluation.physics.NominalPhysics``) is evaluated here at the *recorded* state
of the frame, which makes the context an open-loop rollout. For the command on an arm that
compensates with its own model (``true_model``) and for ``none`` nothing is added and the
rollout is exact; for ``nominal_model`` commands the catalogue's g(q) is added; for total
torques with ``true_model`` the fitted robot's own g(q) is taken off (g is linear in the link
masses, so it is assembled from per-link terms computed once per context).

Every arm of :mod:`robomorph.sim.arms` (the recipe's ``robot``): its own links, joints and
catalogue values, the same kinds of parameters.
"""

from __future__ import annotations

import copy
import os
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.sim import arms, panda
from robomorph.sim.open_loop import ThreadedRollout
from robomorph.sim.randomize import RandomizationConfig, Randomizer

KINDS = ("mass", "damping", "armature", "frictionloss")
# The centres of mass (3 coordinates per link) as well: what the regressor fits for total torques, where gravity
# is paid in the recorded torque (a centimetre: ~0.1 N m). Not in KINDS, every fit's and head's default layout.
GRAVITY_KINDS = KINDS + ("com",)
# The joint springs (toward where the robot started): tiny in a context, but at the catalogue's value the largest
# error left in a commanded arm's slow drift (the true robot but its springs, 64 held-out robots: 1.6 mrad RMS at
# 13.3 s; its centres of mass 0.7, itself 0.08). The regressor fits them beside the kinds above (linear in them).
SPRING_KINDS = ("stiffness",)
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


class IdentificationError(RoboMorphError, ValueError):
    """Identification settings or data that cannot work; the message says what to change."""


@dataclass(frozen=True)
class IdentifyConfig:
    """How the parameters are fitted.

    Attributes:
        kinds: parameter kinds to fit, from :data:`KINDS` and :data:`SPRING_KINDS`.
        prior: weight of the pull toward the catalogue value, per half-range of a parameter;
            the data term is the joint RMS error in units of ``sigma``, so moving a parameter
            across its whole half-range costs as much as ``prior * sigma`` of RMS error.
        sigma: joint-position error [rad] that costs 1.
        max_iters: most cost evaluations (scipy's ``max_nfev``); each accepted step adds one Jacobian.
        tol: early stop: relative change of the cost (``ftol``) or of the step (``xtol``).
        fd_step: finite-difference step, as a fraction of each parameter's half-range.
        nthread: rollout threads (0: one per core, at most one per Jacobian column).
    """

    kinds: tuple[str, ...] = KINDS
    prior: float = 0.03
    sigma: float = 1e-3
    max_iters: int = 30
    tol: float = 1e-2
    fd_step: float = 1e-3
    nthread: int = 0

    def __post_init__(self):
        bad = [k for k in self.kinds if k not in KINDS + SPRING_KINDS]
        if bad or not self.kinds:
            raise IdentificationError(f"identify kinds must be a non-empty subset of {KINDS + SPRING_KINDS}, got {self.kinds}")
        if not (self.prior >= 0 and self.sigma > 0 and self.tol > 0 and 0 < self.fd_step < 1):
            raise IdentificationError("identify needs prior >= 0, sigma > 0, tol > 0 and 0 < fd_step < 1")
        if self.max_iters < 1 or self.nthread < 0:
            raise IdentificationError("identify needs max_iters >= 1 and nthread >= 0")


@dataclass(frozen=True)
class ParameterSpace:
    """The fitted entries of a parameter vector and their bounds.

    Attributes:
        names: the fitted parameters' names (:func:`robomorph.sim.randomize.param_names`).
        index: their positions in the full vector.
        low, high: their bounds (the randomization ranges).
    """

    names: tuple[str, ...]
    index: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(cls, randomizer: Randomizer, cfg: RandomizationConfig, kinds=KINDS) -> "ParameterSpace":
        gain = randomizer.gain  # per joint, as the randomizer scales its draws (ones for the Panda)
        where = randomizer.split(np.arange(len(randomizer.names), dtype=np.float64))
        spans = {"mass": (randomizer.mass0 * (1 - cfg.mass_pct / 100), randomizer.mass0 * (1 + cfg.mass_pct / 100)),
                 "damping": (cfg.damping[0] * gain, cfg.damping[1] * gain),
                 "armature": (cfg.armature[0] * gain, cfg.armature[1] * gain),
                 "frictionloss": (randomizer.friction0 * cfg.frictionloss_scale[0],
                                  randomizer.friction0 * cfg.frictionloss_scale[1]),
                 "com": ((randomizer.ipos0 - cfg.com_offset).ravel(), (randomizer.ipos0 + cfg.com_offset).ravel()),
                 "stiffness": (cfg.stiffness[0] * gain, cfg.stiffness[1] * gain)}
        index, low, high = [], [], []
        for kind in GRAVITY_KINDS + SPRING_KINDS:  # KINDS first: their layouts are those checkpoints record
            if kind not in kinds:
                continue
            lo, hi = spans[kind]
            # A collapsed range (or a zero nominal value) leaves nothing to fit.
            keep = hi - lo > 1e-9 * np.maximum(1.0, np.abs(hi))
            index.append(where[kind].astype(np.int64).ravel()[keep])
            low.append(lo[keep])
            high.append(hi[keep])
        index = np.concatenate(index)
        return cls(tuple(randomizer.names[i] for i in index), index, np.concatenate(low), np.concatenate(high))

    def __len__(self) -> int:
        return len(self.index)

    def to_unit(self, values: np.ndarray) -> np.ndarray:
        """Values -> [-1, 1] (the bounds at -1 and 1)."""
        return (values - (self.low + self.high) / 2) / ((self.high - self.low) / 2)

    def from_unit(self, z: np.ndarray) -> np.ndarray:
        return (self.low + self.high) / 2 + z * (self.high - self.low) / 2


@dataclass
class Fit:
    """One identification.

    Attributes:
        params: the full parameter vector: ``base`` with the identified entries replaced.
        names, values: the identified parameters and their values.
        rms: joint RMS error [rad] of the fitted robot's simulation over the context.
        rms_start: the same for ``base`` (before the fit).
        qvel_end: (7,) joint velocity of the fitted simulation at the last context sample.
        iterations: Jacobians computed; evaluations: cost evaluations.
        rollouts: simulations of the context run (each Jacobian column is one).
        seconds: wall time of the fit.
        converged: stopped by the tolerances (not by ``max_iters``).
    """

    params: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray
    rms: float
    rms_start: float
    qvel_end: np.ndarray
    iterations: int
    evaluations: int
    rollouts: int
    seconds: float
    converged: bool


def lean_model(substeps: int, dt: float, gravity_compensation: bool, robot: str = arms.DEFAULT_ROBOT) -> mujoco.MjModel:
    """An arm (:mod:`robomorph.sim.arms`) for fits to contact-free motion: the same bodies, inertias,
    joints and actuators (the inertias are explicit, not derived from the meshes), without the mesh
    geoms, the sensors or contacts. A motion without contacts is the same to the bit, at a hundredth of the
    memory (a full Panda holds ~28 MB of meshes) and 40 % less time per step. The stores' robots never touch
    anything (the generator rejects any contact), so a fit must not be steered by a candidate's contacts either."""
    model = lean_spec(substeps, dt, gravity_compensation, robot).compile()
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return model


def lean_spec(substeps: int, dt: float, gravity_compensation: bool, robot: str = arms.DEFAULT_ROBOT) -> mujoco.MjSpec:
    """The spec :func:`lean_model` compiles (contacts are disabled on the compiled model)."""
    timestep = float(dt) / substeps
    if robot == "panda":
        # Without the mesh and texture files: compiling copies them all (14 MB), 45 of 47 ms, for nothing used.
        spec = mujoco.MjSpec.from_string(panda.compiled_xml(timestep, bool(gravity_compensation))[0])
    else:
        spec = arms.build_spec(arms.get(robot), timestep, bool(gravity_compensation))
    for kind in ("geoms", "meshes", "sensors", "textures", "materials"):
        for element in list(getattr(spec, kind)):
            if kind != "geoms" or element.type == mujoco.mjtGeom.mjGEOM_MESH:
                spec.delete(element)
    return spec


class RolloutEngine:
    """Robots of one lean arm model simulated side by side: what the identifier's fits, the hybrid's backbone,
    the smoother, the friction mixture and the tangent candidates all run their rollouts on.

    Attributes:
        model: the lean arm (:func:`lean_model`) whose copies are simulated.
        models: one copy per robot simulated at once (a rollout sets each copy's parameters).
        rollout: the threaded ``mujoco.rollout`` runner (:class:`robomorph.sim.open_loop.ThreadedRollout`).
        scratch: an ``MjData`` of :attr:`model` for one-off computations (a state's gravity, a forward pass).
        feedback: what the formulation adds to the torque at each frame start: ``catalogue`` (the catalogue
            arm's gravity compensation, commands to a ``nominal_model`` arm), ``own`` (the simulated robot's,
            total torques of a ``true_model`` arm) or None (open loop).
    """

    def __init__(self, model: mujoco.MjModel, copies: int, nthread: int, feedback: str | None):
        self.model, self.feedback = model, feedback
        self.models = [copy.deepcopy(model) for _ in range(max(1, copies))]
        self.rollout = ThreadedRollout(model, min(nthread, len(self.models)))
        self.scratch = mujoco.MjData(model)

    def close(self) -> None:
        self.rollout.close()


class Identifier:
    """Fits parameters to contexts of one recipe's robots (reusable; call :meth:`close` when done).

    Args:
        recipe: the generator recipe (:class:`robomorph.sim.recipe.Recipe`): sample time,
            substeps, gravity compensation and the randomization ranges (the bounds).
        inputs: ``total`` or ``command``: which torques :meth:`fit` is given.
        config: how to fit.
    """

    def __init__(self, recipe, inputs: str = "command", config: IdentifyConfig | None = None):
        self.config = config or IdentifyConfig()
        self.substeps = int(recipe.substeps)
        self.inputs = inputs
        in_actuators = recipe.gravity_compensation == "true_model"
        self.model = lean_model(recipe.substeps, recipe.dt, in_actuators, recipe.robot)
        self.randomizer = Randomizer(self.model, recipe.randomization, recipe.robot)
        self.space = ParameterSpace.of(self.randomizer, recipe.randomization, self.config.kinds)
        # What the formulation adds to the torque at each frame start (see the module docstring).
        if inputs == "command" and recipe.gravity_compensation == "nominal_model":
            feedback = "catalogue"
        elif inputs == "total" and in_actuators:
            feedback = "own"
        else:
            feedback = None
        self.catalogue_gravity = None  # the catalogue arm's gravity compensation the commands lack, where it adds one
        if feedback == "catalogue":
            from robomorph.sim.episode import NominalGravity  # noqa: PLC0415

            self.catalogue_gravity = NominalGravity(recipe)
        self.engine = RolloutEngine(self.model, len(self.space), self.config.nthread or os.cpu_count() or 1, feedback)

    def close(self) -> None:
        self.engine.close()

    def __enter__(self) -> "Identifier":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def fit(self, base: np.ndarray, q: np.ndarray, torque: np.ndarray, qvel0: np.ndarray) -> Fit:
        """Fits the parameters to one context.

        Args:
            base: (P,) the starting and prior parameter vector (the catalogue robot, its
                springs anchored where it started); entries not fitted keep its values.
            q: (T, 7) recorded joint positions of the context (row t: start of frame t).
            torque: (T, 7) the torques of the formulation, ``torque[t]`` applied over frame t.
            qvel0: (7,) joint velocity at row 0 (zero when the context opens the trajectory).
        """
        from scipy.optimize import least_squares  # noqa: PLC0415  (scipy only when fitting)

        t0 = time.perf_counter()
        base = np.asarray(base, dtype=np.float64)
        q, torque = np.asarray(q, dtype=np.float64), np.asarray(torque, dtype=np.float64)
        nj = self.randomizer.nj
        if q.ndim != 2 or q.shape != torque.shape or len(q) < 3 or q.shape[1] != nj:
            raise IdentificationError(f"identify needs (T >= 3, {nj}) joint positions and torques of the same shape, "
                                      f"got {q.shape} and {torque.shape}")
        sp, cfg = self.space, self.config
        problem = ContextProblem(self, base, q, torque, np.asarray(qvel0, dtype=np.float64))
        prior = np.clip(sp.to_unit(base[sp.index]), -1.0, 1.0)
        # Strictly inside (a start on a bound stalls), and rounding noise snapped to the
        # middle: scipy sizes its first trust region by |z0|, 1 when z0 is exactly zero.
        z0 = np.clip(np.where(np.abs(prior) < 1e-6, 0.0, prior), -0.95, 0.95)
        weight = np.sqrt(1.0 / (q[1:].size * cfg.sigma ** 2))

        def residual(z: np.ndarray) -> np.ndarray:
            dq = problem.joint_error(z[None])[0]
            return np.concatenate([weight * dq, cfg.prior * (z - prior)])

        def jacobian(z: np.ndarray) -> np.ndarray:
            r0 = problem.cached(z)
            h = np.where(z + cfg.fd_step <= 1.0, cfg.fd_step, -cfg.fd_step)  # stay inside the bounds
            zs = z[None] + np.diag(h)  # (n, n): one perturbed parameter per row
            cols = (problem.joint_error(zs) - r0[None]) * weight / h[:, None]  # (n, m)
            return np.vstack([cols.T, cfg.prior * np.eye(len(z))])

        if len(sp) == 0:
            return problem.result(np.zeros(0), 0, 0, t0, True, problem.rms(np.zeros(0)))
        rms_start = problem.rms(z0)
        sol = least_squares(residual, z0, jac=jacobian, bounds=(-1.0, 1.0), method="trf",
                            ftol=cfg.tol, xtol=cfg.tol, gtol=1e-10, max_nfev=cfg.max_iters, x_scale=1.0)
        return problem.result(sol.x, int(sol.njev or 0), int(sol.nfev), t0, sol.status > 0, rms_start)


class ContextProblem:
    """One context: the rollouts of parameter vectors and their joint errors."""

    def __init__(self, ident: Identifier, base: np.ndarray, q: np.ndarray, torque: np.ndarray, qvel0: np.ndarray):
        self.ident, self.base, self.q = ident, base, q
        self.frames = len(q) - 1  # frames simulated: rows 1..T-1 are compared
        m, ss = ident.model, ident.substeps
        d = ident.engine.scratch
        mujoco.mj_resetData(m, d)
        nj = ident.randomizer.nj
        d.qpos[:nj] = q[0]
        d.qvel[:nj] = qvel0
        self.x0 = np.empty(mujoco.mj_stateSize(m, _STATE))
        mujoco.mj_getState(m, d, self.x0, _STATE)
        self.torque = torque[:self.frames]
        self._gravity = None
        if ident.engine.feedback == "catalogue":
            self.torque = self.torque + np.stack([ident.catalogue_gravity(qt) for qt in q[:self.frames]])
        elif ident.engine.feedback == "own":
            # The centres of mass are not fitted: those of ``base`` are the fitted robot's.
            gm = ident.engine.models[0]
            ident.randomizer.apply(gm, base)
            self._gravity = _gravity_terms(gm, d, q[:self.frames], ident.randomizer.index.body_ids)
        # state[k] is the state after physics step k: row t is the end of step t*ss - 1.
        self.rows = np.arange(1, self.frames + 1) * ss - 1
        self.nstep = self.frames * ss
        self.rollouts = 0
        self._cache: dict[bytes, np.ndarray] = {}
        self._qvel_end: dict[bytes, np.ndarray] = {}

    def params(self, z: np.ndarray) -> np.ndarray:
        p = self.base.copy()
        p[self.ident.space.index] = self.ident.space.from_unit(z)
        return p

    def joint_error(self, zs: np.ndarray) -> np.ndarray:
        """(k, frames * 7) simulated minus recorded joint positions for each row of ``zs`` (k, n)."""
        ident, k = self.ident, len(zs)
        models = ident.engine.models[:k]
        masses = []
        for model, z in zip(models, zs):
            p = self.params(z)
            ident.randomizer.apply(model, p)
            masses.append(ident.randomizer.split(p)["mass"])
        ctrl = self.control(np.asarray(masses)) if self._gravity is not None else self.torque[None]
        control = np.repeat(ctrl, ident.substeps, axis=1)
        state = np.empty((k, self.nstep, len(self.x0)))
        ident.engine.rollout(models, self.x0, control, state=state)
        self.rollouts += k
        nq = ident.randomizer.nj
        qsim = state[:, self.rows, 1:1 + nq]  # FULLPHYSICS: time, qpos, qvel, ...
        # A diverged rollout (MuJoCo resets bad states) still gives finite but wrong rows.
        err = np.nan_to_num(qsim - self.q[None, 1:], nan=10.0, posinf=10.0, neginf=-10.0).reshape(k, -1)
        nv0 = 1 + self.ident.model.nq
        self.last_qvel_end = state[:, -1, nv0:nv0 + nq].copy()  # (k, nj): where each rollout ends
        if k == 1:
            key = zs[0].tobytes()
            self._cache = {key: err[0]}
            self._qvel_end = {key: self.last_qvel_end[0].copy()}
        return err

    def control(self, masses: np.ndarray) -> np.ndarray:
        """(k, frames, 7) the torque each frame's rollout applies to robots of link masses ``masses`` (k, links),
        the formulation's feedback at the recorded state included: the same for every robot but where total torques
        take off each robot's own g(q) (linear in its link masses)."""
        if self._gravity is None:
            return np.broadcast_to(self.torque, (len(masses), *self.torque.shape))
        g_fixed, per_link = self._gravity
        return self.torque[None] - g_fixed[None] - np.einsum("tbj,kb->ktj", per_link, masses)

    def end_velocity(self, z: np.ndarray) -> np.ndarray:
        """(nj,) where the rollout of ``z`` (unit coordinates) ends in velocity: the last single rollout's."""
        self.cached(z)
        return self._qvel_end[z.tobytes()]

    def cached(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in self._cache:
            self.joint_error(z[None])
        return self._cache[key]

    def rms(self, z: np.ndarray) -> float:
        return float(np.sqrt(np.mean(self.cached(z) ** 2)))

    def result(self, z: np.ndarray, iterations: int, evaluations: int, t0: float, converged: bool,
               rms_start: float) -> Fit:
        rms = self.rms(z)
        sp = self.ident.space
        return Fit(self.params(z), sp.names, sp.from_unit(z), rms, rms_start, self._qvel_end[z.tobytes()].copy(),
                   iterations, evaluations, self.rollouts, time.perf_counter() - t0, bool(converged))


def _gravity_terms(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray,
                   links: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The actuators' gravity compensation at each recorded state, split by link mass.

    g(q) = sum_b m_b G_b(q) with G_b(q) = -J_b(q)^T gravity, J_b the Jacobian of body b's
    centre of mass: linear in the masses for fixed centres of mass.

    Returns:
        ``(g_fixed (T, 7), per_link (T, n_links, 7))``: the part of the bodies not
        randomized, and each randomized link's per-kilogram term.
    """
    nj = q.shape[1]
    links = [int(b) for b in links]  # the randomized links' body ids
    others = [b for b in range(1, model.nbody) if b not in set(links) and model.body_mass[b] > 0]
    jac = np.empty((3, model.nv))
    g_fixed = np.zeros((len(q), nj))
    per_link = np.zeros((len(q), len(links), nj))
    mujoco.mj_resetData(model, data)
    for t, qt in enumerate(q):
        data.qpos[:nj] = qt
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        for i, b in enumerate(links):
            mujoco.mj_jacBodyCom(model, data, jac, None, b)
            per_link[t, i] = -(jac.T @ model.opt.gravity)[:nj] * model.body_gravcomp[b]
        for b in others:
            mujoco.mj_jacBodyCom(model, data, jac, None, b)
            g_fixed[t] += -model.body_mass[b] * (jac.T @ model.opt.gravity)[:nj] * model.body_gravcomp[b]
    return g_fixed, per_link
