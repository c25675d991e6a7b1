"""What ``fit`` prints: steps against the budget and one line per validation, without
Lightning's epochs, tips and model summary (unless --verbose)."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys

import pytest
import yaml

from robomorph.training.fitting import build_cli
from robomorph.training.progress import Budget, StepBar, ValidationLines, clock
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LINE = re.compile(r"^validation at step (\d+)/(\d+): val/loss (-?[\d.e+-]+), val/fit (-?[\d.e+-]+) \| elapsed (\d+:\d\d)$")


@pytest.fixture(scope="module")
def store(linear_store):
    return linear_store(n=32, steps=CKPT_CONTEXT + CKPT_HORIZON)


def _fit_cli(store, tmp_path, run, *flags, wandb: str = "disabled", **sections) -> tuple[subprocess.CompletedProcess, str]:
    """``python -m robomorph.fit`` of the tiny model (7 steps, validating every 3) in a subprocess."""
    args = {**tiny_fit_args(store, tmp_path / "runs", run, steps=7, **sections), "wandb": wandb}
    config = tmp_path / f"{run}.yaml"
    config.write_text(yaml.safe_dump(args))
    env = {**os.environ, "WANDB_MODE": "disabled"}
    env.pop("PYTHONWARNINGS", None)
    done = subprocess.run([sys.executable, "-m", "robomorph.fit", "--config", str(config), *flags], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return done, str(tmp_path / "runs" / run)


def _validations(run_dir: str) -> list[int]:
    with open(os.path.join(run_dir, "logs", "metrics.csv")) as f:
        return [int(r["step"]) for r in csv.DictReader(f) if r.get("val/loss")]


def test_fit_prints_one_line_per_validation_and_nothing_of_lightnings(store, tmp_path):
    done, run_dir = _fit_cli(store, tmp_path, "quiet")
    out = done.stdout + done.stderr
    lines = [m for m in map(LINE.match, out.splitlines()) if m]
    logged = _validations(run_dir)
    # every 3 steps and the last one (the CSV log counts steps from 0)
    assert [int(m[1]) for m in lines] == [3, 6, 7] and [s + 1 for s in logged] == [3, 6, 7]
    assert all(m[2] == "7" for m in lines)
    for noise in ("Epoch", "Tip", "litlogger", "litmodels", "GPU available", "Total params", "| Name", "Deprecat"):
        assert noise not in out, noise


def test_verbose_shows_lightnings_messages_and_the_summary(store, tmp_path):
    done, _ = _fit_cli(store, tmp_path, "loud", "--verbose", "true", trainer={"enable_model_summary": True})
    out = done.stdout + done.stderr
    assert "Total params" in out and "GPU available" in out
    assert len([line for line in out.splitlines() if LINE.match(line)]) == 3


def test_the_bar_counts_optimizer_steps_and_replaces_lightnings(store, tmp_path):
    cli = build_cli(tiny_fit_args(store, tmp_path, "bar", steps=40, trainer={"enable_progress_bar": True,
                                                                           "max_time": "00:00:10:00"}))
    with cli.quiet:
        trainer = cli.trainer
        assert isinstance(trainer.progress_bar_callback, StepBar)
        assert sum(isinstance(cb, ValidationLines) for cb in trainer.callbacks) == 1
        budget = Budget(trainer)
        assert budget.max_steps == 40 and budget.cap == pytest.approx(600.0)
        assert budget.steps(12) == "12/40" and budget.time().endswith(" of 10:00")
    off = build_cli(tiny_fit_args(store, tmp_path, "nobar"))  # enable_progress_bar false: lines only
    with off.quiet:
        assert off.trainer.progress_bar_callback is None
        assert any(isinstance(cb, ValidationLines) for cb in off.trainer.callbacks)
        assert Budget(off.trainer).cap is None and Budget(off.trainer).steps(3) == "3/6"


def test_clock():
    assert (clock(0), clock(65.4), clock(3725), clock(-1)) == ("0:00", "1:05", "1:02:05", "0:00")


def test_the_bar_reads_the_loss_only_every_few_steps():
    """Reading the loss syncs a GPU with the host: not in every training step."""
    import io
    from types import SimpleNamespace

    from tqdm import tqdm

    from robomorph.training.progress import POSTFIX_EVERY

    class CountingMetrics(dict):
        reads = 0

        def get(self, key, default=None):
            CountingMetrics.reads += 1
            return super().get(key, default)

    bar = StepBar()
    bar.budget = SimpleNamespace(cap=None)
    bar.bar = tqdm(total=100, file=io.StringIO(), disable=False)
    trainer = SimpleNamespace(global_step=0, callback_metrics=CountingMetrics({"train/loss": 0.5}))
    for step in range(1, 3 * POSTFIX_EVERY + 1):
        trainer.global_step = step
        bar.on_train_batch_end(trainer)
    assert bar.bar.n == 3 * POSTFIX_EVERY
    assert CountingMetrics.reads == 3  # once every POSTFIX_EVERY steps
    bar.bar.disable = True  # not a terminal: nothing is drawn, nothing is read
    trainer.global_step += POSTFIX_EVERY
    bar.on_train_batch_end(trainer)
    assert CountingMetrics.reads == 3
    bar.close()


def test_in_a_log_fit_prints_a_line_of_steps_every_few_seconds_and_no_third_party_warning(store, tmp_path,
                                                                                           monkeypatch):
    """stderr a pipe (a log): the bar becomes plain lines of steps; an offline wandb run adds no warning (its
    "The anonymous setting has no effect" came from the setting Lightning passes: fitting.QuietWandbLogger)."""
    monkeypatch.setenv("ROBOMORPH_PROGRESS_SECONDS", "0.1")
    done, run_dir = _fit_cli(store, tmp_path, "logged", wandb="offline", trainer={"enable_progress_bar": True})
    lines = [line for line in done.stderr.splitlines() if line.startswith("training: ")]
    assert lines and all(re.match(r"training: \d/7 steps, ", line) for line in lines[:-1]), done.stderr[-2000:]
    assert re.fullmatch(r"training: 7/7 steps in \d+:\d\d \(.*\)", lines[-1])
    assert "\r" not in done.stderr  # no bar redrawn into the log
    assert os.path.isdir(os.path.join(run_dir, "wandb"))  # the wandb run was made
    out = done.stdout + done.stderr
    for noise in ("anonymous", "wandb: WARNING", "Deprecat", "FutureWarning"):
        assert noise not in out, (noise, out[-2000:])
