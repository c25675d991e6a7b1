import dataclasses

import mujoco
import numpy as np
import pytest

from robomorph.core.config import from_dict
from robomorph.data.store import open_store
from robomorph.evaluation.physics import NominalPhysics
from robomorph.sim import panda
from robomorph.identification.identify import (
    IdentificationError,
    Identifier,
    IdentifyConfig,
    ParameterSpace,
    _gravity_terms,
    lean_model,
)
from robomorph.sim.randomize import RandomizationConfig, Randomizer
from robomorph.sim.recipe import Recipe

# Robots that differ from the catalogue in their joint damping only: every other range collapsed.
DAMPING_ONLY = {"mass_pct": 0.0, "com_offset": 0.0, "damping": [5.0, 10.0], "stiffness": [0.03, 0.03],
                "armature": [0.1, 0.1], "frictionloss_scale": [1.0, 1.0]}
CONTEXT = 60


@pytest.fixture(scope="module")
def damping_store(simulated_store):
    return open_store(simulated_store(robots=2, steps=CONTEXT + 60, seed=3, randomization=DAMPING_ONLY))


def _recipe(ds) -> Recipe:
    return from_dict(Recipe, ds.attrs["config"], "store config")


def _context(ds, inputs="command"):
    y, u = ds.read("y"), ds.read_inputs(inputs)
    return y[:, :CONTEXT, 7:14].astype(np.float64), u[:, :CONTEXT].astype(np.float64), ds.read("params")


@pytest.mark.parametrize("inputs", ["command", "total"])
def test_recovers_the_damping_of_robots_that_differ_only_there(damping_store, inputs):
    q, u, params = _context(damping_store, inputs)
    sim = NominalPhysics(damping_store.attrs, inputs)
    with Identifier(_recipe(damping_store), inputs) as ident:
        assert ident.space.names == tuple(f"damping_q{j}" for j in range(7))  # nothing else can differ
        for b in range(len(q)):
            fit = ident.fit(sim.params(q[b, 0]), q[b], u[b], np.zeros(7))  # the context opens the trajectory
            truth = params[b, ident.space.index]
            assert np.abs(fit.values - truth).max() < 0.1  # N m s/rad, over a range of 5
            catalogue = np.abs(7.5 - truth).mean()
            assert np.abs(fit.values - truth).mean() < 0.05 * catalogue
            assert fit.rms < 1e-4 and fit.rms < 0.01 * fit.rms_start  # rad, over the context
            # Only the identified entries change.
            rest = np.setdiff1d(np.arange(len(fit.params)), ident.space.index)
            np.testing.assert_array_equal(fit.params[rest], sim.params(q[b, 0])[rest])
            assert fit.converged and 1 <= fit.iterations < IdentifyConfig().max_iters
            assert fit.rollouts >= fit.iterations * len(ident.space)  # each Jacobian: one rollout per column


def test_recovers_the_springs_of_robots_that_differ_only_there(simulated_store):
    """The joints' springs (their stiffness, toward where the robot started) fitted when the kinds name
    them, as the command hybrid's regression fits them (the SPRINGS_ONLY robots of test_regressor.py)."""
    springs_only = {**DAMPING_ONLY, "damping": [7.5, 7.5], "stiffness": [1.0, 5.0]}
    ds = open_store(simulated_store(robots=2, steps=CONTEXT + 60, seed=6, randomization=springs_only))
    q, u, params = _context(ds)
    sim = NominalPhysics(ds.attrs, "command")
    with Identifier(_recipe(ds), "command", IdentifyConfig(kinds=("damping", "stiffness"))) as ident:
        assert ident.space.names == tuple(f"stiffness_q{j}" for j in range(7))  # the damping's range is collapsed
        for b in range(len(q)):
            fit = ident.fit(sim.params(q[b, 0]), q[b], u[b], np.zeros(7))  # anchored where the robot started
            truth = params[b, ident.space.index]
            assert np.abs(fit.values - truth).mean() < 0.2 * np.abs(3.0 - truth).mean()  # N m/rad
            assert fit.rms < 0.05 * fit.rms_start


def test_a_fit_is_deterministic(damping_store):
    q, u, _ = _context(damping_store)
    base = NominalPhysics(damping_store.attrs, "command").params(q[0, 0])
    with Identifier(_recipe(damping_store), "command") as ident:
        a = ident.fit(base, q[0], u[0], np.zeros(7))
        b = ident.fit(base, q[0], u[0], np.zeros(7))
    with Identifier(_recipe(damping_store), "command", IdentifyConfig(nthread=1)) as single:
        c = single.fit(base, q[0], u[0], np.zeros(7))
    np.testing.assert_array_equal(a.params, b.params)
    np.testing.assert_array_equal(a.params, c.params)  # threads change nothing
    np.testing.assert_array_equal(a.qvel_end, c.qvel_end)


def test_the_fit_stays_within_the_randomization_ranges(damping_store):
    """Identified with ranges narrower than the robots' own: the values stop at the bounds."""
    q, u, params = _context(damping_store)
    recipe = _recipe(damping_store)
    narrow = dataclasses.replace(recipe, randomization=dataclasses.replace(recipe.randomization, damping=(7.0, 7.5)))
    base = NominalPhysics(damping_store.attrs, "command").params(q[0, 0])
    with Identifier(narrow, "command") as ident:
        base[ident.space.index] = 7.25  # the narrow range's catalogue value
        fit = ident.fit(base, q[0], u[0], np.zeros(7))
    assert fit.values.min() >= 7.0 and fit.values.max() <= 7.5
    truth = params[0, ident.space.index]
    assert ((truth < 7.0) | (truth > 7.5)).any()
    # The robot lies outside the box, so the best fit inside it presses against the bounds.
    assert (np.minimum(fit.values - 7.0, 7.5 - fit.values) < 1e-3).sum() >= 2


def test_parameter_space_bounds_by_the_randomization_ranges(nominal_model):
    cfg = RandomizationConfig()
    r = Randomizer(nominal_model, cfg)
    sp = ParameterSpace.of(r, cfg)
    assert len(sp) == 29 and sp.names[0] == "mass_panda_link1" and sp.names[-1] == "frictionloss_q6"
    assert [r.names[i] for i in sp.index] == list(sp.names)
    np.testing.assert_allclose(sp.low[:8], 0.9 * r.mass0)
    np.testing.assert_allclose(sp.high[8:15], 10.0)
    z = np.linspace(-1, 1, len(sp))
    np.testing.assert_allclose(sp.to_unit(sp.from_unit(z)), z, atol=1e-12)
    # Collapsed ranges are known exactly: nothing to fit.
    fixed = dataclasses.replace(cfg, mass_pct=0.0, armature=(0.1, 0.1))
    names = ParameterSpace.of(r, fixed, ("mass", "armature", "frictionloss")).names
    assert names == tuple(f"frictionloss_q{j}" for j in range(7))


def test_bad_settings_are_refused():
    with pytest.raises(IdentificationError, match="kinds"):
        IdentifyConfig(kinds=("com",))  # the regressor's alone
    with pytest.raises(IdentificationError, match="fd_step"):
        IdentifyConfig(fd_step=0.0)


def test_a_context_of_the_wrong_shape_is_refused(damping_store):
    q, u, _ = _context(damping_store)
    with Identifier(_recipe(damping_store), "command") as ident:
        with pytest.raises(IdentificationError, match="same shape"):
            ident.fit(np.zeros(len(ident.randomizer.names)), q[0], u[0, :-1], np.zeros(7))


def test_the_lean_model_moves_as_the_full_one(damping_store):
    """A stored robot (contact-free by the generator's filters) simulated by both models."""
    q, u, params = _context(damping_store)
    recipe = _recipe(damping_store)
    full = panda.build_model(recipe.substeps, recipe.dt)
    lean = lean_model(recipe.substeps, recipe.dt, True)
    assert lean.nmesh == 0 and lean.nsensor == 0 and lean.nbuffer < full.nbuffer / 20
    for field in ("body_mass", "body_inertia", "body_ipos", "dof_damping", "dof_armature", "dof_frictionloss"):
        np.testing.assert_array_equal(getattr(lean, field), getattr(full, field))
    qpos = []
    for model in (full, lean):
        Randomizer(model, recipe.randomization).apply(model, params[0].astype(np.float64))
        data = mujoco.MjData(model)
        data.qpos[:7] = q[0, 0]
        rows = []
        for t in range(CONTEXT):
            rows.append(data.qpos[:7].copy())
            data.ctrl[:] = u[0, t]
            mujoco.mj_step(model, data, nstep=recipe.substeps)
        qpos.append(np.array(rows))
    np.testing.assert_array_equal(qpos[1], qpos[0])
    np.testing.assert_allclose(qpos[0], q[0], atol=1e-6)  # and both are the stored robot


@pytest.mark.parametrize("robot", ["panda", "kinova3", "ur5e"])
def test_gravity_is_linear_in_the_link_masses(robot):
    """The total-torque formulation takes each fitted robot's own g(q) off the torque (any arm)."""
    from robomorph.sim import arms

    if robot != "panda":
        try:
            arms.robosuite_xml(arms.get(robot).folder)
        except arms.AssetsMissingError:
            pytest.skip("robosuite (the `arms` extra) is not installed")
    model = lean_model(8, 1 / 60, True, robot)
    data = mujoco.MjData(model)
    r = Randomizer(model, RandomizationConfig(), robot)
    params = r.sample(np.random.default_rng(0))
    r.apply(model, params)
    nj = r.nj
    q = r.split(params)["qinit"] + np.random.default_rng(1).uniform(-0.3, 0.3, (3, nj))
    g_fixed, per_link = _gravity_terms(model, data, q, r.index.body_ids)
    for t in range(3):
        data.qpos[:nj] = q[t]
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(g_fixed[t] + r.split(params)["mass"] @ per_link[t], data.qfrc_gravcomp[:nj],
                                   atol=1e-10)
