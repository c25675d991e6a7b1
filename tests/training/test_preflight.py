"""Pre-flight checks of fit(): every refusal is one line before the run folder exists."""

import os

import numpy as np
import pytest

from robomorph.data.generation import generate
from robomorph.data.store import create_store
from robomorph.fit import main
from robomorph.inference.checkpoint import CheckpointError, load_checkpoint_file
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit
from robomorph.training.preflight import FitError
from tests.conftest import tiny_fit_args

os.environ.setdefault("WANDB_MODE", "offline")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("data") / "ms.zarr")
    generate(load_recipe(None, {"task": "multisine", "robots": 20, "steps": 60, "chunk": 10, "seed": 1}),
             path, workers=1, progress=False)
    return path


def _args(store, runs, run, steps=2, **extra):
    return tiny_fit_args(store, runs, run, steps, data={"context_len": 20, "horizon": 40, "val_subset": 8,
                                                        **extra.pop("data", {})},
                         model={"patch": 10, "warmup_steps": 1, **extra.pop("model", {})},
                         trainer={"val_check_interval": 2, **extra.pop("trainer", {})}, **extra)


def test_zero_max_steps_is_refused_before_anything_is_written(store, tmp_path):
    with pytest.raises(FitError, match="max_steps"):
        fit(_args(store, tmp_path, "zero", steps=0))
    assert not (tmp_path / "zero").exists()


def test_a_resume_with_another_architecture_leaves_the_run_alone(store, tmp_path):
    first = fit(_args(store, tmp_path, "arch", steps=2))
    config = open(os.path.join(first.run_dir, "config.yaml")).read()
    with pytest.raises(CheckpointError, match="d_model"):
        fit(_args(store, tmp_path, "arch", steps=4, model={"d_model": 32}))
    assert open(os.path.join(first.run_dir, "config.yaml")).read() == config
    assert load_checkpoint_file(first.last_ckpt)["global_step"] == 2


@pytest.fixture(scope="module")
def nan_store(tmp_path_factory):
    """A 2-in 3-out store with one NaN (trajectory 7), and beside it ``ok.zarr`` without."""
    root = tmp_path_factory.mktemp("nan")
    rng = np.random.default_rng(0)
    u, y = rng.normal(size=(10, 60, 2)).astype(np.float32), rng.normal(size=(10, 60, 3)).astype(np.float32)
    for name in ("ok.zarr", "n.zarr"):
        if name == "n.zarr":
            y[7, 30, 1] = np.nan
        w = create_store(str(root / name), 10, 60, ["a", "b"], ["c", "d", "e"], [], {"dt": 0.01})
        w.append(u, y, np.zeros((10, 0), np.float32))
        w.finalize()
    return str(root / "n.zarr")


def _cli(store, runs, run, *extra):
    return ["--data.stores", store, "--data.context_len", "20", "--data.horizon", "40", "--data.batch_size", "4",
            "--model.d_model", "16", "--model.n_head", "2", "--model.n_layer", "1", "--model.patch", "5",
            "--trainer.max_steps", "2", "--trainer.accelerator", "cpu", "--trainer.enable_progress_bar", "false",
            "--run", run, "--runs_dir", str(runs), "--wandb", "disabled", *extra]


@pytest.mark.parametrize("extra, message", [
    (["--model.n_head", "3"], "d_model"),
    (["--data.context_len", "21", "--data.horizon", "30"], "--data.context_len 21 is not a multiple of --model.patch 5"),
    (["--data.horizon", "100"], "horizon 100"),
    (["--model.max_context", "10"], "max_context"),
    (["--model.lr", "-1"], "lr"),
    (["--data.batch_size", "0"], "batch_size"),
    (["--trainer.max_steps", "0"], "max_steps"),
])
def test_bad_settings_are_one_line_before_training(store, tmp_path, capsys, extra, message):
    assert main(_cli(store, tmp_path, "bad", *extra)) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and "u_ctx[:" not in err  # no advice meant for the Python API
    assert not (tmp_path / "bad").exists()  # a failed fit leaves no run folder


def test_nan_in_a_store_is_one_line_naming_the_trajectory(nan_store, tmp_path, capsys):
    assert main(_cli(nan_store, tmp_path, "nan")) == 2
    err = capsys.readouterr().err
    assert "trajectory 7" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "nan").exists()


def test_a_corrupt_last_checkpoint_is_one_line_and_the_run_is_kept(store, tmp_path, capsys):
    assert main(_cli(store, tmp_path, "cut")) == 0
    last, config_file = tmp_path / "cut" / "checkpoints" / "last.ckpt", tmp_path / "cut" / "config.yaml"
    data, config = last.read_bytes(), config_file.read_text()
    last.write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert main(_cli(store, tmp_path, "cut", "--trainer.max_steps", "4")) == 2
    err = capsys.readouterr().err
    assert "last.ckpt" in err and "corrupt" in err and "--ckpt_path" in err and len(err.strip().splitlines()) == 1
    assert config_file.read_text() == config
    assert last.stat().st_size == len(data) // 2  # nothing deleted behind the user's back


def test_a_failure_inside_training_removes_the_new_run_folder(store, nan_store, tmp_path):
    base = fit(_args(store, tmp_path, "base", steps=2))
    # other channels and no reinit_io: refused when the transfer loads, inside trainer.fit
    with pytest.raises(CheckpointError, match="reinit_io"):
        fit(_args(nan_store.replace("n.zarr", "ok.zarr"), tmp_path, "gone", steps=2, model={"init_ckpt": base.last_ckpt}))
    assert not (tmp_path / "gone").exists()
