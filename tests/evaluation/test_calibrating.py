"""``robomorph.calibrate``: fitted on the validation split, stored atomically, used by the
Predictor and evaluate, removable; bad input refused without touching the checkpoint."""

import os
import subprocess
import sys

import numpy as np
import pytest

from robomorph.data.splits import split_rows
from robomorph.evaluation.calibrating import calibrate, remove
from robomorph.evaluation.evaluator import evaluate
from robomorph.evaluation.requests import CalibrateConfig, EvaluateConfig
from robomorph.evaluation.sources import predict
from robomorph.evaluation.windows import load_window
from robomorph.inference.calibration import CALIBRATION_KEY, fit
from robomorph.inference.checkpoint import load_checkpoint_file, load_trained
from robomorph.inference.predictor import Predictor
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ROBOTS = 40


@pytest.fixture(scope="module")
def gaussian(simulated_store, tmp_path_factory):
    """(training store, best.ckpt of a tiny Gaussian-head model trained on it)."""
    from robomorph.training.fitting import fit as train

    store = simulated_store(robots=ROBOTS, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1)
    result = train(tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "gauss",
                                 model={"anchor": True, "gaussian": True, "loss": "nll"}))
    return store, result.best_ckpt


def _copy(ckpt: str, folder, name: str = "model.ckpt") -> str:
    dst = str(folder / name)
    with open(ckpt, "rb") as f, open(dst, "wb") as g:
        g.write(f.read())
    return dst


def _query(store: str, rows=slice(0, 6)):
    w = load_window(store, CKPT_CONTEXT, CKPT_HORIZON, None, None, 7, 14, rows=np.arange(ROBOTS)[rows])
    return w.split()


def test_it_fits_on_the_validation_robots_only_and_the_predictor_uses_it(gaussian, tmp_path):
    store, best = gaussian
    ckpt = _copy(best, tmp_path)
    report = calibrate(CalibrateConfig(ckpt=ckpt, method="quantile"))
    src = report["calibration"]["source"]
    val = split_rows(ROBOTS, (0.8, 0.1, 0.1), 0, 0)["val"]
    assert (src["split"], src["data"], src["n"]) == ("val", [store], len(val))
    # The same fit, done by hand on exactly the validation rows, gives the same scales.
    raw = Predictor.from_checkpoint(best, device="cpu")
    u_ctx, y_ctx, u_q, y_q = load_window(store, CKPT_CONTEXT, CKPT_HORIZON, None, raw.data_info, 7, 14,
                                         rows=val).split()
    mean, std = predict(raw, u_ctx, y_ctx, u_q, 64, with_std=True)
    np.testing.assert_allclose(fit(y_q, mean, std, "quantile").scale, report["calibration"]["scale"], rtol=1e-5)
    # Stored in the checkpoint; the predictor scales the std by it and keeps the mean.
    assert load_checkpoint_file(ckpt)[CALIBRATION_KEY]["method"] == "quantile"
    model, _ = load_trained(ckpt)
    assert model.calibration is not None
    pred = Predictor.from_checkpoint(ckpt, device="cpu")
    u_ctx, y_ctx, u_q, _ = _query(store)
    m0, s0 = raw.simulate(u_ctx, y_ctx, u_q, return_std=True)
    m1, s1 = pred.simulate(u_ctx, y_ctx, u_q, return_std=True)
    np.testing.assert_array_equal(m0, m1)
    np.testing.assert_allclose(s1, s0 * pred.calibration.factors(CKPT_HORIZON)[None], rtol=1e-5)
    with pred.raw_std():
        np.testing.assert_allclose(pred.simulate(u_ctx, y_ctx, u_q, return_std=True)[1], s0, rtol=1e-6)
    assert pred.calibration is not None  # restored after the block
    # Calibrating again fits on the head's own std, not on the calibrated one: same scales.
    again = calibrate(CalibrateConfig(ckpt=ckpt, method="quantile"))
    np.testing.assert_allclose(again["calibration"]["scale"], report["calibration"]["scale"], rtol=1e-6)
    assert again["before"] == report["before"] and len(again["after"]["1sigma"]) == len(again["steps"])


def test_evaluate_scores_the_calibrated_std_and_says_where_it_was_fitted(gaussian, tmp_path, simulated_store):
    store, best = gaussian
    ckpt = _copy(best, tmp_path)
    calibrate(CalibrateConfig(ckpt=ckpt))
    test = simulated_store(robots=8, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=7)
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "eval"), baselines=("hold",), samples=0))
    meta = res["meta"]["std_calibration"]
    assert meta["split"] == "val" and meta["method"] == "power" and meta["data"] == [store]
    plain = evaluate(EvaluateConfig(ckpt=best, data=test, out=str(tmp_path / "eval0"), baselines=("hold",), samples=0))
    assert plain["meta"]["std_calibration"] is None
    assert res["approach1"] == plain["approach1"]  # the mean prediction is unchanged
    assert res["horizons"]["calibration"] != plain["horizons"]["calibration"]


def test_remove_and_out_leave_the_original_as_it_was(gaussian, tmp_path):
    _, best = gaussian
    ckpt = _copy(best, tmp_path)
    before = open(ckpt, "rb").read()
    out = str(tmp_path / "calibrated.ckpt")
    calibrate(CalibrateConfig(ckpt=ckpt, out=out))
    assert open(ckpt, "rb").read() == before and CALIBRATION_KEY in load_checkpoint_file(out)
    assert remove(out) is True and CALIBRATION_KEY not in load_checkpoint_file(out)
    assert load_trained(out)[0].calibration is None
    assert remove(out) is False


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "MUJOCO_GL": "disable"}
    return subprocess.run([sys.executable, "-m", "robomorph.calibrate", *args], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=300)


def test_refusals_are_one_line_exit_2_and_leave_the_checkpoint_untouched(gaussian, tiny_checkpoint, tmp_path,
                                                                        capsys):
    from robomorph.calibrate import main

    store, best = gaussian
    ckpt = _copy(best, tmp_path)
    before = open(ckpt, "rb").read()
    done = _cli("--ckpt", ckpt, "--data", store)  # one in a process of its own: what a shell sees
    assert done.returncode == 2 and "is a training store" in done.stderr and "Traceback" not in done.stderr

    def refused(*args: str) -> str:  # the others in this process (seconds of imports fewer each)
        assert main(list(args)) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("error: "), err
        return err

    assert "--model.physics amortized" in refused("--ckpt", ckpt, "--observer", "on")  # a black box: no context to correct
    plain = _copy(tiny_checkpoint, tmp_path, "plain.ckpt")
    plain_bytes = open(plain, "rb").read()
    assert "no Gaussian head" in refused("--ckpt", plain)
    assert open(ckpt, "rb").read() == before and open(plain, "rb").read() == plain_bytes
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_the_command_prints_the_coverage_before_and_after(gaussian, tmp_path, simulated_store):
    _, best = gaussian
    ckpt = _copy(best, tmp_path)
    held_out = simulated_store(robots=8, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=9)
    done = _cli("--ckpt", ckpt, "--data", held_out, "--horizons", "1,10,end")
    assert done.returncode == 0, done.stderr
    assert "±1σ before" in done.stdout and "whole store" in done.stdout and f"written: {ckpt}" in done.stdout
    # The default method on 8 windows: its power column reads 1, and the report says why.
    assert "power (median)" in done.stdout and "power stays 1 (a scale alone) on fewer than 128 windows" in done.stdout
    steps = [line.strip("|").split("|")[0].strip() for line in done.stdout.splitlines() if line.startswith("|")]
    assert steps[2:] == ["1", "10", str(CKPT_HORIZON)]  # after the header and the separator


def test_the_report_ranks_the_spread_and_says_when_heavy_tails_leave_a_band():
    from robomorph.evaluation.calibrating import report_text

    base = {"ckpt": "m.ckpt", "out": "m.ckpt", "steps": [1, 60], "seconds": [0.0167, 1.0], "scale": [1.1, 1.3],
            "power": [1.0, 0.75], "skill": [0.41, 0.12],
            "calibration": {"method": "power", "source": {"n": 256, "data": ["cal.zarr"], "split": "whole",
                                                          "context_len": 200, "horizon": 800}},
            "before": {"1sigma": [0.6, 0.5], "2sigma": [0.9, 0.8]}}
    inside = report_text({**base, "after": {"1sigma": [0.69, 0.71], "2sigma": [0.95, 0.94]}})
    assert "spread-error rank corr." in inside and "| 0.12" in inside and "heavier-tailed" not in inside
    tails = report_text({**base, "after": {"1sigma": [0.69, 0.74], "2sigma": [0.95, 0.91]}})
    assert "at step(s) 60 the errors are heavier-tailed" in tails and "rank correlation of 0.12-0.12" in tails


def test_the_brief_summary_is_one_line_of_the_reports_coverage(gaussian, tmp_path):
    from robomorph.evaluation.calibrating import report_text
    from robomorph.reproduction.demo import brief_text

    _, best = gaussian
    report = calibrate(CalibrateConfig(ckpt=_copy(best, tmp_path), method="coverage"))
    line = brief_text(report)
    assert "\n" not in line and len(report_text(report).splitlines()) > 5
    n = report["calibration"]["source"]["n"]
    assert line.startswith(f"std calibrated (coverage) on {n} validation windows from the start: ±1σ covers ")
    lo, hi = min(report["after"]["1sigma"]), max(report["after"]["1sigma"])
    after = f"{lo:.0%}" if f"{lo:.0%}" == f"{hi:.0%}" else f"{lo:.0%}-{hi:.0%}"
    assert f"-> {after}, ±2σ " in line and line.endswith("(ideal 68 % / 95 %)")
