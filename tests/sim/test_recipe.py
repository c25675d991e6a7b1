"""Recipes: YAML plus overrides, task mixtures, validation."""

import pytest

from robomorph.core.config import ConfigError
from robomorph.sim.recipe import load_recipe, replace


def test_overrides_win_over_the_file_and_none_is_no_override(tmp_path):
    path = tmp_path / "r.yaml"
    path.write_text("task: chirp\nrobots: 10\nsteps: 50\ndt: 1\n")
    recipe = load_recipe(str(path), {"robots": 3, "steps": None})
    assert (recipe.task, recipe.robots, recipe.steps, recipe.dt) == ("chirp", 3, 50, 1.0)
    assert load_recipe(None).to_dict()["task"] == "multisine"


def test_a_mixture_is_normalized_and_labelled():
    recipe = load_recipe(None, {"task": {"multisine": 1, "spiral": 3}})
    assert recipe.task_weights == {"multisine": 0.25, "spiral": 0.75}
    assert recipe.task_label == "multisine+spiral" and recipe.has_osc
    assert not load_recipe(None, {"task": "chirp"}).has_osc


@pytest.mark.parametrize("over, message", [({"task": "walk"}, "unknown task 'walk'"),
                                           ({"task": {"chirp": 0}}, "weights must be positive"),
                                           ({"robots": 0}, "robots must be >= 1"),
                                           ({"gravity_compensation": "half"}, "gravity_compensation")])
def test_invalid_recipes_name_the_field(over, message):
    with pytest.raises(ConfigError, match=message):
        load_recipe(None, over)


def test_replace_validates():
    recipe = load_recipe(None)
    assert replace(recipe, robots=5).robots == 5
    with pytest.raises(ConfigError, match="steps must be >= 1"):
        replace(recipe, steps=0)
