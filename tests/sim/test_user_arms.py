"""The user's own arms (robomorph.sim.user_arms, robomorph arms): URDFs written here, refusals, the registry."""

from __future__ import annotations

import json
import os

import mujoco
import numpy as np
import pytest

from robomorph import arms as arms_door
from robomorph.core.errors import MissingInputError, OutputExistsError
from robomorph.sim import arms, user_arms
from robomorph.sim.user_arms import ArmDescriptionError, ArmRequest
from tests.sim.urdf_factory import serial_arm, write


@pytest.fixture
def user_folder(tmp_path, monkeypatch):
    folder = tmp_path / "user_arms"
    monkeypatch.setenv(arms.USER_ARMS_ENV, str(folder))
    return folder


def _add(tmp_path, name: str, text: str, overwrite: bool = False, **kw) -> arms.Arm:
    return user_arms.add(ArmRequest(name, write(tmp_path / f"{name}.urdf", text), "urdf", **kw), overwrite=overwrite)


def _rotation(rpy) -> np.ndarray:
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx  # URDF: fixed axes x, then y, then z


def test_three_link_urdf_is_registered_and_compiled_as_written(tmp_path, user_folder):
    arm = _add(tmp_path, "three", serial_arm(3))
    assert arms.get("three") == arm and "three" in arms.names() and "three" in arms.ARMS
    assert arm.joint_names == ("joint1", "joint2", "joint3") and arm.hand == "tool"
    assert arm.torque_limits == (80.0, 70.0, 60.0)
    model = arm.build_model(gravity_compensation=False)
    assert (model.nq, model.nu, model.ngeom) == (3, 3, 1)  # the floor only: no geometry of the arm
    np.testing.assert_allclose(model.dof_damping, [0.3, 0.4, 0.5], atol=1e-12)
    np.testing.assert_allclose(model.dof_frictionloss, [0.05, 0.10, 0.15], atol=1e-12)
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], [80, 70, 60])
    # Inertials as the URDF writes them (rotated by their origin's rpy), to 1e-6.
    rng = np.random.default_rng(3)
    for k in range(3):
        b = model.body(f"link{k + 1}")
        d = rng.uniform(0.005, 0.02, 3)
        ixx, iyy, izz, ixy, ixz, iyz = d[1] + d[2], d[0] + d[2], d[0] + d[1], 0.1 * d[0], -0.05 * d[1], 0.02 * d[2]
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        rot = _rotation((0.05 * k, 0.0, 0.1))
        expected = rot @ tensor @ rot.T
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, b.iquat)
        mat = mat.reshape(3, 3)
        np.testing.assert_allclose(mat @ np.diag(b.inertia) @ mat.T, expected, atol=1e-6)
        assert b.mass[0] == pytest.approx(3.0 - 2.0 * k / 3, abs=1e-12)
        np.testing.assert_allclose(b.ipos, [0.01 * (k % 2), 0, 0.12], atol=1e-12)
    # The EE site sits on the tool link: straight up at q = 0 (0.1 + 2 x 0.25 + 0.1 m).
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("ee").xpos, [0, 0, 0.7], atol=1e-12)
    stored = json.loads((user_folder / "three" / "arm.json").read_text())
    assert stored["format"] == "urdf" and (user_folder / "three" / "model.urdf").is_file()
    assert "mesh" not in (user_folder / "three" / "model.urdf").read_text()


def test_six_link_urdf_with_a_gripper_welds_the_finger(tmp_path, user_folder):
    path = write(tmp_path / "six.urdf", serial_arm(6, gripper=True))
    with pytest.raises(ArmDescriptionError, match="joint 'finger_joint' .* is prismatic"):
        user_arms.add(ArmRequest("six", path, "urdf"))  # the deepest chain runs through the finger
    arm = user_arms.add(ArmRequest("six", path, "urdf", ee_link="tool"))
    assert arm.n_joint == 6 and arm.hand == "tool"
    model = arm.build_model()
    assert model.nq == 6 and model.body("finger").mass[0] == pytest.approx(0.05)
    assert arm.joint_gain.shape == (6,) and np.all(arm.joint_gain > 0)


def test_mjcf_of_a_shipped_arm_agrees_with_it(tmp_path, user_folder):
    """A public arm's description (robosuite's iiwa MJCF, MIT) added as a user arm: inertias and
    forward dynamics agree with the shipped arm to 1e-6 (contacts off: the user arm has no geometry)."""
    shipped = arms.get("iiwa")
    try:
        xml = arms.robosuite_xml(shipped.folder)
    except arms.AssetsMissingError:
        pytest.skip("robosuite's assets are not installed")
    mine = user_arms.add(ArmRequest("my_iiwa", xml, "mjcf", ee_link=shipped.hand, joints=shipped.joint_names))
    assert mine.torque_limits == shipped.torque_limits
    m1, m2 = shipped.build_model(gravity_compensation=False), mine.build_model(gravity_compensation=False)
    m1.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    for j in shipped.joint_names:
        b1, b2 = m1.body(m1.jnt_bodyid[m1.joint(j).id]), m2.body(m2.jnt_bodyid[m2.joint(j).id])
        np.testing.assert_allclose([*b1.mass, *b1.inertia, *b1.ipos], [*b2.mass, *b2.inertia, *b2.ipos], atol=1e-6)
    d1, d2 = mujoco.MjData(m1), mujoco.MjData(m2)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q, v, tau = rng.uniform(-1, 1, 7), rng.normal(size=7), rng.normal(size=7) * 5
        for m, d in ((m1, d1), (m2, d2)):
            d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, tau
            mujoco.mj_forward(m, d)
        np.testing.assert_allclose(d2.qacc, d1.qacc, atol=1e-6 * np.abs(d1.qacc).max())
        np.testing.assert_allclose(d2.site("ee").xpos, d1.site("ee").xpos, atol=1e-6)


@pytest.mark.parametrize("bad, match", [
    ({"link": 1, "mass": 0.0, "inertia": (0.01, 0.01, 0.01, 0, 0, 0)}, "link 'link2' .* has no mass"),
    ({"link": 1, "mass": None, "inertia": None}, "link 'link2' .* has no mass"),
    ({"link": 0, "mass": -1.0, "inertia": (0.01, 0.01, 0.01, 0, 0, 0)}, "link 'link1' .* has mass -1.0"),
    ({"link": 2, "mass": 1.0, "inertia": (0.01, -0.02, 0.01, 0, 0, 0)}, "link 'link3' .* not positive definite"),
    ({"link": 2, "mass": 1.0, "inertia": (0.01, 0.01, 0.01, 0.02, 0, 0)}, "link 'link3' .* not positive definite"),
    ({"link": 0, "mass": 1.0, "inertia": (0.001, 0.001, 0.01, 0, 0, 0)}, "link 'link1' .* triangle inequality"),
])
def test_ill_posed_inertials_are_refused_with_the_link(tmp_path, user_folder, bad, match):
    with pytest.raises(ArmDescriptionError, match=match):
        _add(tmp_path, "bad", serial_arm(3, bad_link=bad))
    assert not user_folder.exists() and "bad" not in arms.names()


def test_other_bad_descriptions(tmp_path, user_folder):
    with pytest.raises(MissingInputError, match="URDF file not found"):
        user_arms.add(ArmRequest("x", str(tmp_path / "none.urdf"), "urdf"))
    mjcf = write(tmp_path / "m.xml", "<mujoco><worldbody/></mujoco>")
    with pytest.raises(ArmDescriptionError, match="not a URDF .* --mjcf"):
        user_arms.add(ArmRequest("x", mjcf, "urdf"))
    with pytest.raises(ArmDescriptionError, match="no torque limit .* --torque-limits"):
        _add(tmp_path, "x", serial_arm(3, effort=0.0))
    with pytest.raises(ArmDescriptionError, match="no link 'hand'"):
        _add(tmp_path, "x", serial_arm(3), ee_link="hand")
    with pytest.raises(ArmDescriptionError, match="shipped arm"):
        user_arms.add(ArmRequest("panda", mjcf, "urdf"))
    with pytest.raises(ArmDescriptionError, match="cannot read .* as XML"):
        user_arms.add(ArmRequest("x", write(tmp_path / "broken.urdf", "<robot><link"), "urdf"))
    broken = serial_arm(3).replace("</robot>", '<joint name="loose" type="fixed"><parent link="link3"/></joint></robot>')
    with pytest.raises(ArmDescriptionError, match="joint 'loose' .* <child link=...> names no link"):
        _add(tmp_path, "x", broken)
    assert not user_folder.exists()
    # --torque-limits stands in for missing effort limits.
    arm = _add(tmp_path, "x", serial_arm(3, effort=0.0), torque_limits=(5.0, 4.0, 3.0))
    assert arm.torque_limits == (5.0, 4.0, 3.0)


def test_add_exists_overwrite_and_remove(tmp_path, user_folder):
    first = _add(tmp_path, "arm", serial_arm(3))
    with pytest.raises(OutputExistsError, match="pass --overwrite"):
        _add(tmp_path, "arm", serial_arm(4))
    second = _add(tmp_path, "arm", serial_arm(4), overwrite=True)
    assert second.n_joint == 4 and second.digest != first.digest
    assert arms.get("arm").build_model().nq == 4  # the cached 3-joint model is not served
    with pytest.raises(ArmDescriptionError, match="only your own arms"):
        user_arms.remove("panda")
    user_arms.remove("arm")
    assert "arm" not in arms.names() and not (user_folder / "arm").exists()
    with pytest.raises(MissingInputError, match="no user arm 'arm'"):
        user_arms.remove("arm")
    with pytest.raises(arms.UnknownRobotError, match="robomorph arms add"):
        arms.get("arm")


def test_the_door(tmp_path, user_folder, capsys):
    urdf = write(tmp_path / "r.urdf", serial_arm(3))
    assert arms_door.main(["add", "mine", "--urdf", urdf]) == 0
    assert "mine: 3 joints (joint1, joint2, joint3)" in capsys.readouterr().out
    assert arms_door.main(["list"]) == 0
    listing = capsys.readouterr().out
    assert "panda" in listing and "mine     user" in listing and str(user_folder) in listing
    bad = write(tmp_path / "bad.urdf", serial_arm(3, bad_link={"link": 0, "mass": 0.0, "inertia": (1, 1, 1, 0, 0, 0)}))
    assert arms_door.main(["add", "other", "--urdf", bad]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "link 'link1'" in err[0] and not (user_folder / "other").exists()
    assert arms_door.main(["remove", "jaco"]) == 2
    assert arms_door.main(["remove", "mine"]) == 0 and not os.path.exists(user_folder / "mine")


def test_a_damaged_user_arm_is_named_not_a_traceback(tmp_path, user_folder, capsys):
    _add(tmp_path, "arm", serial_arm(3))
    (user_folder / "arm" / "arm.json").write_text("{not json")
    with pytest.raises(arms.UnknownRobotError, match="user arm 'arm' .* is damaged.*robomorph arms remove arm"):
        arms.get("arm")
    assert arms_door.main(["list"]) == 0 and "arm      damaged" in capsys.readouterr().out
    assert arms_door.main(["remove", "arm"]) == 0 and "arm" not in arms.names()
