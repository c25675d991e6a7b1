"""The public real-arm sources: their readers, splits and stores, and ``benchmarks/real_robots.py``
end to end, on logs simulated here and written in each source's own file formats (the real
logs are not shipped: their licences differ and nothing downloads in tests).

The Kinova-format logs come from the catalogue ``kinova3`` arm in MuJoCo at 1 kHz, driven by
its own gravity torques plus small sines and logged as the arm's torque sensors log the total
joint torque: on them the catalogue physics is the true robot, which the benchmark must show.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.io

from robomorph.data import public_logs

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _kinova_log(seed: int, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """(L, 7) total joint torques and (L, 7) joint angles of the catalogue Kinova at 1 kHz: the
    torques of a joint PD controller with gravity compensation tracking slow sines (as real arms
    are logged), and the catalogue arm's motion under them."""
    import mujoco

    from robomorph.evaluation.physics import NominalPhysics
    from robomorph.sim import arms

    arm = arms.get("kinova3")
    model = arm.build_model(substeps=1, dt=1e-3, gravity_compensation=False)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    data.qpos[:7] = np.asarray(arm.home) + rng.uniform(-0.2, 0.2, 7)
    mujoco.mj_forward(model, data)
    start = data.qpos[:7].copy()
    freq, phase = rng.uniform(0.3, 1.2, 7), rng.uniform(0, 2 * np.pi, 7)
    n = int(seconds * 1000)
    u, q = np.empty((n, 7)), np.empty((n, 7))
    for k in range(n):
        q[k] = data.qpos[:7]
        ref = start + 0.3 * np.sin(2 * np.pi * freq * k * 1e-3 + phase)
        u[k] = np.clip(data.qfrc_bias[:7] + 10.0 * (ref - q[k]) - 1.0 * data.qvel[:7], -arm.limits, arm.limits)
        data.ctrl[:7] = u[k]
        mujoco.mj_step(model, data)
    # Those torques replayed on the catalogue arm as the benchmark builds it (its nominal
    # damping, armature and friction): the log's robot is then exactly the catalogue robot.
    sim = NominalPhysics({"task": "ingested", "arm": "kinova3", "dt": 1e-3, "config": {},
                          "u_names": list(arm.u_names), "y_names": list(arm.y_names)})
    return u, sim.rollout(u, start)[:, 7:]


def write_sources(root: str) -> None:
    """Tiny logs in the four sources' layouts under ``root``, each folder named as its clone."""
    rng = np.random.default_rng(0)
    kin = os.path.join(root, "dynamic-identification", "pyDynaMapp", "data", "kinova")
    header = (["Time"] + [f"Position{j}" for j in range(1, 8)] + [f"Velocity{j}" for j in range(1, 8)]
              + [f"Torque{j}" for j in range(1, 8)] + [f"TorqueCur{j}" for j in range(1, 8)])
    for k, (folder, name) in enumerate((("identification_data", "Trajectory1.csv"),
                                        ("jointwise_motion", "joint_1_trapez.csv"),
                                        ("validation_data", "opti_traj_testing1.csv"))):
        u, q = _kinova_log(k, 2.6)
        # The sensors' Torque columns read 0, as they do on the real arm's joint 7; TorqueCur is read.
        rows = np.column_stack([np.arange(len(u)), q, np.gradient(q, 1e-3, axis=0), np.zeros_like(u), u])
        os.makedirs(os.path.join(kin, folder), exist_ok=True)
        np.savetxt(os.path.join(kin, folder, name), rows, delimiter=",", header=",".join(header), comments="")

    ur5 = os.path.join(root, "ur5_modeling_force_estimate", "JointSpaceControl_Model_C_ForceEstim", "RecordedUR5Data")
    for movement in ("Movement_No1", "Movement_No6_Acc_slow_Verify_Model"):
        folder = os.path.join(ur5, movement, "csv_files")
        os.makedirs(folder)
        t = 0.05 + 0.008 * np.arange(1100) + rng.uniform(-5e-4, 5e-4, 1100)  # the UR clock's jitter
        q = 0.3 * np.sin(0.7 * t[:, None] + np.arange(6))
        for name, x in (("log_q_actual.csv", q), ("log_m_target.csv", 5 * np.cos(0.7 * t[:, None] + np.arange(6)))):
            np.savetxt(os.path.join(folder, name), np.column_stack([t, x]), delimiter=", ", fmt="%.6f")
        with open(os.path.join(folder, "log_q_actual.csv"), "a") as f:
            f.write("1.0, 2.0, 3\n")  # a truncated last line, as some of the real logs end

    schunk = os.path.join(root, "AutoKoopman", "autoKoopman_codeocean", "data", "Robot")
    inputs = [rng.normal(size=(760, 6)) for _ in range(3)]
    for m in range(1, 8):
        folder = os.path.join(schunk, f"measurement_{m}")
        os.makedirs(folder)
        u = inputs[(m - 1) % 3]  # runs 1, 4, 7 share an input, as the real runs repeat theirs
        np.savetxt(os.path.join(folder, "input.csv"), u, delimiter=",")
        np.savetxt(os.path.join(folder, "time.csv"), 0.004 * np.arange(len(u)))
        np.savetxt(os.path.join(folder, "trajectory.csv"), np.cumsum(1e-3 * u, axis=0).repeat(2, axis=1)[:, :12],
                   delimiter=",")

    mat = os.path.join(root, "Physics-Guided-Recurrent-State-Space-Neural-Networks", public_logs.INDUSTRIAL_MAT)
    os.makedirs(os.path.dirname(mat))
    arrays = {}
    for split, n in (("train", 1300), ("val", 300), ("test", 1210)):
        u = rng.normal(size=(6, n))
        arrays[f"u_{split}"], arrays[f"y_{split}"] = u, 30 * np.sin(np.cumsum(0.01 * u, axis=1))  # degrees
    scipy.io.savemat(mat, arrays)


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("sources"))
    write_sources(root)
    return root


def test_readers_split_by_recording_and_keep_repeated_inputs_together(sources):
    kinova = public_logs.get("kinova_gen3").recordings(sources)
    assert [r.split for r in kinova if "validation_data" in r.name] == ["test"]
    assert {r.split for r in kinova if "validation_data" not in r.name} == {"train"}
    assert all(r.u.shape == r.q.shape and r.u.shape[1] == 7 and r.dt == 1e-3 for r in kinova)

    ur5 = {os.path.basename(os.path.dirname(r.name)): r for r in public_logs.get("ur5").recordings(sources)}
    assert ur5["Movement_No6_Acc_slow_Verify_Model"].split == "test" and ur5["Movement_No1"].split == "train"
    assert "1 malformed rows dropped" in ur5["Movement_No1"].note
    # Interpolated onto the 8 ms grid: the logged angles at the grid's times, within the sine's curvature.
    r = ur5["Movement_No1"]
    assert r.dt == 0.008 and np.abs(np.diff(r.q, axis=0)).max() < 0.01

    schunk = public_logs.get("schunk").recordings(sources)
    by_input = {}
    for rec in schunk:
        by_input.setdefault(rec.u.tobytes(), set()).add(rec.split)
    assert all(len(splits) == 1 for splits in by_input.values())  # no input in both splits
    assert {rec.name.rsplit("_", 1)[-1] for rec in schunk if rec.split == "test"} == {"3", "6"}

    robot = {r.split: r for r in public_logs.get("industrial_robot").recordings(sources)}
    assert set(robot) == {"train", "val", "test"} and robot["test"].q.shape == (1210, 6)
    assert np.abs(robot["train"].q).max() <= np.deg2rad(30) + 1e-9  # degrees stored as radians


def test_stores_hold_the_arm_layout_and_only_test_recordings_in_test(sources, tmp_path):
    from robomorph.data.store import open_store

    stores = public_logs.write_stores(public_logs.get("kinova_gen3"), sources, str(tmp_path / "k"))
    test, train = open_store(stores["test"]), open_store(stores["train"])
    assert test.attrs["arm"] == "kinova3" and test.y_names[:3] == ["ee_x", "ee_y", "ee_z"] and len(test.y_names) == 14
    assert test.dt == pytest.approx(1 / 200) and test.steps == 400
    assert all("validation_data" in s for s in test.attrs["sources"])
    assert not any("validation_data" in s for s in train.attrs["sources"])


def test_a_missing_clone_is_one_line_naming_the_clone_command(tmp_path):
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "real_robots.py"), "--data", str(tmp_path),
                          "--robots", "ur5"], capture_output=True, text=True, cwd=str(tmp_path))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "git clone https://github.com/kkufieta/ur5_modeling_force_estimate" in out.stderr


@pytest.mark.slow  # a benchmark script end to end, as tests/evaluation/test_benchmarks.py's
def test_benchmark_scores_every_predictor_on_every_robot_and_physics_wins_on_its_own_arm(sources, tmp_path):
    md = tmp_path / "real_robots.md"
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "real_robots.py"), "--data", sources,
                          "--work", str(tmp_path / "work"), "--md", str(md), "--identified", "--windows", "3"],
                         capture_output=True, text=True, cwd=str(tmp_path))
    assert out.returncode == 0, out.stderr[-2000:]
    text = md.read_text()
    assert text.startswith("*Produced by `") and "at commit" in text
    for name in public_logs.SOURCES:  # the error-growth figures beside the tables
        assert (tmp_path / "real_robots" / f"{name}.png").stat().st_size > 1000
    for source in public_logs.SOURCES.values():
        assert f"## {source.robot}" in text
    kinova = text.split("## Kinova")[1].split("\n## ")[0]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in kinova.splitlines() if line.startswith("| ") and "joint RMS" not in line}
    assert set(rows) == {"hold", "constant_velocity", "constant_acceleration", "arx", "arx_train", "accel_arx",
                         "accel_arx_train", "nominal_physics", "identified_physics", "hybrid (total)",
                         "hybrid (nominal commands)", "stacked (kinematic)", "stacked (zero-shot)",
                         "stacked (training recordings)", "hybrid_train", "hybrid_train +offsets",
                         "hybrid_train +offsets +residual", "constant_velocity +residual"}
    assert "Issue 62's goals" in kinova and "zero-shot at most 1.05x the best kinematic at every step: **" in kinova
    # The logs were made by the catalogue arm itself: its physics beats hold at 0.25 s (step 50 at 200 Hz).
    assert float(rows["nominal_physics"][1]) < 0.5 * float(rows["hold"][1])
    industrial = text.split("## KUKA")[1]
    # its published readings live in their own benchmark, named here instead of an NRMSE beside them
    assert "arx_train" in industrial and "benchmarks/industrial_robot.py" in industrial
    assert "published" not in industrial.replace("published readings", "")
    schunk = text.split("## Schunk")[1].split("\n## ")[0]
    assert "nominal_physics" not in schunk and "hybrid_train" not in schunk  # no MJCF: not run
    assert "| constant_velocity +residual" in schunk  # the residual on constant velocity: every arm
    assert "hybrid_train +offsets, with the training recordings at most 0.5x the best kinematic" in kinova
    assert "effect of the per-context offsets:" in kinova


def test_ingest_source_writes_the_split_stores_and_refuses_mixed_requests(sources, tmp_path, capsys):
    from robomorph.data.store import open_store
    from robomorph.ingest import main as ingest_main

    out = str(tmp_path / "schunk")
    assert ingest_main(["--source", "schunk", "--data", sources, "--out", out]) == 0
    printed = capsys.readouterr().out
    assert "train.zarr" in printed and "test.zarr" in printed
    test = open_store(os.path.join(out, "test.zarr"))
    assert test.steps == 700 and test.y_names == [f"q{j}" for j in range(6)] and test.n == 2
    # A second run refuses to replace the stores without --overwrite, and keeps them.
    assert ingest_main(["--source", "schunk", "--data", sources, "--out", out]) == 2
    assert open_store(os.path.join(out, "test.zarr")).n == 2
    for argv in (["--source", "schunk", "--out", out],  # no --data
                 ["--source", "schunk", "--data", sources, "--steps", "10", "--out", out]):
        with pytest.raises(SystemExit) as exc:
            ingest_main(argv)
        assert exc.value.code == 2
    assert ingest_main(["--source", "bogus", "--data", sources, "--out", out]) == 2
    assert "unknown public source 'bogus'" in capsys.readouterr().err


def test_the_industrial_robot_is_read_from_the_official_loaders_download_when_no_clone_is_there(sources, tmp_path):
    """The official loader (nonlinear-benchmarks) leaves its file under DATA/nonlinear_benchmarks;
    a clone of the copy wins where both are present. Asking for the download without the loader
    is one line, exit 2."""
    import shutil

    clone = os.path.join(sources, "Physics-Guided-Recurrent-State-Space-Neural-Networks", public_logs.INDUSTRIAL_MAT)
    loader = tmp_path / "nonlinear_benchmarks" / "Industrial_robot" / "forward_identification_without_raw_data.mat"
    loader.parent.mkdir(parents=True)
    shutil.copy(clone, loader)
    recs = public_logs.get("industrial_robot").recordings(str(tmp_path))
    assert {r.split for r in recs} == {"train", "val", "test"}
    assert all(r.name.startswith(os.path.join("Industrial_robot", "forward_identification_without_raw_data.mat"))
               for r in recs)
    assert public_logs.get("industrial_robot").root(sources).endswith("Physics-Guided-Recurrent-State-Space-Neural-Networks")
    empty = tmp_path / "empty"
    empty.mkdir()
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "real_robots.py"), "--data", str(empty),
                          "--robots", "industrial_robot", "--download-industrial"], capture_output=True, text=True,
                         cwd=str(tmp_path), env={**os.environ, "PYTHONNOUSERSITE": "1"})
    # Without the loader (it is not a dependency) or without the network: one line, exit 2.
    assert out.returncode == 2 and "Traceback" not in out.stderr and out.stderr.count("\n") == 1
    if importlib.util.find_spec("nonlinear_benchmarks") is None:
        assert "pip install nonlinear-benchmarks" in out.stderr


def test_the_industrial_robots_section_reads_the_benchmark_by_its_published_readings(sources, tmp_path):
    """real_robots.py's KUKA section: the benchmark's own readings (a)-(d) of hold, constant velocity and the
    least-squares ARX, free-run over the benchmark file's test trajectories, instead of an NRMSE of its windows
    printed beside figures of another reading; hold's reading (c) is the hand-computed one."""
    md = tmp_path / "rr.md"
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "real_robots.py"), "--data", sources,
                          "--robots", "industrial_robot", "--windows", "2", "--no-stacked", "--work",
                          str(tmp_path / "work"), "--md", str(md)], capture_output=True, text=True, cwd=str(tmp_path))
    assert out.returncode == 0, out.stderr[-2000:]
    section = md.read_text().split("## KUKA")[1]
    rows = {line.split("|")[1].strip(): [float(c) for c in line.split("|")[2:-1]]
            for line in section.split("(d) prediction [deg]")[1].splitlines()
            if line.startswith("| ") and line.split("|")[1].strip() in ("hold", "constant_velocity", "arx_ls")}
    assert set(rows) == {"hold", "constant_velocity", "arx_ls"} and all(len(v) == 5 for v in rows.values())
    from robomorph.data import industrial

    test = industrial.load(sources).test  # hold from the first sample: RMSE of y - y0 over each range
    hand = np.mean([np.sqrt(np.mean((y[1:] - y[0]) ** 2, 0)) / (y[1:].max(0) - y[1:].min(0)) for _, y in test])
    assert rows["hold"][2] == pytest.approx(hand, rel=1e-3)  # printed to 4 significant digits
    assert "benchmarks/industrial_robot.py" in section and "published" not in section.replace("published readings", "")


@pytest.mark.parametrize("name", list(public_logs.SOURCES))
def test_the_context_backtest_stacks_every_sources_logs(name, sources, tmp_path):
    """The stacks of benchmarks/stacking.py on logs in each source's own format: every candidate backtested on the
    same windows, weights that sum to one, a std, and each goal's verdict."""
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    try:
        import stacking
    finally:
        sys.path.pop(0)
    from robomorph.data.store import open_store
    from robomorph.evaluation.windows import load_window

    source = public_logs.get(name)
    stores = public_logs.write_stores(source, sources, str(tmp_path / name))
    test = open_store(stores["test"])
    w = load_window(stores["test"], source.context, source.horizon, 3, None, len(test.u_names), len(test.y_names))
    preds, stds = stacking.stacked_predictions(source.arm, w, stores.get("train"), hybrid=False)
    assert set(stds) == set(stacking.STACKS if "train" in stores else stacking.STACKS[:2])
    for stack in stds:
        assert preds[stack].shape == stds[stack].shape == w.y[:, w.context_len:].shape
        assert np.isfinite(preds[stack]).all() and (stds[stack] > 0).all()
    res = stacking.summarize(source, w, preds, stds)
    assert any(v.startswith("zero-shot at most 1.05x") for v in res["verdicts"])
    # Window by window and step by step, never further off than the furthest kinematic bar: a convex combination of
    # candidates (here the kinematic ones), whatever the backtest ranked.
    truth = w.y[:, w.context_len:].astype(np.float64)
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]

    def err(p):
        return np.sqrt(((p - truth)[..., joints] ** 2).mean(axis=2))  # (B, H)

    worst = np.max([err(preds[k]) for k in ("hold", "constant_velocity", "constant_acceleration")], axis=0)
    assert np.all(err(preds["stacked (kinematic)"]) <= worst * (1 + 1e-9) + 1e-12)
