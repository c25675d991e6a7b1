"""The README's "Your own robot" workflow end to end, at tiny size, through the commands.

Logs like a real arm's (benchmarks/real_log_fixture.py: 6 torques in, 6 joint angles out,
10 Hz, measurement noise, recordings of unequal length) -> ingest with units -> train from
scratch with a validation store -> fine-tune a model of several simulated arms (its channel
set, the logs' joints mapped by role) -> evaluate against hold, ARX (per context and fitted
on the training data) and the scratch model.
"""

import importlib.util
import json
import os

import numpy as np
import pytest

from robomorph.data.generation import generate
from robomorph.data.store import open_store
from robomorph.evaluate import main as evaluate_main
from robomorph.fit import main as fit_main
from robomorph.ingest import main as ingest_main
from robomorph.inference.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

os.environ.setdefault("WANDB_MODE", "offline")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _fixture_module():
    spec = importlib.util.spec_from_file_location("real_log_fixture", os.path.join(ROOT, "benchmarks", "real_log_fixture.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_fixture_behaves_like_a_real_log(tmp_path):
    fx = _fixture_module()
    paths = fx.write_logs(str(tmp_path), lengths=(130, 90), seed=3)
    data = [np.loadtxt(p, delimiter=",", skiprows=1) for p in paths]
    assert [d.shape for d in data] == [(130, 13), (90, 13)]
    assert np.allclose(np.diff(data[0][:, 0]), 0.1)
    again = fx.write_logs(str(tmp_path / "again"), lengths=(130, 90), seed=3)
    assert np.array_equal(np.loadtxt(again[0], delimiter=",", skiprows=1), data[0])  # seeded
    clean = np.loadtxt(fx.write_logs(str(tmp_path / "clean"), lengths=(130,), seed=3, noise=False)[0],
                       delimiter=",", skiprows=1)
    noise = data[0][:, 1:] - clean[:, 1:]  # measurement noise on every column, torques and angles
    assert 0.03 < noise[:, :6].std() < 0.07 and 0.001 < noise[:, 6:].std() < 0.003
    assert data[0][:, 2].mean() < -4  # joint 2 holds around -6 N m


def _fit_args(store, runs, run, steps, **extra):
    args = ["--data.stores", store, "--data.context_len", "20", "--data.horizon", "40", "--data.batch_size", "8",
            "--model.d_model", "16", "--model.n_head", "2", "--model.n_layer", "1", "--model.warmup_steps", "2",
            "--model.max_context", "64", "--model.max_horizon", "64", "--trainer.max_steps", str(steps),
            "--trainer.val_check_interval", "10", "--trainer.accelerator", "cpu",
            "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false",
            "--run", run, "--runs_dir", str(runs), "--wandb", "disabled"]
    for key, value in extra.items():
        args += [f"--{key}", str(value)]
    return args


@pytest.mark.slow
def test_your_own_robot_workflow(tmp_path, capsys):
    logs = _fixture_module().write_logs(str(tmp_path / "logs"), lengths=(420, 310, 260, 200, 180), seed=0)
    units = ["--u-units", ",".join(["N m"] * 6), "--y-units", ",".join(["rad"] * 6)]
    cols = ["--u-cols", "tau1,tau2,tau3,tau4,tau5,tau6", "--y-cols", "q1,q2,q3,q4,q5,q6", "--time-col", "t",
            "--layout", "joints"]
    stores = {}
    for name, files, stride in (("train", logs[:3], 20), ("val", logs[3:4], 60), ("test", logs[4:], 60)):
        stores[name] = str(tmp_path / f"{name}.zarr")
        assert ingest_main([*files, *cols, *units, "--steps", "60", "--stride", str(stride),
                            "--out", stores[name]]) == 0
    out = capsys.readouterr().out
    assert "rec0.csv: 420 samples -> 19 windows, 0 tail samples dropped" in out
    assert "rec4.csv: 180 samples -> 3 windows, 0 tail samples dropped" in out
    train = open_store(stores["train"])
    assert train.dt == pytest.approx(0.1) and train.attrs["y_units"] == ["rad"] * 6

    runs = tmp_path / "runs"
    held_out = {"data.val_store": stores["val"], "data.test_store": stores["test"]}
    assert fit_main(_fit_args(stores["train"], runs, "scratch", 20, **held_out)) == 0
    final = capsys.readouterr().out.strip().splitlines()[-1]
    assert "step 20, validation at step 20: val/fit=" in final

    # A model of two simulated arms (7 and 6 joints), fine-tuned in its own channel set: the
    # logs' joints (named by role at ingest) map onto its q0..q5, nothing is re-initialized.
    arms = []
    for robot in ("panda", "ur5e"):
        arms.append(str(tmp_path / f"{robot}.zarr"))
        generate(load_recipe(None, {"task": "multisine", "robot": robot, "robots": 8, "steps": 60, "seed": 1}),
                 arms[-1], workers=1, progress=False)
    sim = fit({"data": {"stores": arms, "context_len": 20, "horizon": 40, "batch_size": 8, "joint_dropout": 0.2},
               "model": {"d_model": 16, "n_head": 2, "n_layer": 1, "max_context": 64, "max_horizon": 64},
               "trainer": {"max_steps": 4, "accelerator": "cpu", "enable_progress_bar": False,
                           "enable_model_summary": False},
               "run": "arms", "runs_dir": str(runs), "wandb": "disabled"})
    assert fit_main(_fit_args(stores["train"], runs, "tuned", 20, **held_out, **{
        "model.init_ckpt": sim.best_ckpt})) == 0
    tuned_model = Predictor.from_checkpoint(str(runs / "tuned" / "checkpoints" / "best.ckpt"), device="cpu")
    assert tuned_model.model.config.channel_mask and tuned_model.data_info["y_names"][-1] == "q6"
    capsys.readouterr()

    scratch = str(runs / "scratch" / "checkpoints" / "best.ckpt")
    tuned = str(runs / "tuned" / "checkpoints" / "best.ckpt")
    ev = str(tmp_path / "eval")
    evaluate_main(["--ckpt", tuned, "--data", stores["test"], "--out", ev, "--baselines", "hold,arx,arx_train",
                   "--arx-orders", "1,1", "--compare", f"scratch={scratch}", "--plot-trajectories", "1"])
    text = capsys.readouterr().out
    for source in ("model", "hold", "arx", "arx_train", "scratch"):
        assert f"  {source} " in text, text
    res = json.load(open(os.path.join(ev, "metrics.json")))
    assert set(res["baselines"]) == {"hold", "arx", "arx_train", "scratch"}
    # arx_train saw exactly the training store (val and test came from their own stores)
    assert res["meta"]["baseline_notes"]["arx_train"]["trajectories"] == train.n
    assert res["meta"]["n"] == 3 and res["meta"]["u_names"] == [f"tau{i}" for i in range(6)]
    assert list(res["approach2"]["channels"]) == [f"q{i}" for i in range(6)]  # the arm's own outputs


# ---------------------------------------------------------------- resampling, the Panda layout, splits

def _write_csv(path, columns: dict) -> str:
    names = list(columns)
    rows = np.stack([columns[n] for n in names], axis=1)
    np.savetxt(path, rows, delimiter=",", header=",".join(names), comments="", fmt="%.9g")
    return str(path)


def test_resample_filters_what_the_new_rate_cannot_hold(tmp_path, capsys):
    # A 1 kHz log: a slow 2 Hz motion plus a 400 Hz vibration. At 100 Hz, 400 Hz folds onto
    # 0 Hz: every 10th sample sees the vibration at one phase, a constant offset of 0.5.
    t = np.arange(4000) / 1000.0
    slow = np.sin(2 * np.pi * 2 * t)
    vib = 0.5 * np.sin(2 * np.pi * 400 * t + np.pi / 2)
    log = _write_csv(tmp_path / "arm.csv", {"t": t, "tau": slow + vib, "q": slow})
    out = str(tmp_path / "slow.zarr")
    assert ingest_main([log, "--u-cols", "tau", "--y-cols", "q", "--time-col", "t", "--resample", "100",
                        "--steps", "100", "--out", out]) == 0
    assert "resampled from 1000 Hz" in capsys.readouterr().out
    ds = open_store(out)
    assert ds.dt == pytest.approx(0.01) and ds.attrs["original_dt"] == pytest.approx(0.001)
    assert ds.n == 4 and ds.attrs["recordings"][0]["original_samples"] == 4000
    u = ds.read("u")[:, :, 0].reshape(-1)
    truth = np.sin(2 * np.pi * 2 * np.arange(400) / 100.0)
    naive = (slow + vib)[::10]
    assert np.abs(naive - truth).max() > 0.45  # decimation without a filter: the vibration aliased
    assert np.abs(u - truth)[5:-5].max() < 0.02  # filtered: the slow motion only
    np.testing.assert_allclose(ds.read("y")[:, :, 0].reshape(-1)[5:-5], truth[5:-5], atol=0.02)


@pytest.mark.parametrize("rate, message", [("0.3", "error: cannot resample from 1000 Hz to 0.3 Hz"),
                                           ("0", "error: --resample must be a positive, finite rate"),
                                           ("inf", "error: --resample must be a positive, finite rate")])
def test_resample_refuses_rates_it_cannot_reach(tmp_path, capsys, rate, message):
    log = _write_csv(tmp_path / "a.csv", {"tau": np.zeros(50), "q": np.zeros(50)})
    code = ingest_main([log, "--u-cols", "tau", "--y-cols", "q", "--dt", "0.001", "--resample", rate,
                        "--steps", "10", "--out", str(tmp_path / "o.zarr")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(message) and err.count("\n") == 1 and "Traceback" not in err
    assert not os.path.exists(tmp_path / "o.zarr")


def test_panda_layout_computes_the_simulators_end_effector_pose(simulated_store, tmp_path):
    from robomorph.sim import panda

    sim = open_store(simulated_store(robots=3, steps=60, seed=4))
    u, y = sim.read("u"), sim.read("y")
    logs = []
    for i in range(sim.n):  # a "real" log: torques and joint angles only, named as the arm's driver names them
        cols = {f"effort{j}": u[i, :, j] for j in range(7)}
        cols.update({f"position{j}": y[i, :, 7 + j] for j in range(7)})
        logs.append(_write_csv(tmp_path / f"panda{i}.csv", cols))
    out = str(tmp_path / "real.zarr")
    assert ingest_main([*logs, "--u-cols", ",".join(f"effort{j}" for j in range(7)),
                        "--y-cols", ",".join(f"position{j}" for j in range(7)), "--dt", str(sim.dt),
                        "--steps", "60", "--layout", "panda", "--out", out]) == 0
    real = open_store(out)
    assert real.u_names == list(panda.U_NAMES) and real.y_names == list(panda.Y_NAMES)
    assert real.attrs["y_units"][:3] == ["m"] * 3 and real.attrs["y_units"][7:] == ["rad"] * 7
    np.testing.assert_allclose(real.read("u"), u, atol=1e-6)
    # The pose from the catalogue kinematics is the one the simulator recorded (float32 precision).
    np.testing.assert_allclose(real.read("y"), y, atol=2e-6)


def test_panda_layout_needs_seven_joints(tmp_path, capsys):
    log = _write_csv(tmp_path / "a.csv", {"tau": np.zeros(50), "q": np.zeros(50)})
    code = ingest_main([log, "--u-cols", "tau", "--y-cols", "q", "--dt", "0.01", "--steps", "10", "--layout", "panda",
                        "--out", str(tmp_path / "o.zarr")])
    err = capsys.readouterr().err
    assert code == 2 and "--layout panda needs 7 --u-cols" in err and "Traceback" not in err


def test_joints_layout_names_any_arms_channels_by_role(tmp_path, capsys):
    t = np.arange(80) * 0.1
    cols = {**{f"effort{j}": np.sin(t + j) for j in range(6)}, **{f"angle{j}": np.cos(t + j) for j in range(6)}}
    log = _write_csv(tmp_path / "arm.csv", cols)
    common = [log, "--dt", "0.1", "--steps", "40", "--layout", "joints"]
    out = str(tmp_path / "arm.zarr")
    assert ingest_main([*common, "--u-cols", ",".join(f"effort{j}" for j in range(6)),
                        "--y-cols", ",".join(f"angle{j}" for j in range(6)), "--out", out]) == 0
    ds = open_store(out)
    assert ds.u_names == [f"tau{j}" for j in range(6)] and ds.y_names == [f"q{j}" for j in range(6)]
    np.testing.assert_allclose(ds.read("y")[0, :, 2], np.cos(t[:40] + 2), atol=1e-6)  # the angles, in order
    capsys.readouterr()
    code = ingest_main([*common, "--u-cols", "effort0,effort1", "--y-cols", "angle0,angle1,angle2",
                        "--out", str(tmp_path / "bad.zarr")])
    err = capsys.readouterr().err
    assert code == 2 and "--layout joints needs one --u-cols column per joint angle" in err
    assert len(err.strip().splitlines()) == 1 and not os.path.exists(tmp_path / "bad.zarr")


def _recording_store(store_factory, path, recordings: int, windows: int = 6, seed: int = 0) -> str:
    from tests.conftest import linear_system

    u, y = linear_system(recordings * windows, 40, seed=seed)
    index = np.repeat(np.arange(recordings), windows).astype(np.int32)
    return store_factory(path, u, y, extras={"recording_index": ((), "int32", index)})


def test_a_single_training_recording_with_a_val_store_still_trains(store_factory, tmp_path):
    from robomorph.data.datamodule import RoboMorphDataModule
    from robomorph.data.splits import SplitAdaptedWarning

    train = _recording_store(store_factory, tmp_path / "train.zarr", recordings=1)
    val = _recording_store(store_factory, tmp_path / "val.zarr", recordings=1, seed=1)
    dm = RoboMorphDataModule(stores=train, val_store=val, context_len=10, horizon=20, batch_size=2)
    with pytest.warns(SplitAdaptedWarning, match="test split is empty.*--data.test_store"):
        dm.setup()
    assert len(dm.splits[0]["train"]) == 6 and len(dm.splits[0]["test"]) == 0 and len(dm.val_set) == 6


def test_without_held_out_stores_the_message_names_them_and_the_split(store_factory, tmp_path):
    from robomorph.data.datamodule import RoboMorphDataModule
    from robomorph.data.splits import SplitError

    train = _recording_store(store_factory, tmp_path / "train.zarr", recordings=1)
    with pytest.raises(SplitError, match="leaves none for training; give --data.val_store"):
        RoboMorphDataModule(stores=train, context_len=10, horizon=20, batch_size=2).setup()
    val = _recording_store(store_factory, tmp_path / "val.zarr", recordings=1, seed=1)
    test = _recording_store(store_factory, tmp_path / "test.zarr", recordings=1, seed=2)
    # Both held-out stores given: the store's own shares are dropped, everything trains.
    dm = RoboMorphDataModule(stores=train, val_store=val, test_store=test, context_len=10, horizon=20, batch_size=2)
    dm.setup()
    assert len(dm.splits[0]["train"]) == 6


@pytest.mark.slow
def test_sim_to_real_zero_shot_then_fine_tuned(simulated_store, tmp_path, capsys):
    """docs/guide/real-logs.md, "Sim to real", at tiny size: Panda logs of torques and joint
    angles (simulated robots the model never saw) -> ingest --layout panda -> the simulation
    model zero-shot -> fine-tuned from it -> both scored on the same test recordings."""
    sim_store = simulated_store(robots=12, steps=60, seed=1)
    runs = tmp_path / "runs"
    sim = fit({"data": {"stores": sim_store, "context_len": 20, "horizon": 40, "batch_size": 8},
               "model": {"d_model": 16, "n_head": 2, "n_layer": 1, "max_context": 64, "max_horizon": 64},
               "trainer": {"max_steps": 4, "accelerator": "cpu", "enable_progress_bar": False,
                           "enable_model_summary": False},
               "run": "ms", "runs_dir": str(runs), "wandb": "disabled"}).best_ckpt
    robot = open_store(simulated_store(robots=6, steps=120, seed=9))  # "the real robot": other robots
    u, y = robot.read("u"), robot.read("y")
    stores = {}
    for part, rows in (("train", [0, 1, 2]), ("val", [3]), ("test", [4, 5])):
        logs = []
        for i in rows:
            cols = {"t": np.arange(120) * robot.dt}
            cols.update({f"tau_J{j + 1}": u[i, :, j] for j in range(7)})
            cols.update({f"q{j + 1}": y[i, :, 7 + j] for j in range(7)})
            logs.append(_write_csv(tmp_path / f"{part}{i}.csv", cols))
        stores[part] = str(tmp_path / f"panda_real_{part}.zarr")
        assert ingest_main([*logs, "--time-col", "t", "--resample", "60", "--layout", "panda",
                            "--u-cols", ",".join(f"tau_J{j}" for j in range(1, 8)),
                            "--y-cols", ",".join(f"q{j}" for j in range(1, 8)), "--steps", "60", "--stride", "30",
                            "--out", stores[part]]) == 0
    capsys.readouterr()
    zero = str(tmp_path / "zero")
    assert evaluate_main(["--ckpt", sim, "--data", stores["test"], "--out", zero, "--baselines", "hold",
                          "--plot-trajectories", "1", "--device", "cpu"]) == 0
    assert "in-sample" not in capsys.readouterr().out
    assert fit_main(_fit_args(stores["train"], runs, "panda-real-tuned", 4, **{
        "data.val_store": stores["val"], "data.test_store": stores["test"], "model.init_ckpt": sim})) == 0
    tuned = str(runs / "panda-real-tuned" / "checkpoints" / "best.ckpt")
    capsys.readouterr()
    ev = str(tmp_path / "tuned")
    assert evaluate_main(["--ckpt", tuned, "--data", stores["test"], "--out", ev, "--baselines", "hold",
                          "--compare", f"zeroshot={sim}", "--plot-trajectories", "1", "--device", "cpu"]) == 0
    res = json.load(open(os.path.join(ev, "metrics.json")))
    assert set(res["baselines"]) == {"hold", "zeroshot"} and res["meta"]["in_sample"] is False
    zero_res = json.load(open(os.path.join(zero, "metrics.json")))
    # The zero-shot entry of the comparison is the zero-shot evaluation itself.
    assert res["baselines"]["zeroshot"]["approach1"]["mean"]["rmse"]["mean"] == pytest.approx(
        zero_res["approach1"]["mean"]["rmse"]["mean"], rel=1e-5)
