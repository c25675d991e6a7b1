"""Every command turns bad input into one line on stderr and exit code 2, never a traceback.

Each command runs in a subprocess, as a user runs it, through both spellings:
``python -m robomorph.<command>`` and ``python -m robomorph <command>`` (the code behind
the ``robomorph`` console script).
"""

import concurrent.futures
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
    ("arms", ["add", "mine", "--urdf", "{tmp}/missing.urdf"], "URDF file not found"),
    ("merge", ["{tmp}/missing.zarr", "--out", "{tmp}/m.zarr"], "dataset not found"),
    ("priors", ["{tmp}/missing.zarr", "--out", "{tmp}/p.zarr"], "dataset not found"),
    ("fit", ["--data.stores", "{tmp}/missing.zarr", "--data.context_len", "0", "--runs_dir", "{tmp}/runs",
             "--wandb", "disabled"], "context_len must be >= 1"),
    ("evaluate", ["--ckpt", "{tmp}/missing.ckpt", "--data", "{tmp}/missing.zarr", "--out", "{tmp}/eval"],
     "checkpoint not found"),
    ("calibrate", ["--ckpt", "{tmp}/missing.ckpt"], "checkpoint not found"),
    ("export", ["--ckpt", "{tmp}/missing.ckpt", "--out", "{tmp}/model"], "checkpoint not found"),
    ("report", ["{tmp}/no_runs"], "does not exist"),
    ("sweep", ["{tmp}/no_space.yaml", "--n-trials", "1"], "config file not found"),
    ("sweep", ["summary", "--study-name", "nope", "--storage", "sqlite:///{tmp}/optuna.db"], "no study 'nope'"),
    ("reproduce", ["table1", "--steps-factor", "0", "--work", "{tmp}/work", "--out", "{tmp}/out"],
     "steps_factor must be > 0"),
    ("demo", ["--robots", "0", "--out", "{tmp}/demo", "--runs-dir", "{tmp}/runs"],
     "argument --robots: takes a whole number >= 1"),
    ("control", ["--robots", "0", "--out", "{tmp}/control"], "argument --robots: takes a whole number >= 1"),
]


def _env() -> dict:
    return {**os.environ, "WANDB_MODE": "disabled", "MUJOCO_GL": "disable"}


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=ROOT, env=_env(),
                          timeout=300)


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory) -> list[subprocess.CompletedProcess]:
    """Every case's finished process; a few run at once (they spend their time importing)."""
    argvs = []
    for i, (command, args, _) in enumerate(BAD_INPUT):
        tmp = str(tmp_path_factory.mktemp(command))
        args = [a.replace("{tmp}", tmp) for a in args]
        # Alternate the spellings so both are exercised across the commands.
        argvs.append([f"robomorph.{command}", *args] if i % 2 == 0 else ["robomorph", command, *args])
    with concurrent.futures.ThreadPoolExecutor(max_workers=3) as pool:
        return list(pool.map(_run, argvs))


def test_every_command_is_covered():
    assert {command for command, _, _ in BAD_INPUT} == set(COMMANDS)


@pytest.mark.parametrize("i", range(len(BAD_INPUT)), ids=[f"{c}-{a[0]}" for c, a, _ in BAD_INPUT])
def test_bad_input_is_one_line_and_exit_code_2(i, bad_runs):
    code, out, err = bad_runs[i].returncode, bad_runs[i].stdout, bad_runs[i].stderr
    assert code == 2, (out, err)
    assert "Traceback" not in err + out
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and BAD_INPUT[i][2] in errors[0], err


def test_an_unknown_command_names_the_choices():
    done = _run(["robomorph", "train"])
    assert done.returncode == 2 and "unknown command 'train'" in done.stderr and "fit" in done.stderr


def test_valid_input_still_works(tmp_path):
    done = _run(["robomorph", "generate", "--robots", "1", "--steps", "5", "--out", str(tmp_path / "s.zarr"),
                 "--quiet", "--workers", "1"])
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{tmp_path / 's.zarr'}: 1 trajectories x 5 steps")
