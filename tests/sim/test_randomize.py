import mujoco
import numpy as np
import pytest

from robomorph.sim import panda
from robomorph.sim.randomize import RandomizationConfig, Randomizer, param_names


@pytest.fixture()
def rnd(nominal_model):
    return Randomizer(nominal_model, RandomizationConfig())


def test_values_within_ranges(rnd):
    cfg = rnd.cfg
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = rnd.split(rnd.sample(rng))
        ratio = p["mass"] / rnd.mass0
        assert np.all((ratio >= 0.9) & (ratio <= 1.1))
        assert np.all(np.abs(p["com"] - rnd.ipos0) <= cfg.com_offset)
        assert np.all((p["damping"] >= 5) & (p["damping"] <= 10))
        assert np.all((p["stiffness"] >= 0.01) & (p["stiffness"] <= 0.05))
        assert np.all((p["armature"] >= 0.05) & (p["armature"] <= 0.15))
        lo_f, hi_f = cfg.frictionloss_scale
        assert np.all(rnd.friction0 > 0)  # else the bounds below say nothing
        assert np.all((p["frictionloss"] >= lo_f * rnd.friction0 - 1e-12) & (p["frictionloss"] <= hi_f * rnd.friction0 + 1e-12))
        lo, hi = rnd.index.joint_range.T
        assert np.all((p["qinit"] > lo) & (p["qinit"] < hi))


def test_seeds(rnd):
    a = rnd.sample(np.random.default_rng(1))
    b = rnd.sample(np.random.default_rng(1))
    c = rnd.sample(np.random.default_rng(2))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert len(a) == len(param_names()) == len(set(param_names()))


def test_nothing_compounds_and_params_match_the_model(nominal_model, rnd):
    import copy

    model = copy.deepcopy(nominal_model)
    rng = np.random.default_rng(3)
    first = rnd.sample(rng)
    rnd.apply(model, first)
    snapshot = (model.body_mass.copy(), model.body_inertia.copy(), model.body_ipos.copy())
    for _ in range(100):
        rnd.apply(model, rnd.sample(rng))
    rnd.apply(model, first)
    for got, want in zip((model.body_mass, model.body_inertia, model.body_ipos), snapshot):
        np.testing.assert_array_equal(got, want)
    p, ids = rnd.split(first), rnd.index.body_ids
    np.testing.assert_array_equal(model.body_mass[ids], p["mass"])
    np.testing.assert_array_equal(model.body_ipos[ids], p["com"])
    np.testing.assert_array_equal(model.dof_damping[:7], p["damping"])
    np.testing.assert_array_equal(model.jnt_stiffness[:7], p["stiffness"])
    np.testing.assert_array_equal(model.dof_armature[:7], p["armature"])
    np.testing.assert_array_equal(model.dof_frictionloss[:7], p["frictionloss"])
    # the randomized mass is what the physics sees: gravity compensation follows it
    data = mujoco.MjData(model)
    data.qpos[:] = panda.HOME_QPOS
    mujoco.mj_forward(model, data)
    fresh = mujoco.MjData(nominal_model)
    fresh.qpos[:] = panda.HOME_QPOS
    mujoco.mj_forward(nominal_model, fresh)
    assert not np.allclose(data.sensordata[panda.SENS_TAU], fresh.sensordata[panda.SENS_TAU])


@pytest.mark.parametrize("kwargs, word", [
    ({"mass_pct": -1}, "mass_pct"),
    ({"damping": (10.0, 5.0)}, "inverted"),
    ({"stiffness": (-1.0, 0.0)}, "below"),
    ({"init_q0_fraction": (0.2, 1.5)}, "init_q0_fraction"),
])
def test_bad_ranges_are_refused(kwargs, word):
    with pytest.raises(ValueError, match=word):
        RandomizationConfig(**kwargs)
