"""The hybrid model's prediction: parameters read from the context, the robot simulated with them.

A model trained with ``--model.physics amortized`` carries a parameter head
(:meth:`robomorph.model.transformer.MetaModel.forward_params`) and, in its data record, the
parameter layout and the generator recipe of its training stores. Prediction:

1. the network reads the context (normalized as in training) and gives the mean and
   log-variance of each identifiable parameter in unit coordinates;
2. the parameters are estimated by one of three modes, and the robot with them is
   simulated over the horizon from the last context sample
   (:class:`robomorph.identification.backbone.PhysicsBackbone`):
   ``learned``, the parameter head's mean; ``regression``, bounded linear least-squares
   solves of the regressor form of the inverse dynamics (:mod:`robomorph.identification.regressor`,
   milliseconds) pulled weakly toward the catalogue; ``fused``, the same solve with the
   parameter head's Gaussian as its prior (the posterior mode: the network says what
   robots like this one usually are, the context's torques say what this one is);
   ``refined``, a few Gauss-Newton iterations of the rollout fit
   (:class:`robomorph.identification.identify.Identifier`) over the armature and friction losses
   (:data:`REFINE_KINDS`), started from the regression's estimate and pulled toward it;
   ``smoothed`` (total torques, where any simulation forward diverges), the regression's robot
   over the whole horizon at once, smoothed against the decoder's prediction
   (:mod:`robomorph.identification.smoother`);
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
from robomorph.core.names import PHYSICS_MODES
from robomorph.inference.hybrid_spread import default_points, draw_spread
from robomorph.inference.settings import HybridSettings

MODES = PHYSICS_MODES
# The modes that read the parameter head (a model trained with --model.physics amortized).
HEAD_MODES = ("learned", "fused")
# What ``refined`` fits over rollouts: the parameters the regression leaves least certain. Early
# steps follow the armature (the finite-difference accelerations the regression reads blur
# it), late ones the friction losses (piecewise linear, little seen in many contexts).
# Measured on 16 held-out robots: below identified_physics at every reported step from the
# trajectory start, at a sixth of its cost; refitting all 29 parameters was no better.
REFINE_KINDS = ("armature", "frictionloss")
# The modes whose estimate comes from the regression, and so knows which joints held still in the
# context: their prediction is the friction mixture of :mod:`robomorph.identification.stiction` (command formulation).
MIXED_MODES = ("regression", "fused", "refined")


class HybridError(RoboMorphError, ValueError):
    """A hybrid prediction that cannot be made; the message says what to do."""


class Hybrid:
    """The physics backbone of one trained model (reusable; :meth:`close` when done).

    Args:
        model: the :class:`robomorph.inference.checkpoint.TrainedModel` (with a parameter head).
        physics: the ``physics`` entry of the model's data record (layout and recipe).
        inputs: the formulation the model was trained on.
        settings: its knobs (:class:`robomorph.inference.settings.HybridSettings`; default: the record's, in
            effect); :meth:`apply` gives it others. The std's robots (``points``) default to the observer's
            start where it runs, else the covariance's columns.
    """

    def __init__(self, model, physics: dict, inputs: str, settings: HybridSettings | None = None):
        from robomorph.identification.backbone import PhysicsBackbone  # noqa: PLC0415  (MuJoCo only when used)
        from robomorph.identification.smoother import new_report  # noqa: PLC0415

        if model.config.n_params and model.config.n_params != len(physics["names"]):
            raise HybridError(f"the model's parameter head has {model.config.n_params} outputs but its record "
                              f"names {len(physics['names'])} parameters: the checkpoint is inconsistent")
        self.model, self.physics, self.inputs = model, physics, inputs
        self.backbone = PhysicsBackbone(physics, inputs)
        # The arm's joints: y is the EE pose (7 channels), then one angle per joint.
        self.n_joint = len(self.backbone.ident.randomizer.friction0)
        self._identifier = None
        self._regressor = None
        self._regressor_kinds: tuple[str, ...] = ()
        self._stiction = None
        self._held: np.ndarray | None = None  # (B, nj) of the last regression: joints that held still
        self._covs: list[np.ndarray] = []  # of the last regression: each window's estimate covariance
        self._offsets: np.ndarray | None = None  # (B, nj) of the last regression, where it identified them
        self._noise: np.ndarray | None = None  # (B,) the encoder noise measured in the last contexts (denoise)
        self._cov_space: tuple = ()  # the entries those cover: their indices in a parameter vector, their bounds
        self.smoothing = new_report()  # what mode ``smoothed`` did so far (robomorph.identification.smoother)
        self.last_fits: list = []
        default = HybridSettings.of_record(physics, inputs, getattr(model, "blend", None))
        self.apply(settings or default.in_effect(inputs, (physics.get("recipe") or {}).get("gravity_compensation")))

    def apply(self, settings: HybridSettings) -> None:
        """Predicts with ``settings`` from now on (the backbone's step, observer and candidates too)."""
        if settings.points is None:
            settings = settings.replace(points=default_points(settings.observer and self.inputs == "command"))
        self.settings = settings
        bb = self.backbone
        bb.coarse, bb.observe, bb.candidates = settings.substeps, settings.observer, settings.candidates

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
                mode: str = "regression", return_std: bool = False, calibration=None, anchor=None
                ) -> tuple[np.ndarray, np.ndarray | None]:
        """(B, H, n_y) mean prediction and, with ``return_std``, the std over robots around the estimate (:attr:`points`).

        Args:
            at_rest: bool or (B,) bools: the context opens its trajectory (the robot starts at rest); default False.
            mode: one of :data:`MODES`.
            calibration: a :class:`robomorph.inference.calibration.StdCalibration` of this
                mode's std (``robomorph calibrate``), applied to it; None: the raw spread.
            anchor: (B, 7) where each robot started (its springs' rest pose); default: the first context sample.

        Raises: HybridError: an unknown mode, or a simulated robot that diverged."""
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415
        from robomorph.identification.stiction import mixed_horizon  # noqa: PLC0415

        check_mode(self.model, mode)
        uc, yc, uq = (t.double().cpu().numpy() for t in (u_ctx, y_ctx, u_query))
        q_ctx, quat_last = yc[..., 7:7 + self.n_joint], yc[:, -1, 3:7]
        B = len(uc)
        rest = np.broadcast_to(np.asarray(False if at_rest is None else at_rest, dtype=bool), (B,))
        # Candidate torque sequences on one context (model-predictive control): the robot is
        # identified once and only the horizons are simulated per row.
        shared = B > 1 and bool(np.all(uc == uc[:1]) and np.all(yc == yc[:1]) and np.all(rest == rest[0]))
        one = slice(0, 1) if shared else slice(None)
        qvel_start = np.repeat(-estimate_velocity(q_ctx[one, ::-1], self.backbone.dt), B if shared else 1, axis=0)
        qvel_start[rest] = 0.0
        anchor = q_ctx[:, 0] if anchor is None else np.asarray(anchor, dtype=np.float64).reshape(B, -1)
        params, z, z_std = self._identify(u_ctx[one], y_ctx[one], mode, anchor[one], qvel_start[one])
        if solves_whole_horizon(self.model, mode):
            return self._smoothed(u_ctx, y_ctx, u_query, params, mode, return_std, calibration)
        uc, uq, q_ctx = self._as_identified(params, uc, uq, q_ctx, qvel_start, one)
        mixture = self._mixture(mode, params, q_ctx[one], uc[one], qvel_start[one])
        if mixture is not None:
            # The std's parameter draws go around each window's weighted mean member, not its most likely one: an
            # argmax jumps from member to member when two weights cross, and moved the std by up to 24 % between
            # CPUs whose last bits differ (issue 61); the weights are continuous in the context, so is their mean.
            params = np.stack([w @ m for m, w, _ in mixture])
            if shared:
                mixture = mixture * B  # the one context's members, for every candidate row

        def horizon(p: np.ndarray, kick: tuple[int, float] | None = None) -> np.ndarray:
            """(B, H, n_y) of robots ``p`` (a row each, or one for all on a shared context); ``kick``: the std's."""
            qvel_end = self.backbone.context_velocity(p, q_ctx[one], uc[one], qvel_start[one], kick)
            if shared:
                p, qvel_end = np.repeat(p, B, axis=0), np.repeat(qvel_end, B, axis=0)
            return self.backbone.simulate(p, q_ctx, uc, uq, qvel_start, quat_last, qvel_end)

        if mixture is not None:
            mean, mix_var = mixed_horizon(self.backbone, mixture, q_ctx, uc, uq, qvel_start, quat_last)
        else:
            mean, mix_var = horizon(params), None
        if mode == "blend":
            spread = (lambda: self._spread("regression", params, z, z_std, mean, horizon, None)) if return_std else None
            return _blend(self.model, u_ctx, y_ctx, u_query, mean, spread, calibration)
        if not np.all(np.isfinite(mean)):
            raise HybridError("the simulated robot diverged (non-finite outputs): check the torques' units and "
                              "scale, or predict with physics_mode 'none'")
        if not return_std or mix_var is None:
            return mean, self._spread(mode, params, z, z_std, mean, horizon, calibration) if return_std else None
        # The parameters' uncertainty about the members' weighted mean, and the friction's between members.
        std = np.sqrt(self._spread(mode, params, z, z_std, horizon(params), horizon, None) ** 2 + mix_var)
        return mean, std if calibration is None else calibration.scaled(std)

    def _as_identified(self, params: np.ndarray, uc: np.ndarray, uq: np.ndarray, q_ctx: np.ndarray,
                       qvel_start: np.ndarray, one: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The torques and context joints the identified robots are simulated with: less the offsets the
        regression found (``settings.offsets``), and with the contexts' ends denoised where noise was measured
        (``settings.denoise``, :func:`robomorph.identification.noise.denoised_context`); as given otherwise."""
        from robomorph.identification import extra_terms, noise  # noqa: PLC0415

        offsets = self._offsets
        if offsets is not None:
            full = offsets if len(offsets) == len(uc) else np.repeat(offsets, len(uc), axis=0)  # a shared context
            uc, uq = extra_terms.corrected(uc, full), extra_terms.corrected(uq, full)
        if self._noise is not None and np.any(self._noise > noise.NOISE_FLOOR):
            clean = noise.denoised_context(self.backbone, params, q_ctx[one], uc[one], qvel_start[one], self._noise)
            q_ctx = clean if len(clean) == len(q_ctx) else np.repeat(clean, len(q_ctx), axis=0)
        return uc, uq, q_ctx

    @property
    def covariances(self) -> list[np.ndarray]:
        """Each window's estimate covariance (n, n) in unit coordinates from the last regression (:meth:`identify`
        or :meth:`predict` in a mode that regresses): what the std's parameter draws sample from."""
        return list(self._covs)

    def _mixture(self, mode: str, params: np.ndarray, q_ctx: np.ndarray, uc: np.ndarray,
                 qvel_start: np.ndarray) -> list | None:
        """Per window, the friction mixture's ``(members, weights, qvel_end)``; None where it does
        not apply (total torques, modes without the regression, ``members`` 1, no joint held)."""
        from robomorph.identification.stiction import FrictionMixture  # noqa: PLC0415

        members = self.settings.members
        if members < 2 or self.inputs != "command" or mode not in MIXED_MODES or self._held is None \
                or not self._held.any():
            return None
        if self._stiction is None or self._stiction.members != members:
            self._stiction = FrictionMixture(self.backbone.ident, members)
        return [self._stiction.weigh(params[b], self._held[b], q_ctx[b], uc[b], qvel_start[b], self.backbone.observe)
                for b in range(len(params))]

    @torch.no_grad()
    def identify(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, mode: str = "regression",
                 anchor: np.ndarray | None = None, at_rest: bool = False) -> np.ndarray:
        """(B, P) the robots' full parameter vectors read from their contexts in ``mode``.

        What a model-predictive controller simulates its candidates with (the parameters
        change slowly, the candidates at every plan). Where joints held still in the context, the
        friction mixture's weighted mean (:mod:`robomorph.identification.stiction`). ``anchor``: (B, 7) where each robot
        started (its springs' rest pose); default: the first context sample.
        """
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415

        check_mode(self.model, mode)
        q_ctx = y_ctx.double().cpu().numpy()[..., 7:7 + self.n_joint]
        qvel_start = np.zeros_like(q_ctx[:, 0]) if at_rest else -estimate_velocity(q_ctx[:, ::-1], self.backbone.dt)
        params = self._identify(u_ctx, y_ctx, mode, q_ctx[:, 0] if anchor is None else anchor, qvel_start)[0]
        mixture = self._mixture(mode, params, q_ctx, u_ctx.double().cpu().numpy(), qvel_start)
        # One robot per context: the friction mixture's weighted mean (what the candidates are simulated with).
        return params if mixture is None else np.stack([w @ m for m, w, _ in mixture])

    def _identify(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, mode: str, anchor: np.ndarray,
                  qvel_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full parameter vectors (B, P), and the head's mean and std in unit coordinates."""
        uc = u_ctx.double().cpu().numpy()
        q_ctx = y_ctx.double().cpu().numpy()[..., 7:7 + self.n_joint]
        if mode not in HEAD_MODES:
            # The solve reads the context alone: the parameter head is not needed (nor run).
            z = z_std = np.zeros((len(uc), len(self.backbone.index)))
        else:
            z, z_std = self.parameters(u_ctx, y_ctx, u_ctx[:, :1])
        # The springs are anchored where the robot started: the first context sample when the context opens it.
        params = self.backbone.full_params(z, anchor)
        self._held, self._offsets, self._noise = None, None, None
        if self.settings.denoise and mode != "learned":
            from robomorph.identification.noise import encoder_noise  # noqa: PLC0415

            self._noise = np.array([encoder_noise(q) for q in q_ctx])
        if mode != "learned":
            prior = (z, z_std) if mode == "fused" else None
            params = self._regress(params, q_ctx, uc, prior, anchor, qvel_start)
        if mode == "refined":
            params = self._refine(params, q_ctx, uc, qvel_start)
        return params, z, z_std

    def _spread(self, mode: str, params: np.ndarray, z: np.ndarray, z_std: np.ndarray, mean: np.ndarray,
                horizon, calibration) -> np.ndarray:
        """The std (B, H, n_y): the horizons of robots drawn around the estimate, about ``mean``."""
        covs = None if mode == "learned" else self._covs
        space = (self.backbone.index, self.backbone.low, self.backbone.high) if covs is None else self._cov_space
        std = draw_spread(space, params, z_std, covs, mean, horizon, self.settings.samples, self.settings.seed,
                          self.settings.points)
        return std if calibration is None else calibration.scaled(std)

    def _refine(self, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, qvel_start: np.ndarray) -> np.ndarray:
        from robomorph.identification.identify import Identifier, IdentifyConfig  # noqa: PLC0415

        from robomorph.identification.identify import KINDS  # noqa: PLC0415

        kinds = KINDS if self.settings.refine_all else REFINE_KINDS
        if self._identifier is None or self._identifier.config.max_iters != self.settings.refine_iters \
                or self._identifier.config.kinds != kinds:
            if self._identifier is not None:
                self._identifier.close()
            config = IdentifyConfig(kinds=kinds, max_iters=self.settings.refine_iters)
            self._identifier = Identifier(self.backbone.recipe, self.inputs, config)
        self.last_fits = [self._identifier.fit(params[b], q_ctx[b], u_ctx[b], qvel_start[b]) for b in range(len(params))]
        return np.stack([f.params for f in self.last_fits])

    def _regress(self, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, prior=None,
                 anchor: np.ndarray | None = None, qvel_start: np.ndarray | None = None) -> np.ndarray:
        """The catalogue robot's identified entries solved for, window by window (springs anchored at ``anchor``, default
        the first context sample), debiased where the hybrid says so (commands, no prior; ``qvel_start``: (B, 7) the
        velocity at each context's first sample, where its simulation starts)."""
        from robomorph.identification.identify import GRAVITY_KINDS, KINDS, SPRING_KINDS  # noqa: PLC0415

        # Total torques pay gravity in the torque: the centres of mass are solved for as well (a
        # centimetre moves it by ~0.1 N m), except under the head's prior, which does not name them.
        # With ``payload``, also commands to an arm that compensates with its catalogue model: the rest of gravity is
        # in the motion there.
        nominal = self.backbone.recipe.gravity_compensation == "nominal_model"
        payload = self.settings.payload and prior is None
        gravity = (self.inputs == "total" or (payload and nominal)) and prior is None
        kinds = (GRAVITY_KINDS if gravity else KINDS) + (SPRING_KINDS if self.settings.springs and prior is None else ())
        # What a real arm has beyond the robot's vector (robomorph.identification.extra_terms): the offsets' columns,
        # the friction beyond the box; not under the head's prior, which does not name them.
        extras = ("offsets",) if self.settings.offsets and prior is None else ()
        wide = self.settings.coulomb and prior is None
        self._build_regressor(kinds, extras, wide, payload)
        base = np.stack([self.backbone.catalogue(q) for q in (q_ctx[:, 0] if anchor is None else anchor)])
        out, self._covs, held = [], [], []
        debias = self.settings.debias and prior is None and qvel_start is not None  # (commands only: in effect)
        fits = []  # each window's solve, which the debiasing moves (robomorph.inference.debias); kept only for it
        # The layout's entries come first; the std's robots move those, and the springs where they were fitted
        # (the centres of mass of total torques stay at the estimate).
        n = len(self.backbone.index)
        space = self._regressor.space
        keep = np.r_[np.arange(n), np.flatnonzero([k.startswith(SPRING_KINDS) for k in space.names])]
        self._cov_space = (space.index[keep], space.low[keep], space.high[keep])
        noise = np.zeros(len(params)) if self._noise is None else self._noise
        offsets = []
        for b in range(len(params)):
            out.append(self._regressor.fit(base[b], q_ctx[b], u_ctx[b], *((prior[0][b], prior[1][b]) if prior else ()),
                                           noise=float(noise[b])))
            self._covs.append(self._regressor.last_cov[np.ix_(keep, keep)])
            held.append(self._regressor.last_held)
            offsets.append(self._regressor.last_extra["offsets"])
            if debias:
                fits.append(self._regressor.last_fit)
        self._held = np.stack(held)
        self._offsets = np.stack(offsets) if extras else None
        out = np.stack(out)
        if debias:
            from robomorph.identification.extra_terms import corrected  # noqa: PLC0415
            from robomorph.identification.noise import NOISE_FLOOR  # noqa: PLC0415
            from robomorph.inference.debias import debiased  # noqa: PLC0415

            # The bias is measured on the estimate's robot simulated under the torques it feels (less its offsets),
            # by the same solve; a noisy context's solve smooths what the simulated one would not: left as it is.
            rows = np.flatnonzero(noise <= NOISE_FLOOR)
            if len(rows):
                torque = corrected(u_ctx[rows], None if self._offsets is None else self._offsets[rows])
                out[rows] = debiased(self.backbone, self._regressor, out[rows], q_ctx[rows], torque, qvel_start[rows],
                                     [fits[i] for i in rows])
        return out

    def _build_regressor(self, kinds: tuple, extras: tuple, wide: bool, payload: bool):
        """The regression's solver for these kinds and terms (kept while they stay the same): the one solver that
        both a context's identification and one over a robot's training recordings (:meth:`identify_recordings`) run."""
        from robomorph.identification.identify import KINDS, ParameterSpace  # noqa: PLC0415
        from robomorph.identification.regressor import RegressorIdentifier  # noqa: PLC0415

        if self._regressor is None or self._regressor_kinds != (kinds, extras, wide, payload):
            from robomorph.identification.extra_terms import friction_space, payload_space  # noqa: PLC0415

            ident = self.backbone.ident
            space = ParameterSpace.of(ident.randomizer, self.backbone.recipe.randomization, kinds) \
                if kinds != KINDS else ident.space
            if wide:
                space = friction_space(space, ident.randomizer, self.backbone.recipe.randomization)
            if payload:
                space = payload_space(space, ident.randomizer, ident.model)
            self._regressor = RegressorIdentifier(self.backbone.recipe, space, ident.randomizer, self.inputs,
                                                    iterations=self.settings.iterations, extras=extras,
                                                    relinearize_com=payload)
            self._regressor_kinds = (kinds, extras, wide, payload)
        self._regressor.iterations = self.settings.iterations
        return self._regressor

    @property
    def regressor(self):
        """The regression solver the last identification ran (its data, inverse dynamics and residuals), or None
        before any: what :class:`robomorph.inference.recordings.RecordingsPredictor` keeps after
        :meth:`identify_recordings`."""
        return self._regressor

    def identify_recordings(self, q: list[np.ndarray], torque: list[np.ndarray], reference: int | None = None,
                            drift: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One robot from many recordings of it: ``(params (P,), offsets (nj,))``, the regression's solve
        (:meth:`_regress`'s solver, kinds and terms as the settings say, constant torque offsets always) fed with every
        recording's rows at once, as a robot's identification run is (the Kinova source's own code fits all its
        trajectories together). ``q``: each recording's joints (T, nj); ``torque``: its torques, in the model's
        formulation. The springs are left out: they pull toward where one context started, which many do not share.
        Noisy recordings are smoothed one by one where ``denoise`` is on (:mod:`robomorph.identification.noise`).

        ``reference``: samples of one context. The solve's pull toward the catalogue is per row of data, so it would
        bias a fit over many recordings as much as one over a context; with ``reference`` it is as strong in all as
        over that many samples, and more data outweigh it as a prior should be (None: the context's pull per row).
        ``drift``: each recording has its own offsets (projected out of the solve: one offset for all would leave each
        recording's departure from it to the robot's entries), and the offsets returned are their mean over the
        rows; False: one offset for all, solved for with the rest."""
        from robomorph.identification.identify import GRAVITY_KINDS, KINDS  # noqa: PLC0415
        from robomorph.identification.noise import encoder_noise  # noqa: PLC0415

        nominal = self.backbone.recipe.gravity_compensation == "nominal_model"
        payload = self.settings.payload
        gravity = self.inputs == "total" or (payload and nominal)
        regressor = self._build_regressor(GRAVITY_KINDS if gravity else KINDS, ("offsets",), self.settings.coulomb,
                                          payload)
        q = [np.asarray(p, dtype=np.float64)[:, :self.n_joint] for p in q]
        noise = [encoder_noise(p) if self.settings.denoise else 0.0 for p in q]
        kept = regressor.prior
        if reference is not None:
            regressor.prior = kept * float(np.sqrt(min(1.0, reference / sum(len(p) for p in q))))
        try:
            params = regressor.fit(self.backbone.catalogue(q[0][0]), q, list(torque), noise=noise, piece_offsets=drift)
        finally:
            regressor.prior = kept  # the contexts' own solves keep theirs
        if not drift:
            return params, regressor.last_extra["offsets"].copy()
        residual = regressor.residual(params, regressor.data(q, list(torque), noise))
        return params, residual.mean(axis=0)

    def simulate_identified(self, params: np.ndarray, offsets: np.ndarray | None, u_ctx, y_ctx,
                            u_query) -> np.ndarray:
        """(B, H, n_y) robot ``params`` (P,) simulated over each horizon from its context's end, the torques less
        ``offsets`` ((nj,) or (B, nj); None: none), its velocity observed and its start denoised as :meth:`predict`
        does: the prediction of a robot identified elsewhere (over its training recordings), nothing fitted here."""
        from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415
        from robomorph.identification.noise import encoder_noise  # noqa: PLC0415

        uc, yc, uq = (np.asarray(a.cpu() if isinstance(a, torch.Tensor) else a, dtype=np.float64)
                      for a in (u_ctx, y_ctx, u_query))
        q_ctx, quat_last = yc[..., 7:7 + self.n_joint], yc[:, -1, 3:7]
        B = len(uc)
        qvel_start = -estimate_velocity(q_ctx[:, ::-1], self.backbone.dt)
        p = np.repeat(np.asarray(params, dtype=np.float64)[None], B, axis=0)
        self._offsets = None if offsets is None else np.broadcast_to(np.asarray(offsets, dtype=np.float64),
                                                                    (B, self.n_joint)).copy()
        self._noise = np.array([encoder_noise(q) for q in q_ctx]) if self.settings.denoise else None
        uc, uq, q_ctx = self._as_identified(p, uc, uq, q_ctx, qvel_start, slice(None))
        qvel_end = self.backbone.context_velocity(p, q_ctx, uc, qvel_start)
        out = self.backbone.simulate(p, q_ctx, uc, uq, qvel_start, quat_last, qvel_end)
        if not np.all(np.isfinite(out)):
            raise HybridError("the identified robot diverged (non-finite outputs): check the torques' units and "
                              "that the recordings it was identified on are of this arm")
        return out

    def record(self) -> tuple:
        """What the last call left about its windows: ``(held joints or None, estimate covariances, refined
        fits)``, for :meth:`merge` (a batch split over hybrids)."""
        return self._held, self._covs, self.last_fits

    def merge(self, records: list[tuple], refined: bool) -> None:
        """Takes the record of a whole batch from :meth:`record` of its parts, in order, as if this hybrid had
        predicted the batch alone. The refined fits only after a refined call: other modes leave
        ``last_fits`` as they found it."""
        held = [r[0] for r in records]
        self._held = np.concatenate(held) if all(x is not None for x in held) else None
        self._covs = [c for r in records for c in r[1]]
        if refined:
            self.last_fits = [f for r in records for f in r[2]]

    @torch.no_grad()
    def _smoothed(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, params: np.ndarray,
                  mode: str, with_std: bool, calibration) -> tuple[np.ndarray, np.ndarray | None]:
        """Mode ``smoothed``, or a blend of it (:mod:`robomorph.identification.smoother`): mean and std (B, H, n_y)."""
        from robomorph.identification.smoother import SmootherConfig, smooth_windows  # noqa: PLC0415

        if self.inputs != "total":
            raise HybridError("physics mode 'smoothed' is for total torques (their simulation diverges); in the "
                              "command formulation the simulation is stable: use 'regression'")
        mean, std = self.model.forward_dist_raw(u_ctx, y_ctx, u_query)
        if std is None:
            raise HybridError("physics mode 'smoothed' weighs the decoder by its standard deviation, and this model "
                              "has no Gaussian head: use 'regression' or 'none'")
        decoder, decoder_std = mean.double().cpu().numpy(), std.double().cpu().numpy()
        uc, yc, uq = (t.double().cpu().numpy() for t in (u_ctx, y_ctx, u_query))
        out, out_std = smooth_windows(self.backbone, params, yc[..., 7:7 + self.n_joint], uc, uq, yc[:, -1, 3:7], decoder,
                                      decoder_std, self.settings.smoother or SmootherConfig(), with_std,
                                      self.smoothing)
        if mode == "blend":
            out, out_std = self.model.blend.combine(out, decoder, out_std, decoder_std)
        return out, (None if not with_std else out_std if calibration is None else calibration.scaled(out_std))


def solves_whole_horizon(model, mode: str) -> bool:
    """Whether ``mode`` predicts the horizon as one smoothing problem (``smoothed``, or a blend of
    it), whose last steps have no later torque to pin them, rather than simulating it forward."""
    blend = getattr(model, "blend", None)
    return mode == "smoothed" or (mode == "blend" and blend is not None and blend.physics_mode == "smoothed")


def check_mode(model, mode: str) -> None:
    """Refuses a physics mode that ``model`` (a :class:`robomorph.inference.checkpoint.TrainedModel`) cannot run."""
    if mode not in MODES:
        raise HybridError(f"physics mode must be one of {MODES}, got {mode!r}")
    if mode in HEAD_MODES and not model.config.n_params:
        raise HybridError(f"physics mode {mode!r} reads a parameter head, which this model has not (it was "
                          "trained with --model.physics none): use 'regression' or 'blend'")
    if mode == "blend" and getattr(model, "blend", None) is None:
        raise HybridError("physics mode 'blend' needs the blend's weights, which this model has not: fit them "
                          "with robomorph calibrate --blend")


@torch.no_grad()
def _blend(model, u_ctx, y_ctx, u_query, physics: np.ndarray, spread, calibration):
    """The physics prediction and the decoder's, weighted by step and channel; with ``spread`` (a
    callable giving the physics' std), their std too."""
    mean, std = model.forward_dist_raw(u_ctx, y_ctx, u_query)
    decoder = mean.double().cpu().numpy()
    if spread is None:
        return model.blend.combine(physics, decoder)[0], None
    if std is None:
        raise HybridError("the blend's standard deviation needs the decoder's, and this model has no Gaussian "
                          "head: drop return_std")
    with np.errstate(invalid="ignore", over="ignore"):
        physics_std = spread()
    out, out_std = model.blend.combine(physics, decoder, physics_std, std.double().cpu().numpy())
    return out, out_std if calibration is None else calibration.scaled(out_std)
