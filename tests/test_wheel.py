"""The package works installed as a wheel, from a folder outside the repository.

The wheel is built from a copy of the sources (so the build leaves nothing in the
repository) and installed without its dependencies into a fresh virtual environment. The
dependencies are the project venv's, already pinned and installed: a ``.pth`` file appends
their site-packages to the new environment's path, after its own, so nothing is downloaded
and ``robomorph`` itself can only come from the wheel (the repository is not on the path
and the editable install's import hook is not loaded).
"""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
# What the build reads: the metadata, setup.py's recipe step, the package and the recipes.
SOURCES = ("pyproject.toml", "setup.py", "README.md", "robomorph", "datamodules", "sweeps")
IGNORED = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")


def _run(cmd: list, cwd: Path, env: dict | None = None, timeout: int = 300) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{cmd} exited {proc.returncode}:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc


def _dependency_dirs() -> list[str]:
    """The project venv's site-packages (and the base Python's, when the venv reuses them)."""
    return [p for p in sys.path if os.path.basename(p) in ("site-packages", "dist-packages") and os.path.isdir(p)]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    for name in SOURCES + tuple(p.name for p in ROOT.glob("LICENSE*")):
        (shutil.copytree(ROOT / name, src / name, ignore=IGNORED) if (ROOT / name).is_dir()
         else shutil.copy2(ROOT / name, src / name))
    dist = tmp_path_factory.mktemp("dist")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "--disable-pip-version-check", "-q", "-w", dist, src], cwd=dist)
    (whl,) = dist.glob("robomorph-*.whl")
    return whl


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory) -> Path:
    env_dir = tmp_path_factory.mktemp("venv") / "env"
    _run([sys.executable, "-m", "venv", "--without-pip", env_dir], cwd=env_dir.parent)
    python = env_dir / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index",
          "--disable-pip-version-check", "-q", wheel], cwd=env_dir.parent)
    site = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=env_dir).stdout.strip()
    # Written after the install, so pip never saw the project's own (editable) robomorph.
    (Path(site) / "_robomorph_dependencies.pth").write_text("\n".join(_dependency_dirs()) + "\n")
    return env_dir


@pytest.fixture(scope="module")
def user(venv, tmp_path_factory):
    """Runs a command as a user of the installed wheel, in an empty folder outside the repo."""
    work = tmp_path_factory.mktemp("user")
    assert not work.resolve().is_relative_to(ROOT)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}", WANDB_MODE="disabled", MUJOCO_GL="disable",
               PYTHONWARNINGS="ignore")

    def run(*args: str) -> subprocess.CompletedProcess:
        return _run(list(args), cwd=work, env=env)

    run.work = work
    return run


def test_the_wheel_carries_the_recipes_and_every_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for kind in ("datamodules", "sweeps"):
        shipped = {p.name for p in (ROOT / kind).glob("*.yaml")}
        assert shipped and {n.rsplit("/", 1)[1] for n in names if n.startswith(f"robomorph/_recipes/{kind}/")} == shipped
    # Any non-Python file the package reads beside its modules (templates, models) ships too.
    data = {p.relative_to(ROOT).as_posix() for p in (ROOT / "robomorph").rglob("*")
            if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts}
    assert data <= names, sorted(data - names)
    assert {p.relative_to(ROOT).as_posix() for p in (ROOT / "robomorph").rglob("*.py")} <= names


def test_commands_run_from_an_empty_folder(user, venv):
    where = user("python", "-c", "import robomorph, robomorph.core.recipes as r; print(robomorph.__file__); "
                 "print(r.locate('multisine')); print(r.locate('ci', 'sweeps'))").stdout.split()
    assert all(Path(p).resolve().is_relative_to(venv.resolve()) for p in where), where
    assert "generate" in user("robomorph", "--help").stdout

    out = user("robomorph", "generate", "--config", "multisine", "--robots", "12", "--steps", "90", "--seed", "1",
               "--out", "ms.zarr", "--workers", "1", "--quiet").stdout
    assert "ms.zarr: 12 trajectories x 90 steps (multisine)" in out

    user("robomorph", "fit", "--data.stores", "ms.zarr", "--data.context_len", "30", "--data.horizon", "60",
         "--data.batch_size", "4", "--data.val_subset", "4", "--model.d_model", "16", "--model.n_head", "2",
         "--model.n_layer", "1", "--model.patch", "5", "--model.warmup_steps", "2", "--model.max_context", "64",
         "--model.max_horizon", "64", "--trainer.max_steps", "4", "--trainer.val_check_interval", "2",
         "--trainer.accelerator", "cpu", "--trainer.devices", "1", "--trainer.enable_progress_bar", "false",
         "--run", "tiny", "--runs_dir", "runs", "--wandb", "disabled")
    ckpt = user.work / "runs" / "tiny" / "checkpoints" / "best.ckpt"
    assert ckpt.is_file()

    user("robomorph", "evaluate", "--ckpt", str(ckpt), "--data", "ms.zarr", "--out", "eval", "--baselines", "hold",
         "--device", "cpu")
    assert (user.work / "eval" / "metrics.json").is_file()
    assert "--minutes" in user("robomorph", "demo", "--help").stdout
