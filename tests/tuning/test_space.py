"""Search spaces: parsed with errors that name the problem, suggestions, fit arguments."""

import glob
import os

import optuna
import pytest

from robomorph.tuning.space import SpaceError, load_space, parse_space

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_bad_spaces_give_clear_errors():
    good = {"objective": {"metric": "val/loss", "direction": "minimize"}, "params": {"model.lr": {"low": 1e-4, "high": 1e-2}}}
    cases = [
        ({**good, "params": {"model.no_such_arg": {"choices": [1]}}}, "unknown parameter 'model.no_such_arg'"),
        ({**good, "params": {"model.n_layer": {"choices": []}}}, "non-empty"),
        ({**good, "params": {"model.lr": {"low": 1e-2, "high": 1e-4}}}, "low 0.01 > high 0.0001"),
        ({**good, "params": {"nowhere.lr": {"low": 1, "high": 2}}}, "section"),
        ({**good, "objective": {"metric": "val/loss", "direction": "up"}}, "direction"),
        ({**good, "sampler": {"name": "cma"}}, "sampler"),
        ({**good, "colour": "blue"}, "unknown keys"),
    ]
    for data, msg in cases:
        with pytest.raises(SpaceError, match=msg.replace("(", r"\(")):
            parse_space(data)


@pytest.mark.parametrize("name", ["model.n_u", "model.n_y", "model.context_len"])
def test_what_the_data_decide_is_not_a_search_parameter(name):
    space = {"objective": {"metric": "val/loss", "direction": "minimize"}, "params": {name: {"choices": [1, 2]}}}
    with pytest.raises(SpaceError, match=f"unknown parameter '{name}'"):
        parse_space(space)


def test_every_shipped_space_parses():
    for path in sorted(glob.glob(os.path.join(ROOT, "sweeps", "*.yaml"))):
        space = load_space(path)
        assert space.params and space.direction in ("minimize", "maximize"), path


def test_a_suggestion_becomes_fit_arguments():
    space = parse_space({"objective": {"metric": "val/loss", "direction": "minimize"},
                         "params": {"model.lr": {"low": 1e-4, "high": 1e-2, "log": True},
                                    "model.n_layer": {"choices": [1, 2]}}})
    trial = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0)).ask()
    values = space.suggest(trial)
    assert 1e-4 <= values["model.lr"] <= 1e-2 and values["model.n_layer"] in (1, 2)
    args = space.fit_args(values, "t0", "runs")
    assert args["model"]["lr"] == values["model.lr"] and (args["run"], args["runs_dir"]) == ("t0", "runs")
