"""Identification once, prediction many times: a hybrid's predictions along a rolling context.

A robot does not change between two frames of a controller, yet :meth:`Predictor.simulate` identifies it
from its context at every call: the regression's solves, the friction mixture's members re-enacting the whole
context, each member's simulated context for its start velocity. At the realistic recipe's 960 Hz physics that is
most of a call's 60 to 500 ms (``benchmarks/realtime.py`` profiles it). :class:`RollingHybrid` identifies every
``reidentify`` calls and, in between, keeps what the identification found (the robot or the mixture's members and
weights, the torque offsets, the encoder noise measured) and recomputes only what the newest samples move: the
denoised end of the context (:func:`robomorph.identification.noise.denoised_context`) and each member's start
velocity (its simulated context, :func:`robomorph.identification.backbone.observed_velocity`; with ``tail``, only
the observer's short tail of it).

    roll = RollingHybrid(Predictor.from_arm("panda", "realistic"), reidentify=60)
    for frame in ...:
        y_pred = roll.predict(u[f - 200:f], y[f - 200:f], u_plan)      # (H, n_y), or (K, H, n_y) for K plans

The first call, and every ``reidentify``-th after it, is the Predictor's own prediction (the same numbers,
``identified`` True); the others differ from a fresh identification by what the robot's estimate would have moved
over the frames since (``benchmarks/realtime.py`` measures it against the recorded motion).
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.core.errors import RoboMorphError


class RollingError(RoboMorphError, ValueError):
    """A rolling prediction that cannot be made; the message says what to do."""


class RollingHybrid:
    """One robot's hybrid predictions along its rolling context (commands, the Predictor's settings in effect).

    Args:
        predictor: a :class:`robomorph.inference.predictor.Predictor` with a physics backbone in the command
            formulation, predicting in ``regression`` mode (a catalogue arm's, ``Predictor.from_arm``, or a trained
            command hybrid's).
        reidentify: calls between identifications (1: every call, as ``simulate``).
        tail: between identifications, each member's start velocity from the observer's short tail
            (:data:`robomorph.identification.backbone.OBSERVED_TAIL` samples) instead of its whole context: a
            sixteenth of the physics steps, but on noisy contexts a start less sure (measured in
            ``benchmarks/realtime.py``); without the observer (``settings.observer`` off) the whole context always.

    Attributes:
        identified: whether the last call identified the robot.
        calls: calls so far.
    """

    def __init__(self, predictor, reidentify: int = 60, tail: bool = True):
        if isinstance(reidentify, bool) or int(reidentify) != reidentify or reidentify < 1:
            raise RollingError(f"reidentify must be a whole number of calls >= 1, got {reidentify!r}")
        if not predictor.physics or predictor.inputs != "command" or predictor.settings.mode != "regression":
            raise RollingError("a rolling hybrid re-uses a command hybrid's regression: give a Predictor with a physics "
                               "backbone, trained on commands, in mode 'regression' (Predictor.from_arm gives one)")
        self.predictor, self.reidentify, self.tail = predictor, int(reidentify), bool(tail)
        self.calls, self.identified = 0, False
        self._kept: dict | None = None

    def predict(self, u_ctx, y_ctx, u_query, at_rest: bool = False, anchor=None) -> np.ndarray:
        """The mean prediction of the query: (H, n_y) for one plan (H, n_u), (K, H, n_y) for K plans (K, H, n_u) on
        the one context (Tc, n_u), (Tc, n_y).

        Raises:
            RollingError: a batch of contexts (one robot rolls on), or arrays of unequal widths.
        """
        u_ctx, y_ctx = (np.asarray(a, dtype=np.float64) for a in (u_ctx, y_ctx))
        query = np.asarray(u_query, dtype=np.float64)
        if u_ctx.ndim != 2 or y_ctx.ndim != 2 or query.ndim not in (2, 3) or len(u_ctx) != len(y_ctx):
            raise RollingError("a rolling context is one robot's: u_ctx (Tc, n_u) and y_ctx (Tc, n_y) of equal length, "
                               f"u_query (H, n_u) or (K, H, n_u); got {u_ctx.shape}, {y_ctx.shape}, {query.shape}")
        plans = query if query.ndim == 3 else query[None]
        due = self._kept is None or self.calls % self.reidentify == 0
        self.calls += 1
        self.identified = due
        if due:
            out = self._identify(u_ctx, y_ctx, plans, at_rest, anchor)
        else:
            out = self._reuse(u_ctx, y_ctx, plans)
        return out if query.ndim == 3 else out[0]

    def _identify(self, u_ctx, y_ctx, plans, at_rest, anchor) -> np.ndarray:
        """What the Predictor's hybrid predicts for these plans on this context (its mean, the same steps in the same
        order), and what it identified kept for the calls until the next."""
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415

        hybrid = self.predictor.hybrid()
        mode, backbone, nj = self.predictor.settings.mode, hybrid.backbone, hybrid.n_joint
        q_ctx = y_ctx[None, :, 7:7 + nj]
        qvel_start = np.zeros((1, nj)) if at_rest else -estimate_velocity(q_ctx[:, ::-1], backbone.dt)
        anchor = q_ctx[:, 0] if anchor is None else np.asarray(anchor, dtype=np.float64).reshape(1, -1)
        tensors = [torch.as_tensor(a[None]) for a in (u_ctx, y_ctx)]
        # The Hybrid's own steps of a prediction, in its order (Hybrid.predict), stopped where the horizons begin:
        # what they identified is kept here, which the Hybrid does not keep between calls.
        params = hybrid._identify(*tensors, mode, anchor, qvel_start)[0]  # private: Hybrid.predict's first step
        uc, uq, q_ctx = hybrid._as_identified(params, u_ctx[None], plans, q_ctx, qvel_start, slice(None))  # private: its 2nd
        mixture = hybrid._mixture(mode, params, q_ctx, uc, qvel_start)  # private: its third
        if mixture is None:
            members, weights = params, np.ones(1)
            qvel_end = backbone.context_velocity(params, q_ctx, uc, qvel_start)
        else:
            members, weights, qvel_end = mixture[0]
        offsets, noise_std = hybrid._offsets, hybrid._noise  # private: what _identify left, kept as it found them
        self._kept = {"params": params, "members": members, "weights": weights, "offsets": offsets, "noise": noise_std}
        return _mixed(backbone, members, weights, qvel_end, q_ctx, uc, uq, qvel_start, y_ctx[None, -1, 3:7])

    def _reuse(self, u_ctx, y_ctx, plans) -> np.ndarray:
        """The kept robot (or members) from the newest samples: the denoised end and each member's start velocity
        from the observer's tail (or, without the observer, the whole context)."""
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415
        from robomorph.identification import extra_terms, noise  # noqa: PLC0415
        from robomorph.identification.backbone import _context_start, observed_velocity  # noqa: PLC0415

        hybrid, kept = self.predictor.hybrid(), self._kept
        backbone, nj = hybrid.backbone, hybrid.n_joint
        q_ctx = y_ctx[None, :, 7:7 + nj]
        uc, uq = (extra_terms.corrected(a, kept["offsets"]) for a in (u_ctx[None], plans))
        qvel_start = -estimate_velocity(q_ctx[:, ::-1], backbone.dt)
        if kept["noise"] is not None and np.any(kept["noise"] > noise.NOISE_FLOOR):
            q_ctx = noise.denoised_context(backbone, kept["params"], q_ctx, uc, qvel_start, kept["noise"])
        members = kept["members"]
        m = len(members)
        s0, v0 = _context_start(q_ctx, qvel_start, backbone.observe and self.tail, backbone.dt)
        qvel_end, residual = backbone.context_rollouts(members, np.repeat(q_ctx[:, s0:], m, axis=0),
                                                       np.repeat(uc[:, s0:], m, axis=0), np.repeat(v0, m, axis=0))
        if backbone.observe:
            qvel_end = observed_velocity(qvel_end, residual, backbone.dt, None, np.repeat(q_ctx, m, axis=0))
        return _mixed(backbone, members, kept["weights"], qvel_end, q_ctx, uc, uq, qvel_start, y_ctx[None, -1, 3:7])


def _mixed(backbone, members: np.ndarray, weights: np.ndarray, qvel_end: np.ndarray, q_ctx: np.ndarray,
           uc: np.ndarray, uq: np.ndarray, qvel_start: np.ndarray, quat_last: np.ndarray) -> np.ndarray:
    """(K, H, n_y) the weighted mean over ``members`` (M, P), each from its ``qvel_end`` (M, nj), of the horizons of
    the K plans ``uq`` on the one context (``q_ctx``, ``uc``: (1, T, nj)):
    :func:`robomorph.identification.stiction.mixed_horizon` with the context's mixture for every plan."""
    from robomorph.identification.stiction import mixed_horizon  # noqa: PLC0415

    k = len(uq)
    mean, _ = mixed_horizon(backbone, [(members, weights, qvel_end)] * k, *(np.repeat(a, k, axis=0) for a in (
        q_ctx, uc)), uq, np.repeat(qvel_start, k, axis=0), np.repeat(quat_last, k, axis=0))
    if not np.all(np.isfinite(mean)):
        raise RollingError("the simulated robot diverged (non-finite outputs): check the torques' units and scale")
    return mean
