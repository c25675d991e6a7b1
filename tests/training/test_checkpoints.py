"""Checkpoint I/O that is never half-written, and the CSV log a resumed run prunes."""

import csv

import pytest
import torch

from robomorph.training.checkpoints import AtomicCheckpointIO, prune_log


def test_an_interrupted_checkpoint_write_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "last.ckpt"
    io = AtomicCheckpointIO()
    io.save_checkpoint({"global_step": 1, "w": torch.ones(3)}, str(path))
    before = path.read_bytes()

    def dies_mid_write(obj, f, *a, **k):
        f.write(b"half a checkpoint")
        raise KeyboardInterrupt  # the job is killed while writing

    monkeypatch.setattr(torch, "save", dies_mid_write)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"global_step": 2, "w": torch.zeros(3)}, str(path))
    assert path.read_bytes() == before
    assert torch.load(path, weights_only=False)["global_step"] == 1



def _write_log(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["step", "train/loss", "val/loss"])
        w.writeheader()
        w.writerows(rows)


def test_prune_log_drops_the_steps_a_resumed_run_logs_again(tmp_path):
    path = tmp_path / "metrics.csv"
    _write_log(path, [{"step": s, "train/loss": 1.0 / (s + 1), "val/loss": ""} for s in (0, 9, 10, 19, 20, 29)])
    prune_log(str(path), 20)
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ["step", "train/loss", "val/loss"]
        assert [int(r["step"]) for r in reader] == [0, 9, 10, 19]
    before = path.read_bytes()
    prune_log(str(path), 100)  # nothing past the checkpoint: the file is left alone
    assert path.read_bytes() == before
    prune_log(str(tmp_path / "absent.csv"), 5)  # a run that never logged
    assert not (tmp_path / "absent.csv").exists()
