"""Every command turns bad input into one line on stderr and exit code 2, never a traceback.

Each command runs in a subprocess, as a user runs it, through both spellings:
``python -m robomorph.<command>`` and ``python -m robomorph <command>`` (the code behind
the ``robomorph`` console script).
"""

import os
import subprocess
import sys

import pytest

from robomorph.cli import COMMANDS

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# (command, arguments with {tmp} for a scratch folder, a phrase the message must hold)
BAD_INPUT = [
    ("generate", ["--robots", "0", "--steps", "5", "--out", "{tmp}/x.zarr", "--quiet"], "robots must be >= 1"),
    ("inspect", ["{tmp}/missing.zarr"], "dataset not found"),
    ("ingest", ["{tmp}/none.csv", "--u-cols", "a", "--y-cols", "b", "--steps", "5", "--dt", "0.1",
                "--out", "{tmp}/o.zarr"], "log file not found"),
    ("merge", ["{tmp}/missing.zarr", "--out", "{tmp}/m.zarr"], "dataset not found"),
    ("fit", ["--data.stores", "{tmp}/missing.zarr", "--data.context_len", "0", "--runs_dir", "{tmp}/runs",
             "--wandb", "disabled"], "context_len must be >= 1"),
    ("evaluate", ["--ckpt", "{tmp}/missing.ckpt", "--data", "{tmp}/missing.zarr", "--out", "{tmp}/eval"],
     "checkpoint not found"),
    ("report", ["{tmp}/no_runs"], "does not exist"),
    ("sweep", ["{tmp}/no_space.yaml", "--n-trials", "1"], "config file not found"),
    ("sweep", ["summary", "--study-name", "nope", "--storage", "sqlite:///{tmp}/optuna.db"], "no study 'nope'"),
    ("reproduce", ["table1", "--steps-factor", "0", "--work", "{tmp}/work", "--out", "{tmp}/out"],
     "steps_factor must be > 0"),
    ("demo", ["--robots", "0", "--out-dir", "{tmp}/demo", "--runs-dir", "{tmp}/runs"], "robots must be >= 1"),
]


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "MUJOCO_GL": "disable"}
    return subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=300)


def test_every_command_is_covered():
    assert {command for command, _, _ in BAD_INPUT} == set(COMMANDS)


@pytest.mark.parametrize("i", range(len(BAD_INPUT)), ids=[f"{c}-{a[0]}" for c, a, _ in BAD_INPUT])
def test_bad_input_is_one_line_and_exit_code_2(i, tmp_path):
    command, args, phrase = BAD_INPUT[i]
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    # Alternate the spellings so both are exercised across the commands.
    argv = [f"robomorph.{command}", *args] if i % 2 == 0 else ["robomorph", command, *args]
    done = _run(argv)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr + done.stdout
    errors = [line for line in done.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and phrase in errors[0], done.stderr


def test_an_unknown_command_names_the_choices():
    done = _run(["robomorph", "train"])
    assert done.returncode == 2 and "unknown command 'train'" in done.stderr and "fit" in done.stderr


def test_valid_input_still_works(tmp_path):
    done = _run(["robomorph", "generate", "--robots", "1", "--steps", "5", "--out", str(tmp_path / "s.zarr"),
                 "--quiet", "--workers", "1"])
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{tmp_path / 's.zarr'}: 1 trajectories x 5 steps")
