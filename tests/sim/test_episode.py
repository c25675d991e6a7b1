"""One attempt: its random draws follow (seed, index) alone; a closed-loop run gives a row."""

import mujoco
import numpy as np

from robomorph.sim import episode, panda
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import load_recipe, replace


def test_draws_depend_on_seed_and_index_only(nominal_model):
    recipe = load_recipe(None, {"task": "multisine", "steps": 30, "seed": 4})
    rand = Randomizer(nominal_model, recipe.randomization)
    a, b, c = (episode.draw(recipe, rand, i) for i in (7, 7, 8))
    np.testing.assert_array_equal(a.params, b.params)
    np.testing.assert_array_equal(a.ctrl, b.ctrl)
    assert a.ctrl.shape == (30, panda.N_JOINT) and not np.allclose(a.ctrl, c.ctrl)
    other_seed = episode.draw(replace(recipe, seed=5), rand, 7)
    assert not np.allclose(a.params, other_seed.params)


def test_a_mixture_draws_each_task_and_osc_draws_no_signal():
    recipe = load_recipe(None, {"task": {"multisine": 1, "spiral": 1}, "seed": 0})
    tasks = [episode.draw_task(recipe, i) for i in range(40)]
    assert set(tasks) == {"multisine", "spiral"}
    assert episode.is_open_loop(recipe, "multisine") and not episode.is_open_loop(recipe, "spiral")
    nominal = replace(recipe, gravity_compensation="nominal_model")
    assert not episode.is_open_loop(nominal, "multisine")  # gravity then needs feedback


def test_nominal_gravity_is_the_bias_force_at_rest():
    recipe = load_recipe(None, {"gravity_compensation": "nominal_model"})
    g = episode.NominalGravity(recipe)(panda.HOME_QPOS)
    assert g.shape == (panda.N_JOINT,) and np.abs(g).max() > 1.0  # the arm's weight acts on its joints
    assert np.abs(episode.NominalGravity(recipe)(panda.HOME_QPOS) - g).max() == 0


def test_nominal_gravity_is_a_forward_pass_bias_force_to_the_bit():
    """Its Newton-Euler pass (no collision detection) gives what a whole forward pass gives, on every arm's joints."""
    for robot in ("panda", "ur5e"):
        recipe = load_recipe(None, {"gravity_compensation": "nominal_model", "robot": robot})
        gravity = episode.NominalGravity(recipe)
        model = gravity.model
        data = mujoco.MjData(model)
        for q in np.random.default_rng(0).uniform(-1.5, 1.5, (20, model.nq)):
            data.qpos[:], data.qvel[:] = q, 0.0
            mujoco.mj_forward(model, data)
            assert np.array_equal(gravity(q), data.qfrc_bias[:gravity.nj])


def test_a_closed_loop_attempt_gives_a_dataset_row():
    recipe = load_recipe(None, {"task": "spiral", "steps": 40, "seed": 2})
    out = episode.ClosedLoopRunner(recipe)(3)
    assert (out.task, out.index, out.reason) == ("spiral", 3, None)
    assert out.u.shape == (40, panda.N_JOINT) and out.y.shape == (40, 14) and out.target.shape == (40, 3)
    assert np.isfinite(out.kp) and np.isfinite(out.u).all()
