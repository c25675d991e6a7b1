"""Closed-loop horizons and contexts (commands to an arm compensating with its catalogue model) on the lean arm, on
threads: the numbers of the full arm's closed loop and of one context problem at a time, only sooner."""

from __future__ import annotations

import numpy as np
import pytest

CONTEXT = 40


@pytest.fixture(scope="module")
def nominal(simulated_store):
    """Two robots' windows of a store under catalogue gravity compensation, and its backbone's layout."""
    from robomorph.data.store import open_store
    from robomorph.identification.backbone import parameter_layout

    ds = open_store(simulated_store(robots=3, steps=CONTEXT + 70, seed=21, gravity_compensation="nominal_model"))
    u, y = ds.read_inputs("command").astype(np.float64), ds.read("y").astype(np.float64)
    return u, y, ds.read("params").astype(np.float64), parameter_layout(dict(ds.attrs))


def _full_arm_closed_loop(bb, params, qpos0, qvel0, torque):
    """What the backbone simulated before: the full arm (meshes, contacts) through the generator's closed loop."""
    from robomorph.sim import arms
    from robomorph.sim.closed_loop import formulation_controller, simulate_closed_loop
    from robomorph.sim.episode import NominalGravity
    from robomorph.sim.filters import SensorLayout

    import mujoco

    recipe = bb.recipe
    model = arms.get(recipe.robot).build_model(bb.substeps, recipe.dt, False)
    data = mujoco.MjData(model)
    bb.ident.randomizer.apply(model, params)
    torque = np.concatenate([torque, torque[-1:]])
    control = formulation_controller(torque, "command", False, len(qpos0), NominalGravity(recipe))
    sens = simulate_closed_loop(model, data, qpos0, len(torque), bb.substeps, control, qvel0,
                                (bb.FINE_STEPS, bb.coarse))
    return sens[:, SensorLayout.of_width(sens.shape[1]).qpos]  # the joints' sensors, float64


def test_closed_loop_horizons_are_the_full_arms_on_the_lean_arm_and_threads(nominal):
    from robomorph.identification.backbone import PhysicsBackbone, frame_torques

    u, y, params, layout = nominal
    q = y[:, :CONTEXT, 7:]
    qvel0 = (q[:, -1] - q[:, -2]) / 0.0167
    torque = frame_torques(u[:, :CONTEXT], u[:, CONTEXT:])  # 70 frames: the coarse step after the first 60
    with PhysicsBackbone(layout, "command", nthread=2) as bb:
        assert not bb.open_loop and bb.coarse != bb.substeps
        threaded = bb._closed_loops(params, q[:, -1], qvel0, torque)
        one = np.stack([bb._closed_loop(bb._closed_workers(1)[0], params[b], q[b, -1], qvel0[b], torque[b])
                        for b in range(len(params))])
        full = np.stack([_full_arm_closed_loop(bb, params[b], q[b, -1], qvel0[b], torque[b])
                         for b in range(len(params))])
    assert threaded.shape == (len(params), torque.shape[1] + 1, 7)
    np.testing.assert_array_equal(threaded, one)  # each robot on its own model and data: threads change nothing
    np.testing.assert_allclose(threaded, full, rtol=0, atol=1e-9)  # the lean arm steps a contact-free motion alike
    assert np.abs(threaded[:, -1] - threaded[:, 0]).max() > 1e-3  # the robots move


def test_closed_loop_contexts_batched_equal_one_problem_at_a_time(nominal):
    from robomorph.identification.backbone import PhysicsBackbone
    from robomorph.identification.identify import ContextProblem

    u, y, params, layout = nominal
    q, torque = y[:, :CONTEXT, 7:], u[:, :CONTEXT]
    qvel0 = np.zeros((len(q), 7))
    with PhysicsBackbone(layout, "command", nthread=2) as bb:
        end, residual = bb.context_rollouts(params, q, torque, qvel0)
        space = bb.ident.space
        for b in range(len(q)):
            problem = ContextProblem(bb.ident, params[b], q[b], torque[b], qvel0[b])
            err = problem.joint_error(space.to_unit(params[b][space.index])[None])
            np.testing.assert_array_equal(end[b], problem.last_qvel_end[0])
            np.testing.assert_array_equal(residual[b], -err.reshape(-1, 7))
    assert residual.shape == (len(q), CONTEXT - 1, 7) and np.abs(end).max() > 1e-3
