"""Batched inverse dynamics (robomorph.identification.stacked) and the regression's box-constrained solve."""

import mujoco
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from robomorph.core.config import from_dict
from robomorph.data.store import open_store
from robomorph.identification.identify import lean_model, lean_spec
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import Recipe
from robomorph.identification.regressor import _bounded_lstsq
from robomorph.identification.stacked import StackedInverse, _read_friction, _shares, _signs, carried_bodies


def inverse_pass(m, d, nj, carried, q, v, a, bodies=False, friction=False):
    """The reference: what :meth:`StackedInverse.run` returns, one ``mj_inverse`` call per state on the single arm."""
    out = np.empty((len(q), nj))
    cdof = np.empty((len(q), nj, 6)) if bodies else None
    cfrc = np.empty((len(q), m.nbody, 6)) if bodies else None
    states, readable = np.zeros((len(q), nj), dtype=np.int32), friction
    for t in range(len(q)):
        d.qpos[:nj], d.qvel[:nj], d.qacc[:nj] = q[t], v[t], a[t]
        mujoco.mj_inverse(m, d)
        out[t] = d.qfrc_inverse[:nj]
        if readable:
            readable = _read_friction(d, states[t:t + 1], 1, m.nv, nj)
        if bodies:
            mujoco.mj_rnePostConstraint(m, d)
            cdof[t], cfrc[t] = d.cdof[:nj], d.cfrc_int
    shares = _shares(m.nbody, m.body_parentid, cdof, cfrc, carried) if bodies else None
    return out, shares, (_signs(states) if readable else None)


@pytest.fixture(scope="module")
def context(simulated_store):
    ds = open_store(simulated_store(robots=2, steps=60, seed=5))
    recipe = from_dict(Recipe, ds.attrs["config"], "store config")
    return recipe, ds.read("y").astype(np.float64)[..., 7:14], ds.read("params").astype(np.float64)


@pytest.mark.parametrize("copies", [7, 50])
@pytest.mark.parametrize("gravity", [False, True])
def test_every_copy_gives_the_single_arms_inverse_dynamics_to_the_bit(context, copies, gravity):
    """58 states in calls of 7 (a last call part full) or 50 copies: the torques, each body's share of
    them and the friction losses' columns equal one call per state on the single arm, for each robot's
    own parameters, with gravity (total torques) and without (commands)."""
    recipe, q_all, params = context
    single = lean_model(recipe.substeps, recipe.dt, False)
    if not gravity:
        single.opt.gravity[:] = 0.0
    single.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_INVDISCRETE
    rz = Randomizer(single, recipe.randomization)
    stacked = StackedInverse(lambda: lean_spec(recipe.substeps, recipe.dt, False), single, 7, copies)
    data, carried, dt = mujoco.MjData(single), carried_bodies(single, 7), recipe.dt
    for b in range(len(q_all)):
        q = q_all[b]
        v, a = (q[2:] - q[:-2]) / (2 * dt), (q[2:] - 2 * q[1:-1] + q[:-2]) / dt ** 2
        rz.apply(single, params[b])
        expect = inverse_pass(single, data, 7, carried, q[1:-1], v, a, True, True)
        stacked.load(single)
        got = stacked.run(q[1:-1], v, a, carried, True, True)
        for e, g in zip(expect, got):
            np.testing.assert_array_equal(g, e)
        assert np.abs(got[0]).max() > 0.1 and np.abs(got[2]).max() == 1.0  # torques, and some joint slid
        torque = stacked.run(q[1:-1], v, a, carried)
        np.testing.assert_array_equal(torque[0], expect[0])
        assert torque[1] is None and torque[2] is None  # shares and columns only when asked for


def test_the_copies_follow_the_single_arms_options(context):
    """The stacked model takes its options from the single arm at every load (a caller may switch the
    discrete inverse or gravity off), so it never answers for a model other than the one it mirrors."""
    recipe, q_all, params = context
    single = lean_model(recipe.substeps, recipe.dt, False)
    stacked = StackedInverse(lambda: lean_spec(recipe.substeps, recipe.dt, False), single, 7, 5)
    q = q_all[0, :8]
    v, a = np.full((8, 7), 0.3), np.full((8, 7), -2.0)
    data, carried = mujoco.MjData(single), carried_bodies(single, 7)
    answers = []
    for flip in (False, True):
        if flip:
            single.opt.enableflags ^= mujoco.mjtEnableBit.mjENBL_INVDISCRETE
            single.opt.gravity[:] = 0.0
        stacked.load(single)
        got = stacked.run(q, v, a, carried)[0]
        np.testing.assert_array_equal(got, inverse_pass(single, data, 7, carried, q, v, a)[0])
        answers.append(got)
    assert np.abs(answers[0] - answers[1]).max() > 1.0  # the switch mattered: gravity alone is newtons


def test_the_box_constrained_solve_is_bvls_minimum():
    """The active-set solve lands where scipy's BVLS does (the problem has one minimum), with entries on
    both bounds and inside, and returns the unconstrained minimum untouched when that lies in the box."""
    rng = np.random.default_rng(0)
    bounds_hit = 0
    for _ in range(300):
        n = int(rng.integers(2, 30))
        A = rng.normal(size=(n + 20, n)) * rng.uniform(0.01, 3.0, n)
        hess = A.T @ A / len(A) + 0.03 ** 2 * np.eye(n)
        grad = rng.normal(size=n) * rng.uniform(0.1, 5.0)
        z = _bounded_lstsq(hess, grad)
        chol = np.linalg.cholesky(hess)
        ref = lsq_linear(chol.T, np.linalg.solve(chol, grad), bounds=(-1.0, 1.0), method="bvls").x
        cost = lambda x: 0.5 * x @ hess @ x - grad @ x  # noqa: E731
        assert np.all(np.abs(z) <= 1.0) and cost(z) <= cost(ref) + 1e-10
        np.testing.assert_allclose(z, ref, atol=1e-6)
        bounds_hit += int(np.any(np.abs(z) == 1.0) and np.any(np.abs(z) < 1.0))
    assert bounds_hit > 100
    hess, grad = np.diag([2.0, 4.0]), np.array([1.0, -2.0])
    np.testing.assert_array_equal(_bounded_lstsq(hess, grad), np.linalg.solve(hess, grad))


@pytest.mark.parametrize("robot", ["ur5e", "iiwa", "kinova3", "xarm7", "sawyer", "jaco"])
def test_every_arms_copies_give_its_inverse_dynamics_to_the_bit(robot):
    """The other arms of the library stack as the Panda does (their joints, bodies and constraint rows in
    contiguous blocks per copy): random states, torques and bodies' shares equal one call per state."""
    single = lean_model(8, 1 / 60, False, robot)
    single.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_INVDISCRETE
    nj = single.nu
    stacked = StackedInverse(lambda: lean_spec(8, 1 / 60, False, robot), single, nj, 4)
    rng = np.random.default_rng(1)
    q, v, a = rng.normal(0.0, 0.3, (10, nj)), rng.normal(0.0, 1.0, (10, nj)), rng.normal(0.0, 3.0, (10, nj))
    carried = carried_bodies(single, nj)
    expect = inverse_pass(single, mujoco.MjData(single), nj, carried, q, v, a, True, True)
    stacked.load(single)
    got = stacked.run(q, v, a, carried, True, True)
    for e, g in zip(expect, got):
        assert (e is None) == (g is None)
        if e is not None:
            np.testing.assert_array_equal(g, e)
    assert np.abs(got[0]).max() > 0.1
