"""Total torques over a whole horizon: the identified robot's physics, smoothed against the decoder.

In the paper's formulation the recorded torque holds gravity paid at the *recorded* state, so
a simulation forward from the last context sample meets uncompensated gravity at every
deviation, and the deviation grows about tenfold every 57 steps: even the true robot leaves
the trajectory within seconds. The horizon is still determined, from both of its ends:

- the directions that the gravity makes stable are fixed by the last context state and
  remain so forward (a simulation follows them);
- the unstable ones are fixed by the *future*: the arm stayed on its trajectory because the
  controller paid gravity where the arm was, so the torques recorded after step ``k`` say where
  it was at ``k``, and an error there decays tenfold every 57 steps *backwards* in time.

So the horizon is estimated as a whole, as a nonlinear smoothing problem over the states
``x_k = (q_k, v_k)`` at query steps 0..H (step 0: the last context sample):

    minimize  |x_0 - x0|^2_P0  +  sum_k |x_{k+1} - F_k(x_k)|^2_Q  +  sum_k |q_k - d_k|^2_R_k

with ``F_k`` one sample of the identified robot's physics under the recorded torque (the
generator's gravity compensation: the command ``u_k - g(q_k)`` held over the sample, gravity
compensated through the actuators at every physics step), ``Q`` the model's error per sample
and ``d_k`` the decoder's prediction with its standard deviation (inflated by ``alpha``: its
errors are correlated over many steps, where the smoother takes them as independent). The
decoder anchors the unstable directions near the end of the horizon. Levenberg-Marquardt
Gauss-Newton steps are each a Rauch-Tung-Striebel smoother over the linearized frames, whose
Jacobians are finite differences in one threaded ``mujoco.rollout`` call; started at the
decoder, its weight lowered in stages (``alphas``). The smoothed covariance gives the std.
"""

from __future__ import annotations

import copy
import dataclasses

import mujoco
import numpy as np
from robomorph.core.errors import RoboMorphError
from robomorph.core.progress import progress
from robomorph.identification.kalman import rts

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


class SmootherError(RoboMorphError, ValueError):
    """Smoother settings or inputs that cannot work; the message says what to change."""


@dataclasses.dataclass(frozen=True)
class SmootherConfig:
    """How the horizon is smoothed.

    Attributes:
        q_std, v_std: the model's error per sample in joint position [rad] and velocity [rad/s].
        q0_std, v0_std: the last context state's uncertainty (positions recorded, velocity estimated).
            Screened on 16 robots of another store with a half-trained decoder (2e-3, 5e-4, 2e-4):
            2e-4 kept the first step at 0.03 mrad against 0.19, and 0.25 s / 1 s at 0.60 / 1.70
            against 1.22 / 2.23, the rest of the horizon unchanged.
        alphas: the decoder's standard deviation is multiplied by each in turn (its errors are
            correlated over steps; the last is the weight of the answer).
        iterations: most Gauss-Newton steps per stage.
        tol: a stage ends when a step lowers the cost by less than this fraction.
        jacobian_substeps: physics steps per sample of the Jacobians' rollouts (None: the recipe's).
        grow, fail_cost: where the solve ends with a cost above ``fail_cost`` per decoder
            measurement, the decoder was too far from any path the physics allows for Gauss-Newton
            to start from it (out of distribution: chirp torques); the horizon is then solved
            again over its first ``grow`` steps, then ``grow`` more, ..., each stage started from
            the last one's answer and the physics forward from its end (a forward simulation
            leaves only tenfold per 57 steps), the lower cost kept; 0: never. Per measurement: at most
            761 in distribution (there stages found lower-cost, worse paths), 7e4 and more on stalled chirp.
        handover: a smoothed path that leaves the joint range the recorded robots stay inside (the
            generator discards trajectories that come near a limit) has fallen where nothing
            holds it (a decoder out of distribution, unsure of itself); from the last step before
            it left at which it agreed with the decoder within this many decoder stds, the
            window is the decoder's (:func:`handover_steps`).
    """

    q_std: float = 1e-6
    v_std: float = 1e-4
    q0_std: float = 1e-6
    v0_std: float = 2e-4
    alphas: tuple[float, ...] = (1.0, 3.0, 8.0)
    iterations: int = 4
    tol: float = 1e-2
    jacobian_substeps: int | None = None
    grow: int = 100
    fail_cost: float = 1e4
    handover: float = 5.0

    def __post_init__(self):
        stds = (self.q_std, self.v_std, self.q0_std, self.v0_std)
        if not all(np.isfinite(s) and s > 0 for s in stds):
            raise SmootherError(f"smoother standard deviations must be positive, got {stds}")
        if not self.alphas or min(self.alphas) <= 0:
            raise SmootherError(f"smoother alphas must be positive, got {self.alphas}")
        if self.iterations < 1 or not 0 < self.tol < 1:
            raise SmootherError("smoother iterations must be >= 1 and 0 < tol < 1")
        if self.grow < 0 or not self.fail_cost > 0 or not self.handover > 0:
            raise SmootherError(f"smoother grow must be >= 0, fail_cost and handover > 0, got {self.grow}, "
                                f"{self.fail_cost}, {self.handover}")
        if self.jacobian_substeps is not None and self.jacobian_substeps < 1:
            raise SmootherError(f"jacobian_substeps must be >= 1, got {self.jacobian_substeps}")


class FrameMap:
    """One robot's physics over one sample under a total torque, for many states at once.

    Args:
        model: the lean arm (:func:`robomorph.identification.identify.lean_model`) of the recipe; copied.
        apply: ``apply(model)`` writes the robot's parameters into the copy.
        substeps: physics steps per sample (the recipe's).
        gravity_in_actuators: the recipe compensated gravity through the actuators
            (``true_model``): the command is then ``u - g(q)`` at the sample's start.
        rollout: a :class:`robomorph.sim.open_loop.ThreadedRollout` to run on.
    """

    def __init__(self, model: mujoco.MjModel, apply, substeps: int, gravity_in_actuators: bool, rollout):
        self.model = copy.deepcopy(model)
        apply(self.model)
        self.substeps, self.gravity_in_actuators, self._rollout = int(substeps), bool(gravity_in_actuators), rollout
        self._data = mujoco.MjData(self.model)
        self._size = mujoco.mj_stateSize(self.model, _STATE)
        mujoco.mj_resetData(self.model, self._data)
        self._template = np.empty(self._size)
        mujoco.mj_getState(self.model, self._data, self._template, _STATE)
        self.nq = self.model.nq
        self.timestep = float(self.model.opt.timestep)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """(N, nj) g(q) of each row (the bias force at rest: the velocity is never set, so zero)."""
        m, d = self.model, self._data
        out, bias = np.empty_like(q), np.empty(m.nv)
        nj = q.shape[1]
        for i, row in enumerate(q):
            d.qpos[:nj] = row
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_rne(m, d, 0, bias)
            out[i] = bias[:nj]
        return out

    def __call__(self, x: np.ndarray, torque: np.ndarray, substeps: int | None = None) -> np.ndarray:
        """(N, 2 nj) states [q, v] and (N, nj) torques at the sample's start -> the states one sample later."""
        n, nj = len(x), torque.shape[1]
        ss = int(substeps or self.substeps)
        x0 = np.repeat(self._template[None], n, axis=0)
        x0[:, 1:1 + nj], x0[:, 1 + self.nq:1 + self.nq + nj] = x[:, :nj], x[:, nj:]
        command = torque - self.gravity(x[:, :nj]) if self.gravity_in_actuators else torque
        state = np.empty((n, ss, self._size))
        try:
            self.model.opt.timestep = self.timestep * self.substeps / ss
            self._rollout([self.model] * n, x0, np.repeat(command[:, None], ss, axis=1), state=state)
        finally:
            self.model.opt.timestep = self.timestep
        out = np.empty_like(x)
        out[:, :nj], out[:, nj:] = state[:, -1, 1:1 + nj], state[:, -1, 1 + self.nq:1 + self.nq + nj]
        return out

    def linearize(self, x: np.ndarray, torque: np.ndarray, substeps: int | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """F(x_k) (H, n) and its Jacobians (H, n, n) by forward differences (one rollout call:
        the nominal rows at the recipe's step, the differences at ``substeps``)."""
        h, n = x.shape
        eps = np.r_[np.full(n // 2, 1e-6), np.full(n // 2, 1e-5)]
        rows = np.repeat(x[:, None], n + 1, axis=1)
        rows[:, 1:] += np.diag(eps)[None]
        nominal = self(x, torque)
        if substeps is None or substeps == self.substeps:
            moved = self(rows[:, 1:].reshape(-1, n), np.repeat(torque, n, axis=0)).reshape(h, n, n)
            base = nominal
        else:  # both ends of each difference at the coarse step
            both = self(rows.reshape(-1, n), np.repeat(torque, n + 1, axis=0), substeps).reshape(h, n + 1, n)
            moved, base = both[:, 1:], both[:, 0]
        jac = ((moved - base[:, None]) / eps[None, :, None]).transpose(0, 2, 1)
        return nominal, jac


class Smoother:
    """Smooths horizons of one robot (:class:`FrameMap`) against a decoder's predictions."""

    def __init__(self, frames: FrameMap, config: SmootherConfig = SmootherConfig()):
        self.frames, self.config = frames, config
        self.last_cost, self.last_steps = None, 0
        self.grown = False  # the last window's answer came from the horizon grown in stages

    def _cost(self, x, x0, w0, torque, d, wd, wq) -> float:
        r = x[1:] - self.frames(x[:-1], torque)
        nj = d.shape[1]
        return float(np.sum(r * r * wq) + np.sum((x[1:, :nj] - d) ** 2 * wd) + np.sum((x[0] - x0) ** 2 * w0))

    def __call__(self, q_last: np.ndarray, v_last: np.ndarray, torque: np.ndarray, decoder: np.ndarray,
                 decoder_std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The smoothed joint positions (H, nj) at query steps 1..H and their covariances (H, nj, nj).

        Args:
            q_last, v_last: (nj,) the last context sample and its velocity estimate.
            torque: (H, nj) the torques of samples 0..H-1 (the last context torque, then the query's).
            decoder, decoder_std: (H, nj) the decoder's joint positions at steps 1..H and their std.
        """
        cfg, frames = self.config, self.frames
        h, nj = decoder.shape
        if torque.shape != (h, nj) or decoder_std.shape != (h, nj):
            raise SmootherError(f"smoother needs torques and stds shaped as the decoder's {decoder.shape}, got "
                                f"{torque.shape} and {decoder_std.shape}")
        x0 = np.r_[q_last, v_last].astype(np.float64)
        w0 = 1.0 / np.r_[np.full(nj, cfg.q0_std), np.full(nj, cfg.v0_std)] ** 2
        wq = 1.0 / np.r_[np.full(nj, cfg.q_std), np.full(nj, cfg.v_std)] ** 2
        start = np.empty((h + 1, 2 * nj))
        start[0], start[1:, :nj] = x0, decoder
        start[1:, nj:] = np.gradient(np.concatenate([q_last[None], decoder]), frames.timestep * frames.substeps,
                                     axis=0)[1:]
        problem = (x0, w0, torque, decoder, decoder_std)
        self.last_steps, self.grown = 0, False
        x, cov, cost = self._solve(start, problem, wq, cfg.alphas)
        if cfg.grow and not cost <= cfg.fail_cost * h * nj:
            y, cov_y, cost_y = self._in_stages(problem, wq)
            if cost_y < cost:
                x, cov, cost, self.grown = y, cov_y, cost_y, True
        self.last_cost = cost
        return x[1:, :nj], cov[1:, :nj, :nj]

    def _in_stages(self, problem: tuple, wq: np.ndarray) -> tuple:
        """The horizon solved over its first ``grow`` steps, then ``grow`` more, ..., each stage at
        the first alpha (the decoder's strongest pull), started from the last one's answer and the
        physics forward from its end; then the whole horizon through all alphas: ``(x, cov, cost)``."""
        cfg = self.config
        x0, w0, torque, decoder, decoder_std = problem
        h = len(decoder)
        x, n = x0[None].copy(), int(cfg.grow)
        while True:
            n = min(n, h)
            ext = [x[-1]]
            for k in range(len(x) - 1, n):
                ext.append(self.frames(ext[-1][None], torque[k:k + 1])[0])
            x = np.concatenate([x, np.asarray(ext[1:]).reshape(-1, x.shape[1])])
            x = self._solve(x, (x0, w0, torque[:n], decoder[:n], decoder_std[:n]), wq, cfg.alphas[:1])[0]
            if n == h:
                return self._solve(x, problem, wq, cfg.alphas)
            n += int(cfg.grow)

    def _solve(self, x: np.ndarray, problem: tuple, wq: np.ndarray, alphas) -> tuple:
        """Levenberg-Marquardt Gauss-Newton from ``x`` (H + 1, 2 nj) with model-error weights
        ``wq``, the decoder's std scaled by each of ``alphas`` in turn: ``(x, cov, cost)``, the cost
        at the last alpha (where no step was taken, the covariance of the starting point)."""
        cfg, frames = self.config, self.frames
        x0, w0, torque, decoder, decoder_std = problem
        h, nj = decoder.shape
        q = np.diag(1.0 / wq)
        # Levenberg-Marquardt: a pull toward the linearization point of variance damp / lam.
        damp = 1.0 / np.r_[np.full(nj, 1e-2), np.full(nj, 1e-1)] ** 2
        nominal, jac = frames.linearize(x[:-1], torque, cfg.jacobian_substeps)
        cov, cost = None, np.inf
        for alpha in alphas:
            wd = 1.0 / (alpha * np.maximum(decoder_std, 1e-9)) ** 2
            cost, lam = self._cost(x, x0, w0, torque, decoder, wd, wq), 1.0
            for _ in range(cfg.iterations):
                weight = np.broadcast_to(lam * damp, (h + 1, 2 * nj)).copy()
                meas = x.copy()
                # The decoder's measurement and the damping's, of the same positions, as one.
                wpos = weight[1:, :nj] + wd
                meas[1:, :nj] = (weight[1:, :nj] * x[1:, :nj] + wd * decoder) / wpos
                weight[1:, :nj] = wpos  # (the prior on x_0 enters as the filter's start)
                trial, cov_trial = rts(x0, np.diag(1.0 / w0), nominal, jac, x[:-1], q, meas, weight)
                new = self._cost(trial, x0, w0, torque, decoder, wd, wq) if np.isfinite(trial).all() else np.inf
                if new < cost:
                    gain, cost, x, cov = cost - new, new, trial, cov_trial
                    lam = max(lam / 3, 1e-6)
                    self.last_steps += 1
                    nominal, jac = frames.linearize(x[:-1], torque, cfg.jacobian_substeps)
                    if gain < cfg.tol * cost:
                        break
                else:
                    lam *= 10
                    if lam > 1e4:
                        break
        if cov is None:  # the linearization at hand is the starting point's
            return x, rts(x0, np.diag(1.0 / w0), nominal, jac, x[:-1], q, x, np.zeros((h + 1, 2 * nj)))[1], cost
        # The covariance of the answer itself: linearized where the solve ended, the decoder's weights alone. The
        # accepted step's carried the Levenberg-Marquardt damping, whose size depends on how many trials were
        # accepted or refused: a one-ulp change of the context moved that std by a third (issue 61).
        weight = np.zeros((h + 1, 2 * nj))
        weight[1:, :nj] = wd
        meas = x.copy()
        meas[1:, :nj] = decoder
        return x, rts(x0, np.diag(1.0 / w0), nominal, jac, x[:-1], q, meas, weight)[1], cost


def smooth_windows(backbone, params: np.ndarray, q_ctx: np.ndarray, u_ctx: np.ndarray, u_query: np.ndarray,
                   quat_last: np.ndarray, decoder: np.ndarray, decoder_std: np.ndarray, config: SmootherConfig,
                   with_std: bool = True, report: dict | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Smoothed outputs (B, H, n_y) of windows of total torques, and their std (None without ``with_std``).

    Args:
        backbone: the :class:`robomorph.identification.backbone.PhysicsBackbone` (recipe, lean arm, rollout threads).
        params: (B, P) each window's robot, or (1, P) one robot for every row (candidates on one context).
        q_ctx, u_ctx: (B, Tc, 7) the contexts' joint positions and torques; u_query (B, H, 7).
        quat_last: (B, 4) the last context quaternion, whose sign the outputs keep.
        decoder, decoder_std: (B, H, n_y) the decoder's prediction and std (its joints are read).
        config: the smoother's settings (``jacobian_substeps`` None: the backbone's coarse step).
        report: a :func:`new_report` to add these windows to (how many, solved in stages, handed over).

    A window whose smoothing is not finite is its decoder's (mean and std).
    """
    from robomorph.core.velocity import estimate_velocity  # noqa: PLC0415
    from robomorph.identification.backbone import coarse_substeps, frame_torques, signed  # noqa: PLC0415

    b_n, h, nj = len(u_ctx), u_query.shape[1], q_ctx.shape[2]
    if config.jacobian_substeps is None:
        config = dataclasses.replace(config, jacobian_substeps=coarse_substeps(backbone.recipe))
    v_last, torque = estimate_velocity(q_ctx, backbone.dt), frame_torques(u_ctx, u_query)
    in_actuators = backbone.recipe.gravity_compensation == "true_model"
    randomizer, cols = backbone.ident.randomizer, slice(7, 7 + nj)
    q, cov = np.empty((b_n, h + 1, nj)), np.empty((b_n, h, nj, nj))
    q[:, 0] = q_ctx[:, -1]
    staged = 0
    for b in progress(range(b_n), "smoothing", unit="window"):  # seconds each
        p = params[min(b, len(params) - 1)]
        frames = FrameMap(backbone.ident.model, lambda m, p=p: randomizer.apply(m, p), backbone.substeps,
                          in_actuators, backbone.ident.engine.rollout)
        smoother = Smoother(frames, config)
        q[b, 1:], cov[b] = smoother(q_ctx[b, -1], v_last[b], torque[b], decoder[b, :, cols], decoder_std[b, :, cols])
        staged += smoother.grown
    out = signed(backbone.outputs(q), quat_last)[:, 1:]
    bad = ~np.isfinite(out).all(axis=(1, 2))
    out[bad] = decoder[bad]
    box = joint_box(backbone.ident.model, nj, backbone.recipe.filters.joint_margin)
    start = handover_steps(q[:, 1:], decoder[..., cols], decoder_std[..., cols], box, config.handover)
    after = np.arange(h)[None] >= start[:, None]  # (B, H): the decoder's steps
    out[after] = decoder[after]
    if report is not None:
        report["windows"] += b_n
        report["staged"] += staged
        report["handed_from"] += [int(k) + 1 for k in start[start < h]]  # 1-based steps
    if not with_std:
        return out, None
    std = output_std(backbone, q[:, 1:], cov)
    std[bad], std[after] = decoder_std[bad], decoder_std[after]
    return out, std


def new_report() -> dict:
    """An empty tally of :func:`smooth_windows`: windows, those solved in stages, and the (1-based)
    step from which each handed-over window is its decoder's."""
    return {"windows": 0, "staged": 0, "handed_from": []}


def joint_box(model: mujoco.MjModel, nj: int, margin: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The range (lo, hi) of the first ``nj`` joints that a stored trajectory stays inside: the
    limits less the generator's discard ``margin``; None where a joint has no limit."""
    if not model.jnt_limited[:nj].all():
        return None
    rng = np.asarray(model.jnt_range[:nj], dtype=np.float64)
    return rng[:, 0] + margin, rng[:, 1] - margin


def handover_steps(q: np.ndarray, decoder: np.ndarray, decoder_std: np.ndarray, box, gate: float) -> np.ndarray:
    """(B,) the first step index (0-based) from which each window is its decoder's; H where never.

    A window whose smoothed joints ``q`` (B, H, nj) leave ``box`` (lo, hi; None: no range) is
    handed over from the step after the last one, before it left, at which every joint lay within
    ``gate`` decoder stds of the decoder (from step 0 if none did)."""
    b_n, h = q.shape[:2]
    start = np.full(b_n, h)
    if box is None:
        return start
    out = ((q < box[0]) | (q > box[1])).any(axis=2)
    apart = (np.abs(q - decoder) > gate * decoder_std).any(axis=2)
    for b in np.flatnonzero(out.any(axis=1)):
        agreed = np.flatnonzero(~apart[b, :int(np.argmax(out[b]))])
        start[b] = agreed[-1] + 1 if len(agreed) else 0
    return start


def output_std(backbone, q: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(N, T, n_y) standard deviations of the outputs for joint positions ``q`` (N, T, 7) with
    covariances ``cov`` (N, T, 7, 7): the kinematics linearized (differences of 1e-6 rad)."""
    step = 1e-6
    y0 = backbone.outputs(q)
    jac = np.stack([(backbone.outputs(q + step * np.eye(q.shape[-1])[j]) - y0) / step
                    for j in range(q.shape[-1])], axis=-1)  # (N, T, n_y, 7)
    var = np.einsum("ntcj,ntjk,ntck->ntc", jac, cov, jac)
    return np.sqrt(np.maximum(var, 0.0))
