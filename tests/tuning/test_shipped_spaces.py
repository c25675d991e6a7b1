"""Every shipped search space runs end to end at a tiny budget, searching what it says."""

from __future__ import annotations

import dataclasses
import glob
import os

import optuna
import pytest
import yaml

from robomorph.training.fitting import fit
from robomorph.tuning.runner import run_sweep, with_overrides
from robomorph.tuning.space import Param, SpaceError, load_space
from robomorph.tuning.storage import open_storage

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SPACES = sorted(os.path.basename(p)[:-5] for p in glob.glob(os.path.join(ROOT, "sweeps", "*.yaml")))
QUICK = ("ci", "architecture_cpu", "context_cpu")  # the others (a pre-training, several regimes) are `slow`
STEPS = 4
# A tiny model and window on a 200-step store: every context_frac of the context spaces
# (5 % to 50 %) gives a whole number of patches that fits the positional table.
TINY = ["model.d_model=16", "model.n_head=2", "model.n_layer=1", "model.n_layer_dec=1", "model.patch=5",
        "model.max_context=128", "model.max_horizon=64", "model.warmup_steps=1", "model.n_init=0",
        "data.horizon=60", "data.batch_size=8", "data.val_subset=4", "data.context_min=null", "data.horizon_min=null",
        "data.split=[0.75, 0.25, 0.0]", f"trainer.max_steps={STEPS}", "trainer.val_check_interval=2",
        "trainer.max_time=null", "trainer.accelerator=cpu", "trainer.devices=1", "trainer.enable_progress_bar=false"]
SIZES = {"model.d_model": 16, "model.n_head": 2, "model.n_layer": 1}  # searched sizes, shrunk


@pytest.fixture(scope="module")
def store(linear_store):
    return linear_store(n=24, steps=200)


def _tiny(space, store: str, pairs=tuple(TINY)):
    space = with_overrides(space, [*pairs, f"data.stores={store}"])
    if space.base.get("data", {}).get("context_len", 0) is not None:
        space = with_overrides(space, ["data.context_len=30"])
    params = tuple(Param(p.name, choices=(SIZES[p.name],)) if p.name in SIZES else p for p in space.params)
    return dataclasses.replace(space, params=params)


@pytest.mark.parametrize("name", [n if n in QUICK else pytest.param(n, marks=pytest.mark.slow) for n in SPACES])
def test_every_shipped_space_runs_end_to_end(name, store, tmp_path):
    space = _tiny(load_space(name), store)
    runs = tmp_path / "runs"
    regimes = next((p.choices for p in space.params if p.name == "transfer.regime"), None)
    if regimes:
        # The pre-training the space's header documents, tiny: the space's own model on the store.
        pre = fit({**space.fit_args({}, "pretrain", str(runs)), "wandb": "disabled"})
        space = dataclasses.replace(with_overrides(space, [f"transfer.init_ckpt={pre.best_ckpt}",
                                                           f"transfer.steps={STEPS}"]), eval_data=store)
    n = len(regimes) if regimes else 1
    study = run_sweep(space, n, open_storage(f"sqlite:///{tmp_path / 'optuna.db'}"), name, str(runs), wandb="disabled")
    trials = study.get_trials()
    assert len(trials) == n and all(t.state == optuna.trial.TrialState.COMPLETE for t in trials), \
        [(t.state, t.user_attrs) for t in trials]
    trained = [t for t in trials if t.params.get("transfer.regime") != "zero_shot"]
    assert trained
    for t in trained:
        with open(os.path.join(t.user_attrs["run_dir"], "config.yaml")) as f:
            config = yaml.safe_load(f)
        assert config["trainer"]["max_steps"] == STEPS and t.user_attrs["global_step"] == STEPS
        assert (config["model"]["loss"] == "nll") == config["model"]["gaussian"]  # the head is trained
        for p in space.params:
            if not p.name.startswith("transfer."):
                section, arg = p.name.split(".")
                assert config[section][arg] == t.params[p.name]  # searched what it says


def test_the_spaces_own_budget_is_what_a_trial_trains(store, tmp_path):
    """architecture_cpu's base config (train_cpu.yaml) asks for 20,000 steps; the space's budget wins."""
    space = load_space("architecture_cpu")
    assert space.budget["max_steps"] == 3500 and space.base_args()["trainer"]["max_steps"] == 20000
    pairs = [p for p in TINY if not p.startswith(("trainer.max_steps", "trainer.max_time", "trainer.val_check"))]
    tiny = _tiny(dataclasses.replace(space, budget={**space.budget, "max_steps": 3}), store, pairs)
    study = run_sweep(tiny, 1, open_storage(f"sqlite:///{tmp_path / 'b.db'}"), "budget", str(tmp_path), "disabled")
    trial = study.get_trials()[0]
    with open(os.path.join(trial.user_attrs["run_dir"], "config.yaml")) as f:
        config = yaml.safe_load(f)
    assert config["trainer"]["max_steps"] == 3 and config["trainer"]["val_check_interval"] == 250
    assert trial.user_attrs["global_step"] == 3


def test_a_transfer_space_without_its_checkpoint_is_refused_before_any_trial(store, tmp_path):
    space = _tiny(load_space("transfer"), store)
    with pytest.raises(SpaceError, match=r"transfer.init_ckpt results/runs/pretrain-ms-chirp/checkpoints/best.ckpt "
                                         r"does not exist: pre-train it first .* --set transfer.init_ckpt=PATH"):
        run_sweep(space, 1, open_storage(f"sqlite:///{tmp_path / 't.db'}"), "t", str(tmp_path), "disabled")
    assert not glob.glob(str(tmp_path / "t-t*"))  # no trial ran
