"""The fit's last validation, its final line, the resume's schedule note and SIGTERM."""

import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest

from robomorph.data.store import create_store
from robomorph.inference.checkpoint import load_checkpoint_file
from robomorph.training.fitting import final_line, fit
from robomorph.training.module import schedule_change

os.environ.setdefault("WANDB_MODE", "offline")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A tiny linear system: 24 trajectories of 40 steps, 2 inputs, 2 outputs."""
    path = str(tmp_path_factory.mktemp("data") / "lin.zarr")
    rng = np.random.default_rng(0)
    u = rng.normal(size=(24, 40, 2)).astype(np.float32)
    y = np.cumsum(0.1 * u, axis=1).astype(np.float32)
    w = create_store(path, 24, 40, ["a", "b"], ["c", "d"], [], {"dt": 0.1})
    w.append(u, y, np.zeros((24, 0), np.float32))
    w.finalize()
    return path


def _args(store, runs, run, steps, val_every=10):
    return {
        "data": {"stores": store, "context_len": 10, "horizon": 20, "batch_size": 4, "val_subset": 4},
        "model": {"d_model": 8, "n_head": 2, "n_layer": 1, "patch": 5, "warmup_steps": 2, "lr": 3e-3,
                  "max_context": 32, "max_horizon": 32},
        "trainer": {"max_steps": steps, "val_check_interval": val_every, "accelerator": "cpu", "devices": 1,
                    "enable_progress_bar": False, "enable_model_summary": False},
        "run": run, "runs_dir": str(runs), "wandb": "disabled",
    }


def test_the_last_step_is_validated_and_the_final_line_names_it(store, tmp_path):
    result = fit(_args(store, tmp_path, "v", steps=13, val_every=10))
    assert result.global_step == 13 and result.val_step == 13
    # the reported checkpoint holds the validated step, not step 10
    assert load_checkpoint_file(result.last_ckpt)["global_step"] == 13
    line = final_line(result)
    assert "step 13, validation at step 13: val/fit=" in line


def test_resuming_with_another_max_steps_says_how_the_schedule_changes(store, tmp_path, capsys):
    fit(_args(store, tmp_path, "s", steps=10))
    capsys.readouterr()
    fit(_args(store, tmp_path, "s", steps=30))
    err = capsys.readouterr().err
    assert "max_steps 10 -> 30, resuming at step 10" in err
    assert "decay now ends at step 30 instead of 10" in err and "lr at step 10: 0.0003 -> " in err
    hp = {"lr": 1e-3, "warmup_steps": 0, "min_lr_ratio": 0.1, "decay_steps": 50}
    assert schedule_change(hp, 10, hp, 12, 10) == ("max_steps 10 -> 12, resuming at step 10: the learning-rate "
                                                   "schedule is unchanged (decay_steps 50)")
    assert schedule_change(hp, 10, hp, 10, 10) is None


def _read_until(stream, marker: str, seen: list, done: threading.Event) -> None:
    for line in stream:
        seen.append(line)
        if marker in line:
            done.set()
    done.set()


def test_sigterm_saves_last_ckpt_and_the_same_command_resumes(store, tmp_path):
    cmd = [sys.executable, "-m", "robomorph.fit", "--data.stores", store, "--data.context_len", "10",
           "--data.horizon", "20", "--data.batch_size", "4", "--model.d_model", "8", "--model.n_head", "2",
           "--model.n_layer", "1", "--model.patch", "5", "--trainer.max_steps", "1000000",
           "--trainer.val_check_interval", "1000000", "--trainer.accelerator", "cpu",
           "--trainer.enable_progress_bar", "false", "--run", "term", "--runs_dir", str(tmp_path),
           "--wandb", "disabled"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONWARNINGS": "ignore"})
    seen, started = [], threading.Event()
    reader = threading.Thread(target=_read_until, args=(proc.stderr, "training from step", seen, started))
    reader.start()
    assert started.wait(240), "".join(seen)[-2000:]
    assert proc.poll() is None, "".join(seen)[-2000:]
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(120) == 143
    reader.join(10)
    last = tmp_path / "term" / "checkpoints" / "last.ckpt"
    assert last.is_file()  # no validation ran: only the SIGTERM handler can have written it
    step = load_checkpoint_file(str(last))["global_step"]
    assert step >= 1 and f"stopped by SIGTERM at step {step}: saved {last}" in "".join(seen)
    args = _args(store, tmp_path, "term", steps=step + 3)
    args["model"] = {"d_model": 8, "n_head": 2, "n_layer": 1, "patch": 5, "max_context": 1024, "max_horizon": 1024}
    resumed = fit(args)
    assert resumed.global_step == step + 3
