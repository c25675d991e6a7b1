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


GOOD = {"objective": {"metric": "val/r2", "direction": "maximize"}, "params": {"model.lr": {"low": 1e-4, "high": 1e-2}}}


@pytest.mark.parametrize("model, params, message", [
    ({"gaussian": True}, {"model.loss": {"choices": ["mse", "huber"]}}, "model.loss mse with model.gaussian true"),
    ({"gaussian": True, "loss": "nll"}, {"model.loss": {"choices": ["nll", "huber"]}}, "model.loss huber"),
    ({"gaussian": True, "loss": "huber"}, {}, "model.loss huber with model.gaussian true"),
    ({}, {"model.loss": {"choices": ["nll"]}}, "model.loss nll with model.gaussian false"),
    ({"loss": "nll"}, {"model.gaussian": {"choices": [True, False]}}, "model.loss nll with model.gaussian false"),
])
def test_a_space_must_train_the_head_it_has(model, params, message):
    with pytest.raises(SpaceError, match=message):
        parse_space({**GOOD, "base": {"model": model}, "params": {**GOOD["params"], **params}})


def test_the_same_head_and_loss_are_accepted():
    parse_space({**GOOD, "base": {"model": {"gaussian": True, "loss": "nll"}}})
    parse_space({**GOOD, "params": {"model.loss": {"choices": ["mse", "huber"]}}})  # default: no Gaussian head


def test_the_budget_wins_over_the_base_config_file_and_a_conflict_is_refused(tmp_path):
    config = tmp_path / "train.yaml"
    config.write_text("trainer: {max_steps: 20000, val_check_interval: 500, gradient_clip_val: 1.0}\n"
                      "model: {gaussian: true, loss: nll}\n")
    space = parse_space({**GOOD, "base": {"config": str(config)}, "budget": {"max_steps": 35, "val_check_interval": 5}})
    trainer = space.fit_args({}, "t", "runs")["trainer"]
    assert trainer == {"max_steps": 35, "val_check_interval": 5, "gradient_clip_val": 1.0}
    with pytest.raises(SpaceError, match="budget.max_steps and base.trainer.max_steps are both set"):
        parse_space({**GOOD, "base": {"trainer": {"max_steps": 9}}, "budget": {"max_steps": 35}})


def test_every_shipped_space_tunes_a_consistent_model_within_its_budget():
    for path in sorted(glob.glob(os.path.join(ROOT, "sweeps", "*.yaml"))):
        space = load_space(path)
        args = space.fit_args({p.name: (p.choices or [p.low])[0] for p in space.params}, "t", "runs")
        model = args.get("model", {})
        assert (model.get("loss", "huber") == "nll") == bool(model.get("gaussian", False)), path
        for key, value in space.budget.items():
            assert args["trainer"][key] == value, (path, key)
