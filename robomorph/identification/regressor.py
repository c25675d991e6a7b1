"""Identification in one linear solve: inverse dynamics is linear in the identified parameters.

The torque at a state ``(q, v, a)`` is (with gravity ``g`` for total torques; the command
formulation's arm compensates its own)

    tau = M(q; m) a + c(q, v; m) + armature * a + damping * v + friction(v; frictionloss)   [+ g(q; m)]

and the first terms are linear in one kind of parameter each: a link's mass scales its whole
inertia (:class:`robomorph.sim.randomize.Randomizer` scales the inertia tensor with the mass,
and the centres of mass stay at the catalogue's), so ``M``, ``c`` and ``g`` are linear in
the link masses; damping and armature act joint by joint. The friction loss is a soft
constraint in MuJoCo: Coulomb friction when it saturates, a stiff viscous force near rest
(on the light wrist joint that regime covers most of the motion), so it enters linearized
around the catalogue value. This is the classical regressor form of robot identification,
``tau = Y(q, v, a) theta``: each column of ``Y`` is a difference of MuJoCo's own inverse
dynamics (``mj_inverse`` of the discrete step, ``mjENBL_INVDISCRETE``, so the implicit
damping of the integrator is accounted for), and the parameters follow from a bounded
linear least-squares solve regularized toward the catalogue values as
:mod:`robomorph.identification.identify` does. Modelling the friction as a fixed smooth sign instead
left the wrist's damping and friction at their bounds (measured: 3.5 N m s/rad of damping
error on joint 7, against 0.08 with the constraint's own linearization).

Velocities and accelerations are central differences of the recorded joint positions. A
second difference spans two frames of zero-order-held torque, so it is matched with the
mean of the two torques. Cost: one inverse-dynamics pass over the context for the catalogue
robot, which also gives the link masses' columns (each body's share of the torque) and the friction
losses' (each constraint's state: saturated, +-1; else 0); one more per re-linearization, and for the
last solve one bumping all friction losses (the held joints' test keeps the bump's margin). Four passes
for the Panda's three solves (14 with a pass per link mass; 6 with every solve's friction bumped: 20.3
-> 17.2 ms per single-robot window, 64 robots, interleaved), a few milliseconds per 200-step context
on one core, against seconds for the nonlinear fit over rollouts, which it can start (``refined``).

A joint whose friction loss never saturated at the estimate is *held*: its column is zero, and
the solves cannot move it. That is right for a joint that stood still (the context only bounds
its friction loss: :mod:`robomorph.identification.stiction`), but a joint that slid slowly at a friction
loss below the estimate's can look held too, the soft constraint's viscous regime explaining
its motion. So where a joint held, the solves are repeated from the low end of its friction
range (two more solves, three passes), where its column is the Coulomb force's, and that fit is
kept if it explains the context's torques much better (:data:`SLIP_RATIO`); a joint that truly
held fits worse from below, a constant Coulomb force where a varying holding force was needed.

Two terms a real arm has and the parameter vector does not (``offsets``, ``coulomb``): a constant torque
per joint (a torque sensor's offset; the asymmetric part of a friction that differs by direction; the
mean of an unknown payload's gravity over the context) and a Coulomb friction per joint beyond the
catalogue box's friction loss (``Fc tanh(v / COULOMB_VELOCITY)``, the realism recipes' law without its
Stribeck hump). Both are linear, so they are further columns of the same solve, bounded and pulled
toward zero like the rest; they are not entries of the robot's vector (:meth:`extra`), and a backbone
simulates them as a change of the torque it is given (:mod:`robomorph.identification.extra_terms`).
With noisy joints (``noise``, measured in the context: :mod:`robomorph.identification.noise`) the
joints and the torques are smoothed alike before the differences, over a window the noise sets
(module ``noise``'s docstring gives the rule and its measurement).
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from robomorph.identification import extra_terms, noise as encoder
from robomorph.identification.stacked import StackedInverse, carried_bodies

# A re-tried fit of the joints that held (:meth:`RegressorIdentifier._slipped`) replaces the fit
# when its linearized torque residual is below this fraction of the fit's. Chosen on the 64 robots
# of ``ms_cal`` (the ratio was 0.15 for the one context whose wrist slid, 0.93 or more for the other
# 45 with a held joint); on the 64 held-out robots it was 0.29-0.47 for four and 0.97 or more for 42.
SLIP_RATIO = 0.5
# Solves of the re-try (a pass each, and the last a bump). With one, the held-out ratios were 0.31-0.56 and 0.97 or
# more (one context nearer the threshold, the same predictions to three digits): two keep the gap.
RETRY_SOLVES = 2
# The step of a centre-of-mass coordinate's column [m] (the randomization moves them by up to 1 cm).
# Fitted for total torques only: their gravity torque is linear in them, their inertia nearly so
# over a centimetre, so the column is a difference of the inverse dynamics taken once.
COM_STEP = 1e-3
# Rows per block of the normal equations' gram matrix (:func:`_solve`).
GRAM_ROWS = 256


class RegressorIdentifier:
    """Bounded linear least squares of the regressor form (reusable, not thread-safe).

    Args:
        recipe: the generator recipe (sample time, substeps, ranges).
        space: the :class:`robomorph.identification.identify.ParameterSpace` of the fitted parameters.
        randomizer: the recipe's randomizer (catalogue masses and inertias).
        prior: weight of the pull toward the catalogue, per half-range of a parameter, in
            units of the torque error's ``sigma``.
        sigma: torque error [N m] that costs 1.
        exact_columns: one inverse-dynamics pass per parameter (damping, armature and friction
            loss included) instead of the analytic damping and armature columns and one pass
            for all friction losses: slower, and measured to give the same fits (the shortcut
            leaves out how the friction constraint's softness depends on the inertia).
    """

    def __init__(self, recipe, space, randomizer, inputs: str = "command", prior: float = 0.03, sigma: float = 0.05,
                 exact_columns: bool = False, iterations: int = 3, extras: tuple[str, ...] = (),
                 relinearize_com: bool = False):
        from robomorph.sim.episode import NominalGravity  # noqa: PLC0415
        from robomorph.identification.identify import lean_model, lean_spec  # noqa: PLC0415

        # Commands to an arm that adds its catalogue model's gravity (a real arm's controller):
        # the joints feel the command plus that g(q), and the robot's own gravity, which is
        # linear in its masses, stays in the solve, as for total torques.
        self._catalogue_gravity = (NominalGravity(recipe) if inputs == "command"
                                   and recipe.gravity_compensation == "nominal_model" else None)
        self.dt = float(recipe.dt)
        self.space, self.randomizer = space, randomizer
        self.prior, self.sigma = float(prior), float(sigma)
        # Commands: no gravity (the arm compensates its own; none: there is none to see).
        # Total torques hold g(q), which is linear in the link masses as well. The inverse is
        # that of the discrete step (implicit damping adds h D to the inertia).
        self.model = lean_model(recipe.substeps, recipe.dt, False, recipe.robot)
        if inputs == "command" and self._catalogue_gravity is None:
            self.model.opt.gravity[:] = 0.0
        self.model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_INVDISCRETE
        self._nj = len(randomizer.friction0)
        self._stacked = StackedInverse(lambda: lean_spec(recipe.substeps, recipe.dt, False, recipe.robot),
                                       self.model, self._nj)
        self.last_cov: np.ndarray | None = None  # of the last fit, in unit coordinates
        # (nj,) of the last fit: joints whose friction loss never saturated over the context at
        # the estimate (their friction column is zero: the context bounds it, does not identify it).
        self.last_held: np.ndarray | None = None
        self.exact_columns = bool(exact_columns)
        self._carried = carried_bodies(self.model, self._nj)
        if int(iterations) < 1:
            raise ValueError(f"the regressor needs iterations >= 1, got {iterations}")
        self.iterations = int(iterations)
        self._half = (space.high - space.low) / 2
        self._mid = (space.high + space.low) / 2
        self._friction = _friction_entries(space, randomizer)
        # The terms beside the robot's vector (:mod:`robomorph.identification.extra_terms`): their columns' scale
        # (half their bounds' width, per joint) and the last fit's values [N m] (zeros where off).
        self.extras = extra_terms.check(extras)
        # The centres of mass's columns taken again at every solve (where a mass moves far, as a payload's does, its
        # centre's column, proportional to it, moves with it); else once, where the first solve starts.
        self.relinearize_com = bool(relinearize_com)
        self._extra_half = extra_terms.half_ranges(self.extras, recipe.arm.limits)
        self.last_extra = extra_terms.zeros(self._nj)
        # (pieces,) rows of each piece when each has its own constant torque per joint (a recording's offsets, which
        # drift from one to the next): every piece's rows are taken less their means, joint by joint, before the
        # solve, which is the least-squares fit with a free offset per piece and joint (the offsets' own columns
        # vanish then, pulled to zero); None: one offset over all (the ``offsets`` extra term, where on).
        self.piece_offsets: np.ndarray | None = None

    def fit(self, base: np.ndarray, q: np.ndarray, torque: np.ndarray, prior_mean: np.ndarray | None = None,
            prior_std: np.ndarray | None = None, noise: float = 0.0, piece_offsets: bool = False) -> np.ndarray:
        """The full parameter vector ``base`` with the identified entries solved for.

        Args:
            base: (P,) the catalogue vector (springs anchored where the robot started).
            q: (T, 7) recorded joint positions (T >= 3), or a list of recordings' (:meth:`data`).
            torque: (T, 7) (or a list, as ``q``) the commands (gravity compensated by the arm, with its own model or
                with the catalogue's) or total torques.
            prior_mean, prior_std: (n,) a Gaussian prior on the identified entries in unit
                coordinates (a learned estimate, :mod:`robomorph.inference.hybrid`); the solve is
                then the posterior mode, the data weighted by their residual variance.
                Default: the weak pull toward ``base`` (``prior``).
            noise: the encoder noise std [rad] measured in the context (:func:`robomorph.identification.noise.encoder_noise`):
                above :data:`robomorph.identification.noise.NOISE_FLOOR` the joints and torques are smoothed alike
                before the differences, over a window that grows with it; below, nothing changes.
            piece_offsets: each piece of a list its own constant torque per joint (:attr:`piece_offsets`), projected
                out of the solve: recordings whose offsets drift; they are not estimated (the mean residual of each
                piece under the fit is its offset).
        """
        data = self.data(q, torque, noise)
        self.piece_offsets = self.last_pieces if piece_offsets else None
        try:
            return self._fit(base, data, prior_mean, prior_std)
        finally:
            self.piece_offsets = None

    def data(self, q, torque, noise=0.0) -> tuple:
        """(positions, velocities, accelerations, torques) at the inner samples the solve reads, the catalogue's
        gravity added where the arm compensates with it and noisy joints smoothed (:meth:`fit`'s ``noise``).

        ``q``, ``torque`` and ``noise`` may also be lists, one entry per recording (each its own trajectory, of any
        length >= 3): each piece's differences are taken on its own and the rows stacked, so one solve reads them
        all (an identification over a robot's whole training recordings, :mod:`robomorph.inference.recordings`)."""
        if not isinstance(q, list):
            q, torque, noise = [q], [torque], [noise]
        elif not isinstance(noise, list):
            noise = [noise] * len(q)
        if not q or len(q) != len(torque) or len(q) != len(noise):
            raise ValueError(f"the regressor reads as many torque pieces as joint pieces (one or more), got "
                             f"{len(q)} and {len(torque)}")
        pieces = []
        for qp, tp, n in zip(q, torque, noise):
            qp, tp = np.asarray(qp, dtype=np.float64), np.asarray(tp, dtype=np.float64)
            if qp.ndim != 2 or qp.shape != tp.shape[:1] + qp.shape[1:] or len(qp) < 3:
                raise ValueError(f"each piece is (T, joints) joints and torques with T >= 3, got {qp.shape} and "
                                 f"{tp.shape}")
            if self._catalogue_gravity is not None:
                tp = tp + np.stack([self._catalogue_gravity(qt) for qt in qp])
            if n > encoder.NOISE_FLOOR:
                qp, tp = encoder.smooth_pair(qp, tp, n)
            pieces.append(_differences(qp, tp, self.dt))
        self.last_pieces = np.array([len(p[0]) for p in pieces])  # each piece's rows (states), in order
        return pieces[0] if len(pieces) == 1 else tuple(np.concatenate(parts) for parts in zip(*pieces))

    def residual(self, params: np.ndarray, data: tuple) -> np.ndarray:
        """(T, nj) the torque ``data`` (of :meth:`data`) holds beyond robot ``params``'s inverse dynamics at the
        recorded motion: what its offsets and any model error must explain."""
        qs, v, a, tau = data
        return tau - self._inverse(np.asarray(params, dtype=np.float64), qs, v, a)[0]

    def _fit(self, base: np.ndarray, data: tuple, prior_mean, prior_std) -> np.ndarray:
        base = np.asarray(base, dtype=np.float64)
        z_base = self._unit(base)
        fit = self._solves(base, z_base, data, self.iterations)
        self.last_held = _held(self._friction, fit.cols, self._nj)
        if prior_mean is None and self.last_held.any():
            fit = self._slipped(fit, z_base, data)
        params, self.last_fit = fit.params, fit
        self.last_extra = extra_terms.values(self.extras, fit.x_extra * self._extra_half if len(fit.x_extra) else None,
                                             self._nj)
        n, m = len(fit.b_z), len(z_base)
        # The estimate's covariance in unit coordinates (Gauss-Markov, the residual's variance):
        # what the draws behind the hybrid's standard deviation sample from (the robot's entries: the
        # extra terms' marginalized out).
        s2 = float(np.einsum("i,i->", fit.err, fit.err)) / max(1, n - len(fit.gram))
        self.last_cov = (s2 * np.linalg.inv(fit.gram + n * self.prior ** 2 * np.eye(len(fit.gram))))[:m, :m]
        if prior_mean is not None:
            if len(fit.x_extra):
                raise ValueError("a prior on the robot's entries (the fused mode) takes no extra terms: build the "
                                 "regressor without extras")
            # The posterior mode under the prior: data in units of their residual spread.
            mu = np.asarray(prior_mean, dtype=np.float64)
            w = 1.0 / np.maximum(np.asarray(prior_std, dtype=np.float64), 1e-3)
            s2 = max(s2, 1e-12)
            hess = fit.gram / s2 + np.diag(w ** 2)
            params = params.copy()
            params[self.space.index] = self._mid + _bounded_lstsq(hess, fit.atb / s2 + w ** 2 * mu) * self._half
            self.last_cov = np.linalg.inv(hess)
        return params

    @property
    def half_range(self) -> np.ndarray:
        """(n,) half the bounds' width of each identified entry: one unit coordinate in the parameter's units."""
        return self._half

    def _unit(self, params: np.ndarray) -> np.ndarray:
        return (params[self.space.index] - self._mid) / self._half

    def _solves(self, params: np.ndarray, z_base: np.ndarray, data: tuple, iterations: int,
                cols: np.ndarray | None = None) -> "_Fit":
        """``iterations`` solves, the first linearized at ``params``, each next one where the last
        landed; all pulled toward ``z_base``. ``cols``: the regressor of an earlier fit, whose
        columns other than the friction losses' are kept (they do not depend on where they are taken)."""
        qs, v, a, tau = data
        index, params = self.space.index, params.copy()
        extra_cols = self._extra_columns(v)  # (T * nj, e): fixed, they depend on the recorded motion alone
        e = extra_cols.shape[1]
        # The linearization point: the robot's entries where the estimate is, the extra terms at zero (the torque
        # the inverse dynamics gives holds none of theirs, so each solve finds them whole).
        z_lin = np.r_[self._unit(params), np.zeros(e)]
        z_pull = np.r_[z_base, np.zeros(e)]  # the extra terms are pulled toward none
        for it in range(iterations):
            # The torque linearized at the current estimate: exact in the masses, damping and armature;
            # the friction loss is piecewise linear (Coulomb where its constraint saturates, no dependence
            # where it does not), so its column is re-taken where the estimate is and the solve repeated:
            # one pass for the torque and one for the friction columns per extra iteration. The first
            # pass also keeps each body's share of the torque: the link masses' columns.
            fresh = it == 0 and cols is None
            # The last solve's friction columns bumped (a held joint, :func:`_held`, keeps the bump's margin);
            # the others read from the torque's own pass, a pass fewer each.
            tau0, bodies, signs = self._inverse(params, qs, v, a, fresh and not self.exact_columns, it < iterations - 1)
            cols = self._columns(params, qs, v, a, tau0, None if fresh else cols, bodies, signs)
            A_z = self._design(cols, extra_cols)
            resid = (tau - tau0).ravel() / self.sigma
            if self.piece_offsets is not None:
                A_z, resid = _within(A_z, resid, self.piece_offsets, self._nj)
            x, b_z, gram, atb = _solve(A_z, resid, z_lin, z_pull, self.prior)
            params[index] = self._mid + x[:len(index)] * self._half
            z_lin = np.r_[x[:len(index)], np.zeros(e)]
        return _Fit(params, cols, b_z, gram, atb, np.einsum("ij,j->i", A_z, x) - b_z, z_base, x[len(index):])

    def _design(self, cols: np.ndarray, extra_cols: np.ndarray) -> np.ndarray:
        """(T * nj, n + e) the solve's matrix in unit coordinates and units of ``sigma``: the robot's regressor
        ``cols`` (T, nj, n), then the extra terms' columns (already per unit coordinate)."""
        A_z = cols.reshape(-1, len(self.space.index)) * (self._half / self.sigma)[None, :]
        return np.concatenate([A_z, extra_cols / self.sigma], axis=1) if extra_cols.shape[1] else A_z

    def _extra_columns(self, v: np.ndarray) -> np.ndarray:
        """(T * nj, e) the extra terms' torque per unit coordinate at the context's states (velocities ``v``)."""
        return extra_terms.columns(self.extras, v, self._extra_half)

    def _slipped(self, fit: "_Fit", z_base: np.ndarray, data: tuple) -> "_Fit":
        """The fit again, the friction losses of the joints that held at its estimate started at
        the low end of their ranges; kept where it explains the context's torques much better
        (:data:`SLIP_RATIO`; why: the module's docstring)."""
        start = fit.params.copy()
        for c, j in self._friction:
            if self.last_held[j]:
                start[self.space.index[c]] = self.space.low[c]
        alt = self._solves(start, z_base, data, RETRY_SOLVES, fit.cols)
        if np.linalg.norm(alt.err) >= SLIP_RATIO * np.linalg.norm(fit.err):
            return fit
        self.last_held = _held(self._friction, alt.cols, self._nj)
        return alt

    def _columns(self, params: np.ndarray, qs: np.ndarray, v: np.ndarray, a: np.ndarray, tau0: np.ndarray,
                 previous: np.ndarray | None = None, bodies: np.ndarray | None = None,
                 signs: np.ndarray | None = None) -> np.ndarray:
        """(T, nj, n) the regressor: each identified parameter's torque per unit, at every state.

        ``previous``: the columns at an earlier estimate, of which only the friction losses'
        are taken again (the others do not depend on where they are taken, to first order).
        ``bodies``: (T, nj, nbody) each body's share of the torque (:meth:`_inverse`), from which
        the link masses' columns are read instead of a pass per mass. ``signs``: the friction losses' (:meth:`_inverse`)."""
        index = self.space.index
        cols = np.zeros((len(qs), self._nj, len(index))) if previous is None else previous.copy()
        h = self.model.opt.timestep
        friction = []  # (column, parameter, joint) of the friction losses, bumped together below
        anchor = self.randomizer.split(params)["qinit"]  # where each joint's spring pulls toward
        for c, k in enumerate(index):
            kind, _, joint = self.randomizer.names[k].rpartition("_q")
            j = int(joint) if joint.isdigit() else -1
            com = self.randomizer.names[k].startswith("com_")
            if previous is not None and kind != "frictionloss" and not (com and self.relinearize_com):
                continue
            if self.exact_columns and j >= 0:
                kind = "bump"
            if kind == "damping":
                # Damping is linear and joint-local: D v plus, from the implicit integration
                # of the discrete step, h D a (equal to the difference below to 1e-3).
                cols[:, j, c] = v[:, j] + h * a[:, j]
            elif kind == "armature":
                cols[:, j, c] = a[:, j]  # the armature adds to the inertia's diagonal: exact
            elif kind == "stiffness":
                # The spring pulls toward where the robot started; position-dependent, so outside the
                # implicit integration's velocity terms: exact.
                cols[:, j, c] = qs[:, j] - anchor[j]
            elif kind == "frictionloss":
                friction.append((c, k, j))
            elif com:  # gravity in the torque (see COM_STEP)
                cols[:, :, c] = self._bumped(params, k, COM_STEP, (qs, v, a), tau0)
            elif bodies is not None:
                # The torque is linear in a link's mass (its inertia scales with it, its centre of
                # mass stays): its column is the link's share of the torque per kilogram.
                cols[:, :, c] = bodies[:, :, self.randomizer.index.body_ids[k]] / params[k]
            else:
                # A link's mass (inertia scaled with it) moves every joint's torque: a difference
                # of MuJoCo's own inverse dynamics (exact for a mass: the torque is linear in it).
                cols[:, :, c] = self._bumped(params, k, 0.01 * max(abs(params[k]), 1e-3), (qs, v, a), tau0)
        if friction and signs is not None:
            for c, k, j in friction:  # read from the torque's own pass (:func:`robomorph.identification.stacked._signs`)
                cols[:, j, c] = signs[:, j]
        elif friction:
            # A joint's friction loss is a soft constraint on that joint alone (its constraint
            # Jacobian row is the joint's unit vector), so all of them are bumped in one pass and
            # each joint's torque change is its own column: a linearization (Coulomb when
            # saturated, viscous near rest).
            bumped = params.copy()
            steps = {}
            for c, k, j in friction:
                steps[c] = 0.01 * max(abs(params[k]), 1e-3)
                bumped[k] += steps[c]
            diff = self._inverse(bumped, qs, v, a)[0] - tau0
            for c, k, j in friction:
                cols[:, j, c] = diff[:, j] / steps[c]
        return cols

    def _inverse(self, params: np.ndarray, q: np.ndarray, v: np.ndarray, a: np.ndarray, bodies: bool = False,
                 friction: bool = False) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        self.randomizer.apply(self.model, params)  # then its inverse dynamics, many states per call
        self._stacked.load(self.model)
        return self._stacked.run(q, v, a, self._carried, bodies, friction)

    def shift(self, fit: "_Fit", q, torque) -> np.ndarray:
        """(n,) in unit coordinates: how far the estimate of ``fit`` (a :attr:`last_fit` of this identifier)
        moves when its joints are ``q`` (T, 7) instead (the same torques), the solve linearized there with that fit's
        regressor: one inverse-dynamics pass instead of a fit's several (:mod:`robomorph.inference.debias`).

        ``q`` and ``torque`` may also be lists of pieces of the context that overlap by two samples (each piece its
        own trajectory): each piece's differences give the inner samples it holds whole, in order."""
        pieces = [_differences(qp, tp, self.dt) for qp, tp in zip(*((q, torque) if isinstance(q, list) else ([q], [torque])))]
        qs, v, a, tau = (np.concatenate(parts) for parts in zip(*pieces))
        if len(qs) != len(fit.cols):
            raise ValueError(f"shift: the pieces hold {len(qs)} inner samples, the fit read {len(fit.cols)}")
        resid = (tau - self._inverse(fit.params, qs, v, a)[0]).ravel() / self.sigma
        A_z = self._design(fit.cols, self._extra_columns(v))
        n, pull, m = len(resid), self.prior ** 2, len(self.space.index)
        # The solve's normal equations with these torques' residual, less its own at z. The torques given are
        # taken to be the robot's own (any extra terms already taken off them): those terms are at zero here, and
        # only the robot's entries' move is returned.
        e = len(fit.gram) - m
        z, z_base = np.r_[self._unit(fit.params), np.zeros(e)], np.r_[fit.z_base, np.zeros(e)]
        return np.linalg.solve(fit.gram / n + pull * np.eye(len(z)), A_z.T @ resid / n - pull * (z - z_base))[:m]

    def _bumped(self, params: np.ndarray, k: int, step: float, states: tuple,
                tau0: np.ndarray) -> np.ndarray:
        """(T, nj, ...) the torque's change per unit of parameter ``k``: a difference of MuJoCo's inverse dynamics."""
        bumped = params.copy()
        bumped[k] += step
        return (self._inverse(bumped, *states)[0] - tau0) / step


def _differences(q: np.ndarray, torque: np.ndarray, dt: float) -> tuple:
    """(positions, velocities, accelerations, torques) at a context's inner samples: central differences."""
    q, torque = np.asarray(q, dtype=np.float64), np.asarray(torque, dtype=np.float64)
    v = (q[2:] - q[:-2]) / (2 * dt)
    a = (q[2:] - 2 * q[1:-1] + q[:-2]) / dt ** 2
    return q[1:-1], v, a, (torque[:-2] + torque[1:-1]) / 2  # a second difference spans two frames' torques


class _Fit(NamedTuple):
    """A fit's estimate, regressor, normal equations and linearized residual (in units of ``sigma``)."""

    params: np.ndarray
    cols: np.ndarray
    b_z: np.ndarray
    gram: np.ndarray
    atb: np.ndarray
    err: np.ndarray
    z_base: np.ndarray  # where the solves were pulled toward (unit coordinates)
    x_extra: np.ndarray  # the extra terms' estimate in unit coordinates (empty without them)


def _friction_entries(space, randomizer) -> list[tuple[int, int]]:
    """(column, joint) of each friction loss among the identified parameters."""
    out = []
    for c, k in enumerate(space.index):
        kind, _, joint = randomizer.names[k].rpartition("_q")
        if kind == "frictionloss" and joint.isdigit():
            out.append((c, int(joint)))
    return out


def _held(friction: list[tuple[int, int]], cols: np.ndarray, nj: int) -> np.ndarray:
    """(nj,) whether each joint's friction loss never saturated: its column (the Coulomb force's
    sign per unit of friction loss where the constraint saturates, zero where it holds the
    joint) stays below half a unit at every state of the context. ``friction``: (column, joint)."""
    held = np.zeros(nj, dtype=bool)
    for c, j in friction:
        held[j] = bool(np.max(np.abs(cols[:, j, c])) < 0.5)
    return held


def _within(A_z: np.ndarray, resid: np.ndarray, pieces: np.ndarray, nj: int) -> tuple[np.ndarray, np.ndarray]:
    """``A_z`` and ``resid`` (rows state-major, then joint) less each piece's mean per joint: a constant per piece and
    joint projected out of the solve (``pieces``: each piece's states, in order)."""
    A_z, resid = A_z.copy(), resid.copy()
    start = 0
    for n in pieces:
        rows = slice(start * nj, (start + n) * nj)
        a, r = A_z[rows].reshape(n, nj, -1), resid[rows].reshape(n, nj)
        a -= a.mean(axis=0)
        r -= r.mean(axis=0)
        start += n
    return A_z, resid


def _solve(A_z: np.ndarray, resid: np.ndarray, z_lin: np.ndarray, z_base: np.ndarray, prior: float):
    """One solve of the torque linearized at ``z_lin``, pulled toward ``z_base``: the
    estimate, the right-hand side and the normal equations (``A_z' A_z``, ``A_z' b_z``)."""
    n = len(resid)
    # No multi-threaded BLAS on the tall products: waking its threads takes far longer than these
    # (thousands x 29) products (measured: 99 of 117 ms of a fit on two busy cores), and the scorer
    # runs fits beside other work. The gram matrix in blocks of GRAM_ROWS rows, which OpenBLAS
    # multiplies on the calling thread (its threshold: 4 x 65536 multiply-adds): 0.09 ms against
    # einsum's 0.58 for 1386 x 29, 6 % of the single robot's time; the vectors in einsum's loops.
    b_z = resid + np.einsum("ij,j->i", A_z, z_lin)
    gram = sum(block.T @ block for block in np.split(A_z, range(GRAM_ROWS, len(A_z), GRAM_ROWS)))
    atb = np.einsum("ti,t->i", A_z, b_z)
    # The data's mean square plus the prior's pull (prior per unit of z).
    eye = np.eye(len(z_base))
    return _bounded_lstsq(gram / n + prior ** 2 * eye, atb / n + prior ** 2 * z_base), b_z, gram, atb


def _bounded_lstsq(hess: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """argmin 0.5 z' H z - g' z over the box [-1, 1]^n, for a small positive definite H: a primal
    active-set method from the unconstrained minimum clipped to the box (each step solves the free
    entries with the bound ones held, moves as far toward that as the box allows, and frees the bound
    entry whose multiplier has the wrong sign). The problem is strictly convex, so this is the one
    minimum scipy's ``lsq_linear`` (BVLS on H's Cholesky factor) finds, at a tenth of its time
    (0.5 ms a call, a tenth of the single robot's window); that stays the fallback."""
    z = np.linalg.solve(hess, grad)  # the unconstrained minimum
    if np.all(np.abs(z) <= 1.0):
        return z  # inside the box, so also the box's minimum (a convex problem): no bounded solve
    z = np.clip(z, -1.0, 1.0)
    bound = np.abs(z) >= 1.0
    for _ in range(4 * len(z)):
        free = ~bound
        target = z.copy()
        if free.any():
            target[free] = np.linalg.solve(hess[np.ix_(free, free)], grad[free] - hess[np.ix_(free, bound)] @ z[bound])
        step = target - z
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(step > 0, (1.0 - z) / step, np.where(step < 0, (-1.0 - z) / step, np.inf))
        alpha = min(1.0, float(room[free].min())) if free.any() else 1.0
        z = z + alpha * step
        if alpha < 1.0:  # a free entry reached the box: it is bound from here
            hit = free & (room <= alpha)
            z[hit] = np.sign(step[hit])
            bound |= hit
            continue
        slope = (hess @ z - grad) * np.sign(z)  # > 0 at a bound entry: moving it inward lowers the cost
        wrong = bound & (slope > 1e-12)
        if not wrong.any():
            return z
        bound[int(np.argmax(np.where(wrong, slope, -np.inf)))] = False
    from scipy.optimize import lsq_linear  # noqa: PLC0415  (not reached on the fits measured)

    chol = np.linalg.cholesky(hess)  # H = L L': ||L' z - L^-1 g||^2 = z'Hz - 2 g'z + const
    return lsq_linear(chol.T, np.linalg.solve(chol, grad), bounds=(-1.0, 1.0), method="bvls").x
