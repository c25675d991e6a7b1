"""The README's "Your own robot" workflow end to end, at tiny size, through the commands.

Logs like a real arm's (benchmarks/real_log_fixture.py: 6 torques in, 6 joint angles out,
10 Hz, measurement noise, recordings of unequal length) -> ingest with units -> train from
scratch with a validation store -> fine-tune a simulated-Panda checkpoint on the new
channels -> evaluate against hold, ARX (per context and fitted on the training data) and
the scratch model.
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
    cols = ["--u-cols", "tau1,tau2,tau3,tau4,tau5,tau6", "--y-cols", "q1,q2,q3,q4,q5,q6", "--time-col", "t"]
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

    panda = str(tmp_path / "panda.zarr")
    generate(load_recipe(None, {"task": "multisine", "robots": 12, "steps": 60, "seed": 1}), panda,
             workers=1, progress=False)
    sim = fit({"data": {"stores": panda, "context_len": 20, "horizon": 40, "batch_size": 8},
               "model": {"d_model": 16, "n_head": 2, "n_layer": 1, "max_context": 64, "max_horizon": 64},
               "trainer": {"max_steps": 4, "accelerator": "cpu", "enable_progress_bar": False,
                           "enable_model_summary": False},
               "run": "panda", "runs_dir": str(runs), "wandb": "disabled"})
    assert fit_main(_fit_args(stores["train"], runs, "tuned", 20, **held_out, **{
        "model.init_ckpt": sim.best_ckpt, "model.reinit_io": "true"})) == 0
    capsys.readouterr()

    scratch = str(runs / "scratch" / "checkpoints" / "best.ckpt")
    tuned = str(runs / "tuned" / "checkpoints" / "best.ckpt")
    ev = str(tmp_path / "eval")
    evaluate_main(["--ckpt", tuned, "--data", stores["test"], "--out", ev, "--baselines", "hold,arx,arx_train",
                   "--arx-orders", "1,1", "--compare", f"scratch={scratch}", "--samples", "1"])
    text = capsys.readouterr().out
    for source in ("model", "hold", "arx", "arx_train", "scratch"):
        assert f"  {source} " in text, text
    res = json.load(open(os.path.join(ev, "metrics.json")))
    assert set(res["baselines"]) == {"hold", "arx", "arx_train", "scratch"}
    # arx_train saw exactly the training store (val and test came from their own stores)
    assert res["meta"]["baseline_notes"]["arx_train"]["trajectories"] == train.n
    assert res["meta"]["n"] == 3 and res["meta"]["u_names"] == [f"tau{i}" for i in range(1, 7)]
