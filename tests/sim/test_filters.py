import numpy as np
import pytest

from robomorph.sim import panda
from robomorph.sim.filters import FilterConfig, check, continuous_quaternion, to_outputs
from robomorph.sim.open_loop import OpenLoopEngine

CFG = FilterConfig()


def _rollout(model, ctrl, frames, qpos0=panda.HOME_QPOS):
    with OpenLoopEngine(model, 1, 8) as eng:
        sens, _ = eng.run(lambda m, i: None, qpos0[None], np.tile(ctrl, (1, frames, 1)))
    return sens[0].copy()


def test_quiet_rollout_is_valid(nominal_model):
    sens = _rollout(nominal_model, np.zeros(7), 120)
    assert check(sens, nominal_model.jnt_range[:7], CFG) is None


def test_forced_collision_is_rejected(nominal_model):
    # shoulder pitched forward hard: the arm folds onto the floor / itself
    sens = _rollout(nominal_model, np.array([0, 40.0, 0, 0, 0, 0, 0]), 240)
    assert sens[:, panda.SENS_CONTACTS].max() > 0
    assert check(sens, nominal_model.jnt_range[:7], CFG) == "contact"


def test_forced_joint_limit_is_rejected(nominal_model):
    # the last joint spins freely until its limit (no contact possible)
    sens = _rollout(nominal_model, np.array([0, 0, 0, 0, 0, 0, 3.0]), 240)
    assert sens[:, panda.SENS_CONTACTS].max() == 0
    assert check(sens, nominal_model.jnt_range[:7], CFG) == "joint_limit"


def test_saturation_is_rejected(nominal_model):
    sens = _rollout(nominal_model, np.array([0, 0, 0, 0, 0, 0, 11.5]), 3)
    tau = sens[:, panda.SENS_TAU]
    assert np.abs(tau[:, 6]).max() <= 12 + 1e-9  # the motor clamps at the real limit
    assert check(sens, nominal_model.jnt_range[:7], CFG) == "saturation"


def test_nan_and_quaternion_jump_are_rejected(nominal_model):
    sens = _rollout(nominal_model, np.zeros(7), 20)
    jr = nominal_model.jnt_range[:7]
    bad = sens.copy()
    bad[5, 0] = np.nan
    assert check(bad, jr, CFG) == "nan"
    jump = sens.copy()
    jump[10:, panda.SENS_EE_QUAT] = [0.5, 0.5, 0.5, 0.5]  # a different rotation, not a sign flip
    assert check(jump, jr, CFG) == "quaternion_jump"
    flip = sens.copy()
    flip[10:, panda.SENS_EE_QUAT] *= -1  # the same rotation: not a jump
    assert check(flip, jr, CFG) is None


def test_continuous_quaternion_removes_sign_flips():
    rng = np.random.default_rng(0)
    q = np.cumsum(rng.normal(0, 0.01, (200, 4)), axis=0) + [1, 0, 0, 0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    signs = np.where(rng.random(200) < 0.3, -1.0, 1.0)
    fixed = continuous_quaternion(q * signs[:, None])
    np.testing.assert_allclose(np.abs(fixed), np.abs(q))
    assert np.abs(np.diff(fixed, axis=0)).max() < 0.1
    assert fixed[0, 0] * q[0, 0] > 0 or signs[0] > 0


def test_outputs_layout(nominal_model):
    sens = _rollout(nominal_model, np.zeros(7), 10)[::8]
    u, y = to_outputs(sens)
    assert u.shape == (10, 7) and y.shape == (10, 14) and y.dtype == np.float32
    np.testing.assert_allclose(y[:, 7:], sens[:, panda.SENS_QPOS], atol=1e-6)
    wxyz = sens[:, panda.SENS_EE_QUAT]
    np.testing.assert_allclose(np.abs(y[:, 3:7]), np.abs(wxyz[:, [1, 2, 3, 0]]), atol=1e-6)


def test_bad_thresholds():
    with pytest.raises(ValueError, match="joint_margin"):
        FilterConfig(joint_margin=-1)
