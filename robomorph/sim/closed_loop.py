"""Closed-loop rollouts: a Python controller updates the torque once per recorded frame.

The recording convention is the open-loop one (:mod:`robomorph.sim.open_loop`): row ``t``
holds the sensor data MuJoCo computes in the forward pass at the start of frame ``t``,
that is the state at the frame start and the torque applied from it. The command is held
for the ``substeps`` physics steps of the frame (zero-order hold).

Each frame runs ``mj_step1`` (position and velocity stages for the current state),
asks the controller for the command, then ``mj_step2`` (actuation, acceleration,
integration). For the Euler and implicit integrators this is bit-for-bit ``mj_step``
with the command set first, and the controller sees up-to-date kinematics, Jacobian
inputs, the factorized mass matrix and the bias forces of the frame-start state instead of
those left over from the previous physics step.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

Controller = Callable[[mujoco.MjData, int], np.ndarray]
"""``controller(data, t) -> (nu,)`` torque command for frame ``t``.

When it is called, ``data`` holds the frame-start state with the position- and
velocity-dependent quantities already computed (``site_xpos``, ``qLD`` for
``mj_solveM``, ``qfrc_bias``, ...). It may return a buffer it reuses; the values are
copied into ``data.ctrl`` at once.
"""

# MuJoCo resets the data (to finite values) when it meets a bad qpos/qvel/qacc and zeroes
# a non-finite ctrl; the warning counters are the only trace left of the divergence.
# BADQPOS, BADQVEL, BADQACC and BADCTRL are consecutive: a slice reads them without copying.
_BAD_STATE_WARNINGS = slice(int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADCTRL) + 1)
assert _BAD_STATE_WARNINGS.stop - _BAD_STATE_WARNINGS.start == 4


def diverged(data: mujoco.MjData) -> bool:
    """Whether MuJoCo met a non-finite (or beyond ``mjMAXVAL``) state or command since reset."""
    return bool(data.warning.number[_BAD_STATE_WARNINGS].any())


def reset_to(model: mujoco.MjModel, data: mujoco.MjData, qpos0: np.ndarray,
             qvel0: np.ndarray | None = None) -> None:
    """Resets ``data`` to joint configuration ``qpos0`` (at rest unless ``qvel0``), runs the forward pass."""
    mujoco.mj_resetData(model, data)
    data.qpos[: len(qpos0)] = qpos0
    data.qvel[:] = 0.0
    if qvel0 is not None:
        data.qvel[: len(qvel0)] = qvel0
    mujoco.mj_forward(model, data)


def simulate_closed_loop(model: mujoco.MjModel, data: mujoco.MjData, qpos0: np.ndarray,
                         steps: int, substeps: int, controller: Controller,
                         qvel0: np.ndarray | None = None, coarse: tuple[int, int] | None = None) -> np.ndarray:
    """Simulates ``steps`` frames with one controller update per frame.

    Args:
        model: the (possibly randomized) model; its timestep is the physics step.
        data: scratch data for ``model``; it is reset here.
        qpos0: (nq,) or shorter initial joint positions; the robot starts at rest
            unless ``qvel0`` gives initial joint velocities.
        steps: recorded frames T.
        substeps: physics steps per frame (the command is held over them).
        controller: ``(data, t) -> (nu,)`` torque command, see :data:`Controller`.
        coarse: ``(frame, substeps)``: from that frame on, that many physics steps per frame, the
            physics step lengthened to match (the frame's duration kept); the model's timestep is
            restored before returning. None: ``substeps`` throughout.

    Returns:
        (T, nsensordata) float64 sensor data at the start of each frame. If the
        simulation diverges (MuJoCo flags a bad state or command) the rows from the frame
        where it was detected on are NaN, which the filters reject as ``"nan"``.
    """
    if steps < 1 or substeps < 1:
        raise ValueError(f"steps and substeps must be >= 1, got {steps}, {substeps}")
    out = np.empty((steps, model.nsensordata))
    reset_to(model, data, qpos0, qvel0)
    sens, ctrl = data.sensordata, data.ctrl
    timestep = model.opt.timestep
    switch, coarse_substeps = coarse if coarse is not None else (steps, substeps)
    rest = substeps - 1
    try:
        for t in range(steps):
            if t == switch and coarse_substeps != substeps:
                model.opt.timestep = timestep * substeps / coarse_substeps
                rest = coarse_substeps - 1
            mujoco.mj_step1(model, data)
            ctrl[:] = controller(data, t)
            mujoco.mj_step2(model, data)
            out[t] = sens
            if rest:
                mujoco.mj_step(model, data, nstep=rest)
            # One counter check per frame: the row of a frame that diverged in its later
            # substeps is kept out too, which errs on the side of rejecting.
            if diverged(data):
                out[t:] = np.nan
                break
    finally:
        model.opt.timestep = timestep
    return out


def formulation_controller(torque: np.ndarray, inputs: str, gravity_in_actuators: bool, n_joint: int,
                           catalogue_gravity: Callable[[np.ndarray], np.ndarray] | None = None) -> Controller:
    """``(data, t) -> ctrl`` that applies recorded torques ``torque`` (T, n) in a formulation.

    ``command``: the command as recorded; an arm that compensates its own gravity through its
    actuators (``true_model``) adds g(q) each substep by itself, and ``catalogue_gravity``
    (``nominal_model``) is added at each frame start. ``total``: the total joint torque; with
    the gravity compensation in the actuators, the part they are about to add back is taken
    off at the frame start.
    """
    nj = n_joint
    if inputs == "command":
        if catalogue_gravity is None:
            return lambda data, t: torque[t]
        return lambda data, t: torque[t] + catalogue_gravity(data.qpos[:nj])
    if gravity_in_actuators:
        return lambda data, t: torque[t] - data.qfrc_gravcomp[:nj]
    return lambda data, t: torque[t]


StepController = Callable[[mujoco.MjData, int], np.ndarray]
"""``controller(data, k) -> (nu,)`` torque sent at physics step ``k`` (frame ``k // substeps``),
called after ``mj_step1`` as :data:`Controller` is; a frame-rate controller returns a held value."""


def simulate_substeps(model: mujoco.MjModel, data: mujoco.MjData, qpos0: np.ndarray, steps: int,
                      substeps: int, controller: StepController, latency: int = 0,
                      idle: np.ndarray | None = None,
                      passive: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulates ``steps`` frames with Python at every physics step (the realism terms' engine).

    Row ``k`` is the sensor data of physics step ``k`` (the state at its start and the torque
    applied from it), the convention of :func:`simulate_closed_loop` and of ``mujoco.rollout``
    at every physics step.

    Args:
        model, data, qpos0, steps, substeps: as :func:`simulate_closed_loop`.
        controller: the torque sent at each physics step, see :data:`StepController`.
        latency: physics steps between sending a torque and its effect on the motors.
        idle: (nu,) torque acting before the first command arrives (default zeros), e.g. the
            gravity compensation holding the arm at rest.
        passive: ``qvel -> (nv,)`` joint force added at every physics step (friction).

    Returns:
        sens (steps * substeps, nsensordata) and the torques sent (steps * substeps, nu); rows
        from a diverged frame on are NaN (rejected as ``"nan"``).
    """
    if steps < 1 or substeps < 1 or latency < 0:
        raise ValueError(f"steps and substeps must be >= 1 and latency >= 0, got {steps}, {substeps}, {latency}")
    total = steps * substeps
    sens, sent = np.empty((total, model.nsensordata)), np.empty((total, model.nu))
    reset_to(model, data, qpos0)
    # queue[k % (latency + 1)] holds what was sent at step k - latency - 1, ... : a ring buffer.
    queue = np.tile(np.zeros(model.nu) if idle is None else np.asarray(idle, dtype=np.float64), (latency + 1, 1))
    for t in range(steps):
        for s in range(substeps):
            k = t * substeps + s
            mujoco.mj_step1(model, data)
            sent[k] = controller(data, k)
            queue[k % (latency + 1)] = sent[k]
            # The slot written latency steps ago: the oldest one, next after this step's.
            data.ctrl[:] = queue[(k + 1) % (latency + 1)] if latency else sent[k]
            if passive is not None:
                data.qfrc_applied[:] = passive(data.qvel)
            mujoco.mj_step2(model, data)
            sens[k] = data.sensordata
        if diverged(data):
            sens[t * substeps:] = np.nan
            break
    return sens, sent
