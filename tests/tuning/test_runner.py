import dataclasses
import glob
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

import optuna
import pytest

from robomorph.sweep import main
from robomorph.tuning.runner import logged_values, open_study, run_sweep, with_overrides
from robomorph.tuning.space import SpaceError, load_space, parse_space
from robomorph.tuning.storage import normalize_url, open_storage
from robomorph.tuning.summary import summarize

os.environ.setdefault("WANDB_MODE", "offline")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CI_SPACE = os.path.join(ROOT, "sweeps", "ci.yaml")
TS = optuna.trial.TrialState


@pytest.fixture(scope="module")
def store(simulated_store):
    return simulated_store(robots=40, steps=90, seed=1)


def _space(store, **budget):
    space = with_overrides(load_space(CI_SPACE), [f"data.stores={store}"])
    return dataclasses.replace(space, budget={**space.budget, **budget}) if budget else space


def _sqlite(tmp_path, name="s.db"):
    return f"sqlite:///{tmp_path / name}"


def test_two_trial_study_then_continue(store, tmp_path):
    storage = open_storage(_sqlite(tmp_path))
    runs = str(tmp_path / "runs")
    study = run_sweep(_space(store), 2, storage, "two", runs, wandb="disabled")
    trials = study.get_trials()
    assert trials[0].state == TS.COMPLETE and trials[1].state in (TS.COMPLETE, TS.PRUNED)
    for t in trials:
        config = open(os.path.join(t.user_attrs["run_dir"], "config.yaml")).read()
        assert "group: two" in config  # the wandb group is the study
        assert "val/r2" in t.user_attrs["metrics"]
    first = trials[0]
    assert first.value == pytest.approx(max(first.intermediate_values.values()))  # maximize val/r2
    assert sorted(first.intermediate_values) == [5, 10, 15, 20]  # reported per validation step
    # Re-running continues the same study up to the new total, then does nothing.
    assert len(run_sweep(_space(store), 3, storage, "two", runs, wandb="disabled").trials) == 3
    assert len(run_sweep(_space(store), 3, storage, "two", runs, wandb="disabled").trials) == 3
    text = summarize(study, str(tmp_path / "summary"))
    assert "best" in text and "model.lr" in text and "importances" in text
    assert os.path.isfile(tmp_path / "summary" / "trials.csv")



def test_summary_command_prints_and_writes_the_table(store, tmp_path, capsys):
    url = _sqlite(tmp_path)
    run_sweep(_space(store), 1, open_storage(url), "sum", str(tmp_path / "runs"), wandb="disabled")
    out = tmp_path / "table"
    assert main(["summary", "--study-name", "sum", "--storage", url, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| " in printed and "**best**: trial 0" in printed
    assert (out / "summary.md").read_text() == printed.rstrip("\n") + "\n"
    with open(out / "trials.csv") as f:
        assert len(f.read().strip().splitlines()) == 2  # header + the one trial
    assert main(["summary", "--study-name", "nope", "--storage", url]) == 2
    assert capsys.readouterr().err.endswith("error: no study 'nope' in this storage; it holds ['sum']\n")


def test_pruning_stops_a_clearly_worse_trial(store, tmp_path):
    storage = open_storage(_sqlite(tmp_path))
    space = _space(store)
    study = open_study(space, storage, "prune")
    study.enqueue_trial({"model.lr": 1e-2, "model.loss": "mse"})
    study.enqueue_trial({"model.lr": 1e-4, "model.loss": "mse"})  # barely moves in 20 steps
    run_sweep(space, 2, storage, "prune", str(tmp_path / "runs"), wandb="disabled")
    good, bad = study.get_trials()
    assert good.state == TS.COMPLETE
    assert bad.state == TS.PRUNED
    assert max(bad.intermediate_values) < 20


def _worker(space_file, store, storage, study, runs, n, *extra):
    return subprocess.Popen(
        [sys.executable, "-m", "robomorph.sweep", space_file, "--n-trials", str(n), "--storage", storage,
         "--study-name", study, "--runs-dir", runs, "--wandb", "disabled", "--set", f"data.stores={store}", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _share(store, tmp_path, url):
    storage = open_storage(url)
    open_study(load_space(CI_SPACE), storage, "shared")  # created once, before the workers race
    runs = str(tmp_path / "runs")
    workers = [_worker(CI_SPACE, store, url, "shared", runs, 4) for _ in range(2)]
    outs = [w.communicate(timeout=600)[0] for w in workers]
    assert all(w.returncode == 0 for w in workers), outs
    trials = optuna.load_study(study_name="shared", storage=storage).get_trials()
    finished = [t for t in trials if t.state in (TS.COMPLETE, TS.PRUNED)]
    # Both workers stop at the study's total (one may finish a trial it had already begun).
    assert 4 <= len(finished) <= 5 and len(finished) == len(trials)
    numbers = [t.number for t in trials]
    dirs = [t.user_attrs["run_dir"] for t in trials]
    assert len(set(numbers)) == len(numbers) and len(set(dirs)) == len(dirs)
    assert all(os.path.isfile(os.path.join(d, "config.yaml")) for d in dirs)
    # Workers started together draw their own parameters (issue 10: they used to run
    # identical trials, each worker's sampler replaying the same seeded stream).
    drawn = [tuple(sorted(t.params.items())) for t in trials]
    assert len(set(drawn)) == len(drawn), drawn


def test_two_workers_share_a_sqlite_study(store, tmp_path):
    _share(store, tmp_path, _sqlite(tmp_path))


@pytest.fixture(scope="module")
def postgres():
    """A throw-away PostgreSQL cluster on 127.0.0.1 (Debian's server binaries)."""
    subprocess.run(["bash", os.path.join(ROOT, "tools", "ensure_postgres.sh")], check=True)
    bindir = sorted(glob.glob("/usr/lib/postgresql/*/bin"))[-1]
    # Not under pytest's tmp dirs: those are private to root, and the server runs as postgres.
    root = pathlib.Path(tempfile.mkdtemp(prefix="robomorph-pg-"))
    data = root / "data"
    as_user = ["runuser", "-u", "postgres", "--"] if os.geteuid() == 0 else []
    if as_user:
        shutil.chown(root, "postgres")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    subprocess.run([*as_user, f"{bindir}/initdb", "-D", str(data), "-A", "trust", "-U", "robomorph"],
                   check=True, capture_output=True)
    opts = f"-p {port} -k {root} -c listen_addresses=127.0.0.1"
    subprocess.run([*as_user, f"{bindir}/pg_ctl", "-D", str(data), "-o", opts, "-l", str(root / "log"), "-w",
                    "start"], check=True, capture_output=True)
    yield f"postgresql+psycopg2://robomorph@127.0.0.1:{port}/postgres"
    subprocess.run([*as_user, f"{bindir}/pg_ctl", "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
    shutil.rmtree(root, ignore_errors=True)


@pytest.mark.slow
def test_two_workers_share_a_postgresql_study(store, tmp_path, postgres):
    _share(store, tmp_path, postgres)


def test_killed_workers_trial_is_failed_and_retried(store, tmp_path):
    url = _sqlite(tmp_path)
    storage = open_storage(url, heartbeat=1, grace=3)
    study = open_study(load_space(CI_SPACE), storage, "killed")
    runs = str(tmp_path / "runs")
    worker = _worker(CI_SPACE, store, url, "killed", runs, 1, "--heartbeat", "1", "--grace", "3",
                     "--set", "trainer.max_steps=100000", "--set", "trainer.val_check_interval=5")
    deadline = time.time() + 120
    while time.time() < deadline:
        trials = study.get_trials()
        if trials and glob.glob(os.path.join(runs, "killed-t0000", "checkpoints", "last.ckpt")):
            break
        time.sleep(0.5)
    else:
        worker.kill()
        pytest.fail("the worker never started a trial: " + worker.communicate()[0][-2000:])
    worker.send_signal(signal.SIGKILL)
    worker.wait()
    assert study.get_trials()[0].state == TS.RUNNING  # nobody told the storage
    time.sleep(4)  # past the grace period
    run_sweep(_space(store), 1, storage, "killed", runs, wandb="disabled")
    first, retry = study.get_trials()[:2]
    assert first.state == TS.FAIL
    assert retry.state == TS.COMPLETE and retry.params == first.params
    assert retry.system_attrs.get("failed_trial") == 0
    assert retry.user_attrs["run_dir"] == first.user_attrs["run_dir"]  # resumed, not restarted
    # The dead worker may have trained past the retry's 20-step budget (then the resume
    # validates no more): the value is the best val/r2 the run's log holds either way.
    logged = logged_values(retry.user_attrs["run_dir"], "val/r2")
    assert logged and retry.value == pytest.approx(max(logged))


def test_bad_storage_and_space_files_give_clear_errors(tmp_path, capsys):
    with pytest.raises(SpaceError, match="cannot open the study storage"):
        open_storage("postgresql+psycopg2://nobody@127.0.0.1:1/none")
    bad = tmp_path / "bad.yaml"
    bad.write_text("objective: {metric: val/loss, direction: minimize}\nparams: {model.lr: {low: 2, high: 1}}\n")
    assert main([str(bad), "--n-trials", "1", "--storage", _sqlite(tmp_path)]) == 2
    assert "low 2 > high 1" in capsys.readouterr().err


def test_transfer_regimes_as_a_study(store, tmp_path):
    from robomorph.training.fitting import fit

    base = load_space(CI_SPACE).base
    trainer = {**base["trainer"], "max_steps": 10, "val_check_interval": 5}
    pre = fit({**base, "data": {**base["data"], "stores": store}, "trainer": trainer,
               "run": "pre", "runs_dir": str(tmp_path / "runs"), "wandb": "disabled"})
    space = parse_space({
        "name": "tr", "objective": {"metric": "fit", "direction": "maximize", "data": store},
        "budget": {"val_check_interval": 5}, "sampler": {"name": "grid"}, "pruner": {"name": "none"},
        "base": {**base, "data": {**base["data"], "stores": store}},
        "transfer": {"init_ckpt": pre.best_ckpt, "steps": 10, "freeze": "encoder"},
        "params": {"transfer.regime": {"choices": ["zero_shot", "finetune", "scratch"]}}})
    study = run_sweep(space, 3, open_storage(_sqlite(tmp_path)), "tr", str(tmp_path / "runs"), wandb="disabled")
    trials = {t.params["transfer.regime"]: t for t in study.get_trials()}
    assert set(trials) == {"zero_shot", "finetune", "scratch"}
    assert all(t.state == TS.COMPLETE and t.value == pytest.approx(t.user_attrs["eval"]["fit"]) for t in trials.values())
    assert "global_step" not in trials["zero_shot"].user_attrs  # evaluated, never trained
    assert trials["finetune"].user_attrs["global_step"] == trials["scratch"].user_attrs["global_step"] == 10
    config = open(os.path.join(trials["finetune"].user_attrs["run_dir"], "config.yaml")).read()
    assert pre.best_ckpt in config and "freeze: encoder" in config
    scratch = open(os.path.join(trials["scratch"].user_attrs["run_dir"], "config.yaml")).read()
    assert "init_ckpt" not in scratch and "freeze: none" in scratch


def test_a_trial_resumed_past_its_budget_takes_its_value_from_the_run_log(store, tmp_path):
    # Two storages, one runs folder: the second study's trial 0 finds run "p-t0000" already
    # at step 20 and its budget is 10, so fit() resumes and stops without validating.
    runs = str(tmp_path / "runs")
    first = run_sweep(_space(store), 1, open_storage(_sqlite(tmp_path, "a.db")), "p", runs, wandb="disabled")
    again = run_sweep(_space(store, max_steps=10), 1, open_storage(_sqlite(tmp_path, "b.db")), "p", runs,
                      wandb="disabled")
    t0, t1 = first.get_trials()[0], again.get_trials()[0]
    assert t1.state == TS.COMPLETE and t1.user_attrs["global_step"] == 20 and not t1.intermediate_values
    assert t1.value == pytest.approx(t0.value) == pytest.approx(max(logged_values(t0.user_attrs["run_dir"], "val/r2")))


def test_the_readme_postgresql_url_form_names_no_driver():
    # SQLAlchemy 2.1 maps a plain postgresql:// to psycopg 3, which is not installed: the
    # error used to blame the server for a missing driver.
    assert normalize_url("postgresql://user@host/db") == "postgresql+psycopg2://user@host/db"
    assert normalize_url("postgres://user:pw@host:5432/db") == "postgresql+psycopg2://user:pw@host:5432/db"
    assert normalize_url("postgresql+psycopg2://u@h/d") == "postgresql+psycopg2://u@h/d"
    with pytest.raises(SpaceError) as err:
        open_storage("postgresql://nobody:secret@127.0.0.1:1/none")
    # The server is what failed now (the old error blamed it for a driver that failed to import).
    assert "import" not in str(err.value) and "Connection refused" in str(err.value)
    assert "server is running" in str(err.value) and "secret" not in str(err.value)


def test_the_readme_postgresql_url_form_opens_a_real_study(postgres):
    plain = postgres.replace("postgresql+psycopg2://", "postgresql://")  # exactly the README's form
    study = optuna.create_study(storage=open_storage(plain), study_name="plain", direction="minimize")
    study.optimize(lambda t: t.suggest_float("x", 0, 1), n_trials=2)
    again = optuna.load_study(study_name="plain", storage=open_storage(plain))
    assert [t.state for t in again.trials] == [TS.COMPLETE, TS.COMPLETE]


def test_summaries_go_beside_the_runs_and_never_overwrite_another_study(store, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # where results/sweeps/<study>/ used to be written

    def sweep(url, runs):
        return main([CI_SPACE, "--n-trials", "1", "--storage", url, "--study-name", "same", "--runs-dir", runs,
                     "--wandb", "disabled", "--set", f"data.stores={store}"])

    a, b = _sqlite(tmp_path, "a.db"), _sqlite(tmp_path, "b.db")
    assert sweep(a, str(tmp_path / "ra")) == 0 and sweep(b, str(tmp_path / "rb")) == 0
    first = (tmp_path / "ra" / "same-summary" / "summary.md").read_text()
    second = (tmp_path / "rb" / "same-summary" / "summary.md").read_text()
    assert "ra/same-t0000" in first and "rb/same-t0000" in second
    assert not (tmp_path / "results").exists()
    # The same study name from the other storage into the first runs folder: refused, and
    # the first study's summary is untouched.
    capsys.readouterr()
    assert sweep(b, str(tmp_path / "ra")) == 2
    assert "holds the summary of another study" in capsys.readouterr().err
    assert main(["summary", "--study-name", "same", "--storage", b, "--runs-dir", str(tmp_path / "ra")]) == 2
    assert "holds the summary of another study" in capsys.readouterr().err
    assert (tmp_path / "ra" / "same-summary" / "summary.md").read_text() == first
    # The summary command finds the study's runs folder by itself.
    assert main(["summary", "--study-name", "same", "--storage", b]) == 0
    assert (tmp_path / "rb" / "same-summary" / "trials.csv").is_file()


def test_a_fit_setting_that_cannot_train_stops_the_sweep_in_one_line(store, tmp_path, capsys):
    assert main([CI_SPACE, "--n-trials", "1", "--storage", _sqlite(tmp_path), "--runs-dir", str(tmp_path / "runs"),
                 "--wandb", "disabled", "--set", f"data.stores={store}", "--set", "data.context_len=21"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("error: --data.context_len 21 is not a multiple of --model.patch 5")
    assert not (tmp_path / "runs" / "ci-t0000").exists()


def test_a_missing_database_driver_is_named_as_such():
    with pytest.raises(SpaceError, match="database driver is not installed") as err:
        open_storage("postgresql+psycopg://nobody@127.0.0.1:1/none")  # psycopg 3: not a dependency
    assert "server is running" not in str(err.value)
