import copy

import mujoco
import numpy as np
import pytest

from robomorph.sim import panda
from robomorph.sim.closed_loop import diverged, simulate_closed_loop
from robomorph.sim.filters import FilterConfig, check
from robomorph.sim.open_loop import OpenLoopEngine

U_CONST = np.array([1.0, -2.0, 1.0, 0.5, 0.2, -0.1, 0.3])


def _pd_to_home(data, t):
    # Reads the state, so any mismatch in what the controller sees shows in the rows.
    return -20.0 * (data.qpos[:7] - panda.HOME_QPOS) - 2.0 * data.qvel[:7] + np.sin(0.1 * t)


def _sim(model, steps, substeps, controller, qpos0=panda.HOME_QPOS, data=None):
    data = data if data is not None else mujoco.MjData(model)
    return simulate_closed_loop(model, data, qpos0, steps, substeps, controller)


def _reference_loop(model, qpos0, steps, substeps, controller):
    """The documented semantics, written out with plain mj_step calls."""
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    data.qpos[:7] = qpos0
    mujoco.mj_forward(model, data)
    rows = []
    for t in range(steps):
        data.ctrl[:] = controller(data, t)
        mujoco.mj_step(model, data)
        rows.append(data.sensordata.copy())
        if substeps > 1:
            mujoco.mj_step(model, data, nstep=substeps - 1)
    return np.array(rows)


@pytest.mark.parametrize("controller", [lambda d, t: np.zeros(7), _pd_to_home], ids=["zero", "pd"])
def test_rows_equal_a_hand_written_mj_step_loop(nominal_model, controller):
    qpos0 = panda.HOME_QPOS + 0.05
    sens = _sim(nominal_model, 60, 8, controller, qpos0)
    ref = _reference_loop(nominal_model, qpos0, 60, 8, controller)
    assert sens.shape == (60, nominal_model.nsensordata) and sens.dtype == np.float64
    np.testing.assert_array_equal(sens, ref)


def test_constant_torque_matches_the_open_loop_engine(nominal_model):
    sens = _sim(nominal_model, 40, 8, lambda d, t: U_CONST)
    with OpenLoopEngine(nominal_model, 1, 8) as eng:
        sens_ol, _ = eng.run(lambda m, i: None, panda.HOME_QPOS[None], np.tile(U_CONST, (1, 40, 1)))
        ref = sens_ol[0][::8]
    np.testing.assert_allclose(sens, ref, rtol=0, atol=1e-12)


def test_first_row_is_the_initial_state_and_its_torque(nominal_model):
    data = mujoco.MjData(nominal_model)
    data.qvel[:] = 3.0  # leftovers from an earlier use must not leak in
    sens = _sim(nominal_model, 5, 4, lambda d, t: U_CONST, data=data)
    np.testing.assert_allclose(sens[0, panda.SENS_QPOS], panda.HOME_QPOS, atol=1e-12)
    # The recorded torque is the command plus the simulator's gravity compensation.
    probe = mujoco.MjData(nominal_model)
    probe.qpos[:] = panda.HOME_QPOS
    mujoco.mj_forward(nominal_model, probe)
    np.testing.assert_allclose(sens[0, panda.SENS_TAU], U_CONST + probe.qfrc_gravcomp, atol=1e-9)


def test_substeps_one_records_every_physics_step(nominal_model):
    a = _sim(nominal_model, 16, 1, _pd_to_home)
    b = _reference_loop(nominal_model, panda.HOME_QPOS, 16, 1, _pd_to_home)
    np.testing.assert_array_equal(a, b)


def test_controller_sees_the_frame_start_kinematics(nominal_model):
    seen = []

    def controller(data, t):
        seen.append(np.array(data.site_xpos[nominal_model.site("ee").id]))
        return U_CONST

    sens = _sim(nominal_model, 10, 8, controller)
    np.testing.assert_allclose(np.array(seen), sens[:, panda.SENS_EE_POS], atol=1e-12)


def test_non_finite_command_gives_nan_rows_from_that_frame(nominal_model):
    def controller(data, t):
        return U_CONST * (np.nan if t >= 20 else 1.0)

    data = mujoco.MjData(nominal_model)
    sens = _sim(nominal_model, 50, 8, controller, data=data)
    ref = _sim(nominal_model, 20, 8, lambda d, t: U_CONST)
    np.testing.assert_array_equal(sens[:20], ref)
    assert np.isnan(sens[20:]).all()
    assert diverged(data)
    assert check(sens, nominal_model.jnt_range[:7], FilterConfig()) == "nan"


def test_unstable_physics_gives_nan_rows(nominal_model):
    model = copy.deepcopy(nominal_model)
    model.dof_damping[:] = -20.0  # the implicit integrator's matrix is no longer positive
    sens = _sim(model, 30, 8, lambda d, t: np.zeros(7))
    assert np.isnan(sens[-1]).all()
    assert check(sens, model.jnt_range[:7], FilterConfig()) == "nan"


def test_rejects_empty_runs(nominal_model):
    with pytest.raises(ValueError, match="steps"):
        _sim(nominal_model, 0, 8, _pd_to_home)
    with pytest.raises(ValueError, match="substeps"):
        _sim(nominal_model, 5, 0, _pd_to_home)


def test_a_coarse_step_from_a_frame_on_keeps_the_rows_before_it_and_the_frame_durations(nominal_model):
    """``coarse=(k, s)``: rows up to frame k are the fine run's to the bit, later rows stay close to it (the same
    frames, simulated with a longer physics step), ``(k, substeps)`` is the fine run itself, and the model's own
    timestep is back afterwards."""
    step = nominal_model.opt.timestep
    fine = _sim(nominal_model, 90, 8, _pd_to_home)
    data = mujoco.MjData(nominal_model)
    same = simulate_closed_loop(nominal_model, data, panda.HOME_QPOS, 90, 8, _pd_to_home, coarse=(60, 8))
    np.testing.assert_array_equal(same, fine)
    coarse = simulate_closed_loop(nominal_model, data, panda.HOME_QPOS, 90, 8, _pd_to_home, coarse=(60, 2))
    assert nominal_model.opt.timestep == step
    np.testing.assert_array_equal(coarse[:61], fine[:61])
    assert not np.array_equal(coarse[61:], fine[61:])
    # The first sensors (the EE position and quaternion) under a physics step 4 times longer, 30 frames on: within
    # a millimetre and a milliradian.
    np.testing.assert_allclose(coarse[61:, :7], fine[61:, :7], atol=1e-3)
