import numpy as np
import pytest

from robomorph.data.store import open_store
from robomorph.evaluation import metrics
from robomorph.evaluation.baselines import hold
from robomorph.evaluation.physics import NominalPhysics, NotApplicable

# The catalogue robot: every range collapsed onto the value the baseline takes as nominal.
UNRANDOMIZED = {"mass_pct": 0.0, "com_offset": 0.0, "damping": [7.5, 7.5], "stiffness": [0.03, 0.03],
                "armature": [0.1, 0.1], "frictionloss_scale": [1.0, 1.0]}


@pytest.fixture(scope="module")
def nominal_store(simulated_store):
    return open_store(simulated_store(robots=4, steps=300, seed=5, randomization=UNRANDOMIZED))


def test_nominal_physics_matches_an_unrandomized_robot(nominal_store):
    u, y = nominal_store.read("u"), nominal_store.read("y")
    c, h = 200, 60
    sim = NominalPhysics(nominal_store.attrs)
    pred = sim(u[:, :c], y[:, :c], u[:, c:c + h])
    truth = y[:, c:c + h].astype(np.float64)
    assert pred.shape == truth.shape
    # Only the context's velocity estimate separates the two (the total torque amplifies it later).
    assert np.abs(pred - truth).max() < 2e-3
    assert metrics.approach2(truth, pred, nominal_store.y_names)["mean"]["r2"] > 0.99
    err_hold = np.abs(hold(u[:, :c], y[:, :c], u[:, c:c + h]) - truth).max()
    assert np.abs(pred - truth).max() < 0.05 * err_hold


def test_nominal_physics_is_skipped_for_other_stores(nominal_store):
    attrs = dict(nominal_store.attrs)
    with pytest.raises(NotApplicable, match="domain"):
        NominalPhysics({**attrs, "domain": "real"})
    with pytest.raises(NotApplicable, match="layout"):
        NominalPhysics({**attrs, "y_names": ["a"] * 14})


def test_true_physics_uses_each_robots_own_parameters(simulated_store):
    ds = open_store(simulated_store(robots=3, steps=260, seed=6))
    u, y, params = ds.read("u"), ds.read("y"), ds.read("params")
    c, h = 200, 60
    sim = NominalPhysics(ds.attrs)
    truth = y[:, c:c + h].astype(np.float64)
    true_err = np.abs(sim(u[:, :c], y[:, :c], u[:, c:c + h], params=params) - truth).max()
    nominal_err = np.abs(sim(u[:, :c], y[:, :c], u[:, c:c + h]) - truth).max()
    assert true_err < 2e-3 and nominal_err > 5 * true_err


@pytest.fixture(scope="module", params=["true_model", pytest.param("nominal_model", marks=pytest.mark.slow)])
def long_store(request, simulated_store):
    """1000-step robots: a context of 200 steps, then the paper's 800-step horizon."""
    return open_store(simulated_store(robots=2, steps=1000, seed=7, gravity_compensation=request.param))


def test_true_physics_follows_the_command_formulation_over_800_steps(long_store):
    """Replaying the command on an arm compensating its own gravity reproduces the stored
    trajectory: within 1 mrad at every step of the horizon (nothing grows)."""
    ds, c = long_store, 200
    y, u_cmd, params = ds.read("y"), ds.read_inputs("command"), ds.read("params")
    sim = NominalPhysics(ds.attrs, inputs="command")
    pred = sim(u_cmd[:, :c], y[:, :c], u_cmd[:, c:], params=params)
    assert pred.shape == (2, 800, 14)
    assert np.abs(pred[..., 7:] - y[:, c:, 7:]).max() < 1e-3
    # The catalogue robot drifts away from the true one: the formulation leaves model error visible.
    nominal = sim(u_cmd[:, :c], y[:, :c], u_cmd[:, c:])
    assert np.abs(nominal[..., 7:] - y[:, c:, 7:]).max() > 10e-3


def test_the_total_torque_formulation_cannot_be_followed_that_far(long_store):
    """Replaying the recorded total torque from the same state: g(q) is paid at the recorded
    state, so the rounding of u grows until the simulated arm has left the recorded one."""
    ds, c = long_store, 200
    y, u, params = ds.read("y"), ds.read_inputs("total"), ds.read("params")
    pred = NominalPhysics(ds.attrs, inputs="total")(u[:, :c], y[:, :c], u[:, c:], params=params)
    err = np.abs(pred[..., 7:] - y[:, c:, 7:]).max(axis=(0, 2))
    assert err[:20].max() < 1e-3 and err[-1] > 0.05
