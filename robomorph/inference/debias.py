"""The regression's bias, measured by simulation and taken off (``HybridSettings.debias``).

The regression (:mod:`robomorph.identification.regressor`) reads velocities and accelerations as central
differences of joints sampled at 60 Hz, while the arm moved under torques held over each sample
and integrated at eight physics steps per sample. On the light wrist joints the damping's time
constant is about one sample, so those differences are not the motion's derivatives, and the
solve's armature and damping come out biased (the armature's error is what most limits the
horizon at 1 s: with it alone set right, the single robot is below identified physics in 64 %
rather than 39 % of the windows there, 64 held-out robots from random offsets).

The bias is a property of the estimator at a given robot and torque, so it can be measured
where the truth is known: the estimate's own robot is simulated over the context under the
recorded torques (the generator's physics step, from the context's first sample), the
regression's solve is moved to that simulated context, linearized with the estimate's own
regressor (:func:`robomorph.identification.regressor.shift`), and the difference between what it finds
there and the estimate it was simulated with is taken off the estimate (indirect inference,
one step). Every identified entry is corrected alike and kept inside its randomization bounds;
a simulated context that diverges leaves its window's estimate as it was. Measured on the 256
held-out robots of ``ms_test256.zarr`` (``results/benchmarks/hybrid_debias.md``): the single
robot below identified physics in 100 / 95 / 83 / 78 / 84 % of the windows at steps 1 / 15 / 60 /
300 / 800 from the start, 92 / 58 / 54 / 61 / 64 % without the correction. Running the whole
regression again instead gave the same horizons at three times the added cost.

Cost: one simulation of the context (200 samples at the recipe's step) and one pass of the
inverse dynamics per window, about 5 ms. One context's simulation is sequential, and a planner's
candidates share one context: it is simulated in two pieces that the rollout's threads run at once,
the second from the recorded joints at its start (:func:`_simulated`; on the 256 held-out robots the
horizons matched the single piece's to three digits, and the shared context's correction fell from
about 10 to 8 ms). Nothing here reads a query sample.
"""

from __future__ import annotations

import numpy as np

# Rounds of the correction: each simulates the corrected robot's context again and takes off what the regression
# still finds there.
ROUNDS = 1


def debiased(backbone, reg, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, qvel_start: np.ndarray,
             fits: list) -> np.ndarray:
    """(B, P) the estimates ``params`` less the bias the regression shows on their own robots' simulated contexts.

    Args:
        backbone: the hybrid's :class:`robomorph.identification.backbone.PhysicsBackbone`, which simulates the contexts.
        reg: the :class:`robomorph.identification.regressor.RegressorIdentifier` whose solves gave ``params``.
        q_ctx, u_ctx: (B, Tc, nj) the recorded contexts' joints and torques (this formulation's).
        qvel_start: (B, nj) the joint velocity at each context's first sample (0 where it opens its trajectory).
        fits: each window's solve (:attr:`robomorph.identification.regressor.RegressorIdentifier.last_fit`).
    """
    index, low, high = reg.space.index, reg.space.low, reg.space.high
    out = params.copy()
    for _ in range(ROUNDS):
        q_sim, cut = _simulated(backbone, out, q_ctx, u_ctx, qvel_start)
        for b in np.flatnonzero([all(np.all(np.isfinite(p)) for p in q_sim[b]) for b in range(len(out))]):
            # (a diverged context: left as it was.) The regression on the simulated context finds its robot plus
            # the bias there; the next estimate is the first less that bias: out - (what it finds - the first one).
            moved = reg.shift(fits[b], q_sim[b], [u_ctx[b, :cut + 2], u_ctx[b, cut:]]) * reg.half_range
            out[b, index] = np.clip(out[b, index] - moved, low, high)
    return out


def _simulated(bb, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, qvel_start: np.ndarray
               ) -> tuple[list, int]:
    """Per window, its robot ``params`` simulated over its context in two pieces side by side, so that the
    rollout's threads run them at once (one context's simulation is sequential, and a planner asks for one):
    from the first sample to ``cut + 1``, and from the recorded joints at ``cut`` (the central difference's
    velocity) to the end. Each inner sample's differences lie within one piece: the first piece's from 1 to
    ``cut``, the second's after. Returns the pieces' joints per window, and ``cut``."""
    nj, n, tc = q_ctx.shape[2], len(params), q_ctx.shape[1]
    frames = (tc + 1) // 2  # both pieces' frames: the second starts at tc - 1 - frames, the first needs cut + 1
    cut = tc - 1 - frames
    v_cut = (q_ctx[:, cut + 1] - q_ctx[:, cut - 1]) / (2 * bb.dt)
    torque = np.concatenate([u_ctx[:, :frames], u_ctx[:, cut:-1]])
    states = bb.frame_states(np.concatenate([params, params]), np.concatenate([q_ctx[:, 0], q_ctx[:, cut]]),
                             np.concatenate([qvel_start, v_cut]), torque, fine=True)
    q = states[..., 1:1 + nj]  # state: time, qpos, qvel, ...
    return [[q[b, :cut + 2], q[n + b]] for b in range(n)], cut
