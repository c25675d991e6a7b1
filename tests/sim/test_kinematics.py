"""The vectorized site kinematics equals MuJoCo's own, row by row, signs included."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from robomorph.sim.kinematics import SiteKinematics, ee_pose

# A chain with what the Panda lacks: a tilted hinge axis, an anchor off the body's origin,
# a reference angle (qpos0) and a body without a joint between two with one.
_TILTED = """
<mujoco>
  <worldbody>
    <body pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2">
      <joint type="hinge" axis="0.3 -0.5 0.8" pos="0.05 -0.02 0.1" ref="0.4"/>
      <geom size="0.05"/>
      <body pos="0 0.3 0" euler="0.3 0.2 0.1">
        <geom size="0.05"/>
        <body pos="0.2 0 0.1">
          <joint type="hinge" axis="1 0 0" pos="0 0.1 0"/>
          <geom size="0.05"/>
          <site name="ee" pos="0.1 0.05 -0.2" euler="1 0.5 -0.3"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

_SLIDE = _TILTED.replace('type="hinge" axis="1 0 0"', 'type="slide" axis="1 0 0"')


def _mujoco_rows(model: mujoco.MjModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data, site = mujoco.MjData(model), model.site("ee").id
    pos, quat = np.empty((len(q), 3)), np.empty((len(q), 4))
    for t, qt in enumerate(q):
        data.qpos[:len(qt)] = qt
        mujoco.mj_kinematics(model, data)
        pos[t] = data.site_xpos[site]
        mujoco.mju_mat2Quat(quat[t], data.site_xmat[site])
    return pos, quat


@pytest.mark.parametrize("which", ["panda", "tilted"])
def test_site_kinematics_equals_mj_kinematics_with_its_quaternion_signs(which):
    from robomorph.sim import panda

    model = panda.build_model() if which == "panda" else mujoco.MjModel.from_xml_string(_TILTED)
    n = panda.N_JOINT if which == "panda" else model.nq
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (500, n))
    kin = SiteKinematics(model)
    assert kin.vectorized
    pos, quat = kin(q)
    ref_pos, ref_quat = _mujoco_rows(model, q)
    np.testing.assert_allclose(pos, ref_pos, atol=1e-12)
    np.testing.assert_allclose(quat, ref_quat, atol=1e-12)  # the same sign, row by row
    # Every one of mju_mat2Quat's four branches was exercised (trace > 0 iff w^2 > 1/4; else
    # the largest diagonal entry is that of the largest vector component).
    branch = np.where(ref_quat[:, 0] ** 2 > 0.25, 0, 1 + np.argmax(ref_quat[:, 1:] ** 2, axis=1))
    assert set(branch) == {0, 1, 2, 3}
    # Leading dimensions are kept.
    pos2, quat2 = kin(q.reshape(5, 100, n))
    np.testing.assert_array_equal(pos2.reshape(500, 3), pos)
    assert quat2.shape == (5, 100, 4)


def test_a_chain_with_other_joints_than_hinges_falls_back_to_mujoco():
    model = mujoco.MjModel.from_xml_string(_SLIDE)
    kin = SiteKinematics(model)
    assert not kin.vectorized
    q = np.random.default_rng(1).uniform(-1, 1, (20, model.nq))
    np.testing.assert_array_equal(np.concatenate(kin(q), axis=1), np.concatenate(_mujoco_rows(model, q), axis=1))


def test_ee_pose_keeps_the_quaternion_continuous_and_refuses_other_shapes():
    q = np.linspace(0, 2 * np.pi, 400)[:, None] * np.ones((1, 7))
    pose = ee_pose(q)
    assert pose.shape == (400, 7)
    assert np.abs(np.diff(pose[:, 3:], axis=0)).max() < 0.1  # no sign flips over a full turn
    with pytest.raises(ValueError, match="shape"):
        ee_pose(np.zeros((3, 6)))
