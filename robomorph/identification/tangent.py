"""A planner's candidates on one robot from one state, cheaply: tangent-linear with dry friction.

A model-predictive controller asks for many candidate torque sequences from one state (the
issue's figure: 256 of 60 frames in 50 ms on 2 cores). Exactly, at the generator's physics step,
that is 123,000 MuJoCo steps (0.4-0.5 s here, two thirds of each step being the friction losses'
constraint solve). This module answers with one exact rollout and a linear model about it:

1. the candidates' mean is simulated exactly (the backbone's physics step);
2. the one-frame map about each of its frames is linearized by forward differences, twice: the
   robot as it is (``A, B``: sticking and sliding joints as the mean has them) and the robot
   without friction losses (``A0, B0``), all perturbed one-frame rollouts in one threaded call
   each (at :data:`JAC_SUBSTEPS` physics steps per frame);
3. each candidate is the mean plus its linear response (``dx' = A dx + B du``), in which the
   friction torque the linearization implies is read from the two maps (its velocity change
   less the frictionless one, through ``B0``'s velocity block) and held inside each joint's
   friction loss (a joint the mean holds still breaks loose when a candidate pushes harder than
   the friction loss), and a joint the mean slides whose velocity would cross zero under the
   mean's friction torque is stopped instead (its torque changed by what stops it, joint by joint,
   again inside the bound). A candidate in the mean's regime at every joint gets the plain
   tangent-linear answer; only the switches of dry friction, which no linearization follows,
   are corrected.

The maps are taken at every second frame (:data:`EVERY`), the first frames' at the mean's own
physics step (:data:`FINE_FRAMES`), and both robots' rollouts go in one threaded call. Measured
against the exact candidates (``benchmarks/candidates.py``, 4 held-out robots given their true
parameters, candidates the recorded torques plus white noise, joint RMS difference at frame 60):
0.21 mrad at 0.2 N m of noise and 1.1 mrad at 1 N m (the candidates' own spread there 2.7 and
13.7 mrad), against 0.91 and 6.6 for the plain tangent-linear model and 0.12 and 0.47 for the
exact rollouts at 2 physics steps per frame, in about 21 ms against their 109-153; at frame 1,
0.006 and 0.052 mrad.
"""

from __future__ import annotations

import numpy as np

# Physics steps per frame of the finite-difference maps (the mean itself runs at the backbone's step).
JAC_SUBSTEPS = 2
# The first frames' maps at the mean's own physics step (step 1: 0.021 -> 0.006 mrad at 0.2 N m, 0.129 -> 0.052
# at 1 N m, for 1-3 ms; four frames changed step 60 by under 0.02 mrad more for 4-5 ms).
FINE_FRAMES = 2
# The maps are taken at every EVERY-th frame and held over the frames between (measured against every frame:
# 0.205 -> 0.210 and 1.125 -> 1.134 mrad at frame 60, 27-37 -> 20-21 ms; every third: 0.218 and 1.173).
EVERY = 2
# Forward-difference step of the states and torques.
EPS = 1e-6
# A joint the mean slides in a frame: its friction torque at least this share of its friction loss.
# (0.5-0.9 measured alike; 0.98 let more reversals through at 1 N m of noise: 1.25 against 1.13 mrad.)
SLIDING = 0.7


def one_frame_maps(bb, robots: list, states: np.ndarray, torque: np.ndarray, every: int = 1,
                   substeps: int = JAC_SUBSTEPS) -> list:
    """Per robot of ``robots`` (full parameter vectors): ``(F, nx)`` the one-frame ends of the unperturbed
    rollouts from ``states`` (F + 1 full physics states) under ``torque`` (F, nj), and ``(F, nx, nx + nj)``
    their Jacobians ``[A | B]`` (nx = 2 nj: joint positions and velocities), taken at every ``every``-th
    frame and held over the frames between; all robots' rollouts in one threaded call."""
    frames, nj = torque.shape
    nx, per = 2 * nj, 1 + 3 * nj  # the unperturbed rollout, then one per state and torque component
    at = np.arange(0, frames, every)
    x0 = np.repeat(states[at, None], per, axis=1)
    x0[:, 1:1 + nx, 1:1 + nx] += EPS * np.eye(nx)  # state: time, qpos, qvel, ...
    ctrl = np.repeat(torque[at, None], per, axis=1)
    ctrl[:, 1 + nx:] += EPS * np.eye(nj)
    # Then the unperturbed rollouts of the frames between (their ends are each frame's own).
    rest = np.setdiff1d(np.arange(frames), at)
    x0 = np.concatenate([x0.reshape(-1, x0.shape[2]), states[rest]])
    ctrl = np.concatenate([ctrl.reshape(-1, nj), torque[rest]])
    models = bb.ident.engine.models[:len(robots)]
    for model, params in zip(models, robots):
        bb.ident.randomizer.apply(model, params)
        model.opt.timestep = bb.dt / substeps
    n = len(x0)
    end = np.empty((len(robots) * n, substeps, x0.shape[1]))
    try:
        bb.ident.engine.rollout([m for m in models for _ in range(n)], np.ascontiguousarray(np.tile(x0, (len(robots), 1))),
                          np.repeat(np.tile(ctrl, (len(robots), 1))[:, None], substeps, axis=1), state=end)
    finally:
        for model in models:
            model.opt.timestep = bb.ident.model.opt.timestep
    out = []
    for r in range(len(robots)):
        e = end[r * n:(r + 1) * n, -1, 1:1 + nx]
        grid = e[:len(at) * per].reshape(len(at), per, nx)
        base = np.empty((frames, nx))
        base[at], base[rest] = grid[:, 0], e[len(at) * per:]
        jac = ((grid[:, 1:] - grid[:, :1]) / EPS).transpose(0, 2, 1)
        out.append((base, jac[np.minimum(np.arange(frames) // every, len(at) - 1)]))
    return out


def candidate_joints(bb, params: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """(K, F + 1, nj) joint positions of K candidates (K, F, nj) of torques on one robot (``params``,
    a full parameter vector) from one state, row 0 the start (module docstring)."""
    k, frames, nj = torque.shape
    nx = 2 * nj
    ref = torque.mean(axis=0)
    states = bb.frame_states(params[None], qpos0[None], qvel0[None], ref[None])[0]
    mean = states[:, 1:1 + nx]
    bound = bb.ident.randomizer.split(params)["frictionloss"]
    free = params.copy()
    bb.ident.randomizer.split(free)["frictionloss"][:] = 0.0  # a view: the robot without friction losses
    (_, jac), (end0, jac0) = one_frame_maps(bb, [params, free], states, ref, EVERY)
    # The first frames at the mean's own physics step: a coarse map's error is largest against the spread there.
    fine = FINE_FRAMES
    (_, jac[:fine]), (end0[:fine], jac0[:fine]) = one_frame_maps(bb, [params, free], states[:fine + 1], ref[:fine], 1,
                                                                 bb.substeps)
    vel = jac0[:, nj:, nx:]  # (F, nj, nj): the velocity change per unit of joint torque over a frame
    vel_inv = np.linalg.inv(vel)
    # The mean's own friction torque per frame: its velocity change less the frictionless one's.
    held = np.clip(np.einsum("fij,fj->fi", vel_inv, mean[1:, nj:] - end0[:, nj:]), -bound, bound)
    sliding = np.abs(held) >= SLIDING * bound
    diag = np.einsum("fjj->fj", vel)
    # One product a frame gives the linear response and the friction torque it implies (its velocity change less
    # the frictionless one's, through vel_inv): (F, nx + nj, nx + nj).
    implied_map = np.einsum("fij,fjk->fki", vel_inv, (jac - jac0)[:, nj:])
    both = np.concatenate([jac.transpose(0, 2, 1), implied_map], axis=2)
    push = jac0[:, :, nx:].transpose(0, 2, 1)  # (F, nj, nx): a torque change's effect on the frame's end
    xu = np.zeros((k, nx + nj))  # the deviation of state and torque from the mean's
    du = torque - ref
    out = np.empty((k, frames + 1, nj))
    out[:, 0] = mean[0, :nj]
    for t in range(frames):
        xu[:, nx:] = du[:, t]
        step = xu @ both[t]
        lin, implied = step[:, :nx], step[:, nx:] + held[t]  # the friction torque the linearization gives
        tau = np.minimum(np.maximum(implied, -bound), bound)
        moved = (tau - implied) @ push[t]
        v_end = mean[t + 1, nj:] + lin[:, nj:] + moved[:, nj:]
        # Friction opposes the motion: a sliding joint's torque has the sign opposite to its velocity, so
        # an end velocity of the torque's sign crossed zero: the joint is stopped instead (within the bound).
        crossed = sliding[t] & (np.sign(v_end) == np.sign(held[t])) & (v_end != 0)
        if crossed.any():
            stopped = np.minimum(np.maximum(np.where(crossed, tau - v_end / diag[t], tau), -bound), bound)
            moved += (stopped - tau) @ push[t]
        xu[:, :nx] = lin + moved
        out[:, t + 1] = mean[t + 1, :nj] + xu[:, :nj]
    return out
