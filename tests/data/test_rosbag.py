"""ROS bags into stores (robomorph.data.rosbag, ingest --rosbag): the reading rules and the refusals."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from robomorph import ingest as ingest_door
from robomorph.core.errors import MissingInputError
from robomorph.data import real_logs, rosbag
from robomorph.data.ingest import IngestError, ingest_rosbag, open_store
from tests.data.bag_factory import bag_path, write_joint_states, write_strings

KINDS = ("ros1", "db3", "mcap")
NAMES = ["j1", "j2", "j3"]
T0 = 1_700_000_000 * 10**9  # a 2023 wall-clock stamp: seconds large enough to matter


def _signals(m: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(m) / 100.0
    q = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in zip((0.3, 0.5, 0.7), rng.uniform(0, 6, 3))], axis=1)
    return q, np.gradient(q, axis=0) * 100, rng.normal(size=(m, 3))


def _stamps(m: int, dt_ns: int = 10**7) -> np.ndarray:
    return T0 + np.arange(m, dtype=np.int64) * dt_ns


@pytest.mark.parametrize("kind", KINDS)
def test_bag_round_trip_every_storage(tmp_path, kind):
    q, qd, tau = _signals(400)
    bag = write_joint_states(bag_path(tmp_path, kind), kind, _stamps(400), NAMES, q, qd, tau)
    ds = ingest_rosbag([str(bag)], str(tmp_path / "s.zarr"), steps=100)
    assert (ds.n, ds.steps) == (4, 100)
    assert ds.dt == pytest.approx(0.01, rel=1e-9)
    assert ds.u_names == [f"effort/{j}" for j in NAMES] and ds.y_names == [f"position/{j}" for j in NAMES]
    u, y = np.asarray(ds.group["u"]), np.asarray(ds.group["y"])
    np.testing.assert_allclose(y.reshape(-1, 3), q, atol=1e-6)  # float32 store
    np.testing.assert_allclose(u.reshape(-1, 3), tau, atol=1e-6)
    np.testing.assert_allclose(np.asarray(ds.group["qvel"]).reshape(-1, 3), qd, atol=1e-5)
    rec = ds.attrs["recordings"][0]
    assert rec["messages"] == 400 and rec["interpolated"] == 0 and rec["stamps"] == "header"


def test_single_storage_file_reads_as_its_bag(tmp_path):
    q, qd, tau = _signals(50)
    bag = write_joint_states(bag_path(tmp_path, "mcap"), "mcap", _stamps(50), NAMES, q, qd, tau)
    file = next(p for p in bag.iterdir() if p.suffix == ".mcap")
    log = rosbag.read_joint_states(str(file))
    np.testing.assert_array_equal(log.values["position"], q)


def test_reordered_names_and_a_joint_missing_from_some_messages(tmp_path):
    m = 200
    q, qd, tau = _signals(m)
    names, rows_q, rows_tau = [], [], []
    for k in range(m):
        order = [2, 0, 1] if k % 2 else [0, 1, 2]
        if k % 10 == 5:
            order = [0, 2]  # j2 is missing from this message
        names.append([NAMES[i] for i in order])
        rows_q.append(q[k, order])
        rows_tau.append(tau[k, order])
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(m), NAMES, rows_q, None, rows_tau,
                             per_message_names=names)
    log = rosbag.read_joint_states(str(bag), joints=NAMES)
    held = np.ones((m, 3), bool)
    held[5::10, 1] = False
    np.testing.assert_array_equal(log.values["position"][held], q[held])
    assert np.isnan(log.values["position"][~held]).all() and np.isnan(log.values["velocity"]).all()
    rec = rosbag.recordings(log, "run.bag")[0]
    # j2's missing samples are interpolated between its neighbours; the others are the messages' own.
    missing = np.arange(5, m, 10)
    expected = (q[missing - 1, 1] + q[missing + 1, 1]) / 2
    np.testing.assert_allclose(rec.columns["position/j2"][missing], expected, atol=1e-12)
    np.testing.assert_array_equal(rec.columns["position/j1"], q[:, 0])
    assert "velocity/j1" not in rec.columns and not rec.report["velocity"]


def test_stamps_not_arrival_set_the_time_out_of_order_and_duplicates(tmp_path):
    m = 300
    q, qd, tau = _signals(m)
    rng = np.random.default_rng(3)
    order = np.arange(m)
    swap = 2 * rng.choice(m // 2 - 1, 20, replace=False)  # disjoint pairs
    order[swap], order[swap + 1] = order[swap + 1], order[swap]  # neighbours arrive swapped
    stamps = _stamps(m)[order]
    arrivals = T0 + np.sort(rng.uniform(0, 3e9, m)).astype(np.int64)  # jittered arrival, in file order
    # A duplicate: message 100's stamp sent again later with other values; the later one wins.
    stamps = np.insert(stamps, 150, _stamps(m)[100])
    arrivals = np.insert(arrivals, 150, arrivals[150])
    qq, tt = np.insert(q[order], 150, q[100] + 1.0, axis=0), np.insert(tau[order], 150, tau[100], axis=0)
    bag = write_joint_states(bag_path(tmp_path, "db3"), "db3", stamps, NAMES, qq, None, tt, arrivals_ns=arrivals)
    rec = rosbag.recordings(rosbag.read_joint_states(str(bag)), "run")[0]
    expected = q.copy()
    expected[100] += 1.0
    np.testing.assert_array_equal(np.stack([rec.columns[f"position/{j}"] for j in NAMES], 1), expected)
    assert rec.report["duplicate_stamps"] == 3 * 2  # one per joint, for position and effort
    assert rec.report["reordered"] > 0 and rec.report["interpolated"] == 0
    assert rec.columns["t"][-1] == pytest.approx((m - 1) * 0.01, abs=1e-9)


def test_gap_is_interpolated_and_split_gap_splits(tmp_path):
    q, qd, tau = _signals(300)
    stamps = _stamps(300)
    stamps[150:] += 5 * 10**9  # a 5 s pause after 1.5 s
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", stamps, NAMES, q, qd, tau)
    log = rosbag.read_joint_states(str(bag))
    whole = rosbag.recordings(log, "run.bag")
    assert len(whole) == 1 and whole[0].report["interpolated"] == 500 and whole[0].report["longest_gap_s"] > 5
    parts = rosbag.recordings(log, "run.bag", split_gap=1.0)
    assert [p.label for p in parts] == ["run.bag#1", "run.bag#2"]
    assert [p.report["samples"] for p in parts] == [150, 150] and all(p.report["interpolated"] == 0 for p in parts)
    ds = ingest_rosbag([str(bag)], str(tmp_path / "s.zarr"), steps=50, split_gap=1.0)
    assert ds.n == 6 and list(np.asarray(ds.group["recording_index"])) == [0, 0, 0, 1, 1, 1]
    assert ds.attrs["sources"] == ["run.bag#1", "run.bag#2"]


def test_resample_uses_the_anti_aliasing_resampler(tmp_path):
    m = 2000
    q, qd, tau = _signals(m)
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(m, 10**6), NAMES, q, qd, tau)  # 1 kHz
    ds = ingest_rosbag([str(bag)], str(tmp_path / "s.zarr"), steps=50, resample_hz=100.0)
    assert ds.dt == pytest.approx(0.01) and ds.attrs["original_dt"] == pytest.approx(0.001)
    expected = real_logs.resample(q, 0.001, 100.0)
    np.testing.assert_allclose(np.asarray(ds.group["y"]).reshape(-1, 3), expected[:ds.n * 50], atol=1e-6)


def test_layout_arm_takes_its_joints_and_names(tmp_path):
    from robomorph.sim import arms

    arm = arms.get("ur5e")
    m = 120
    rng = np.random.default_rng(1)
    q = np.asarray(arm.home) + 0.1 * np.sin(np.arange(m)[:, None] / 20.0)
    tau = rng.normal(size=(m, 6))
    extra = np.zeros((m, 1))  # a gripper joint the arm does not have
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(m), [*arm.joint_names, "finger"],
                             np.hstack([q, extra]), None, np.hstack([tau, extra]))
    ds = ingest_rosbag([str(bag)], str(tmp_path / "s.zarr"), steps=60, layout="ur5e")
    assert ds.u_names == list(arm.u_names) and ds.y_names == list(arm.y_names) and ds.attrs["arm"] == "ur5e"
    np.testing.assert_allclose(np.asarray(ds.group["y"])[..., 7:].reshape(-1, 6), q, atol=1e-6)


# --- refusals: one clear line, nothing written ---------------------------------------------------

def _refused(tmp_path, bag, match, **kw):
    out = tmp_path / "out.zarr"
    with pytest.raises((IngestError, MissingInputError), match=match):
        ingest_rosbag([str(bag)], str(out), steps=10, **kw)
    assert not out.exists() and not list(tmp_path.glob(".out.zarr*"))  # not even a lock file


def test_missing_bag(tmp_path):
    _refused(tmp_path, tmp_path / "nope.bag", "bag not found")


@pytest.mark.parametrize("kind", KINDS)
def test_truncated_bag(tmp_path, kind):
    q, qd, tau = _signals(300)
    bag = write_joint_states(bag_path(tmp_path, kind), kind, _stamps(300), NAMES, q, qd, tau)
    file = bag if kind == "ros1" else next(p for p in bag.iterdir() if p.suffix != ".yaml")
    data = file.read_bytes()
    file.write_bytes(data[:len(data) * 2 // 3])
    _refused(tmp_path, bag, "truncated")


@pytest.mark.parametrize("kind", ("ros1", "mcap"))
def test_missing_topic_and_other_message_type(tmp_path, kind):
    q, qd, tau = _signals(30)
    bag = write_joint_states(bag_path(tmp_path, kind), kind, _stamps(30), NAMES, q, qd, tau)
    _refused(tmp_path, bag, r"no topic '/arm/joint_states'; its topics: /joint_states", topic="/arm/joint_states")
    strings = write_strings(bag_path(tmp_path, kind, "strings"), kind)
    _refused(tmp_path, strings, "carries std_msgs/msg/String, not sensor_msgs/JointState")


def test_out_is_never_the_bag(tmp_path):
    q, qd, tau = _signals(30)
    bag = write_joint_states(bag_path(tmp_path, "db3"), "db3", _stamps(30), NAMES, q, qd, tau)
    before = sorted(p.name for p in bag.iterdir())
    with pytest.raises(Exception, match="is the input"):
        ingest_rosbag([str(bag)], str(bag), steps=10, overwrite=True)
    assert sorted(p.name for p in bag.iterdir()) == before


def test_joint_absent_throughout_and_without_effort(tmp_path):
    q, qd, tau = _signals(30)
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(30), NAMES, q, qd, tau)
    _refused(tmp_path, bag, "joint 'elbow' is absent from every message", joints=["j1", "elbow"])
    no_effort = write_joint_states(bag_path(tmp_path, "ros1", "noeffort"), "ros1", _stamps(30), NAMES, q, qd, None)
    _refused(tmp_path, no_effort, "has no effort in any message")


def test_nan_effort(tmp_path):
    q, qd, tau = _signals(30)
    tau[17, 2] = np.nan
    bag = write_joint_states(bag_path(tmp_path, "db3"), "db3", _stamps(30), NAMES, q, qd, tau)
    _refused(tmp_path, bag, r"effort of joint 'j3' is nan at stamp 1700000000.170000000")
    # The same NaN in a joint that is not read is no reason to refuse.
    log = rosbag.read_joint_states(str(bag), joints=["j1", "j2"])
    assert log.values["effort"].shape == (30, 2)


def test_nan_velocity_is_not_logged_velocity(tmp_path):
    q, qd, tau = _signals(40)
    qd[10, 1] = np.nan  # one missing estimate: interpolated
    qd[:, 2] = np.inf  # a joint without any: no velocity column, so no qvel in the store
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(40), NAMES, q, qd, tau)
    rec = rosbag.recordings(rosbag.read_joint_states(str(bag)), "run.bag")[0]
    assert rec.columns["velocity/j2"][10] == pytest.approx((qd[9, 1] + qd[11, 1]) / 2)
    assert "velocity/j3" not in rec.columns and not rec.report["velocity"]
    ds = ingest_rosbag([str(bag)], str(tmp_path / "s.zarr"), steps=10)
    assert "qvel" not in ds.arrays and ds.attrs["velocity"] is None


def test_door_refuses_with_one_line_and_exit_2(tmp_path, capsys):
    q, qd, tau = _signals(30)
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", _stamps(30), NAMES, q, qd, tau)
    out = tmp_path / "o.zarr"
    code = ingest_door.main(["--rosbag", str(bag), "--steps", "10", "--topic", "/nope", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and not out.exists()
    assert ingest_door.main(["--rosbag", str(bag), "--steps", "10", "--out", str(out)]) == 0
    assert "30 messages (header stamps)" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:  # bag-only flags without a bag
        ingest_door.main(["x.csv", "--u-cols", "a", "--y-cols", "b", "--steps", "3", "--dt", "0.1",
                          "--split-gap", "1", "--out", str(tmp_path / "p.zarr")])
    assert exc.value.code == 2 and "only go with --rosbag" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # what the bag says itself is not given twice
        ingest_door.main(["--rosbag", str(bag), "--steps", "10", "--y-units", "deg", "--out", str(out)])
    assert exc.value.code == 2 and "drop --y-units" in capsys.readouterr().err


def test_zero_stamps_fall_back_to_arrival(tmp_path):
    q, qd, tau = _signals(40)
    bag = write_joint_states(bag_path(tmp_path, "ros1"), "ros1", np.zeros(40, np.int64), NAMES, q, qd, tau,
                             arrivals_ns=_stamps(40))
    rec = rosbag.recordings(rosbag.read_joint_states(str(bag)), "run.bag")[0]
    assert rec.report["stamps"].startswith("arrival") and rec.report["samples"] == 40
    shutil.rmtree(tmp_path / "never", ignore_errors=True)
    assert not os.path.exists(tmp_path / "never")
