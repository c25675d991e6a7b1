"""The one scoring path: 1-based steps, sources, calibration, and the same numbers everywhere."""

import importlib.util
import inspect
import os
import sys

import numpy as np
import pytest

from robomorph.evaluation.horizons import IDEAL, HorizonError
from robomorph.evaluation.scoring import Predictions, resolve_steps, score_windows
from robomorph.evaluation.windows import Window
from tests.conftest import CKPT_CONTEXT as C
from tests.conftest import CKPT_HORIZON as H

DT = 1 / 60
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def ramp_window(n: int = 3, context: int = 10, horizon: int = 320) -> Window:
    """Two channels whose value is 0 at the last context sample and ``k`` at step ``k``."""
    t = np.arange(context + horizon, dtype=np.float64) - (context - 1)
    y = np.repeat(np.stack([t, 2 * t], -1)[None], n, axis=0)
    u = np.zeros((n, context + horizon, 1))
    return Window(u, y, context, horizon, ["u0"], ["a", "b"], DT, {}, np.zeros((n, 0)))


class Zero:
    """Predicts 0 everywhere (the last context value here): its error at step k is k."""

    def simulate(self, u_ctx, y_ctx, u_query):
        return np.zeros(u_query.shape[:2] + (y_ctx.shape[-1],))


class Gaussian(Zero):
    """Predicts 0 with the given std, so the error at step k is k standard deviations / k."""

    def __init__(self, std: float):
        self.std = std

    def simulate(self, u_ctx, y_ctx, u_query, return_std=False):
        mean = super().simulate(u_ctx, y_ctx, u_query)
        return (mean, np.full_like(mean, self.std)) if return_std else mean


def test_step_k_is_k_samples_after_the_last_context_sample():
    s = score_windows(Zero(), ramp_window(), (), "1,0.25s,1s,5s,end")
    h = s.result["horizons"]
    assert h["steps"] == [1, 15, 60, 300, 320]  # seconds -> round(t / dt)
    assert h["rms"]["model"]["a"] == pytest.approx([1, 15, 60, 300, 320])
    assert h["rms"]["model"]["b"] == pytest.approx([2, 30, 120, 600, 640])
    assert h["seconds"] == pytest.approx([k * DT for k in h["steps"]])
    assert s.at("model", "a", 15) == pytest.approx(15.0) and s.curve("model", "a")[0] == pytest.approx(1.0)
    with pytest.raises(HorizonError, match="outside"):
        s.at("model", "a", 0)


def test_hold_is_scored_on_the_same_steps_and_the_model_is_compared_with_it():
    w = ramp_window()
    w.y[..., 0] += 1.0  # the last context value is now 1 (channel a): hold predicts 1, the model 0
    s = score_windows(Zero(), w, ("hold",), [1, 2, 3])
    assert s.result["horizons"]["rms"]["hold"]["a"] == pytest.approx([1, 2, 3])
    assert s.result["horizons"]["rms"]["model"]["a"] == pytest.approx([2, 3, 4])
    assert s.result["horizons"]["below"]["hold"]["a"] == {"fraction": 0.0, "first_not_below": 1}
    assert set(s.result["baselines"]) == {"hold"} and "approach1" in s.result["baselines"]["hold"]


def test_steps_outside_the_horizon_are_refused():
    assert resolve_steps([5, 1, 5], 10, DT) == [1, 5]
    with pytest.raises(HorizonError, match="within 1..10"):
        resolve_steps([0, 3], 10, DT)
    with pytest.raises(HorizonError, match="outside the evaluated horizon"):
        resolve_steps("5s", 10, DT)


def test_calibration_of_a_std_that_grows_as_the_error():
    w = ramp_window(horizon=40)
    k = np.arange(1, 41, dtype=np.float64)
    std = np.repeat(np.stack([k, 2 * k], -1)[None], 3, axis=0)  # error = 1 std exactly at every step
    s = score_windows(Predictions(np.zeros_like(std), std), w, (), [1, 40])
    cal = s.result["horizons"]["calibration"]
    assert cal["all"]["1sigma"] == [1.0, 1.0] and cal["all"]["2sigma"] == [1.0, 1.0]
    miss = s.result["calibration"]["coverage_miss"]["all"]
    assert miss["1sigma"] == pytest.approx(1 - IDEAL[1]) and miss["2sigma"] == pytest.approx(1 - IDEAL[2])
    # NLL of an error of one std: log(std) + 0.5 log(2 pi) + 0.5, averaged over every value.
    expected = np.mean(np.log(std) + 0.5 * np.log(2 * np.pi) + 0.5)
    assert s.result["calibration"]["nll"]["all"] == pytest.approx(expected)
    again = score_windows(Predictions(np.zeros_like(std), 2 * std), w, (), [1])
    assert again.result["horizons"]["calibration"]["all"]["1sigma"] == [1.0]
    assert "calibration" not in score_windows(Zero(), w, (), [1]).result


def test_a_predictor_giving_a_std_is_scored_like_its_predictions():
    w = ramp_window(horizon=20)
    live = score_windows(Gaussian(3.0), w, ("hold",), [1, 20], batch_size=2)
    fixed = score_windows(Predictions(live.preds["model"], live.std), w, ("hold",), [1, 20])
    assert live.result["horizons"] == fixed.result["horizons"]
    assert live.result["calibration"] == fixed.result["calibration"]
    assert live.result["approach1"] == fixed.result["approach1"]


def test_baselines_alone_and_predictions_as_other_sources():
    w = ramp_window(horizon=20)
    s = score_windows(None, w, ("hold",), [1], others={"zero": np.zeros((3, 25, 2))})
    assert "approach1" not in s.result and set(s.preds) == {"hold", "zero"}
    assert s.preds["zero"].shape == (3, 20, 2)  # cut to the horizon
    assert s.summary("zero")["r2"] == s.result["baselines"]["zero"]["approach1"]["mean"]["r2"]["mean"]


def test_a_cut_window_keeps_the_query_start():
    w = ramp_window(context=10, horizon=20)
    short = w.cut(context_len=4, horizon=5)
    assert short.split()[1][0, -1, 0] == 0.0 and short.split()[3][0, :, 0].tolist() == [1, 2, 3, 4, 5]
    assert score_windows(Zero(), short, (), None).result["horizons"]["rms"]["model"]["a"][-1] == pytest.approx(5)


def _benchmark(name: str):
    """A benchmark script imported as a module (its folder on sys.path, as when run)."""
    sys.path.insert(0, os.path.join(REPO, "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location(f"bench_{name}", os.path.join(REPO, "benchmarks", f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(os.path.join(REPO, "benchmarks"))


def test_evaluate_and_the_ablation_benchmark_give_the_same_numbers(tiny_checkpoint, simulated_store, tmp_path):
    from robomorph.evaluation.evaluator import evaluate
    from robomorph.evaluation.requests import EvaluateConfig
    from robomorph.predictor import Predictor

    test = simulated_store(robots=6, steps=C + H, seed=2)
    res = evaluate(EvaluateConfig(ckpt=tiny_checkpoint, data=test, out=str(tmp_path / "ev"), baselines=("hold",), samples=0))
    bench = _benchmark("horizon_ablation").score(Predictor.from_checkpoint(tiny_checkpoint, device="cpu"), test,
                                                 context=C, horizon=H, random_horizon=20)
    h = res["horizons"]
    assert bench["steps"] == h["steps"] == [1, 15, 60]
    assert [bench["curve_model"][k - 1] for k in h["steps"]] == pytest.approx(h["rms"]["model"]["joints"], rel=1e-9)
    assert [bench["curve_hold"][k - 1] for k in h["steps"]] == pytest.approx(h["rms"]["hold"]["joints"], rel=1e-12)
    assert bench["r2"] == pytest.approx(res["approach1"]["mean"]["r2"]["mean"], rel=1e-9)
    assert bench["below_hold_everywhere"] == (h["below"]["hold"]["joints"]["first_not_below"] is None)


def test_the_training_module_scores_through_the_inference_object_it_owns(tiny_checkpoint, simulated_store):
    import torch

    from robomorph.model.files import read_model
    from robomorph.predictor import Predictor
    from robomorph.training.module import MetaModule

    ckpt = read_model(tiny_checkpoint)
    params = inspect.signature(MetaModule.__init__).parameters
    module = MetaModule(**{k: v for k, v in ckpt["hyper_parameters"].items() if k in params and k != "init_ckpt"})
    module.load_state_dict(ckpt["state_dict"])
    trained = module.trained_model
    assert trained.net is module.net and trained.normalizer is module.normalizer
    assert all(k.startswith(("net.", "normalizer.", "stats_ready")) for k in module.state_dict())
    test = simulated_store(robots=6, steps=C + H, seed=2)
    from robomorph.evaluation.windows import load_window

    w = load_window(test, C, H, None, None, 7, 14)
    live = score_windows(Predictor(trained, device="cpu"), w, (), [1, H])
    loaded = score_windows(Predictor.from_checkpoint(tiny_checkpoint, device="cpu"), w, (), [1, H])
    assert live.result["horizons"]["rms"] == loaded.result["horizons"]["rms"]
    with torch.no_grad():  # a weight changed in training is seen by the inference object at once
        module.net.head.weight.add_(1.0)
    assert not np.allclose(Predictor(trained, device="cpu").simulate(*w.split()[:3]), live.preds["model"])
