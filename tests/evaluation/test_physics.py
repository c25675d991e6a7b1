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
    # Only the context's velocity estimate separates the two (chaos amplifies it later).
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
