"""The context backtest and horizon-wise stacking (robomorph.inference.stacking) on cases built to show each rule."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from robomorph.evaluation import baselines
from robomorph.inference import kinematics
from robomorph.inference.stacking import StackConfig, StackedPredictor, StackingError

DT = 0.01


def _walk(seed: int, b: int = 6, t: int = 260, n: int = 3, noise: float = 1e-4):
    """Smooth joint motion (integrated random accelerations) with encoder noise: constant velocity's world."""
    rng = np.random.default_rng(seed)
    acc = rng.standard_normal((b, t, n)) * 0.3
    v = np.cumsum(acc, axis=1) * DT + rng.standard_normal((b, 1, n))
    y = np.cumsum(v, axis=1) * DT
    u = acc.copy()
    return u, y + noise * rng.standard_normal(y.shape)


def _rms(pred, truth, k):
    return float(np.sqrt(np.mean((pred[:, k - 1] - truth[:, k - 1]) ** 2)))


def test_the_evaluation_baselines_are_the_stacked_candidates_not_a_copy():
    assert baselines.KINEMATIC is kinematics.KINEMATIC
    assert baselines.constant_velocity is kinematics.constant_velocity


def test_on_smooth_motion_the_stack_is_no_worse_than_its_best_kinematic_candidate():
    u, y = _walk(0)
    c = 200
    sp = StackedPredictor(None, DT)
    mean = sp.simulate(u[:, :c], y[:, :c], u[:, c:])
    cands = {k: f(u[:, :c], y[:, :c], u[:, c:]) for k, f in kinematics.KINEMATIC.items()}
    for k in (1, 5, 20, 60):
        best = min(_rms(p, y[:, c:], k) for p in cands.values())
        assert _rms(mean, y[:, c:], k) <= 1.1 * best, k


def test_a_robot_holding_still_is_held_not_extrapolated_along_its_noise():
    rng = np.random.default_rng(1)
    y = 0.3 + 1e-3 * rng.standard_normal((8, 240, 2))
    u = np.zeros_like(y)
    c = 200
    mean = StackedPredictor(None, DT).simulate(u[:, :c], y[:, :c], u[:, c:])
    held = kinematics.hold(u[:, :c], y[:, :c], u[:, c:])
    cv = kinematics.constant_velocity(u[:, :c], y[:, :c], u[:, c:])
    for k in (1, 10, 40):
        assert _rms(mean, y[:, c:], k) <= 1.5 * _rms(held, y[:, c:], k)
        assert _rms(mean, y[:, c:], k) < 0.9 * _rms(cv, y[:, c:], k)


def _integrator(u_ctx, y_ctx, u_query):
    """The true dynamics of :func:`_walk` (a double integrator of u), from the context's last two samples."""
    v = (y_ctx[:, -1] - y_ctx[:, -2]) / DT
    out, q = [], y_ctx[:, -1].copy()
    for k in range(u_query.shape[1]):
        v = v + u_query[:, k] * DT
        q = q + v * DT
        out.append(q.copy())
    return np.stack(out, axis=1)


def test_a_model_that_explains_the_robot_carries_the_stack_where_kinematics_fail():
    u, y = _walk(2, noise=0.0)
    c = 200
    sp = StackedPredictor(_integrator, DT)
    mean = sp.simulate(u[:, :c], y[:, :c], u[:, c:])
    cv = kinematics.constant_velocity(u[:, :c], y[:, :c], u[:, c:])
    model = _integrator(u[:, :c], y[:, :c], u[:, c:])
    assert sp.last_check.names[-1] == "model" and sp.last_check.explained["model"].all()
    for k in (5, 30, 60):
        assert _rms(mean, y[:, c:], k) <= 0.2 * _rms(cv, y[:, c:], k)
        assert _rms(mean, y[:, c:], k) <= 1.5 * _rms(model, y[:, c:], k) + 1e-9


def test_a_model_that_does_not_explain_the_context_is_named_in_one_warning():
    u, y = _walk(3)
    wrong = lambda uc, yc, uq: kinematics.hold(uc, yc, uq) + 0.5  # noqa: E731  (another formulation's answer)
    with pytest.warns(UserWarning, match="model explains 6 of 6 context.s. worse than holding the last sample"):
        check = StackedPredictor(wrong, DT).check(u[:, :200], y[:, :200])
    assert not check.explained["model"].any()
    assert "WARNING" in check.summary()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert StackedPredictor(_integrator, DT).check(u[:, :200], y[:, :200]).explained["model"].all()


def test_the_std_is_measured_on_the_context_and_grows_past_the_backtest_reach():
    u, y = _walk(4, b=40, t=400)
    c = 200
    sp = StackedPredictor(None, DT)
    mean, std = sp.simulate(u[:, :c], y[:, :c], u[:, c:], return_std=True)
    assert std.shape == mean.shape == y[:, c:].shape and np.all(std > 0)
    reach = sp.last_check.reach
    assert reach == 100
    med = np.median(std, axis=(0, 2))
    assert np.all(np.diff(med[reach - 1:]) >= 0), "past the reach the std only grows"
    z = np.abs(mean - y[:, c:]) / std
    for k in (1, 20, 80):  # calibrated on the robot's own record, no simulation: within loose bands
        assert 0.5 <= float((z[:, k - 1] <= 1).mean()) <= 0.98
        assert 0.8 <= float((z[:, k - 1] <= 2).mean())


def test_a_one_ulp_change_of_the_context_moves_the_stack_by_no_jump():
    u, y = _walk(5)
    y32 = y.astype(np.float32)
    nudged = y32.copy()
    nudged[:, 0] = np.nextafter(nudged[:, 0], np.float32(np.inf))
    a, sa = StackedPredictor(None, DT).simulate(u[:, :200], y32[:, :200], u[:, 200:], return_std=True)
    b, sb = StackedPredictor(None, DT).simulate(u[:, :200], nudged[:, :200], u[:, 200:], return_std=True)
    assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max()
    assert np.abs(sa - sb).max() <= 1e-4 * np.abs(sa).max()


def test_beyond_the_reach_the_weights_fade_into_the_kinematic_default():
    u, y = _walk(6)
    sp = StackedPredictor(None, DT)
    sp.simulate(u[:, :200], y[:, :200], np.zeros((len(u), 2000, u.shape[2])))
    w = sp.last_check.weights
    assert np.allclose(w.sum(axis=1), 1.0)
    default = sp._default(3, 2000)[:, -1]
    assert np.abs(w[:, :, -1].mean(axis=0) - default).max() < 0.1


@pytest.mark.parametrize("bad", [{"folds": 0}, {"min_context": 0.99}, {"temperature": float("nan")},
                                 {"evidence": -1}, {"default_tau": float("inf")}, {"model_folds": 99}])
def test_settings_out_of_range_are_refused_in_one_line(bad):
    with pytest.raises(StackingError, match="out of range"):
        StackConfig(**bad)


def test_contexts_it_cannot_backtest_are_refused_clearly():
    with pytest.raises(StackingError, match="nothing to backtest"):
        StackedPredictor(None, DT).check(np.zeros((1, 3, 2)), np.zeros((1, 3, 2)))
    with pytest.raises(StackingError, match="NaN"):
        StackedPredictor(None, DT).check(np.zeros((1, 50, 2)), np.full((1, 50, 2), np.nan))
    with pytest.raises(StackingError, match="dt"):
        StackedPredictor(None, 0.0)


def test_a_trained_model_is_backtested_through_the_predictor():
    from robomorph import Predictor
    from tests.inference.kept_predictions import KEPT

    pred = Predictor.from_pretrained(str(KEPT / "total_forward"))
    pred.use_physics("none")
    w = np.load(KEPT / "windows.npz")
    u, y = w["total_u"], w["total_y"]
    check = pred.check(u, y)
    assert check.names == ["hold", "constant_velocity", "constant_acceleration", "model"]
    assert check.rmse.shape[:2] == (len(u), 4) and np.isfinite(check.rmse).all()
    assert all(c % pred.patch == 0 for c in check.folds[1]["model"])
    mean, std = pred.stacked().simulate(u[:, :30], y[:, :30], u[:, 30:], return_std=True)
    assert mean.shape == std.shape == y[:, 30:].shape


def test_several_models_are_stacked_by_name_each_on_its_own_folds():
    u, y = _walk(7, noise=0.0)
    wrong = lambda uc, yc, uq: kinematics.hold(uc, yc, uq) + 5.0  # noqa: E731
    with pytest.warns(UserWarning, match="wrong explains"):
        sp = StackedPredictor({"physics": (_integrator, 4), "wrong": wrong}, DT)
        mean = sp.simulate(u[:, :200], y[:, :200], u[:, 200:])
    check = sp.last_check
    assert check.names == ["hold", "constant_velocity", "constant_acceleration", "physics", "wrong"]
    assert len(check.folds[1]["physics"]) == 4 and len(check.folds[1]["wrong"]) == 1
    assert check.explained["physics"].all() and not check.explained["wrong"].any()
    assert check.weights[:, 4].max() < 1e-6  # the wrong one keeps no weight
    assert _rms(mean, y[:, 200:], 30) <= 0.2 * _rms(kinematics.constant_velocity(u[:, :200], y[:, :200], u[:, 200:]),
                                                    y[:, 200:], 30)
    with pytest.raises(StackingError, match="other than"):
        StackedPredictor({"hold": _integrator}, DT)


def _diverging(u_ctx, y_ctx, u_query):
    """Exact over the first 30 steps of a query, then running away: a per-context ARX that backtested well."""
    out = _integrator(u_ctx, y_ctx, u_query)
    k = np.arange(u_query.shape[1])
    return out + np.where(k >= 30, 10.0 ** np.minimum(k - 30, 6) * 1e-3, 0.0)[None, :, None]


def test_a_model_that_runs_away_on_the_query_loses_its_weight_there():
    u, y = _walk(8, noise=0.0)
    sp = StackedPredictor({"runaway": (_diverging, 8)}, DT)
    mean = sp.simulate(u[:, :200], y[:, :200], u[:, 200:])
    cv = kinematics.constant_velocity(u[:, :200], y[:, :200], u[:, 200:])
    w = sp.last_check.weights
    assert w[:, 3, :20].mean() > 0.5, "exact where it is exact"
    assert w[:, 3, 45:].max() < 1e-3, "gated where it runs away"
    assert _rms(mean, y[:, 200:], 60) <= 1.1 * _rms(cv, y[:, 200:], 60)


def test_training_recordings_teach_the_prior_that_long_horizons_fade_into():
    u, y = _walk(9, b=24, t=400, noise=0.0)
    tests_u, tests_y = _walk(10, b=6, t=400, noise=0.0)
    plain = StackedPredictor({"physics": _integrator}, DT)
    taught = StackedPredictor({"physics": _integrator}, DT).learn(u, y, 200)
    assert set(taught.learned) == {"hold", "constant_velocity", "constant_acceleration", "physics"}
    assert taught.learned["physics"][-1] > 0.9  # exact on every training window, at every step
    far = np.zeros((6, 1000, 3))
    far[:, :200] = tests_u[:, 200:]
    plain.simulate(tests_u[:, :200], tests_y[:, :200], far)
    taught.simulate(tests_u[:, :200], tests_y[:, :200], far)
    assert taught.last_check.weights[:, 3, -1].mean() > 0.9 > plain.last_check.weights[:, 3, -1].mean()
    with pytest.raises(StackingError, match="context_len"):
        StackedPredictor(None, DT).learn(u, y, 400)


def test_the_stack_setting_makes_simulate_the_stacked_prediction_and_off_gives_the_model_back():
    from robomorph import Predictor
    from robomorph.inference.predictor_checks import PredictionError
    from tests.inference.kept_predictions import KEPT

    pred = Predictor.from_pretrained(str(KEPT / "total_forward"))
    pred.use_physics("none")
    w = np.load(KEPT / "windows.npz")
    u, y = w["total_u"], w["total_y"]
    ctx = (u[:, :30], y[:, :30], u[:, 30:])
    plain = pred.simulate(*ctx)
    assert pred.stack is None
    stacked_once = pred.simulate(*ctx, stacked=True)  # one call stacked, the setting untouched
    assert pred.stack is None
    pred.stack = True
    assert pred.stack == StackConfig()
    mean, std = pred.simulate(*ctx, return_std=True)
    expected = pred.stacked().simulate(*ctx)  # the stack of the model's own (plain) prediction, not of itself
    np.testing.assert_allclose(mean, expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    np.testing.assert_allclose(stacked_once, mean, rtol=0, atol=1e-5 * np.abs(expected).max())
    assert mean.dtype == plain.dtype and std.shape == mean.shape and (std > 0).all()
    assert np.abs(mean - plain).max() > 1e-6  # stacked is not the model alone here
    np.testing.assert_array_equal(pred.simulate(*ctx, stacked=False), plain)
    with pytest.raises(PredictionError, match="stack takes a StackConfig"):
        pred.stack = "yes"
    assert pred.stack == StackConfig()  # a refused value changes nothing
    pred.stack = False
    np.testing.assert_array_equal(pred.simulate(*ctx), plain)


def test_evaluate_stacks_on_recordings_of_a_real_robot_and_not_on_simulated_stores_by_default():
    from robomorph.evaluation.evaluator import stacks
    from robomorph.evaluation.requests import EvaluateConfig
    from robomorph.evaluation.windows import EvaluationError

    assert stacks("auto", {"task": "ingested"}) and not stacks("auto", {"task": "multisine"})
    assert stacks("on", {"task": "multisine"}) and not stacks("off", {"task": "ingested"})
    assert EvaluateConfig(data="x.zarr", ckpt="c.ckpt").stacked == "auto"
    with pytest.raises(EvaluationError, match="--stacked"):
        EvaluateConfig(data="x.zarr", ckpt="c.ckpt", stacked="always")
