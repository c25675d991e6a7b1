import os

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
