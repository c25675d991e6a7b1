import mujoco
import numpy as np
import pytest

from robomorph.sim import panda


def _settle(model, qpos, steps=480, ctrl=None):
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    if ctrl is not None:
        data.ctrl[:] = ctrl
    mujoco.mj_step(model, data, nstep=steps)
    return data


def test_compiles_and_steps_without_warnings(nominal_model):
    data = _settle(nominal_model, panda.HOME_QPOS, steps=2000)
    assert all(w.number == 0 for w in data.warning)
    assert np.all(np.isfinite(data.qpos))
    assert nominal_model.opt.timestep == pytest.approx(1 / 480)


def test_sensors_equal_site_pose(nominal_model):
    m = nominal_model
    data = mujoco.MjData(m)
    data.qpos[:] = panda.HOME_QPOS + np.linspace(-0.3, 0.3, 7)
    mujoco.mj_forward(m, data)
    site = m.site("ee").id
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    np.testing.assert_allclose(data.sensordata[panda.SENS_EE_POS], data.site_xpos[site], atol=1e-12)
    # q and -q are the same rotation
    s = np.sign(quat @ data.sensordata[panda.SENS_EE_QUAT])
    np.testing.assert_allclose(data.sensordata[panda.SENS_EE_QUAT], s * quat, atol=1e-9)
    np.testing.assert_allclose(data.sensordata[panda.SENS_QPOS], data.qpos, atol=1e-12)


def test_actuator_limits_are_the_real_ones(nominal_model):
    m = nominal_model
    assert m.nu == 7
    np.testing.assert_array_equal(m.actuator_ctrlrange[:, 1], [87, 87, 87, 87, 12, 12, 12])
    np.testing.assert_array_equal(m.actuator_ctrlrange[:, 0], -m.actuator_ctrlrange[:, 1])
    np.testing.assert_array_equal(m.jnt_actfrcrange[:7, 1], panda.TORQUE_LIMITS)
    assert np.all(m.jnt_actfrclimited[:7]) and np.all(m.jnt_actgravcomp[:7])
    assert np.all(m.dof_damping[:7] >= 0)


def test_gravity_compensation_is_in_the_recorded_torque(nominal_model):
    """true_model: g(q) of the model itself is applied through the motors and recorded."""
    m = nominal_model
    data = _settle(m, panda.HOME_QPOS)
    np.testing.assert_allclose(data.qpos, panda.HOME_QPOS, atol=1e-3)  # holds still at zero command
    # recorded torque == gravity torque of the same model (qfrc_bias at zero velocity)
    probe = mujoco.MjData(m)
    probe.qpos[:] = data.qpos
    mujoco.mj_forward(m, probe)
    nograv = panda.build_model(gravity_compensation=False)
    ref = mujoco.MjData(nograv)
    ref.qpos[:] = data.qpos
    mujoco.mj_forward(nograv, ref)
    np.testing.assert_allclose(probe.sensordata[panda.SENS_TAU], ref.qfrc_bias, atol=1e-6)
    assert np.abs(ref.qfrc_bias).max() > 5  # a non-trivial gravity load


def test_without_compensation_the_arm_falls():
    m = panda.build_model(gravity_compensation=False)
    data = _settle(m, panda.HOME_QPOS)
    assert np.abs(data.qpos - panda.HOME_QPOS).max() > 0.1
    assert np.abs(data.sensordata[panda.SENS_TAU]).max() == 0  # nothing applied by the motors
