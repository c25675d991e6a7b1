"""The typed requests of evaluate and calibrate: validated on construction in one line naming the option,
frozen; the doors build them; ``evaluate --robot`` scores a catalogue arm's untrained hybrid; the
checkpoint is read once per command; the call of earlier releases still works, with a warning."""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest

from robomorph.evaluation.evaluator import EvaluationError, evaluate
from robomorph.evaluation.requests import BlendConfig, CalibrateConfig, EvaluateConfig, legacy
from robomorph.inference.calibration import CalibrationError


@pytest.fixture(scope="module")
def arm_store(simulated_store):
    """A tiny simulated Panda store of the command formulation (4 robots, 60 steps)."""
    return simulated_store(robots=4, steps=60, seed=2)


@pytest.mark.parametrize("kwargs, message", [
    ({}, r"^give --ckpt \(a trained model\) or --robot .*got neither$"),
    ({"ckpt": "a.ckpt", "arm": "panda"}, r"exactly one of them; got both$"),
    ({"ckpt": "a.ckpt", "n": 0}, r"^--n 0: give a positive number"),
    ({"ckpt": "a.ckpt", "batch_size": -1}, r"^--batch-size -1"),
    ({"ckpt": "a.ckpt", "context_len": "30"}, r"^--context-len must be a whole number, got '30'$"),
    ({"ckpt": "a.ckpt", "seed": -3}, r"^--seed must be a whole number >= 0, got -3$"),
    ({"ckpt": "a.ckpt", "samples": -1}, r"^--plot-trajectories must be a whole number >= 0"),
    ({"ckpt": "a.ckpt", "offset": "middle"}, r"^--offset takes 'start', 'random' or a step number"),
    ({"ckpt": "a.ckpt", "baselines": ("oracle",)}, r"^unknown baseline 'oracle'"),
    ({"ckpt": "a.ckpt", "arx_orders": (0, 2)}, r"^--arx-orders takes two whole numbers na,nb >= 1"),
    ({"ckpt": "a.ckpt", "physics": "magic"}, r"^--physics 'magic': choose one of learned, regression"),
    ({"ckpt": "a.ckpt", "inputs": "torque"}, r"^--inputs 'torque': choose one of total, command$"),
    ({"ckpt": "a.ckpt", "normalization": "z"}, r"^--normalization 'z': choose one of train_stats, paper_window$"),
    ({"ckpt": "a.ckpt", "compare": (("a", "x.ckpt"), ("a", "y.ckpt"))}, r"^--compare names \['a'\] more than once"),
    ({"arm": "ur6", "context_len": 30, "horizon": 30}, r"^--robot 'ur6' is not a registered arm: choose one of panda"),
    ({"arm": "panda", "horizon": 30}, r"^--robot panda: a catalogue hybrid records no training window: pass "
                                      r"--context-len and --horizon$"),
    ({"arm": "panda", "context_len": 30, "horizon": 30, "normalization": "paper_window"},
     r"^--normalization paper_window: a catalogue hybrid has no network"),
])
def test_evaluate_config_refuses_what_cannot_work_in_one_line_naming_the_option(kwargs, message):
    with pytest.raises(EvaluationError, match=message) as exc:
        EvaluateConfig(data="x.zarr", **kwargs)
    assert "\n" not in str(exc.value)


def test_evaluate_config_is_frozen_and_keeps_what_it_was_built_with(tmp_path):
    given = ["hold"]
    cfg = EvaluateConfig(data="data/ms_test.zarr", ckpt=str(tmp_path / "run" / "checkpoints" / "best.ckpt"),
                         baselines=given, compare={"scratch": "s.ckpt"}, offset="0", arx_train_data=["a.zarr"])
    given.append("arx")  # the caller's list changed later: the config is what it was built as
    assert cfg.baselines == ("hold",) and cfg.compare == (("scratch", "s.ckpt"),)
    assert cfg.offset == "start" and cfg.arx_train_data == ("a.zarr",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.n = 3
    assert cfg.out_dir == str(tmp_path / "run" / "eval" / "ms_test")  # <run>/eval/<store name>
    arm = EvaluateConfig(data="data/ms_test.zarr", arm="panda", context_len=30, horizon=30)
    assert arm.out_dir == os.path.join("results", "catalogue", "panda", "eval", "ms_test") and arm.model == "arm:panda"
    assert EvaluateConfig(data="d.zarr", ckpt="c.ckpt", out="o").out_dir == "o"


@pytest.mark.parametrize("cls, kwargs, message", [
    (CalibrateConfig, {"method": "median"}, r"^--method 'median': choose one of nll, quantile, coverage, power$"),
    (CalibrateConfig, {"points": "grid"}, r"^--points 'grid': choose one of columns, draws, observed$"),
    (CalibrateConfig, {"physics": "magic"}, r"^--physics 'magic': choose one of"),
    (CalibrateConfig, {"observer": "yes"}, r"^--observer takes on or off, got 'yes'$"),
    (CalibrateConfig, {"horizon": 0}, r"^--horizon 0: give a positive number"),
    (CalibrateConfig, {"ckpt": ""}, r"^--ckpt: give the checkpoint"),
    (BlendConfig, {"physics": "learned"}, r"^--blend-physics 'learned': choose one of smoothed, regression$"),
    (BlendConfig, {"seed": 1.5}, r"^--seed must be a whole number >= 0, got 1.5$"),
    (BlendConfig, {"offset": -2}, r"^--offset must be >= 0, got -2$"),
])
def test_calibrate_and_blend_configs_refuse_in_one_line(cls, kwargs, message):
    with pytest.raises(CalibrationError, match=message) as exc:
        cls(**{"ckpt": "m.ckpt", **kwargs})
    assert "\n" not in str(exc.value)


def test_the_call_of_earlier_releases_builds_the_same_config_with_a_warning():
    with pytest.warns(DeprecationWarning, match=r"evaluate\(ckpt, data, \.\.\.\) with arguments is deprecated"):
        old = legacy(EvaluateConfig, ("c.ckpt", "d.zarr", "out", 30), {"baselines": ("hold",), "samples": 0},
                     "evaluate")
    assert old == EvaluateConfig(data="d.zarr", ckpt="c.ckpt", out="out", context_len=30, baselines=("hold",), samples=0)
    with pytest.warns(DeprecationWarning):
        cal = legacy(CalibrateConfig, ("c.ckpt", "d.zarr", None, 6), {"method": "nll"}, "calibrate")
    assert cal == CalibrateConfig(ckpt="c.ckpt", data="d.zarr", n=6, method="nll")
    with pytest.raises(TypeError, match="takes the EvaluateConfig alone"):
        evaluate(EvaluateConfig(data="d.zarr", ckpt="c.ckpt"), n=3)


def test_evaluate_reads_the_checkpoint_once(tiny_checkpoint, simulated_store, tmp_path, monkeypatch):
    """The model and arx_train's training split come from one read of the file (they took two)."""
    from robomorph.model import files

    reads = []
    real = files._safe_torch_load
    monkeypatch.setattr(files, "_safe_torch_load", lambda path: reads.append(path) or real(path))
    test = simulated_store(robots=4, steps=90, seed=5)
    res = evaluate(EvaluateConfig(data=test, ckpt=tiny_checkpoint, out=str(tmp_path / "ev"),
                                  baselines=("hold", "arx_train"), samples=0, arx_orders=(1, 1)))
    assert "arx_train" in res["baselines"]  # the training split was read back (from the same record)
    assert reads == [tiny_checkpoint]


def test_the_doors_say_neither_or_both_in_one_line_with_exit_2(arm_store, tmp_path, capsys):
    from robomorph.evaluate import main

    for extra, said in (([], "got neither"), (["--ckpt", "a.ckpt", "--robot", "panda"], "got both")):
        assert main(["--data", arm_store, "--out", str(tmp_path / "o"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: give --ckpt") and err.endswith(said) and "\n" not in err
        assert not os.path.exists(tmp_path / "o")


def test_evaluate_arm_scores_the_catalogue_hybrid_with_its_baselines(arm_store, tmp_path, capsys):
    """End to end through the door: the untrained hybrid, built with the store's recipe, beside the baselines."""
    from robomorph.evaluate import main

    out = tmp_path / "arm"
    assert main(["--robot", "panda", "--data", arm_store, "--context-len", "30", "--horizon", "30", "--plot-trajectories", "0",
                 "--baselines", "hold,nominal_physics,arx_train", "--device", "cpu", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "written: " + str(out) in printed
    res = json.loads((out / "metrics.json").read_text())
    meta = res["meta"]
    assert (meta["ckpt"], meta["catalogue_arm"], meta["inputs"], meta["in_sample"]) == ("arm:panda", "panda",
                                                                                          "command", False)
    assert meta["physics"]["mode"] == "regression" and meta["physics"]["observer"]
    assert set(res["baselines"]) == {"hold", "nominal_physics"}
    assert res["skipped_baselines"]["arx_train"] == "a catalogue arm's hybrid has no training data: pass --arx-train-data"
    # The identified robot follows the recorded one far better than holding the last sample or the nominal robot.
    rmse = {name: r["approach1"]["mean"]["rmse"]["mean"] for name, r in res["baselines"].items()}
    model = res["approach1"]["mean"]["rmse"]["mean"]
    assert np.isfinite(model) and model < 0.2 * rmse["hold"] and model < rmse["nominal_physics"]
    assert "inside ±1σ" in (out / "table.md").read_text()  # its std: the spread over robots


def test_evaluate_arm_refuses_another_arms_or_formulations_store_in_one_line(arm_store, linear_store, store_factory,
                                                                              tmp_path, capsys):
    from robomorph.evaluate import main

    u, y = np.zeros((2, 60, 7), np.float32), np.zeros((2, 60, 14), np.float32)
    no_cmd = store_factory(tmp_path / "no_cmd.zarr", u, y, attrs={"dt": 1 / 60, "domain": "panda", "config": {}})
    cases = (
        (["--robot", "ur5e", "--data", arm_store], r"--robot ur5e: .* is of the panda; .* use --robot panda$"),
        (["--robot", "panda", "--data", linear_store()], r"is not a store simulated from a registered arm's recipe"),
        (["--robot", "panda", "--data", no_cmd], r"holds no u_cmd .* regenerate the store, or pass --inputs total$"),
        (["--robot", "panda", "--data", arm_store, "--physics", "learned"],
         r"physics mode 'learned' reads a trained network.*Predictor.from_arm"),
    )
    for args, said in cases:
        assert main([*args, "--context-len", "30", "--horizon", "30", "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err
        assert __import__("re").search(said, err), err
    assert not os.path.exists(tmp_path / "o")


@pytest.mark.skipif(__import__("importlib").util.find_spec("robosuite") is None,
                    reason="robosuite (the `arms` extra) is not installed")
def test_evaluate_arm_runs_on_another_registered_arm(simulated_store, tmp_path):
    """Nothing Panda-specific on the way: a UR5e store (6 joints) scored by the UR5e's catalogue hybrid."""
    from robomorph.evaluate import main

    store = simulated_store(robots=3, steps=60, seed=1, robot="ur5e")
    out = tmp_path / "ur5e"
    assert main(["--robot", "ur5e", "--data", store, "--context-len", "30", "--horizon", "30", "--plot-trajectories", "0",
                 "--baselines", "hold", "--device", "cpu", "--out", str(out)]) == 0
    res = json.loads((out / "metrics.json").read_text())
    meta = res["meta"]
    assert (meta["catalogue_arm"], meta["domain"], len(meta["u_names"])) == ("ur5e", "ur5e", 6)
    model, hold = res["approach1"]["mean"]["rmse"]["mean"], res["baselines"]["hold"]["approach1"]["mean"]["rmse"]["mean"]
    assert model < 0.2 * hold
