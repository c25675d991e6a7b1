"""The ``identified_physics`` baseline: the engineer's answer, identify the robot, then simulate it.

For each window, the physical parameters a context can reveal (a mass per link; damping,
armature and friction loss per joint) are fitted to the context by bounded, regularized
least squares over MuJoCo rollouts (:mod:`robomorph.identification.identify`): bounded by the recipe's
randomization ranges and pulled weakly toward the catalogue values. The fitted robot is then
simulated over the horizon exactly as ``nominal_physics`` simulates the catalogue robot
(same formulation, same gravity compensation), from the last context sample. In the
command formulation the joint velocity there is the fitted simulation's, which follows the
context's dynamics (measured: a fifth of the first step's error of the cubic estimate); in
the total-torque formulation the fitted simulation of the context drifts more (the centres
of mass are not fitted and g(q) is in the torque), so the velocity is the cubic estimate
``nominal_physics`` uses.

Each window costs a fit of its own (seconds where the other baselines take milliseconds);
:meth:`IdentifiedPhysics.notes` reports that cost per window beside the fit's quality, so a
learned (amortized) identification can be compared on accuracy and on time.
"""

from __future__ import annotations

import time

import numpy as np

from robomorph.core.velocity import estimate_velocity
from robomorph.evaluation.physics import NominalPhysics
from robomorph.identification.identify import KINDS, SPRING_KINDS, Fit, IdentifyConfig

NAME = "identified_physics"
# The same fit with the joints' springs too (their stiffness), as the command hybrid's regression fits them.
SPRUNG = "identified_physics_springs"


def config_of(name: str) -> IdentifyConfig:
    """The fit a baseline named :data:`NAME` or :data:`SPRUNG` runs."""
    if name not in (NAME, SPRUNG):
        raise ValueError(f"not an identified-physics baseline: {name!r}")
    return IdentifyConfig(kinds=KINDS + SPRING_KINDS) if name == SPRUNG else IdentifyConfig()


class IdentifiedPhysics:
    """Callable ``(u_ctx, y_ctx, u_query) -> y_query`` for stores of a simulated arm (any of :mod:`robomorph.sim.arms`).

    Args:
        attrs: the store's attributes (domain, channel names and generator config).
        inputs: ``total`` (torques given are ``u``) or ``command`` (they are ``u_cmd``).
        config: how the parameters are fitted (:class:`robomorph.identification.identify.IdentifyConfig`).

    Raises:
        NotApplicable: the store is not a simulated arm's store with its generator config
            (imported real logs, another channel layout): there are no catalogue values or
            ranges to fit within.
    """

    def __init__(self, attrs: dict, inputs: str = "total", config: IdentifyConfig | None = None):
        from robomorph.identification.identify import Identifier  # noqa: PLC0415  (MuJoCo only when used)

        self.physics = NominalPhysics(attrs, inputs)  # refuses stores it cannot simulate (any registered arm)
        self.identifier = Identifier(self.physics.recipe, inputs, config)
        self._fitted_velocity = inputs == "command"
        self.fits: list[Fit] = []
        self.seconds: list[float] = []  # per window: the fit and the horizon's simulation

    def close(self) -> None:
        self.identifier.close()

    def __enter__(self) -> "IdentifiedPhysics":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray, base: np.ndarray | None = None,
                 at_rest: np.ndarray | None = None) -> np.ndarray:
        """Predicts ``y_query`` (B, H, n_y).

        Args:
            base: (B, P) the catalogue parameter vectors to start from, with each robot's
                springs anchored where it started (default: anchored at the context's first
                sample, right when the context opens the trajectory).
            at_rest: (B,) whether each context opens its trajectory (the robot starts at
                rest: zero initial velocity); default: the velocity at the context's first
                sample is estimated from its first samples.
        """
        sim, nj = self.physics, self.physics.n_joint
        q_ctx = y_ctx[..., sim.joints].astype(np.float64)
        # The velocity at the first context sample: a cubic through the first samples, in reverse time.
        qvel_start = -estimate_velocity(q_ctx[:, ::-1], sim.dt)
        if at_rest is not None:
            qvel_start[np.asarray(at_rest, dtype=bool)] = 0.0
        torque_ctx = u_ctx.astype(np.float64)
        torque = np.concatenate([u_ctx[:, -1:], u_query], axis=1).astype(np.float64)
        out = []
        for b in range(len(u_ctx)):
            t0 = time.perf_counter()
            start = sim.params(q_ctx[b, 0]) if base is None else np.asarray(base[b], dtype=np.float64)
            fit = self.identifier.fit(start, q_ctx[b], torque_ctx[b], qvel_start[b])
            qvel = fit.qvel_end[:nj] if self._fitted_velocity else estimate_velocity(q_ctx[b:b + 1], sim.dt)[0]
            y = sim.rollout(torque[b], q_ctx[b, -1], qvel, fit.params)
            if np.dot(y[0, sim.quaternion], y_ctx[b, -1, sim.quaternion]) < 0:  # the context's sign convention
                y[:, sim.quaternion] *= -1.0
            out.append(y[1:])
            self.fits.append(fit)
            self.seconds.append(time.perf_counter() - t0)
        return np.stack(out)

    def notes(self) -> dict:
        """The cost per window and the fits' quality, for ``metrics.json``'s ``baseline_notes``."""
        if not self.fits:
            return {}
        f, s = self.fits, np.asarray(self.seconds)
        return {"seconds_per_window": float(s.mean()), "seconds_per_window_max": float(s.max()),
                "seconds_total": float(s.sum()), "windows": len(f),
                "iterations_mean": float(np.mean([x.iterations for x in f])),
                "rollouts_per_window": float(np.mean([x.rollouts for x in f])),
                "converged": int(sum(x.converged for x in f)),
                "context_rms_mrad": {"catalogue": 1e3 * float(np.sqrt(np.mean([x.rms_start ** 2 for x in f]))),
                                     "identified": 1e3 * float(np.sqrt(np.mean([x.rms ** 2 for x in f])))},
                "parameters": list(f[0].names), "threads": self.identifier.engine.rollout.nthread}


def predict_windows(w, config: IdentifyConfig | None = None, anchors=None) -> tuple[np.ndarray, dict]:
    """``identified_physics`` on a window set (:class:`robomorph.evaluation.windows.Window`):
    (N, H, n_y) predictions and the notes (:meth:`IdentifiedPhysics.notes`), with progress
    on stderr (one step per window).

    ``anchors(physics, w)``: the (N, P) catalogue vectors with each robot's springs anchored
    where it started, or None for the context's first sample (the scoring path passes
    :func:`robomorph.evaluation.sources.nominal_params`).

    Raises:
        NotApplicable: the store is not a simulated arm's store with its generator config.
    """
    from robomorph.core.progress import progress  # noqa: PLC0415

    u_ctx, y_ctx, u_q, _ = w.split()
    with IdentifiedPhysics(w.attrs, inputs=w.inputs, config=config) as ident:
        base = None if anchors is None else anchors(ident.physics, w)
        # A window that opens its trajectory starts at rest (the generator's convention).
        at_rest = w.starts == 0 if len(w.starts) == len(u_ctx) else None
        parts = [ident(u_ctx[b:b + 1], y_ctx[b:b + 1], u_q[b:b + 1],
                       base=None if base is None else base[b:b + 1],
                       at_rest=None if at_rest is None else at_rest[b:b + 1])
                 for b in progress(range(len(u_ctx)), "identified physics", unit="window")]
        return np.concatenate(parts).astype(np.float64), ident.notes()
