"""The hybrid model's prediction: parameters read from the context, the robot simulated with them.

A model trained with ``--model.physics amortized`` carries a parameter head
(:meth:`robomorph.model.transformer.MetaModel.forward_params`) and, in its data record, the
parameter layout and the generator recipe of its training stores. Prediction:

1. the network reads the context (normalized as in training) and gives the mean and
   log-variance of each identifiable parameter in unit coordinates;
2. the parameters are estimated by one of three modes, and the robot with them is
   simulated over the horizon from the last context sample
   (:class:`robomorph.sim.backbone.PhysicsBackbone`):
   ``learned``, the parameter head's mean; ``regression``, bounded linear least-squares
   solves of the regressor form of the inverse dynamics (:mod:`robomorph.sim.regressor`,
   milliseconds) pulled weakly toward the catalogue; ``fused``, the same solve with the
   parameter head's Gaussian as its prior (the posterior mode: the network says what
   robots like this one usually are, the context's torques say what this one is);
   ``refined``, a few Gauss-Newton iterations of the rollout fit
   (:class:`robomorph.sim.identify.Identifier`) over the armature and friction losses
   (:data:`REFINE_KINDS`), started from the regression's estimate and pulled toward it;
3. the standard deviation (when asked for) is the spread of the horizon over ``samples``
   robots drawn from the head's Gaussian (clipped to the ranges), so it says how much the
   parameters the context leaves uncertain move the prediction.

Nothing here reads a query output: the parameters come from the context and the simulation
from the context's last state and the query torques.
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.core.errors import RoboMorphError

MODES = ("learned", "regression", "fused", "refined", "blend")
# The modes that read the parameter head (a model trained with --model.physics amortized).
HEAD_MODES = ("learned", "fused")
# What ``refined`` fits over rollouts: the parameters the regression leaves least certain. Early
# steps follow the armature (the finite-difference accelerations the regression reads blur
# it), late ones the friction losses (piecewise linear, little seen in many contexts).
# Measured on 16 held-out robots: below identified_physics at every reported step from the
# trajectory start, at a sixth of its cost; refitting all 29 parameters was no better.
REFINE_KINDS = ("armature", "frictionloss")


class HybridError(RoboMorphError, ValueError):
    """A hybrid prediction that cannot be made; the message says what to do."""


class Hybrid:
    """The physics backbone of one trained model (reusable; :meth:`close` when done).

    Args:
        model: the :class:`robomorph.model.checkpoint.TrainedModel` (with a parameter head).
        physics: the ``physics`` entry of the model's data record (layout and recipe).
        inputs: the formulation the model was trained on.
        samples: robots drawn from the parameter head for the standard deviation.
        refine_iters: most cost evaluations of the ``refined`` mode's fit (each accepted step adds a
            Jacobian of rollouts).
        iterations: solves of the regression, each linearized where the previous one landed
            (:class:`robomorph.sim.regressor.RegressorIdentifier`); 1: at the catalogue robot.
        seed: the seed of the parameter draws (the same windows give the same std).
    """

    def __init__(self, model, physics: dict, inputs: str, samples: int = 8, refine_iters: int = 3, seed: int = 0,
                 iterations: int = 3):
        from robomorph.sim.backbone import PhysicsBackbone  # noqa: PLC0415  (MuJoCo only when used)

        if model.config.n_params and model.config.n_params != len(physics["names"]):
            raise HybridError(f"the model's parameter head has {model.config.n_params} outputs but its record "
                              f"names {len(physics['names'])} parameters: the checkpoint is inconsistent")
        self.model, self.physics, self.inputs = model, physics, inputs
        self.samples, self.refine_iters, self.seed = int(samples), int(refine_iters), int(seed)
        self.iterations = int(iterations)
        self.backbone = PhysicsBackbone(physics, inputs)
        self._identifier = None
        self._regressor = None
        self.last_fits: list = []

    def close(self) -> None:
        self.backbone.close()
        if self._identifier is not None:
            self._identifier.close()

    @torch.no_grad()
    def parameters(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std (B, n) of the parameters in unit coordinates, from the context alone.

        ``u_query`` only fixes the normalizer's shapes (it is not read by the parameter head)."""
        uc, yc, _ = self.model.normalizer.encode(u_ctx, y_ctx, u_query, None)
        mean, logvar = self.model.net.forward_params(uc, yc)
        return mean.double().cpu().numpy(), torch.exp(0.5 * logvar).double().cpu().numpy()

    def predict(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, at_rest=None,
                mode: str = "regression", return_std: bool = False, calibration=None
                ) -> tuple[np.ndarray, np.ndarray | None]:
        """(B, H, n_y) mean prediction and, with ``return_std``, the std over parameter draws.

        Args:
            at_rest: bool or (B,) bools: the context opens its trajectory (the robot starts
                at rest); default False: the velocity at the first context sample is estimated.
            mode: one of :data:`MODES`.
            calibration: a :class:`robomorph.model.calibration.StdCalibration` of this
                mode's std (``robomorph calibrate``), applied to it; None: the raw spread.

        Raises:
            HybridError: an unknown mode, or a simulated robot that diverged.
        """
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415

        self._check_mode(mode)
        uc, yc, uq = (t.double().cpu().numpy() for t in (u_ctx, y_ctx, u_query))
        q_ctx, quat_last = yc[..., 7:14], yc[:, -1, 3:7]
        B = len(uc)
        rest = np.broadcast_to(np.asarray(False if at_rest is None else at_rest, dtype=bool), (B,))
        qvel_start = -estimate_velocity(q_ctx[:, ::-1], self.backbone.dt)
        qvel_start[rest] = 0.0
        # Candidate torque sequences on one context (model-predictive control): the robot is
        # identified once and only the horizons are simulated per row.
        shared = B > 1 and bool(np.all(uc == uc[:1]) and np.all(yc == yc[:1]) and np.all(rest == rest[0]))
        one = slice(0, 1) if shared else slice(None)
        params, z, z_std = self._identify(u_ctx[one], y_ctx[one], mode, q_ctx[one, 0], qvel_start[one])

        def horizon(p: np.ndarray) -> np.ndarray:
            """(B, H, n_y) of the robots ``p`` (one per row, or one for all on a shared context)."""
            qvel_end = self.backbone.context_velocity(p, q_ctx[one], uc[one], qvel_start[one])
            if shared:
                p, qvel_end = np.repeat(p, B, axis=0), np.repeat(qvel_end, B, axis=0)
            return self.backbone.simulate(p, q_ctx, uc, uq, qvel_start, quat_last, qvel_end)

        mean = horizon(params)
        if mode == "blend":
            return self._blend(u_ctx, y_ctx, u_query, mean, params, z, z_std, horizon, return_std, calibration)
        if not np.all(np.isfinite(mean)):
            raise HybridError("the simulated robot diverged (non-finite outputs): check the torques' units and "
                              "scale, or predict with physics_mode 'none'")
        if not return_std:
            return mean, None
        return mean, self._spread(mode, params, z, z_std, mean, horizon, calibration)

    def _check_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise HybridError(f"physics mode must be one of {MODES}, got {mode!r}")
        if mode in HEAD_MODES and not self.model.config.n_params:
            raise HybridError(f"physics mode {mode!r} reads a parameter head, which this model has not (it was "
                              "trained with --model.physics none): use 'regression' or 'blend'")
        if mode == "blend" and getattr(self.model, "blend", None) is None:
            raise HybridError("physics mode 'blend' needs the blend's weights, which this model has not: fit them "
                              "with robomorph calibrate --blend")

    @torch.no_grad()
    def _blend(self, u_ctx, y_ctx, u_query, physics, params, z, z_std, horizon, return_std, calibration):
        """The physics prediction and the decoder's, weighted by step and channel (and their stds)."""
        mean, std = self.model.forward_dist_raw(u_ctx, y_ctx, u_query)
        decoder = mean.double().cpu().numpy()
        if not return_std:
            return self.model.blend.combine(physics, decoder)[0], None
        if std is None:
            raise HybridError("the blend's standard deviation needs the decoder's, and this model has no Gaussian "
                              "head: drop return_std")
        with np.errstate(invalid="ignore", over="ignore"):
            spread = self._spread("regression", params, z, z_std, physics, horizon, None)
        out, out_std = self.model.blend.combine(physics, decoder, spread, std.double().cpu().numpy())
        return out, out_std if calibration is None else out_std * calibration.factors(out_std.shape[-2])[None]

    @torch.no_grad()
    def identify(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, mode: str = "regression",
                 anchor: np.ndarray | None = None, at_rest: bool = False) -> np.ndarray:
        """(B, P) the robots' full parameter vectors read from their contexts in ``mode``.

        What a model-predictive controller simulates its candidates with (the parameters
        change slowly, the candidates at every plan). ``anchor``: (B, 7) where each robot
        started (its springs' rest pose); default: the first context sample.
        """
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415

        self._check_mode(mode)
        q_ctx = y_ctx.double().cpu().numpy()[..., 7:14]
        qvel_start = np.zeros_like(q_ctx[:, 0]) if at_rest else -estimate_velocity(q_ctx[:, ::-1], self.backbone.dt)
        return self._identify(u_ctx, y_ctx, mode, q_ctx[:, 0] if anchor is None else anchor, qvel_start)[0]

    def _identify(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, mode: str, anchor: np.ndarray,
                  qvel_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full parameter vectors (B, P), and the head's mean and std in unit coordinates."""
        uc = u_ctx.double().cpu().numpy()
        q_ctx = y_ctx.double().cpu().numpy()[..., 7:14]
        if mode not in HEAD_MODES:
            # The solve reads the context alone: the parameter head is not needed (nor run).
            z = z_std = np.zeros((len(uc), len(self.backbone.index)))
        else:
            z, z_std = self.parameters(u_ctx, y_ctx, u_ctx[:, :1])
        # The springs are anchored where the robot started: the first context sample when the context opens it.
        params = self.backbone.full_params(z, anchor)
        if mode != "learned":
            prior = (z, z_std) if mode == "fused" else None
            params = self._regress(params, q_ctx, uc, prior, anchor)
        if mode == "refined":
            params = self._refine(params, q_ctx, uc, qvel_start)
        return params, z, z_std

    def _spread(self, mode: str, params: np.ndarray, z: np.ndarray, z_std: np.ndarray, mean: np.ndarray,
                horizon, calibration) -> np.ndarray:
        """The std (B, H, n_y): the horizons of robots drawn around the estimate, about ``mean``."""
        rng = np.random.default_rng(self.seed)
        # Draws around the estimate used: the head's Gaussian (learned) or the regression's
        # covariance (regression, fused, refined), in unit coordinates.
        index, low, high = self.backbone.index, self.backbone.low, self.backbone.high
        center = (params[:, index] - (low + high) / 2) / ((high - low) / 2)
        if mode == "learned":
            chol = z_std[:, :, None] * np.eye(z.shape[1])[None]
        else:
            chol = np.stack([np.linalg.cholesky(c + 1e-12 * np.eye(len(c))) for c in self._covs])
        draws = []
        for _ in range(self.samples):
            zk = center + np.einsum("bij,bj->bi", chol, rng.standard_normal(center.shape))
            pk = params.copy()
            pk[:, index] = (low + high) / 2 + np.clip(zk, -1, 1) * (high - low) / 2
            draws.append(horizon(pk))
        std = np.sqrt(np.mean((np.stack(draws) - mean[None]) ** 2, axis=0))  # (K, B, H, n_y) -> (B, H, n_y)
        return std if calibration is None else std * calibration.factors(std.shape[-2])[None]

    def _regress(self, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, prior=None,
                 anchor: np.ndarray | None = None) -> np.ndarray:
        """The catalogue robot's identified entries solved for, window by window (springs
        anchored at ``anchor``, default the first context sample)."""
        from robomorph.sim.regressor import RegressorIdentifier  # noqa: PLC0415

        if self._regressor is None:
            ident = self.backbone.ident
            self._regressor = RegressorIdentifier(self.backbone.recipe, ident.space, ident.randomizer, self.inputs,
                                                  iterations=self.iterations)
        self._regressor.iterations = self.iterations
        base = np.stack([self.backbone.catalogue(q) for q in (q_ctx[:, 0] if anchor is None else anchor)])
        out, self._covs = [], []
        for b in range(len(params)):
            out.append(self._regressor.fit(base[b], q_ctx[b], u_ctx[b], *((prior[0][b], prior[1][b]) if prior else ())))
            self._covs.append(self._regressor.last_cov)
        return np.stack(out)

    def _refine(self, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, qvel_start: np.ndarray) -> np.ndarray:
        from robomorph.sim.identify import Identifier, IdentifyConfig  # noqa: PLC0415

        if self._identifier is None:
            config = IdentifyConfig(kinds=REFINE_KINDS, max_iters=self.refine_iters)
            self._identifier = Identifier(self.backbone.recipe, self.inputs, config)
        self.last_fits = [self._identifier.fit(params[b], q_ctx[b], u_ctx[b], qvel_start[b]) for b in range(len(params))]
        return np.stack([f.params for f in self.last_fits])
