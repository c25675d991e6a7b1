"""The demo: its closing table and paths, its showcase data, the std calibration it gives the hybrid (the rest
of the demo is the commands it calls, tested in their rooms)."""

import numpy as np
import pytest

from robomorph.evaluation.horizons import horizon_report
from robomorph.reproduction.demo import horizon_summary

NAMES = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]


def test_demo_ends_with_the_horizon_table_of_model_hold_and_nominal_physics():
    y = np.random.default_rng(0).normal(size=(3, 12, len(NAMES)))
    preds = {name: y + 0.001 * (k + 1) for k, name in enumerate(("model", "hold", "arx", "nominal_physics"))}
    res = {"meta": {"n": 3, "context_len": 20}, "horizons": horizon_report(y, preds, NAMES, 0.1, [1, 12])}
    text = horizon_summary(res)
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if line.startswith("|")]
    assert "3 held-out robots" in text and cells[0][2:] == ["step 1 (0.1 s)", "step 12 (1.2 s)"]
    rows = [r for r in cells if r[0].startswith("joints")]
    assert [r[1] for r in rows] == ["model", "hold", "nominal_physics"]
    assert rows[1][2:] == ["2", "2"]  # hold is off by 2 mrad on every joint here


def test_the_demo_gives_a_total_torque_model_its_blend_before_calibrating(tiny_checkpoint, tmp_path):
    import shutil

    from robomorph.inference.checkpoint import load_trained
    from robomorph.reproduction.demo import calibrate_std

    ckpt = str(tmp_path / "best.ckpt")
    shutil.copy(tiny_checkpoint, ckpt)
    assert load_trained(ckpt)[0].blend is None
    assert calibrate_std(ckpt) is False  # no Gaussian head to calibrate, but the blend is fitted
    model, info = load_trained(ckpt)
    assert info["inputs"] == "total" and model.blend is not None and model.blend.physics is not None


def _result(n: int = 3) -> dict:
    y = np.random.default_rng(0).normal(size=(n, 12, len(NAMES)))
    preds = {name: y + 0.001 * (k + 1) for k, name in enumerate(("model", "hold", "arx", "nominal_physics"))}
    return {"meta": {"n": n, "context_len": 20}, "horizons": horizon_report(y, preds, NAMES, 0.1, [1, 12])}


def test_the_demo_ends_with_one_table_and_the_paths_it_wrote(monkeypatch, capsys):
    from robomorph import demo as door
    from robomorph.reproduction import demo

    asked = {}

    def run_demo(*args):
        asked["verbose"] = args[-1]
        print("a line of a step")  # what the steps print before the end
        return demo.DemoResult(["d/multisine.zarr", "d/chirp.zarr"], "runs/demo", "runs/demo/eval/ms_heldout",
                               "results/report.html", _result(), {"data": 60.0, "training": 120.0, "evaluation": 90.0})

    monkeypatch.setattr(demo, "run_demo", run_demo)
    assert door.main([]) == 0 and asked["verbose"] is False
    lines = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
    tables = [i for i, line in enumerate(lines) if line.startswith("|") and not lines[i - 1].startswith("|")]
    assert len(tables) == 1  # one table, the closing one
    end = next(i for i in range(tables[0], len(lines)) if lines[i].startswith("written"))
    assert lines[end] == "written (minutes: data 1.0, training 2.0, evaluation 1.5):"
    assert "a line of a step" in lines[:tables[0]]  # the steps' lines come before, nothing between but the table's
    tail = lines[end + 1:]
    assert [line.split(":")[0].strip() for line in tail] == ["datasets", "training run", "evaluation", "report"]
    assert "results/report.html" in tail[-1] and "d/chirp.zarr" in tail[0]
    assert door.main(["--verbose"]) == 0 and asked["verbose"] is True


@pytest.mark.slow  # four stores generated and plotted: minutes on a loaded machine
def test_the_showcase_data_draw_the_parameters_once(tmp_path, capsys):
    """Every task draws its robots from one randomization: one histogram page, a summary and a plot per store."""
    import os

    from robomorph.core.names import TASKS
    from robomorph.reproduction.demo import make_data

    paths = make_data(str(tmp_path), robots=2, steps=40, workers=1)
    assert [os.path.basename(p) for p in paths] == [f"{t}.zarr" for t in TASKS]
    for task in TASKS:
        assert (tmp_path / f"{task}.txt").is_file() and (tmp_path / f"{task}.png").is_file()
    assert [t for t in TASKS if (tmp_path / f"{t}_params.png").is_file()] == [TASKS[0]]
    out = capsys.readouterr().out.splitlines()
    assert len(out) == len(TASKS) and f"parameters: {tmp_path / TASKS[0]}_params.png" in out[0]


def test_a_command_hybrid_takes_the_shipped_calibration_of_the_catalogue_arm(simulated_store, tmp_path):
    """The demo's hybrid predicts what Predictor.from_arm predicts (to the bit): the calibration shipped for that
    one is copied into its checkpoint, and its std is then from_arm's, with no calibration fitted."""
    from robomorph.inference.predictor import Predictor
    from robomorph.reproduction.demo import calibrate_std, shipped_std
    from robomorph.training.fitting import fit
    from tests.conftest import CKPT_CONTEXT as C
    from tests.conftest import CKPT_HORIZON as H
    from tests.conftest import tiny_fit_args
    from robomorph.data.store import open_store

    store = simulated_store(robots=24, steps=C + H, seed=3)
    ckpt = fit(tiny_fit_args(store, tmp_path / "runs", "hybrid", steps=2, data={"inputs": "command"},
                             model={"physics": "amortized", "anchor": True})).best_ckpt
    assert Predictor.from_checkpoint(ckpt, device="cpu").calibration is None
    assert calibrate_std(ckpt) is True
    pred = Predictor.from_checkpoint(ckpt, device="cpu")
    ds = open_store(store)
    u, y = ds.read_inputs("command")[:2], ds.read("y")[:2]
    arm = Predictor.from_arm("panda", **ds.attrs["config"])
    got = pred.simulate(u[:, :C], y[:, :C], u[:, C:], return_std=True, at_rest=True)
    want = arm.simulate(u[:, :C], y[:, :C], u[:, C:], return_std=True, at_rest=True)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert pred.calibration.to_dict() == arm.calibration.to_dict()
    line = shipped_std(ckpt)  # again: the same calibrations, replaced
    assert line.startswith("std: the panda's shipped calibration (fitted on ") and "ideal 68 % / 95 %" in line


def test_a_total_torque_model_has_no_shipped_calibration(tiny_checkpoint, tmp_path):
    import filecmp
    import shutil

    from robomorph.reproduction.demo import shipped_std

    ckpt = str(tmp_path / "best.ckpt")
    shutil.copy(tiny_checkpoint, ckpt)
    assert shipped_std(ckpt) is None and filecmp.cmp(ckpt, tiny_checkpoint, shallow=False)


def test_a_run_of_an_older_version_is_set_aside_not_deleted(tmp_path, monkeypatch, capsys):
    """The demo's run folder, when fit cannot resume it (a model of another version), is kept under the first
    free ``.previous-<k>`` name (robomorph.core.atomic.set_aside) and a new run trained."""
    from types import SimpleNamespace

    from robomorph.model.files import CheckpointError
    from robomorph.reproduction import demo
    from robomorph.training import fitting

    runs = tmp_path / "runs"
    (runs / "demo").mkdir(parents=True)
    (runs / "demo" / "last.ckpt").write_text("an older model")
    (runs / "demo.previous-1").mkdir()
    calls = []

    def fit(args):  # the training itself is fit's (tested in training/); here only what the demo does around it
        calls.append(args)
        if len(calls) == 1:
            raise CheckpointError("last.ckpt was written by another version")
        return SimpleNamespace(best_ckpt=str(runs / "demo" / "best.ckpt"), last_ckpt=None, run_dir=str(runs / "demo"))

    monkeypatch.setattr(fitting, "fit", fit)
    run_dir, ckpt = demo.train("train.zarr", "test.zarr", 0.1, str(runs))
    assert len(calls) == 2 and ckpt.endswith("best.ckpt")
    assert (runs / "demo.previous-2" / "last.ckpt").read_text() == "an older model"
    assert not (runs / "demo").exists() and sorted(p.name for p in runs.iterdir()) == ["demo.previous-1",
                                                                                      "demo.previous-2"]
    assert "kept at" in capsys.readouterr().out
