"""Joints that held still in the context: their friction loss is bounded, not identified.

MuJoCo's friction loss is a soft constraint on its joint. While it holds the joint, its
force is whatever holding takes, whatever the friction loss's value above that. A joint that
never broke free over the context (the Panda's wrist in most multi-sine contexts: light, slow,
with much friction for its inertia) therefore leaves its friction loss unidentified: the
regression's column for it is zero (:attr:`robomorph.identification.regressor.RegressorIdentifier.last_held`)
and its prior, the catalogue value, stays. Yet the horizon turns on it: whether and when that
joint breaks free. Measured on 64 held-out multi-sine robots in the command formulation, the
true friction losses in place of the regression's take the joint error at 13.3 s from 5.4
to 1.7 mrad.

So the prediction is a mixture of ``members`` robots. Each equals the estimate except for the
held joints' friction losses, which sit at evenly spaced quantiles of their randomization
range (all held joints at the same quantile). Each member re-enacts the context: one threaded
rollout of all members from the first context sample, which the command formulation's
velocity estimate runs anyway. Its weight is its likelihood under Gaussian joint errors whose
variance is the best member's mean square. Members that re-enact the context equally well
share the weight: there the friction never mattered, and its range stays open. Members that
slip where the robot held, or hold where it slipped, get none. The horizon is the weighted
mean of the members' horizons, each started from its own velocity at the last context sample.
Their weighted spread is the part of the standard deviation that the unknown friction causes.

Measured on the same 64 robots (9 members), joint RMS [mrad] at steps 1/15/60/300/800:
0.0162/0.232/0.738/1.84/4.03, against 0.0181/0.317/0.790/2.09/5.37 for the regression's
single robot (``benchmarks/hybrid.py`` scores it against identified physics). Since the
regression re-tries held joints from below (:mod:`robomorph.identification.regressor`), which finds the
wrists that slid, the single robot is at 0.0146/0.195/0.511/1.65/4.89 and the mixture at
0.0146/0.195/0.632/1.80/3.99: the mixture is the better one at 13.3 s only.
"""

from __future__ import annotations

import numpy as np


class FrictionMixture:
    """Members and weights of the held joints' friction losses, one context at a time.

    Args:
        ident: the backbone's :class:`robomorph.identification.identify.Identifier` (its models and
            threaded rollout; at least ``members`` models).
        members: robots in the mixture (>= 2).
    """

    def __init__(self, ident, members: int = 9):
        space = ident.space
        if int(members) < 2:
            raise ValueError(f"a friction mixture needs at least 2 members, got {members}")
        if int(members) > len(ident.engine.models):
            raise ValueError(f"a friction mixture of {members} members needs as many models; the identifier "
                             f"has {len(ident.engine.models)}")
        self.ident, self.members = ident, int(members)
        # joint -> (position in the full vector, low, high) of its friction loss
        self.friction: dict[int, tuple[int, float, float]] = {}
        for i, name in enumerate(space.names):
            kind, _, joint = name.rpartition("_q")
            if kind == "frictionloss" and joint.isdigit():
                self.friction[int(joint)] = (int(space.index[i]), float(space.low[i]), float(space.high[i]))
        self.quantiles = (np.arange(self.members) + 0.5) / self.members

    def candidates(self, params: np.ndarray, held: np.ndarray) -> np.ndarray:
        """(K, P) the members: ``params`` with the held joints' friction losses at the quantiles
        of their ranges (one member, ``params`` itself, when no joint held)."""
        joints = [j for j in np.flatnonzero(np.asarray(held, dtype=bool)) if j in self.friction]
        if not joints:
            return np.asarray(params, dtype=np.float64)[None].copy()
        out = np.repeat(np.asarray(params, dtype=np.float64)[None], self.members, axis=0)
        for j in joints:
            k, lo, hi = self.friction[j]
            out[:, k] = lo + self.quantiles * (hi - lo)
        return out

    def weigh(self, params: np.ndarray, held: np.ndarray, q_ctx: np.ndarray, torque_ctx: np.ndarray,
              qvel_start: np.ndarray, observe: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The members of one context, their weights and where each leaves the context.

        Args:
            params: (P,) the estimate (a full parameter vector).
            held: (nj,) the joints whose friction loss never saturated over the context.
            q_ctx, torque_ctx: (T, nj) the context's joint positions and torques (command formulation).
            qvel_start: (nj,) the joint velocity at the first context sample.
            observe: each member's end velocity corrected by its context's position residual
                (:func:`robomorph.identification.backbone.observed_velocity`).

        Returns:
            ``(members (K, P), weights (K,) summing to 1, qvel_end (K, nj))``.
        """
        from robomorph.identification.identify import ContextProblem  # noqa: PLC0415

        members = self.candidates(params, held)
        space = self.ident.space
        problem = ContextProblem(self.ident, np.asarray(params, dtype=np.float64), np.asarray(q_ctx, dtype=np.float64),
                           np.asarray(torque_ctx, dtype=np.float64), np.asarray(qvel_start, dtype=np.float64))
        err, qvel_end = alike_or_each(lambda rows: (problem.joint_error(space.to_unit(members[rows][:, space.index])),
                                                    problem.last_qvel_end.copy()), len(members))
        problem.last_qvel_end = qvel_end
        mse = np.mean(err ** 2, axis=1)
        # Gaussian joint errors with the best member's variance: log-likelihoods relative to it.
        logw = -0.5 * err.shape[1] * (mse / max(float(mse.min()), 1e-18) - 1.0)
        w = np.exp(logw - logw.max())
        qvel_end = problem.last_qvel_end.copy()
        if observe:
            from robomorph.identification.backbone import observed_velocity  # noqa: PLC0415

            dt = self.ident.substeps * self.ident.model.opt.timestep
            recorded = np.broadcast_to(np.asarray(q_ctx, dtype=np.float64), (len(members), *np.shape(q_ctx)))
            qvel_end = observed_velocity(qvel_end, -err.reshape(len(members), -1, q_ctx.shape[1]), dt, None, recorded)
        return members, w / w.sum(), qvel_end


def alike_or_each(simulate, count: int) -> tuple[np.ndarray, ...]:
    """``simulate(rows)`` (rows: indices of the members, in ascending order of the held joints' friction losses)
    gives arrays with a row per member; here for all ``count`` members, the extremes simulated first.

    Where the members with the lowest and the highest friction losses give the same numbers to the bit, so do all
    between, and they are not simulated: MuJoCo's friction loss is a bound on a soft constraint's force, which the
    solve reaches or not. A lowest bound never reached leaves the same motion as any higher bound, step by step
    (the constraint's softness does not depend on it); a bound reached anywhere gives that member another force
    there, so the extremes differ. Contexts where the held joints never broke free (their weights alike, nine of
    the realistic recipe's sixteen held-out robots) take two simulations instead of ``count``.
    """
    if count < 3:
        return simulate(np.arange(count))
    ends = simulate(np.array([0, count - 1]))
    if all(np.array_equal(a[0], a[1]) for a in ends):
        return tuple(np.repeat(a[:1], count, axis=0) for a in ends)
    middle = simulate(np.arange(1, count - 1))
    return tuple(np.concatenate([e[:1], m, e[1:]]) for e, m in zip(ends, middle))


def mixed_horizon(backbone, mixture: list, q_ctx: np.ndarray, torque_ctx: np.ndarray, torque_query: np.ndarray,
                  qvel_start: np.ndarray, quat_last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted mean (B, H, n_y) and variance of the members' horizons, window by window.

    Args:
        backbone: the :class:`robomorph.identification.backbone.PhysicsBackbone` that simulates them.
        mixture: per window, :meth:`FrictionMixture.weigh`'s ``(members, weights, qvel_end)``.
        q_ctx, torque_ctx, torque_query, qvel_start, quat_last: as
            :meth:`robomorph.identification.backbone.PhysicsBackbone.simulate` takes them, one row per window.

    Members of negligible weight (below 1e-4 of the window's largest) are not simulated; all the
    others are, in one batch.
    """
    rows = [(b, k) for b, (_, w, _) in enumerate(mixture) for k in np.flatnonzero(w >= 1e-4 * w.max())]
    bs = np.array([b for b, _ in rows])
    params = np.stack([mixture[b][0][k] for b, k in rows])
    qvel_end = np.stack([mixture[b][2][k] for b, k in rows])

    def simulate(r: np.ndarray) -> np.ndarray:
        return backbone.simulate(params[r], q_ctx[bs[r]], torque_ctx[bs[r]], torque_query[bs[r]], qvel_start[bs[r]],
                                 quat_last[bs[r]], qvel_end[r])

    y = _alike_windows(simulate, bs, qvel_end)
    w = np.array([mixture[b][1][k] for b, k in rows])
    w = w / np.bincount(bs, weights=w, minlength=len(mixture))[bs]
    mean = np.zeros((len(mixture),) + y.shape[1:])
    np.add.at(mean, bs, w[:, None, None] * y)
    var = np.zeros_like(mean)
    np.add.at(var, bs, w[:, None, None] * (y - mean[bs]) ** 2)
    return mean, var


def _alike_windows(simulate, bs: np.ndarray, qvel_end: np.ndarray) -> np.ndarray:
    """``simulate(rows)`` of every row (rows of window ``bs``, its members in ascending friction), in two batches:
    first the extreme members of each window whose members start alike (``qvel_end``: their contexts never told
    them apart) with the other windows' members whole; then the middle members of the windows whose extremes
    differed (:func:`alike_or_each`: where they agree, so do the members between)."""
    first, middles = [], {}
    for b in np.unique(bs):
        r = np.flatnonzero(bs == b)
        if len(r) > 2 and all(np.array_equal(qvel_end[r[0]], qvel_end[k]) for k in r[1:]):
            first += [r[0], r[-1]]
            middles[b] = r
        else:
            first += list(r)
    first = np.array(first)
    y_first = simulate(first)
    y = np.empty((len(bs), *y_first.shape[1:]))
    y[first] = y_first
    rest = []
    for b, r in middles.items():
        if np.array_equal(y[r[0]], y[r[-1]]):
            y[r[1:-1]] = y[r[0]]
        else:
            rest += list(r[1:-1])
    if rest:
        y[np.array(rest)] = simulate(np.array(rest))
    return y
