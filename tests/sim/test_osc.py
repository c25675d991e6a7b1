import mujoco
import numpy as np
import pytest

from robomorph.core.config import from_dict
from robomorph.sim import osc, panda, paths
from robomorph.sim.filters import FilterConfig, check, continuous_quaternion

DT = 1 / 60


def _rms_mm(sens, target, settle=30):
    err = np.linalg.norm(sens[settle:, panda.SENS_EE_POS] - target[settle:], axis=1)
    return 1e3 * np.sqrt(np.mean(err**2))


def _run(model, task, seed, steps, cfg=osc.OSCConfig(), path_cfg=None, qpos0=panda.HOME_QPOS, **kw):
    path_cfg = path_cfg or (paths.CircleConfig() if task == "circle" else paths.SpiralConfig())
    return osc.simulate_osc(model, mujoco.MjData(model), qpos0, task, np.random.default_rng(seed),
                            steps, 8, DT, cfg, path_cfg, **kw)


# --- configs ---------------------------------------------------------------------------

@pytest.mark.parametrize("make, field", [
    (lambda: osc.OSCConfig(kp=0.0), "osc.kp"),
    (lambda: osc.OSCConfig(kd=-1.0), "osc.kd"),
    (lambda: osc.OSCConfig(kp_range=(5.0, 1.0)), "osc.kp_range"),
    (lambda: osc.OSCConfig(kp_range=(0.0, 1.0)), "osc.kp_range"),
    (lambda: osc.OSCConfig(kp_rot=-2.0), "osc.kp_rot"),
    (lambda: osc.OSCConfig(kp_null=-1.0), "osc.kp_null"),
    (lambda: osc.OSCConfig(max_task_inertia=0.0), "osc.max_task_inertia"),
    (lambda: paths.CircleConfig(radius=(0.2, 0.1)), "circle.radius"),
    (lambda: paths.CircleConfig(radius=(0.0, 0.1)), "circle.radius"),
    (lambda: paths.CircleConfig(period=0.0), "circle.period"),
    (lambda: paths.SpiralConfig(period=(8.0, 2.0)), "spiral.period"),
    (lambda: paths.SpiralConfig(climb=(-0.1, 0.2)), "spiral.climb"),
    (lambda: paths.SpiralConfig(ramp=-1.0), "spiral.ramp"),
])
def test_invalid_configs_name_the_field(make, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        make()


def test_configs_load_from_recipe_dicts():
    cfg = from_dict(osc.OSCConfig, {"kp_range": [1, 5], "kd": None, "coriolis": False})
    assert cfg.kp_range == (1.0, 5.0) and cfg.kd is None and cfg.coriolis is False
    assert from_dict(paths.SpiralConfig, {"climb": [0.1, 0.3]}).climb == (0.1, 0.3)


def test_random_kp_is_drawn_in_range_and_sets_critical_damping():
    cfg = osc.OSCConfig(kp_range=(1.0, 5.0))
    kps = [cfg.draw_kp(np.random.default_rng(s)) for s in range(20)]
    assert all(1.0 <= k <= 5.0 for k in kps) and len(set(kps)) == 20
    kp6, kd6 = cfg.gains(4.0)
    np.testing.assert_allclose(kd6[:3], 4.0)  # 2 sqrt(4)
    assert osc.OSCConfig().draw_kp(np.random.default_rng(0)) == 10.0


# --- closed loop -----------------------------------------------------------------------

def test_circle_is_tracked_to_millimetres_with_orientation_held(nominal_model):
    sens, target, kp = _run(nominal_model, "circle", 0, 300)
    assert sens.shape == (300, nominal_model.nsensordata) and target.shape == (300, 3)
    assert kp == 10.0
    np.testing.assert_allclose(target[0], sens[0, panda.SENS_EE_POS], atol=1e-12)
    assert _rms_mm(sens, target) < 3.0
    quat = continuous_quaternion(sens[:, panda.SENS_EE_QUAT])
    assert np.abs(quat - quat[0]).max() < 0.03  # about 3 degrees


def test_without_friction_feedforward_the_arm_lags(nominal_model):
    # Documents why joint_friction is on: the Panda's dry friction dominates kp = 10.
    sens, target, _ = _run(nominal_model, "circle", 0, 300, osc.OSCConfig(joint_friction=False))
    assert _rms_mm(sens, target) > 10.0


@pytest.mark.parametrize("task, seed", [("circle", 1), ("spiral", 2)])
def test_typical_trajectories_pass_the_filters(nominal_model, task, seed):
    qpos0 = panda.HOME_QPOS + np.random.default_rng(seed).uniform(-0.1, 0.1, 7)
    sens, target, _ = _run(nominal_model, task, seed, 1000, qpos0=qpos0)
    assert check(sens, nominal_model.jnt_range[:7], FilterConfig()) is None
    assert _rms_mm(sens, target) < 5.0


def test_simulate_osc_is_deterministic(nominal_model):
    a = _run(nominal_model, "spiral", 3, 120, osc.OSCConfig(kp_range=(1.0, 5.0)))
    b = _run(nominal_model, "spiral", 3, 120, osc.OSCConfig(kp_range=(1.0, 5.0)))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2] == b[2] and 1.0 <= a[2] <= 5.0


def _controller_at_rest(model, cfg=osc.OSCConfig(), path_offset=0.0, extra_torque=None):
    data = mujoco.MjData(model)
    pos0, quat0 = osc.start_pose(model, data, panda.HOME_QPOS)
    zeros = np.zeros((5, 3))
    ctrl = osc.OSCController(model, np.tile(pos0 + path_offset, (5, 1)), zeros, zeros, quat0,
                             panda.HOME_QPOS, cfg.kp, cfg, extra_torque)
    mujoco.mj_step1(model, data)
    return ctrl, data


def test_no_command_at_rest_on_target(nominal_model):
    ctrl, data = _controller_at_rest(nominal_model)
    np.testing.assert_allclose(ctrl(data, 0), 0.0, atol=1e-9)


def test_commands_are_clipped_and_extra_torque_added(nominal_model):
    far = np.array([0.0, 0.0, 0.3])
    ctrl, data = _controller_at_rest(nominal_model, osc.OSCConfig(kp=1e6), path_offset=far)
    u = ctrl(data, 0)
    assert np.all(np.abs(u) <= panda.TORQUE_LIMITS) and np.isclose(np.abs(u).max(), 87.0)
    extra = np.arange(7) * 0.1
    ctrl, data = _controller_at_rest(nominal_model, extra_torque=lambda q: extra)
    np.testing.assert_allclose(ctrl(data, 0), extra, atol=1e-9)


def test_task_and_config_mismatches_are_errors(nominal_model):
    with pytest.raises(ValueError, match="unknown OSC task"):
        _run(nominal_model, "square", 0, 10, path_cfg=paths.CircleConfig())
    with pytest.raises(TypeError, match="SpiralConfig"):
        _run(nominal_model, "spiral", 0, 10, path_cfg=paths.CircleConfig())
