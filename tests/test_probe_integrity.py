"""The hostile probe of issue 61, section 2, defects 1 to 10: data loss and integrity, and
tracebacks. Each test names the defect it covers.

A refusal is one ``error:`` line with exit code 2, no traceback, and it comes before anything
is created: every file under the test's folder is as it was (inputs, other stores, foreign
files), and no store, folder or lock file was added. The last test walks every command that
writes through one such refusal.
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import shutil
import sys
import zipfile

import numpy as np
import pytest
import scipy.io

from robomorph import generate, ingest, merge, priors
from robomorph.control import cli as control_cli
from robomorph.core.errors import run_command
from robomorph.data import public_logs
from tests.test_hardening_lost import _files
from tests.test_probe_new_commands import _call

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONTEXT, HORIZON = 60, 20


def _one_error(code: int, err: str, *phrases: str) -> str:
    assert code == 2 and "Traceback" not in err, (code, err)
    # A renamed option's warning may come first (the options keep their old names one release).
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("warning: ")]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    return lines[0]


def _checkpoint(path) -> None:
    """A file as torch.save writes one: a zip archive holding <name>/data.pkl."""
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("victim/data.pkl", b"\x80\x02}q\x00.")


@pytest.fixture
def source(simulated_store, tmp_path):
    """A copy (in the test's folder) of a simulated store with commands: the priors' source."""
    path = str(tmp_path / "S.zarr")
    shutil.copytree(simulated_store(robots=3, steps=CONTEXT + HORIZON + 10, seed=4), path)
    return path


def _priors(*argv: str) -> list[str]:
    return [*argv, "--context", str(CONTEXT), "--horizon", str(HORIZON)]


def _industrial(root, nan_in_test: bool = False) -> str:
    """The industrial robot benchmark's .mat file in its clone's layout under ``root`` (tiny)."""
    mat = os.path.join(root, "Physics-Guided-Recurrent-State-Space-Neural-Networks", public_logs.INDUSTRIAL_MAT)
    os.makedirs(os.path.dirname(mat), exist_ok=True)
    rng = np.random.default_rng(0)
    arrays = {}
    for split, n in (("train", 600), ("val", 300), ("test", 300)):
        u = rng.normal(size=(6, n))
        arrays[f"u_{split}"], arrays[f"y_{split}"] = u, 30 * np.sin(np.cumsum(0.01 * u, axis=1))
    if nan_in_test:
        arrays["y_test"][:, 100:] = np.nan
    scipy.io.savemat(mat, arrays)
    return mat


def _script(name: str):
    """``main(argv)`` of benchmarks/<name>.py (its folder on sys.path, as when it runs), as its command runs it."""
    folder = os.path.join(ROOT, "benchmarks")
    if folder not in sys.path:
        sys.path.insert(0, folder)
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", os.path.join(folder, f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def run(argv: list[str]) -> int:
        if inspect.signature(module.main).parameters:
            return run_command(lambda: module.main(argv))
        saved, sys.argv = sys.argv, [f"{name}.py", *argv]  # a main() that reads sys.argv itself
        try:
            return run_command(module.main)
        finally:
            sys.argv = saved

    return run


def _real_robots():
    return _script("real_robots")


# --- 1. priors over its own source ----------------------------------------------------------------

@pytest.mark.parametrize("where", ["itself", "around"])
def test_priors_never_writes_over_its_source(source, tmp_path, capsys, where):
    """Defect 1: ``priors S.zarr --out S.zarr --overwrite`` deleted its source store, then erred."""
    out = source if where == "itself" else str(tmp_path)
    before = _files(tmp_path)
    code, err = _call(priors.main, _priors(source, "--out", out, "--overwrite"), capsys)
    _one_error(code, err, "--out", "destroy what the command reads")
    assert _files(tmp_path) == before


# --- 2. a benchmark's --md over a checkpoint ---------------------------------------------------------

def test_real_robots_never_replaces_a_checkpoint_with_markdown(tmp_path, capsys, monkeypatch):
    """Defect 2: ``benchmarks/real_robots.py --md victim.ckpt`` overwrote a checkpoint (rc 0)."""
    monkeypatch.chdir(tmp_path)  # --work's default, data/real, lands here if anything is written
    _industrial(str(tmp_path / "sources"))
    _checkpoint(tmp_path / "victim.ckpt")
    before = _files(tmp_path)
    code, err = _call(_real_robots(), ["--data", str(tmp_path / "sources"), "--robots", "industrial_robot",
                                       "--md", str(tmp_path / "victim.ckpt")], capsys)
    _one_error(code, err, "--md", "checkpoint")
    assert _files(tmp_path) == before  # the checkpoint, and no store, plot or table written first


def test_result_file_writers_replace_only_their_own_kind(tmp_path):
    """Defect 2's general fix: every benchmark writes its tables through write_markdown, write_rows or
    ResultsCsv, which replace (or append to) an earlier result file only."""
    from robomorph.core.errors import OutputExistsError
    from robomorph.core.results import ResultsCsv, write_markdown, write_rows

    victim, notes = tmp_path / "victim.ckpt", tmp_path / "notes.txt"
    _checkpoint(victim)
    notes.write_text("my notes, kept by hand\n")
    before = _files(tmp_path)
    for path in (victim, notes):
        with pytest.raises(OutputExistsError, match="refusing to replace it"):
            write_markdown(str(path), "# table\n")
        with pytest.raises(OutputExistsError, match="refusing to replace it"):
            write_rows(str(path), [{"a": 1}])
        with pytest.raises(OutputExistsError, match="refusing to replace it"):
            ResultsCsv(str(path)).append({"a": 1})
    assert _files(tmp_path) == before
    md, csv = tmp_path / "t.md", tmp_path / "t.csv"
    for _ in range(2):  # written, then replaced: an earlier result file is theirs
        write_markdown(str(md), "# table\n")
        write_rows(str(csv), [{"a": 1}])
    ResultsCsv(str(csv)).append({"a": 2})
    assert md.read_text().startswith("*Produced by") and csv.read_text().count("\n1\n") == 1


# The scripts' other options name inputs that need not exist: the outputs are refused before anything is read.
# name: (those options, the output option given a checkpoint)
_SCRIPTS = {"candidates": (["--test", "x.zarr"], "--md"), "hybrid": (["--ckpt", "x.ckpt", "--test", "x.zarr"], "--md"),
            "nuisance": (["--data", "x.zarr"], "--md"), "smoother_ood": (["--ckpt", "x.ckpt", "--data", "x.zarr"], "--md"),
            "spread": (["--ckpt", "x.ckpt", "--cal", "x.zarr", "--test", "x.zarr"], "--md"), "residual": ([], "--md"),
            "sensitivity": ([], "--md"), "calibration": (["--ckpt", "x.ckpt", "--test", "x.zarr"], "--csv"),
            "formulations": ([], "--csv"), "horizon_ablation": ([], "--csv"), "horizon_step": (["--test", "x.zarr"], "--csv"),
            "arms": ([], "--out"), "arms_transfer": ([], "--out"), "confirm_table": (["x.csv"], "--out"),
            "control": (["--ckpt", "x.ckpt"], "--out")}


@pytest.mark.parametrize("name", sorted(_SCRIPTS))
def test_benchmark_scripts_refuse_a_foreign_result_file_before_their_work(tmp_path, capsys, monkeypatch, name):
    """Defect 2 in the other scripts: their --md / --csv / --out are checked before any store is generated or read."""
    monkeypatch.chdir(tmp_path)  # their default work folders (data/...) land here if anything is written
    argv, flag = _SCRIPTS[name]
    victim = tmp_path / ("victim.md" if name == "control" else "victim.ckpt")  # control's --out is a prefix
    _checkpoint(victim)
    before = _files(tmp_path)
    code, err = _call(_script(name), [*argv, flag, str(victim).removesuffix(".md") if name == "control" else str(victim)],
                      capsys)
    _one_error(code, err, flag, "checkpoint")
    assert _files(tmp_path) == before


# --- 3. writes inside another store --------------------------------------------------------------------

def _inside_store_cases(store: str, sources: str) -> dict:
    other = os.path.join(os.path.dirname(store), "T.zarr")  # a store that is no input of merge
    shutil.copytree(store, other)
    return {
        "priors": (priors.main, _priors(store, "--out", os.path.join(store, "pri.zarr"))),
        "ingest": (ingest.main, ["--source", "industrial_robot", "--data", sources, "--out",
                                 os.path.join(store, "real")]),
        "real_robots --md": (_real_robots(), ["--data", sources, "--robots", "industrial_robot", "--md",
                                              os.path.join(store, "table.md")]),
        "real_robots --work store": (_real_robots(), ["--data", sources, "--robots", "industrial_robot",
                                                      "--work", store]),
        "real_robots --work inside": (_real_robots(), ["--data", sources, "--robots", "industrial_robot",
                                                       "--work", os.path.join(store, "work")]),
        "merge": (merge.main, [store, "--out", os.path.join(other, "merged.zarr")]),
        "generate": (generate.main, ["--robots", "1", "--steps", "20", "--workers", "1", "--quiet", "--out",
                                     os.path.join(other, "in.zarr")]),
    }


@pytest.mark.parametrize("case", ["priors", "ingest", "real_robots --md", "real_robots --work store",
                                  "real_robots --work inside", "merge", "generate"])
def test_no_writer_writes_inside_another_store(source, tmp_path, capsys, monkeypatch, case):
    """Defect 3: priors, ingest --source and real_robots.py --md / --work wrote inside a store (rc 0);
    generate and merge did too, while evaluate, control and export refused."""
    monkeypatch.chdir(tmp_path)
    sources = str(tmp_path / "sources")
    _industrial(sources)
    main, argv = _inside_store_cases(source, sources)[case]
    before = _files(tmp_path)  # both stores, the sources' folder, and nothing else
    code, err = _call(main, argv, capsys)
    _one_error(code, err, "Zarr store")
    assert _files(tmp_path) == before


# --- 4. ingest --source: all splits or none ------------------------------------------------------------

def test_ingest_source_writes_no_split_when_one_is_refused(tmp_path, capsys):
    """Defect 4: a NaN-filled test split exited 2 after writing the train and val stores, and the
    rerun was refused until --overwrite."""
    sources, out = str(tmp_path / "sources"), str(tmp_path / "real")
    _industrial(sources, nan_in_test=True)
    before = _files(tmp_path)
    code, err = _call(ingest.main, ["--source", "industrial_robot", "--data", sources, "--out", out], capsys)
    _one_error(code, err, "NaN")
    assert _files(tmp_path) == before
    _industrial(sources)  # the log mended: the same command now runs, no --overwrite needed
    code, err = _call(ingest.main, ["--source", "industrial_robot", "--data", sources, "--out", out], capsys)
    assert code == 0, err
    # The three stores, and nothing of the hidden folder they were written in first (lock files stay, by design).
    assert sorted(n for n in os.listdir(out) if not n.endswith(".lock")) == ["test.zarr", "train.zarr", "val.zarr"]


# --- 5. priors' late refusals ---------------------------------------------------------------------------

@pytest.mark.parametrize("extra", [["--set", "mode=learned"], ["--set", "members=1000000000"],
                                   ["--context", "1"], ["--context", "2"]])
def test_priors_refuses_before_creating_its_store(source, tmp_path, capsys, extra):
    """Defect 5: these refusals came after --out was created, and the empty store then blocked the next
    run ("begun with other arguments")."""
    out = str(tmp_path / "p.zarr")
    before = _files(tmp_path)
    code, err = _call(priors.main, [*_priors(source, "--out", out), *extra], capsys)
    _one_error(code, err)
    assert _files(tmp_path) == before


def test_an_empty_prior_store_left_by_a_stop_does_not_block_the_next_run(source, tmp_path, monkeypatch):
    """Defect 5: an in-progress prior store that holds no window is begun anew, whatever its arguments."""
    from robomorph.data.store import open_store
    from robomorph.evaluation import priors as machinery

    out = str(tmp_path / "p.zarr")
    real = machinery._append

    def stop(*_a):
        raise KeyboardInterrupt

    monkeypatch.setattr(machinery, "_append", stop)
    with pytest.raises(KeyboardInterrupt):
        machinery.write_priors(machinery.PriorRequest(source, out, CONTEXT, HORIZON, (0,), batch=2))
    assert open_store(out, allow_incomplete=True).n == 0
    monkeypatch.setattr(machinery, "_append", real)
    record = machinery.write_priors(machinery.PriorRequest(source, out, CONTEXT, HORIZON - 5, (0,), batch=2))
    done = open_store(out)
    assert done.n == 3 and done.attrs["prior"] == record and record["horizon"] == HORIZON - 5


# --- 6, 7. realism ranges finite and bounded ------------------------------------------------------------

_NONFINITE = [("encoder", "noise", [0, ".nan"]), ("encoder", "resolution", [0, ".inf"]),
              ("torque", "noise", [0, ".nan"]), ("payload", "mass", [0, ".inf"]), ("payload", "com", ".nan"),
              ("friction", "coulomb", [0, ".inf"]), ("friction", "viscous", [".nan", 1]),
              ("feedback", "amplitude", [0.1, ".inf"]), (None, "widen", ".inf"), (None, "widen", ".nan")]


def _recipe(tmp_path, realism: str) -> str:
    path = tmp_path / "recipe.yaml"
    path.write_text(f"task: multisine\nrobots: 1\nsteps: 20\nrealism:\n{realism}")
    return str(path)


def _yaml(value) -> str:
    return f"[{', '.join(map(str, value))}]" if isinstance(value, list) else str(value)


@pytest.mark.parametrize("section,name,value", _NONFINITE)
def test_a_nonfinite_realism_number_is_refused_before_generating(tmp_path, capsys, section, name, value):
    """Defect 6: a NaN or inf in a realism range passed check_range; generate failed with numpy's
    OverflowError and left an empty store."""
    text = f"  {section}: {{{name}: {_yaml(value)}}}\n" if section else f"  {name}: {_yaml(value)}\n"
    recipe = _recipe(tmp_path, text)
    before = _files(tmp_path)
    code, err = _call(generate.main, ["--config", recipe, "--out", str(tmp_path / "g.zarr"), "--workers", "1",
                                      "--quiet"], capsys)
    _one_error(code, err, f"realism.{section + '.' if section else ''}{name}")
    assert _files(tmp_path) == before


def test_latency_has_an_upper_bound(tmp_path, capsys):
    """Defect 7: ``realism.timing.latency: [1, 1e9]`` ended in a 7 GiB allocation traceback."""
    recipe = _recipe(tmp_path, "  timing: {latency: [1, 1000000000]}\n")
    before = _files(tmp_path)
    code, err = _call(generate.main, ["--config", recipe, "--out", str(tmp_path / "g.zarr"), "--workers", "1",
                                      "--quiet"], capsys)
    _one_error(code, err, "realism.timing.latency", "goes above 1000")
    assert _files(tmp_path) == before


# --- 8. --set values that are not plain YAML --------------------------------------------------------------

@pytest.mark.parametrize("value,phrase", [("[1,", "is not a YAML value"),
                                          ("!!python/object/apply:os.system [echo]", "builds objects")])
def test_set_values_that_are_not_plain_yaml_are_one_line(source, tmp_path, capsys, value, phrase):
    """Defect 8: ``priors --set 'members=[1,'`` raised YAML's ParserError traceback, a ``!!python/...``
    value its ConstructorError traceback."""
    before = _files(tmp_path)
    code, err = _call(priors.main, [*_priors(source, "--out", str(tmp_path / "p.zarr")), "--set",
                                    f"members={value}"], capsys)
    _one_error(code, err, "--set members", phrase)
    assert _files(tmp_path) == before
    from robomorph.core.config import ConfigError, yaml_value  # the one reader of every NAME=VALUE option's value

    with pytest.raises(ConfigError, match="--set x"):
        yaml_value(value, "--set x")
    assert yaml_value("[1, 2]", "--set x") == [1, 2] and yaml_value("16", "--set x") == 16


# --- 9. damaged files of the public sources ---------------------------------------------------------------

def _kinova(root) -> str:
    """Two tiny Kinova logs in the clone's layout; returns the test one's path."""
    names = [f"Position{j}" for j in range(1, 8)] + [f"TorqueCur{j}" for j in range(1, 8)]
    rows = np.random.default_rng(1).normal(size=(500, 14))
    paths = []
    for folder in ("identification_data", "validation_data"):
        d = os.path.join(root, "dynamic-identification", "pyDynaMapp", "data", "kinova", folder)
        os.makedirs(d, exist_ok=True)
        paths.append(os.path.join(d, "log.csv"))
        np.savetxt(paths[-1], rows, delimiter=",", header=",".join(names), comments="")
    return paths[-1]


def _schunk(root, trajectory_columns: int = 12) -> str:
    """Two tiny Schunk runs in the clone's layout; returns the second run's folder."""
    u = np.random.default_rng(2).normal(size=(800, 6))
    for m in (1, 2):
        d = os.path.join(root, "AutoKoopman", "autoKoopman_codeocean", "data", "Robot", f"measurement_{m}")
        os.makedirs(d, exist_ok=True)
        np.savetxt(os.path.join(d, "input.csv"), u * m, delimiter=",")
        np.savetxt(os.path.join(d, "time.csv"), 0.004 * np.arange(len(u)))
        np.savetxt(os.path.join(d, "trajectory.csv"), np.cumsum(1e-3 * u, axis=0).repeat(2, axis=1)[:, :trajectory_columns],
                   delimiter=",")
    return d


def _truncate_last_line(path) -> None:
    text = open(path).read().rstrip("\n")
    open(path, "w").write(text[:text.rfind(",", 0, text.rfind(",")) + 3])  # cut two values short, inside a number


@pytest.mark.parametrize("case", ["kinova csv", "schunk csv", "schunk columns", "industrial mat"])
def test_a_damaged_source_file_is_one_line_naming_it(tmp_path, capsys, case):
    """Defect 9: a truncated last CSV line (Kinova, Schunk) raised a loadtxt traceback, a truncated
    .mat an OSError, a Schunk trajectory.csv of 3 columns an IndexError."""
    sources = str(tmp_path / "sources")
    if case == "kinova csv":
        name, bad = "kinova_gen3", _kinova(sources)
        _truncate_last_line(bad)
    elif case == "schunk csv":
        name, bad = "schunk", os.path.join(_schunk(sources), "input.csv")
        _truncate_last_line(bad)
    elif case == "schunk columns":
        name, bad = "schunk", os.path.join(_schunk(sources, trajectory_columns=3), "trajectory.csv")
    else:
        name, bad = "industrial_robot", _industrial(sources)
        with open(bad, "r+b") as f:
            f.truncate(2000)  # inside its first variable (a cut between two reads as a missing variable)
    before = _files(tmp_path)
    code, err = _call(ingest.main, ["--source", name, "--data", sources, "--out", str(tmp_path / "real")], capsys)
    _one_error(code, err, os.path.basename(bad))
    assert _files(tmp_path) == before


# --- 10. control --duration under one frame -----------------------------------------------------------------

@pytest.mark.parametrize("flag", ["--duration", "--warmup"])
def test_control_refuses_less_than_one_frame_in_its_parser(tmp_path, capsys, flag):
    """Defect 10: ``control --duration 0.001`` passed the parser and failed with a ValueError traceback
    (a warm-up longer than the episode)."""
    argv = ["--controllers", "osc", "--robots", "1", "--workers", "1", "--out", str(tmp_path / "ctl"),
            "--warmup", "0.1", "--duration", "0.1", flag, "0.001"]
    with pytest.raises(SystemExit) as stop:
        control_cli.build_parser().parse_args(argv)
    _one_error(stop.value.code, capsys.readouterr().err, flag)
    code, err = _call(control_cli.main, argv, capsys)
    _one_error(code, err, flag)
    assert os.listdir(tmp_path) == []


# --- every command that writes: nothing before its refusal ------------------------------------------------

def _writers(tmp, store: str, ckpt: str) -> dict:
    """``{command: (main, argv)}``: one refusal of each command that writes, found after its output is
    known (inputs read, settings parsed) and before its work; the paths lie under ``tmp``."""
    from robomorph import calibrate, demo, evaluate, export, fit, report, reproduce, sweep

    other = os.path.join(tmp, "T.zarr")
    shutil.copytree(store, other)
    sources = os.path.join(tmp, "sources")
    _industrial(sources, nan_in_test=True)
    log = os.path.join(tmp, "log.csv")
    with open(log, "w") as f:
        f.write("tau,q\n" + "".join(f"{k * 0.1},{'nan' if k == 7 else k}\n" for k in range(20)))
    nan_recipe = os.path.join(tmp, "nan.yaml")
    with open(nan_recipe, "w") as f:
        f.write("task: multisine\nrobots: 1\nsteps: 20\nrealism:\n  encoder: {noise: [0, .nan]}\n")
    victim = os.path.join(tmp, "victim.ckpt")
    _checkpoint(victim)
    notes = os.path.join(tmp, "notes.txt")
    with open(notes, "w") as f:
        f.write("my notes\n")
    space = os.path.join(tmp, "space.yaml")
    with open(space, "w") as f:
        f.write(f"name: tiny\nobjective: {{metric: val/loss, direction: minimize}}\nbudget: {{max_steps: 2}}\n"
                f"base:\n  data: {{stores: {store}}}\nparams:\n  model.lr: {{low: 1.0e-4, high: 1.0e-3, log: true}}\n")
    runs = os.path.join(tmp, "runs")
    return {
        "generate": (generate.main, ["--config", nan_recipe, "--out", os.path.join(tmp, "g.zarr"), "--quiet"]),
        "merge": (merge.main, [store, "--out", os.path.join(other, "m.zarr")]),
        "ingest": (ingest.main, [log, "--u-cols", "tau", "--y-cols", "q", "--steps", "5", "--dt", "0.01", "--out",
                                 os.path.join(tmp, "real.zarr")]),
        "ingest --source": (ingest.main, ["--source", "industrial_robot", "--data", sources, "--out",
                                          os.path.join(tmp, "real")]),
        "priors": (priors.main, [*_priors(store, "--out", os.path.join(tmp, "p.zarr")), "--context", "2"]),
        "fit": (fit.main, ["--data.stores", store, "--data.context_len", "20", "--data.horizon", "40",
                           "--runs_dir", os.path.join(other, "runs"), "--run", "r", "--trainer.max_steps", "1",
                           "--trainer.accelerator", "cpu", "--wandb", "disabled"]),
        "evaluate": (evaluate.main, ["--ckpt", ckpt, "--data", store, "--out", os.path.join(other, "ev")]),
        "calibrate": (calibrate.main, ["--ckpt", ckpt, "--data", store, "--out", notes]),
        "export": (export.main, ["--ckpt", ckpt, "--out", os.path.join(other, "model")]),
        "report": (report.main, [runs, "--out", victim]),
        "sweep": (sweep.main, [space, "--n-trials", "1", "--runs-dir", runs, "--storage",
                               f"sqlite:///{os.path.join(tmp, 'optuna.db')}", "--set", "model.lr=[1,"]),
        "control": (control_cli.main, ["--controllers", "osc", "--robots", "1", "--workers", "1", "--duration", "0.001",
                                       "--out", os.path.join(tmp, "ctl")]),
        "demo": (demo.main, ["--out", os.path.join(other, "demo"), "--runs-dir", runs]),
        "reproduce": (reproduce.main, ["table1", "--scale", "ci", "--work", os.path.join(other, "w"), "--out",
                                       os.path.join(tmp, "paper")]),
        "real_robots.py": (_real_robots(), ["--data", sources, "--robots", "industrial_robot", "--md", victim]),
    }


WRITERS = ["generate", "merge", "ingest", "ingest --source", "priors", "fit", "evaluate", "calibrate", "export",
           "report", "sweep", "control", "demo", "reproduce", "real_robots.py"]


@pytest.mark.parametrize("command", WRITERS)
def test_every_writer_refuses_before_writing_anything(simulated_store, tiny_checkpoint, tmp_path, capsys,
                                                      monkeypatch, command):
    """Issue 61's general fix: whatever a command writes (a store, a run, a folder of results, a page,
    a benchmark's table) is written after its last refusal; a refused command leaves every file under
    its folders as it was, and adds none, lock files included."""
    monkeypatch.chdir(tmp_path)  # a default output (results/, data/) would land here
    monkeypatch.setenv("WANDB_MODE", "disabled")
    store = str(tmp_path / "S.zarr")
    shutil.copytree(simulated_store(robots=3, steps=CONTEXT + HORIZON + 10, seed=4), store)
    main, argv = _writers(str(tmp_path), store, tiny_checkpoint)[command]
    before = _files(tmp_path)
    code, err = _call(main, argv, capsys)
    _one_error(code, err)
    assert _files(tmp_path) == before
