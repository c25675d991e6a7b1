"""The industrial robot benchmark's readings: each on a case computed by hand, identibench's own
tasks against the same arithmetic, and the free runs' isolation from the true outputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robomorph.evaluation import benchmark_readings as br

# Two trajectories of three samples, two joints; each starts at rest at 0.
Y1 = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 4.0]])
Y2 = np.array([[0.0, 0.0], [0.0, 2.0], [2.0, 0.0]])
TEST = [(np.zeros((3, 1)), Y1), (np.zeros((3, 1)), Y2)]


def hold(u, y_init):
    out = np.repeat(y_init[-1:], len(u), 0)
    out[:len(y_init)] = y_init
    return out


def test_each_reading_of_hold_matches_the_hand_computed_value():
    r = br.readings(hold, TEST, warmup=1, identibench=False)
    # test outputs' std: joint 0 {0,2,0,0,0,2} -> var 8/9; joint 1 {0,0,4,0,2,0} -> var 7/3.
    # (a) one sequence from y0: errors over samples 1..5, MSE 8/5 and 20/5.
    assert r["paper"] == pytest.approx(math.sqrt(((8 / 5) / (8 / 9) + 4 / (7 / 3)) / 2), rel=1e-12)
    # (b) each trajectory from its y0: pooled errors over 4 samples, MSE 8/4 and 20/4.
    assert r["per_trajectory"] == pytest.approx(math.sqrt((2 / (8 / 9) + 5 / (7 / 3)) / 2), rel=1e-12)
    # (c) RMSE / range per trajectory and joint: sqrt2/2, sqrt8/4, sqrt2/2, sqrt2/2.
    assert r["range"] == pytest.approx(1 / math.sqrt(2), rel=1e-12)


def test_identibench_arithmetic_matches_the_hand_computed_value():
    u, y = np.zeros((6, 1)), np.concatenate([Y1, Y2])
    # simulation from 1 sample: RMSE over samples 1..5, sqrt(8/5) and 2, their mean.
    assert br.simulation_rmse(hold, u, y, init=1) == pytest.approx((math.sqrt(8 / 5) + 2) / 2, rel=1e-12)
    # prediction, windows of 1 + 2 every 2 (at 0 and 2), RMSE over the whole window:
    # window 0 errors (0,2,0), (0,0,4); window 2 held at (0,4): (0,0,0), (0,-4,-2).
    want = (math.sqrt(4 / 3) + math.sqrt(16 / 3) + 0 + math.sqrt(20 / 3)) / 4
    assert br.prediction_rmse(hold, u, y, init=1, horizon=2, step=2) == pytest.approx(want, rel=1e-12)


def test_a_perfect_predictor_scores_zero_on_every_reading():
    y_all = np.concatenate([Y1, Y2])

    def oracle(u, y_init):  # knows the answer from the input itself (u is y here)
        return u.copy()

    test = [(y, y) for _, y in TEST]
    r = br.readings(oracle, test, identibench=False)
    assert r["paper"] == r["per_trajectory"] == r["range"] == 0.0
    assert br.simulation_rmse(oracle, y_all, y_all, init=1) == 0.0


def test_the_free_runs_never_see_a_true_output_after_their_warm_up():
    rng = np.random.default_rng(0)
    test = [(rng.normal(size=(250, 2)), rng.normal(size=(250, 3))) for _ in range(2)]
    seen = []

    def spy(u, y_init):
        seen.append((len(u), y_init.copy()))
        return hold(u, y_init)

    br.readings(spy, test, warmup=2, identibench=False)
    y_all = np.concatenate([y for _, y in test])
    starts = {len(y_all): y_all, 250: None}
    for n, y_init in seen:
        # (a)-(c) hand over 2 samples, identibench's specs 100: never more than the warm-up
        assert len(y_init) in (2, br.IDENTIBENCH_INIT)
    assert any(n == len(y_all) and np.array_equal(y, starts[n][:2]) for n, y in seen)
    assert any(np.array_equal(y, test[1][1][:2]) for n, y in seen if n == 250)

    # and the prediction does not change when the outputs after the warm-up do
    other = [(u, np.concatenate([y[:2], y[2:] + 100.0])) for u, y in test]
    seen_before = [y for _, y in seen]
    seen.clear()
    br.readings(spy, other, warmup=2, identibench=False)
    assert all(np.array_equal(a, b) for a, b in zip(seen_before[:3], [y for _, y in seen][:3]))


def test_a_predictor_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="returned"):
        br.readings(lambda u, y0: np.zeros((len(u), 5)), TEST, identibench=False)


@pytest.mark.skipif(not br.identibench_installed(), reason="identibench is not installed (pip install -e .[benchmarks])")
def test_identibench_own_tasks_agree_with_the_arithmetic():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(430, 6))
    y = np.cumsum(rng.normal(size=(430, 6)), axis=0)

    def linear(u_seq, y_init):  # depends on the inputs, so the windows differ
        out = y_init[-1] + np.cumsum(0.3 * u_seq, axis=0) - np.cumsum(0.3 * u_seq, axis=0)[len(y_init) - 1]
        out[:len(y_init)] = y_init
        return out

    ours = {"identibench_simulation": br.simulation_rmse(linear, u, y),
            "identibench_prediction": br.prediction_rmse(linear, u, y)}
    theirs = br.identibench_readings(linear, u, y)
    for key in ours:  # identibench reads its files as float32
        assert theirs[key] == pytest.approx(ours[key], rel=1e-5)
