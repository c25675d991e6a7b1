import os

import pytest

from robomorph.core.errors import RoboMorphError
from robomorph.core.rundir import RunDir


def test_layout_of_a_run(tmp_path):
    run = RunDir.named(tmp_path / "runs", "ms")
    root = str(tmp_path / "runs" / "ms")
    assert run.path == root and run.name == "ms"
    assert run.config == os.path.join(root, "config.yaml")
    assert run.last_ckpt == os.path.join(root, "checkpoints", "last.ckpt")
    assert run.best_ckpt == os.path.join(root, "checkpoints", "best.ckpt")
    assert run.metrics_csv == os.path.join(root, "logs", "metrics.csv")
    assert run.eval_dir("data/ms_test.zarr") == os.path.join(root, "eval", "ms_test")
    assert run.eval_dir("data/ms_test.zarr/") == run.eval_dir("ms_test")
    assert run.wandb == os.path.join(root, "wandb") and run.wandb_id == os.path.join(root, "wandb_id.txt")


def test_a_checkpoint_maps_back_to_its_run(tmp_path, monkeypatch):
    run = RunDir.named(tmp_path, "ms")
    assert RunDir.of_checkpoint(run.best_ckpt) == run and RunDir.of_checkpoint(run.last_ckpt) == run
    monkeypatch.chdir(tmp_path)  # a relative checkpoint path resolves from the working directory
    assert RunDir.of_checkpoint(os.path.join("ms", "checkpoints", "best.ckpt")) == run


def test_looks_like_run(tmp_path):
    run = RunDir.named(tmp_path, "r")
    assert not run.looks_like_run()
    os.makedirs(run.checkpoints)
    assert run.looks_like_run()


@pytest.mark.parametrize("bad", ["..", "../../x", "/abs/path", ".", "a/b"])
def test_a_run_name_that_is_not_plain_is_refused(tmp_path, bad):
    with pytest.raises(RoboMorphError, match="is not a plain name"):
        RunDir.named(tmp_path / "runs", bad)


@pytest.mark.parametrize("store", ["..", "x/..", ".", "/", "../..", ".zarr", "a/.zarr/", "../up.zarr"])
def test_an_evaluation_folder_never_leaves_the_runs_eval_folder(tmp_path, monkeypatch, store):
    monkeypatch.chdir(tmp_path)
    run = RunDir.named(tmp_path / "runs", "ms")
    out = run.eval_dir(store)
    evals = os.path.realpath(run.evals)
    assert os.path.dirname(os.path.realpath(out)) == evals, (store, out)
    assert os.path.basename(out) not in ("", ".", "..")


def test_a_resume_point_that_is_a_folder_is_named_with_what_to_do(tmp_path):
    run = RunDir.named(tmp_path, "r")
    run.check_resume_point()  # no last.ckpt: a new run
    os.makedirs(run.last_ckpt)
    with pytest.raises(RoboMorphError, match="last.ckpt is a folder") as err:
        run.check_resume_point()
    assert "delete it" in str(err.value) and "--run" in str(err.value) and "\n" not in str(err.value)
    os.rmdir(run.last_ckpt)
    os.symlink(tmp_path / "nowhere", run.last_ckpt)
    with pytest.raises(RoboMorphError, match="last.ckpt .*cannot be read"):
        run.check_resume_point()
    os.remove(run.last_ckpt)
    with open(run.last_ckpt, "wb") as f:
        f.write(b"PK")
    run.check_resume_point()  # a file: its content is the checkpoint loader's to judge
