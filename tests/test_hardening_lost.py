"""Nothing leaks out of its folder and nothing is lost: plain run and study names, writers
that replace only their own kind of file, merges that never read what they wipe, one writer
per store or run folder, and a damaged resume point refused.

Every refusal is one ``error:`` line with exit code 2 that leaves every file as it was.
"""

import os
import socket
import subprocess
import sys
import zipfile

import pytest

from robomorph import calibrate, fit, merge, report, sweep
from robomorph.core.locks import exclusive
from robomorph.evaluation.evaluator import default_out
from robomorph.ingest import main as ingest_main
from tests.conftest import linear_system, write_store

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _files(root) -> dict[str, bytes | None]:
    """Every path under ``root`` with its bytes (None for folders): a snapshot to compare."""
    seen = {}
    for folder, dirs, names in os.walk(root):
        for d in dirs:
            seen[os.path.join(folder, d)] = None
        for n in names:
            p = os.path.join(folder, n)
            seen[p] = open(p, "rb").read() if os.path.isfile(p) else b"<link>"
    return seen


def _one_error(err: str, *phrases: str) -> str:
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, err
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    return lines[0]


def _env() -> dict:
    return {**os.environ, "WANDB_MODE": "disabled", "MUJOCO_GL": "disable", "PYTHONPATH": ROOT}


def _fit_cli(store, runs, run, *extra):
    return ["--data.stores", store, "--data.context_len", "20", "--data.horizon", "40", "--data.batch_size", "4",
            "--model.d_model", "16", "--model.n_head", "2", "--model.n_layer", "1", "--model.patch", "5",
            "--trainer.max_steps", "2", "--trainer.accelerator", "cpu", "--trainer.enable_progress_bar", "false",
            "--runs_dir", str(runs), "--run", run, "--wandb", "disabled", *extra]


# --- 1. names stay inside their folders -------------------------------------------------------

@pytest.mark.parametrize("run", ["../../x", "ABS", ".", "..", "a/b"])
def test_fit_refuses_a_run_name_that_is_a_path(linear_store, tmp_path, capsys, run):
    work = tmp_path / "work"
    runs = work / "a" / "b" / "runs"
    runs.mkdir(parents=True)
    run = str(tmp_path / "elsewhere") if run == "ABS" else run
    before = _files(tmp_path)
    assert fit.main(_fit_cli(linear_store(), runs, run)) == 2
    _one_error(capsys.readouterr().err, "--run", "is not a plain name")
    assert _files(tmp_path) == before  # nothing written, inside --runs_dir or out of it


def _space(path, name="tiny", store="data/none.zarr"):
    path.write_text(f"name: {name}\nobjective: {{metric: val/loss, direction: minimize}}\n"
                    f"budget: {{max_steps: 2, val_check_interval: 1}}\n"
                    f"base:\n  data: {{stores: {store}}}\n"
                    "params:\n  model.lr: {low: 1.0e-4, high: 1.0e-3, log: true}\n")
    return str(path)


@pytest.mark.parametrize("how", ["flag", "yaml"])
def test_sweep_refuses_a_study_name_that_is_a_path(tmp_path, capsys, how):
    work = tmp_path / "work"
    work.mkdir()
    name = "../.." if how == "flag" else str(tmp_path / "abs")
    space = _space(work / "space.yaml", name="tiny" if how == "flag" else name)
    flag = ["--study-name", name] if how == "flag" else []
    before = _files(tmp_path)
    assert sweep.main([space, "--n-trials", "1", "--storage", f"sqlite:///{work}/optuna.db", "--runs-dir",
                 str(work / "runs"), "--wandb", "disabled", *flag]) == 2
    _one_error(capsys.readouterr().err, "--study-name" if how == "flag" else "name", "is not a plain name")
    assert _files(tmp_path) == before


def test_sweep_summary_refuses_a_study_name_that_is_a_path(tmp_path, capsys):
    before = _files(tmp_path)
    assert sweep.main(["summary", "--study-name", "../..", "--storage", f"sqlite:///{tmp_path}/optuna.db",
                 "--runs-dir", str(tmp_path / "runs")]) == 2
    _one_error(capsys.readouterr().err, "--study-name", "is not a plain name")
    assert _files(tmp_path) == before


@pytest.mark.parametrize("store", ["..", "x/..", ".", "../../..", "/", "data/.zarr"])
def test_evaluate_output_named_after_a_store_stays_in_the_runs_eval_folder(tmp_path, monkeypatch, store):
    monkeypatch.chdir(tmp_path)
    ckpt = tmp_path / "runs" / "ms" / "checkpoints" / "best.ckpt"
    out = os.path.realpath(default_out(str(ckpt), store))
    assert os.path.dirname(out) == os.path.realpath(tmp_path / "runs" / "ms" / "eval"), out


# --- 2. writers replace only files of their own kind ------------------------------------------

def _checkpoint(path) -> bytes:
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("best/data.pkl", b"\x80\x02}q\x00.")
    return path.read_bytes()


@pytest.fixture
def runs_with_a_checkpoint(tmp_path):
    run = tmp_path / "runs" / "ms"
    (run / "logs").mkdir(parents=True)
    (run / "checkpoints").mkdir()
    (run / "logs" / "metrics.csv").write_text("step,train/loss\n1,0.5\n2,0.4\n")
    ckpt = run / "checkpoints" / "best.ckpt"
    return tmp_path / "runs", ckpt, _checkpoint(ckpt)


def test_report_refuses_to_replace_a_checkpoint_or_write_into_a_store(runs_with_a_checkpoint, tmp_path, capsys):
    runs, ckpt, data = runs_with_a_checkpoint
    u, y = linear_system(2, 10)
    store = write_store(tmp_path / "ms.zarr", u, y)
    before = _files(tmp_path)
    assert report.main([str(runs), "--out", str(ckpt)]) == 2
    _one_error(capsys.readouterr().err, f"--out {ckpt} is a checkpoint", "refusing to replace it")
    for out in (os.path.join(store, "report.html"), os.path.join(store, "u", "c.html"), store):
        assert report.main([str(runs), "--out", out]) == 2
        _one_error(capsys.readouterr().err, f"--out {out} is ")
    assert _files(tmp_path) == before and ckpt.read_bytes() == data
    page = tmp_path / "report.html"
    for _ in range(2):  # written, then replaced: a page of its own kind
        assert report.main([str(runs), "--out", str(page)]) == 0


def test_calibrate_refuses_to_replace_a_file_of_another_kind(tiny_checkpoint, tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("not a checkpoint\n")
    page = tmp_path / "report.html"
    page.write_text("<!doctype html><html></html>")
    u, y = linear_system(2, 10)
    store = write_store(tmp_path / "ms.zarr", u, y)
    before = _files(tmp_path)
    for out, found in [(notes, "a file of another kind"), (page, "an HTML page"),
                       (os.path.join(store, "x.ckpt"), "inside the Zarr store")]:
        assert calibrate.main(["--ckpt", tiny_checkpoint, "--remove", "--out", str(out)]) == 2
        _one_error(capsys.readouterr().err, f"--out {out} is {found}")
    assert _files(tmp_path) == before
    copy = tmp_path / "copy.ckpt"
    assert calibrate.main(["--ckpt", tiny_checkpoint, "--remove", "--out", str(copy)]) == 0  # a new file: written
    assert calibrate.main(["--ckpt", tiny_checkpoint, "--remove", "--out", str(copy)]) == 0  # a checkpoint: replaced


# --- 3. a merge never writes over what it reads -----------------------------------------------

def _shards(tmp_path):
    paths = []
    for i in range(2):
        u, y = linear_system(3, 5, seed=i)
        paths.append(write_store(tmp_path / f"sh{i}.zarr", u, y, attrs={"dt": 0.01, "config": {"task": "x"},
                                                                        "shard": [i, 2]}))
    return paths


@pytest.mark.parametrize("out", ["sh0.zarr", "sh0.zarr/", "link.zarr", "sh0.zarr/inner.zarr", "./sh1.zarr"])
def test_merge_refuses_an_output_that_is_one_of_its_inputs(tmp_path, capsys, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    sh0, sh1 = _shards(tmp_path)
    os.symlink("sh0.zarr", "link.zarr")
    before = _files(tmp_path)
    assert merge.main([sh0, sh1, "--out", out, "--overwrite"]) == 2
    _one_error(capsys.readouterr().err, "--out", "is one of the stores to merge")
    assert _files(tmp_path) == before


# --- 4. one writer at a time ------------------------------------------------------------------

def _door(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=ROOT, env=_env(),
                          timeout=300)


def _names_this_process(line: str) -> None:
    assert "is being written by another process" in line and f"pid {os.getpid()} on {socket.gethostname()}" in line


def test_a_second_generate_into_a_busy_store_is_refused(tmp_path):
    out = tmp_path / "ms.zarr"
    with exclusive(out):
        before = _files(tmp_path)
        done = _door("robomorph.generate", "--task", "multisine", "--robots", "2", "--steps", "5", "--out", str(out),
                     "--overwrite", "--quiet", "--workers", "1")
        assert done.returncode == 2, done.stderr
        _names_this_process(_one_error(done.stderr, str(out)))
        assert _files(tmp_path) == before


def test_a_second_fit_of_a_busy_run_is_refused(linear_store, tmp_path):
    runs = tmp_path / "runs"
    with exclusive(runs / "twin", "run folder"):
        before = _files(tmp_path)
        done = _door("robomorph.fit", *_fit_cli(linear_store(), runs, "twin"))
        assert done.returncode == 2, done.stderr
        _names_this_process(_one_error(done.stderr, str(runs / "twin")))
        assert _files(tmp_path) == before


def test_merge_and_ingest_into_a_busy_store_are_refused(tmp_path, capsys):
    sh0, sh1 = _shards(tmp_path)
    log = tmp_path / "log.csv"
    log.write_text("a,b\n" + "".join(f"{i},{2 * i}\n" for i in range(20)))
    out = tmp_path / "out.zarr"
    with exclusive(out):
        before = _files(tmp_path)
        assert merge.main([sh0, sh1, "--out", str(out)]) == 2
        _names_this_process(_one_error(capsys.readouterr().err))
        assert ingest_main([str(log), "--u-cols", "a", "--y-cols", "b", "--steps", "5", "--dt", "0.1",
                       "--out", str(out)]) == 2
        _names_this_process(_one_error(capsys.readouterr().err))
        assert _files(tmp_path) == before
    assert merge.main([sh0, sh1, "--out", str(out)]) == 0  # released: the next writer gets in


# --- 5. a damaged resume point ----------------------------------------------------------------

def test_a_last_checkpoint_that_is_a_folder_is_refused_not_restarted(linear_store, tmp_path, capsys):
    run = tmp_path / "runs" / "r"
    (run / "checkpoints" / "last.ckpt").mkdir(parents=True)
    (run / "logs").mkdir()
    (run / "logs" / "metrics.csv").write_text("step,train/loss\n1,0.5\n2,0.4\n")
    (run / "config.yaml").write_text("run: r\n")
    before = _files(run)
    assert fit.main(_fit_cli(linear_store(), tmp_path / "runs", "r")) == 2
    _one_error(capsys.readouterr().err, "last.ckpt is a folder", "delete it", "--run")
    assert _files(run) == before  # no restart at step 0, no duplicate log rows

