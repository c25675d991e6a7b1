"""A rolling hybrid: its identifying calls are the Predictor's predictions; between them it keeps the robot and
reads only the newest samples, deterministically, for one plan or many."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph.inference.rolling import RollingError, RollingHybrid

CONTEXT, HORIZON = 60, 20


@pytest.fixture(scope="module")
def arm_and_robot(simulated_store):
    """``Predictor.from_arm`` of an arm compensating with its catalogue model, and one robot's commands and outputs."""
    from robomorph.data.store import open_store
    from robomorph.predictor import Predictor

    ds = open_store(simulated_store(robots=1, steps=CONTEXT + HORIZON + 8, seed=23,
                                    gravity_compensation="nominal_model"))
    pred = Predictor.from_arm("panda", gravity_compensation="nominal_model")
    return pred, ds.read_inputs("command")[0], ds.read("y")[0]


def _frames(u, y, first: int, count: int):
    for f in range(first, first + count):
        yield u[f - CONTEXT:f], y[f - CONTEXT:f], u[f:f + HORIZON]


def test_identifying_calls_are_the_predictors_own_predictions(arm_and_robot):
    pred, u, y = arm_and_robot
    roll = RollingHybrid(pred, reidentify=1)
    for args in _frames(u, y, CONTEXT, 3):
        got = roll.predict(*args)
        assert roll.identified and got.shape == (HORIZON, y.shape[1])
        np.testing.assert_allclose(got, pred.simulate(*args), rtol=0, atol=1e-6)  # simulate returns float32


def test_between_identifications_the_kept_robot_predicts_from_the_newest_samples(arm_and_robot):
    pred, u, y = arm_and_robot
    runs = []
    for _ in range(2):
        roll = RollingHybrid(pred, reidentify=4)
        runs.append([(roll.predict(*args), roll.identified) for args in _frames(u, y, CONTEXT, 5)])
    assert [i for _, i in runs[0]] == [True, False, False, False, True]
    for (a, _), (b, _) in zip(*runs):  # the same calls, the same numbers
        np.testing.assert_array_equal(a, b)
    args = list(_frames(u, y, CONTEXT, 5))
    fresh = np.asarray(pred.simulate(*args[2]), dtype=np.float64)
    kept = runs[0][2][0]
    truth = y[CONTEXT + 2 + 1:CONTEXT + 2 + HORIZON + 1, 7:]
    # Not the fresh identification's numbers, but as near the recorded motion as it is.
    assert np.abs(kept - fresh).max() > 0
    assert np.abs(kept[:, 7:] - truth).max() < 2 * np.abs(fresh[:, 7:] - truth).max() + 1e-4
    # It starts from the newest samples, not from the end of the context it was identified on.
    assert np.abs(kept[0, 7:] - truth[0]).max() < 1.1 * np.abs(fresh[0, 7:] - truth[0]).max() + 1e-5
    stale = runs[0][0][0]  # the identifying call's horizon, two frames behind
    assert np.abs(stale[0, 7:] - truth[0]).max() > 3 * np.abs(kept[0, 7:] - truth[0]).max()


def test_many_plans_on_one_context_are_each_plans_prediction(arm_and_robot):
    pred, u, y = arm_and_robot
    frames = list(_frames(u, y, CONTEXT, 2))
    rng = np.random.default_rng(0)
    plans = frames[1][2][None] + rng.normal(0, 0.2, (3, HORIZON, u.shape[1]))
    both = RollingHybrid(pred, reidentify=10)
    both.predict(*frames[0])
    together = both.predict(frames[1][0], frames[1][1], plans)
    assert together.shape == (3, HORIZON, y.shape[1])
    for k in range(3):
        one = RollingHybrid(pred, reidentify=10)
        one.predict(*frames[0])
        np.testing.assert_allclose(together[k], one.predict(frames[1][0], frames[1][1], plans[k]), rtol=0, atol=1e-12)
    assert np.abs(together[0] - together[1]).max() > 1e-4  # the plans differ, so do their horizons


def test_refusals_name_the_problem(arm_and_robot):
    from robomorph.predictor import Predictor

    pred, u, y = arm_and_robot
    for bad in (0, -1, True, 2.5):
        with pytest.raises(RollingError, match="reidentify"):
            RollingHybrid(pred, reidentify=bad)
    with pytest.raises(RollingError, match="command hybrid"):
        RollingHybrid(Predictor.from_arm("panda", inputs="total"))
    with pytest.raises(RollingError, match="one robot"):
        RollingHybrid(pred).predict(u[None, :CONTEXT], y[None, :CONTEXT], u[CONTEXT:CONTEXT + HORIZON])
