import contextlib
import csv
import glob
import json
import math
import os
import re

import pytest

from robomorph import reproduce
from robomorph.evaluation.fit_bands import FIT_BANDS
from robomorph.reproduction import pipeline, skip
from robomorph.reproduction.improved import improved_overrides
from robomorph.reproduction.scales import SCALES

os.environ.setdefault("WANDB_MODE", "disabled")
TESTS = ["test0", "test1", "test2"]
CI_DEPTHS = list(SCALES["ci"].depths)
IMPROVED_RUN = f"table1-improved-L{SCALES['ci'].transfer_depth}-s{SCALES['ci'].train_steps}"
# Table 1's rows: the paper's model at each depth, then the improved model at the middle one.
ROWS = [(d, "paper", t) for d in CI_DEPTHS for t in TESTS] + [(SCALES["ci"].transfer_depth, "improved", t) for t in TESTS]


@contextlib.contextmanager
def spied():
    """Counts the trainings and evaluations a reproduction starts (they still run)."""
    import robomorph.evaluation.evaluator as evaluating
    import robomorph.training.fitting as fitting

    calls = {"fit": [], "evaluate": []}
    real_fit, real_evaluate = fitting.fit, evaluating.evaluate

    def fit(args, callbacks=None):
        calls["fit"].append(args["run"])
        return real_fit(args, callbacks)

    def evaluate(config, *args, **kwargs):
        calls["evaluate"].append(config.out)
        return real_evaluate(config, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fitting, "fit", fit)
        mp.setattr(evaluating, "evaluate", evaluate)
        yield calls


def _argv(target, root):
    return [target, "--scale", "ci", "--out", str(root / "out"), "--work", str(root / "work"), "--wandb", "disabled",
            "--workers", "1"]


@pytest.fixture(scope="module")
def table1_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("reproduce")
    with spied() as calls:
        assert reproduce.main(_argv("table1", root)) == 0
    return root, calls


def _md_table(path):
    """Header cells and data rows of the first markdown table in a file."""
    lines = [ln for ln in open(path).read().splitlines() if ln.startswith("|")]
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    return cells[0], cells[2:]


def test_table1_has_the_papers_rows_and_columns(table1_run):
    root, calls = table1_run
    out = root / "out"
    # one training per depth, and the improved model at the middle depth
    assert calls["fit"] == [f"table1-L{d}-s{SCALES['ci'].train_steps}" for d in CI_DEPTHS] + [IMPROVED_RUN]
    assert len(calls["evaluate"]) == 12  # every model on every test store
    doc = json.load(open(out / "table1.json"))
    assert doc["columns"] == ["r2", "r2_std", "rmse", "rmse_std"]
    assert [(r["n_layer"], r["model"], r["test"]) for r in doc["rows"]] == ROWS
    for r in doc["rows"]:
        assert all(math.isfinite(r[c]) for c in doc["columns"])
        assert r["rmse"] > 0 and r["r2_std"] >= 0 and r["rmse_std"] >= 0
    assert doc["info"]["scale"] == "ci" and doc["info"]["budgets"]["table1_steps_per_depth"] == SCALES["ci"].train_steps

    head, rows = _md_table(out / "table1.md")
    assert head == ["Layers", "Test", "R²", "σ(R²)", "RMSE", "σ(RMSE)"]
    assert [(r[0], r[1]) for r in rows] == [(str(d) if m == "paper" else f"{d} (improved)", t) for d, m, t in ROWS]
    for md, js in zip(rows, doc["rows"]):
        assert float(md[2]) == pytest.approx(js["r2"], abs=1e-3) and float(md[4]) == pytest.approx(js["rmse"], abs=1e-4)
    text = open(out / "table1.md").read()
    assert "Scale `ci`" in text and "python -m robomorph.reproduce table1 --scale ci" in text and "CPUs" in text
    assert re.search(r"UTC \(\d+\.\d min into the command\)", text) and doc["info"]["elapsed_min"] >= 0

    tex = open(out / "table1.tex").read()
    assert tex.count(r"\multicolumn{5}{c}") == 4 and r"\textbf{2 Layers}" in tex
    assert r"\textbf{2 Layers, improved model}" in tex
    assert tex.count(r"\textbf{test1} & ") == 4 and r"\label{tab:layer_comp}" in tex
    assert "Rows marked *improved*" in text


def test_the_improved_row_is_the_default_recipes_options_on_the_papers_model(table1_run):
    import yaml

    from robomorph.predictor import Predictor

    root, _ = table1_run
    with open("datamodules/train_cpu.yaml") as f:
        cpu = yaml.safe_load(f)
    small = SCALES["small"]  # the paper's 200 + 800 window: the recipe's options unchanged
    over = improved_overrides("datamodules/train_cpu.yaml", small.context_len, small.horizon, small.patch)
    assert over == {"data": {k: cpu["data"][k] for k in ("context_min", "horizon_min", "window")},
                    "model": {k: cpu["model"][k] for k in ("n_init", "anchor", "gaussian", "loss", "horizon_weight",
                                                           "horizon_tau")}}
    ci = SCALES["ci"]  # 30 + 60 steps in tokens of 5: scaled, multiples of the patch, within the window
    over = improved_overrides("datamodules/train_cpu.yaml", ci.context_len, ci.horizon, ci.patch)
    assert (over["data"]["context_min"], over["data"]["horizon_min"], over["model"]["n_init"]) == (10, 10, 5)
    # the improved run is the paper's size and budget with those options; the paper's rows are not
    pred = Predictor.from_checkpoint(skip.finished_ckpt(str(root / "work" / "runs" / IMPROVED_RUN)), device="cpu")
    cfg = pred.model.config
    assert pred.has_std and cfg.n_init == 5 and pred.model.anchor and cfg.n_layer == ci.transfer_depth
    paper = Predictor.from_checkpoint(skip.finished_ckpt(
        str(root / "work" / "runs" / f"table1-L{ci.transfer_depth}-s{ci.train_steps}")), device="cpu")
    assert not paper.has_std and paper.model.config.n_init == 0 and not paper.model.anchor


def test_improved_adds_its_rows_to_an_existing_table_and_refuses_without_one(table1_run, tmp_path, capsys):
    root, _ = table1_run
    doc = json.load(open(root / "out" / "table1.json"))
    paper_rows = [r for r in doc["rows"] if r["model"] == "paper"]
    out = tmp_path / "out"  # a table written before the improved row existed: the paper's rows only
    out.mkdir()
    (out / "table1.json").write_text(json.dumps({**doc, "rows": [
        {k: v for k, v in r.items() if k != "model"} for r in paper_rows]}))
    argv = _argv("improved", root)
    argv[argv.index("--out") + 1] = str(out)
    with spied() as calls:
        assert reproduce.main(argv) == 0
    assert calls == {"fit": [], "evaluate": []}  # the finished run and its evaluations are kept
    new = json.load(open(out / "table1.json"))
    assert new["rows"][:len(paper_rows)] == [{k: v for k, v in r.items() if k != "model"} for r in paper_rows]
    assert new["rows"][len(paper_rows):] == [r for r in doc["rows"] if r["model"] == "improved"]
    assert new["info"]["command"] == doc["info"]["command"] and "improved" in new["info"]["improved"]["command"]
    assert "Added by `python -m robomorph.reproduce improved" in open(out / "table1.md").read()
    capsys.readouterr()
    argv[argv.index("--out") + 1] = str(tmp_path / "empty")
    assert reproduce.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "table1.json not found" in err and "reproduce table1 --scale ci" in err
    assert reproduce.main([*_argv("improved", root), "--normalization", "paper_window"]) == 2
    assert "leak-free only" in capsys.readouterr().err


def test_rerun_skips_finished_work_and_redoes_only_what_is_missing(table1_run):
    root, _ = table1_run
    before = json.load(open(root / "out" / "table1.json"))["rows"]
    with spied() as calls:
        reproduce.main(_argv("table1", root))
    assert calls == {"fit": [], "evaluate": []}
    assert json.load(open(root / "out" / "table1.json"))["rows"] == before

    os.remove(root / "work" / "runs" / f"table1-L2-s{SCALES['ci'].train_steps}" / "eval" / "test1" / "metrics.json")
    with spied() as calls:
        reproduce.main(_argv("table1", root))
    assert calls["fit"] == [] and len(calls["evaluate"]) == 1 and calls["evaluate"][0].endswith("test1")


def test_all_reuses_table1_and_writes_table2_and_the_context_figure(table1_run):
    root, _ = table1_run
    with spied() as calls:
        reproduce.main(_argv("all", root))
    # table1's models are reused: only the pre-training, fine-tuning and scratch runs train
    assert [re.sub(r"-L\d+-s\d+$", "", r) for r in calls["fit"]] == ["table2-pretrain", "table2-finetune", "table2-scratch"]
    out, work = root / "out", root / "work"
    doc = json.load(open(out / "table2.json"))
    assert doc["regimes"] == ["zero_shot", "finetune", "scratch"]
    assert len(doc["channels"]) == 14 and list(doc["rows"]) == doc["channels"] + ["mean"]
    marks = {b.mark for b in FIT_BANDS}
    for cells in doc["rows"].values():
        for regime in doc["regimes"]:
            c = cells[regime]
            assert math.isfinite(c["r2"]) and math.isfinite(c["fit"]) and c["mark"] == FIT_BANDS[c["band"]].mark
    # The cells are the paper's second approach (it scores OSC tasks so); the first is kept beside.
    ft_eval = glob.glob(str(root / "work" / "runs" / "table2-finetune-*" / "eval" / "spiral_test" / "metrics.json"))
    res = json.load(open(ft_eval[0]))
    assert doc["approach"] == 2 and doc["rows"]["q1"]["finetune"]["r2"] == res["approach2"]["channels"]["q1"]["r2"]
    assert doc["rows"]["mean"]["finetune"]["fit_a1"] == res["approach1"]["mean"]["fit"]["mean"]
    assert doc["hold"]["r2"] == res["baselines"]["hold"]["approach2"]["mean"]["r2"]

    head, rows = _md_table(out / "table2.md")
    assert len(head) == 7 and head[1].startswith("Zero-shot") and "Scratch" in head[5]
    assert [r[0] for r in rows] == doc["channels"] + ["**mean**"]
    assert all(r[i].split()[0] in marks for r in rows for i in (2, 4, 6))  # every FIT cell carries its colour
    tex = open(out / "table2.tex").read()
    colours = re.findall(r"\\cellcolor\{([^}]*)\}", tex)
    assert len(colours) == 15 * 6 and set(colours) <= {b.latex for b in FIT_BANDS}

    ft = [r for r in calls["fit"] if r.startswith("table2-finetune")][0]
    config = open(work / "runs" / ft / "config.yaml").read()
    assert "init_ckpt: " + str(work / "runs") in config and "table2-pretrain" in config

    with open(out / "context_horizon.csv") as f:
        sweeps = {(r["sweep"], r["source"]) for r in csv.DictReader(f)}
    assert {("horizon", "model"), ("context", "model"), ("horizon", "hold")} <= sweeps
    assert os.path.getsize(out / "context_horizon.png") > 10_000
    html = open(work / "report.html").read()  # the dashboard shows every run with its evaluations
    assert all(r in html for r in calls["fit"]) and "spiral_test" in html and "test0-sweeps" in html


@pytest.mark.parametrize("argv, message", [(["table3"], "invalid choice: 'table3'"),
                                           (["table1", "--scale", "huge"], "invalid choice: 'huge'")])
def test_bad_arguments_are_argparse_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        reproduce.main(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_bad_values_are_one_line_errors(capsys):
    assert reproduce.main(["table2", "--steps-factor", "0"]) == 2
    assert capsys.readouterr().err == "error: steps_factor must be > 0, got 0.0\n"


def test_a_run_stopped_short_of_its_budget_is_not_marked_finished(tmp_path, monkeypatch):
    import robomorph.training.fitting as fitting

    ckpt = tmp_path / "runs" / "r" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"x")
    # what fit() returns after Lightning's graceful shutdown on Ctrl-C: a checkpoint, fewer steps
    monkeypatch.setattr(fitting, "fit", lambda args, callbacks=None: fitting.FitResult(
        str(ckpt.parent.parent), None, str(ckpt), {}, 3))
    plan = pipeline.Plan(SCALES["ci"], str(tmp_path), str(tmp_path / "out"), "test")
    args = pipeline.base_args(plan, 1, ["unused.zarr"], "r", 10)
    with pytest.raises(RuntimeError, match="stopped at step 3 of 10: re-run the same command"):
        pipeline.trained_ckpt(plan, "t", args, "model")
    assert not skip.run_finished(str(ckpt.parent.parent), {"max_steps": 10, "max_time": None})


def test_paper_window_table1_is_labelled_shares_the_stores_and_compares_side_by_side(table1_run, capsys):
    root, _ = table1_run
    out, out_pw = root / "out", root / "out_pw"
    assert pipeline.default_out(SCALES["ci"], "paper_window") == os.path.join("results", "paper", "ci_paper_window")
    argv = [*_argv("table1", root), "--normalization", "paper_window"]
    argv[argv.index("--out") + 1] = str(out_pw)
    with spied() as calls:
        assert reproduce.main(argv) == 0
    # Its own runs beside the leak-free ones (the stores are shared: same data), never theirs.
    assert calls["fit"] == [f"table1-L{d}-s{SCALES['ci'].train_steps}-paper_window" for d in CI_DEPTHS]
    assert all(c.startswith(str(root / "work" / "runs")) and "-paper_window" in c for c in calls["evaluate"])
    doc = json.load(open(out_pw / "table1.json"))
    assert doc["info"]["normalization"] == "paper_window" and doc["info"]["leaks_query_statistics"] is True
    text = open(out_pw / "table1.md").read()
    assert "**⚠ Normalization paper_window (the paper's protocol)" in text.split("| Layers")[0]
    assert "Normalization paper_window" in open(out_pw / "table1.tex").read().splitlines()[0]
    assert "Normalization train_stats" in open(out / "table1.md").read()
    config = open(root / "work" / "runs" / calls["fit"][0] / "config.yaml").read()
    assert "normalization: paper_window" in config and "recenter: false" in config

    assert reproduce.main(["compare", "--scale", "ci", "--out", str(out_pw), "--leak-free", str(out)]) == 0
    cmp = json.load(open(out_pw / "table1_protocols.json"))
    assert [(r["n_layer"], r["paper_n_layer"], r["test"]) for r in cmp["rows"]] == [
        (d, p, t) for d, p in zip(CI_DEPTHS, (10, 12, 16)) for t in TESTS]
    ts, pw = [r for r in json.load(open(out / "table1.json"))["rows"] if r["model"] == "paper"], doc["rows"]
    assert len(pw) == len(ts) == 9  # the paper's protocol: the paper's architecture, no improved row
    for row, a, b in zip(cmp["rows"], ts, pw):
        assert row["train_stats"]["r2"] == a["r2"] and row["paper_window"]["rmse"] == b["rmse"]
    assert cmp["rows"][4]["paper"] == {"r2": 0.787, "rmse": 0.0454}  # 12 layers, test1 in the paper
    head, rows = _md_table(out_pw / "table1_protocols.md")
    assert head[2:5] == ["R² train_stats", "R² paper_window", "R² paper"] and len(rows) == 10
    # Swapped folders: one line, exit code 2, saying what to pass.
    capsys.readouterr()
    assert reproduce.main(["compare", "--scale", "ci", "--out", str(out), "--leak-free", str(out_pw)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "produced with normalization 'paper_window', expected 'train_stats'" in err


def test_gap_closed_is_the_share_of_the_distance_to_the_paper():
    from robomorph.reproduction.protocols import summary

    rows = [{"train_stats": {"r2": 0.3, "rmse": 0.04}, "paper_window": {"r2": 0.5, "rmse": 0.03},
             "paper": {"r2": 0.7, "rmse": 0.05}},
            {"train_stats": {"r2": 0.5, "rmse": 0.02}, "paper_window": {"r2": 0.7, "rmse": 0.01},
             "paper": {"r2": 0.9, "rmse": 0.05}}]
    s = summary(rows)
    assert s["train_stats"]["r2"] == pytest.approx(0.4) and s["paper"]["rmse"] == pytest.approx(0.05)
    assert s["gap_closed"] == pytest.approx(0.5)
    assert summary([{**rows[0], "paper": None}])["gap_closed"] is None


def test_inputs_command_trains_its_own_runs_and_names_the_formulation(table1_run):
    from robomorph.predictor import Predictor

    root, _ = table1_run
    argv = [*_argv("table1", root), "--inputs", "command"]
    argv[argv.index("--out") + 1] = str(root / "out-command")
    with spied() as calls:
        assert reproduce.main(argv) == 0
    # the stores are shared, the total-torque runs are not reused
    assert len(calls["fit"]) == 4 and all(r.endswith("-command") for r in calls["fit"])
    text = open(root / "out-command" / "table1.md").read()
    assert "inputs `command`" in text and "--inputs command" in text
    assert "inputs `total`" in open(root / "out" / "table1.md").read()
    ckpt = skip.finished_ckpt(str(root / "work" / "runs" / calls["fit"][0]))
    assert Predictor.from_checkpoint(ckpt, device="cpu").inputs == "command"


def test_a_sigterm_mid_training_is_one_line_and_exit_code_143(table1_run, monkeypatch, capsys):
    import robomorph.training.fitting as fitting
    from robomorph.core.errors import StoppedBySignal

    root, _ = table1_run

    def stopped(args, callbacks=None):  # what fit() raises after saving last.ckpt on a scheduler's SIGTERM
        raise StoppedBySignal("runs/x", "runs/x/checkpoints/last.ckpt", 7)

    monkeypatch.setattr(fitting, "fit", stopped)
    argv = [*_argv("table1", root), "--inputs", "command"]
    argv[argv.index("--work") + 1] = str(root / "work-sigterm")
    capsys.readouterr()
    assert reproduce.main(argv) == 143
    err = capsys.readouterr().err.strip()
    assert err == ("stopped by SIGTERM at step 7: saved runs/x/checkpoints/last.ckpt; re-run the same command to "
                   "resume from there")


def test_a_stop_while_the_improved_row_trains_leaves_a_table_of_the_papers_rows(table1_run, monkeypatch, capsys):
    from robomorph.core.errors import StoppedBySignal

    root, _ = table1_run

    def stopped(*args, **kwargs):  # a lease or a scheduler ends the command while the improved model trains
        raise StoppedBySignal("runs/improved", "runs/improved/checkpoints/last.ckpt", 5)

    monkeypatch.setattr(pipeline, "improved_results", stopped)
    argv = _argv("table1", root)
    argv[argv.index("--out") + 1] = str(root / "out-stopped")
    assert reproduce.main(argv) == 143
    doc = json.load(open(root / "out-stopped" / "table1.json"))
    assert [(r["n_layer"], r["model"], r["test"]) for r in doc["rows"]] == [r for r in ROWS if r[1] == "paper"]
    assert doc["info"]["pending"] == "improved"
    text = open(root / "out-stopped" / "table1.md").read()
    assert "The *improved* rows are not here yet" in text and "Re-run it to add them" in text
    # the finished table (the same paper rows) carries no such note
    assert "not here yet" not in open(root / "out" / "table1.md").read()
    assert "pending" not in json.load(open(root / "out" / "table1.json"))["info"]


def _evaluations_only(work, dest, skip_run=None):
    """Copies each run's evaluations (metrics.json alone: no checkpoints, no stores) as a machine
    whose lease ended would send them back."""
    for path in glob.glob(os.path.join(work, "runs", "*", "eval", "*", "metrics.json")):
        rel = os.path.relpath(path, work)
        if skip_run and rel.split(os.sep)[1] == skip_run:
            continue
        os.makedirs(os.path.dirname(os.path.join(dest, rel)), exist_ok=True)
        with open(path) as src, open(os.path.join(dest, rel), "w") as out:
            out.write(src.read())


def test_collect_writes_table1_from_the_evaluations_alone(table1_run, tmp_path, capsys):
    root, _ = table1_run
    full = json.load(open(root / "out" / "table1.json"))
    _evaluations_only(str(root / "work"), str(tmp_path / "work"))
    argv = ["collect", "--scale", "ci", "--work", str(tmp_path / "work"), "--out", str(tmp_path / "out")]
    assert reproduce.main(argv) == 0
    doc = json.load(open(tmp_path / "out" / "table1.json"))
    assert doc["rows"] == full["rows"]  # the same rows, numbers and order as the command that trained them
    evaluation = json.load(open(glob.glob(str(root / "work" / "runs" / "table1-L1-*" / "eval" / "test0" /
                                               "metrics.json"))[0]))["provenance"]
    assert doc["info"]["command"] == evaluation["command"] and evaluation["machine"] in doc["info"]["machine"]
    assert doc["info"]["collected"]["missing"] == []
    assert "python -m robomorph.reproduce collect --scale ci" in open(tmp_path / "out" / "table1.md").read()

    # a depth whose evaluations never came back is left out and named
    _evaluations_only(str(root / "work"), str(tmp_path / "part"), skip_run=f"table1-L2-s{SCALES['ci'].train_steps}")
    argv = ["collect", "--scale", "ci", "--work", str(tmp_path / "part"), "--out", str(tmp_path / "out2")]
    assert reproduce.main(argv) == 0
    doc = json.load(open(tmp_path / "out2" / "table1.json"))
    assert {r["n_layer"] for r in doc["rows"] if r["model"] == "paper"} == {1, 3}
    assert doc["info"]["collected"]["missing"] == ["2"]
    assert "Runs not scored there, so not in this table: 2." in open(tmp_path / "out2" / "table1.md").read()

    # nothing scored: one line naming the folder and what makes the evaluations
    capsys.readouterr()
    argv = ["collect", "--scale", "ci", "--work", str(tmp_path / "empty"), "--out", str(tmp_path / "out3")]
    assert reproduce.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no Table 1 run of scale ci" in err and "reproduce table1 --scale ci" in err
    assert not os.path.exists(tmp_path / "out3" / "table1.json")


def test_device_reproduce_packs_what_collect_needs(table1_run, tmp_path):
    """tools/device_reproduce.sh, as one device call runs it: the reproduction under a time limit,
    then every evaluation packed; collect then writes the same Table 1 from the pack alone."""
    import subprocess
    import sys
    import tarfile

    root, _ = table1_run
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = tmp_path / "device_out"
    argv = ["bash", "tools/device_reproduce.sh", "300", str(out), "table1", "--scale", "ci", "--work",
            str(root / "work"), "--out", str(root / "out-device"), "--workers", "1"]
    done = subprocess.run(argv, cwd=repo, env={**os.environ, "PYTHON": sys.executable}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "device_reproduce: reproduce exited with 0" in open(out / "reproduce.log").read()
    with tarfile.open(out / "evaluations.tgz") as pack:
        names = pack.getnames()
        assert not any(n.endswith((".ckpt", ".zarr")) for n in names)
        pack.extractall(tmp_path / "back", filter="data")
    work = tmp_path / "back" / os.path.relpath(root / "work", "/")
    steps = SCALES["ci"].train_steps  # Table 1's runs: 3 depths and the improved model, 3 test stores each
    assert len(glob.glob(str(work / "runs" / f"table1-*-s{steps}" / "eval" / "test[0-2]" / "metrics.json"))) == 12
    assert reproduce.main(["collect", "--scale", "ci", "--work", str(work), "--out", str(tmp_path / "table")]) == 0
    assert json.load(open(tmp_path / "table" / "table1.json"))["rows"] == \
        json.load(open(root / "out-device" / "table1.json"))["rows"]


def test_collect_writes_table2_and_the_context_figure_from_the_evaluations_alone(table1_run, tmp_path):
    root, _ = table1_run
    assert reproduce.main(_argv("all", root)) == 0  # finished work is kept: only what is missing runs
    _evaluations_only(str(root / "work"), str(tmp_path / "work"))
    argv = ["collect", "--scale", "ci", "--work", str(tmp_path / "work"), "--out", str(tmp_path / "out")]
    assert reproduce.main(argv) == 0
    full, got = json.load(open(root / "out" / "table2.json")), json.load(open(tmp_path / "out" / "table2.json"))
    assert got["rows"] == full["rows"] and got["titles"] == full["titles"] and got["regimes"] == full["regimes"]
    assert "Collected from the evaluations" in open(tmp_path / "out" / "table2.md").read()
    fig = json.load(open(tmp_path / "out" / "context_horizon.json"))
    assert fig["sweeps"] == json.load(open(root / "out" / "context_horizon.json"))["sweeps"]
    assert os.path.getsize(tmp_path / "out" / "context_horizon.png") > 10_000

    # without the fine-tuned run's evaluation Table 2 is not written; Table 1 and the figure still are
    _evaluations_only(str(root / "work"), str(tmp_path / "part"),
                      skip_run=f"table2-finetune-L{SCALES['ci'].transfer_depth}-s{SCALES['ci'].finetune_steps}")
    argv = ["collect", "--scale", "ci", "--work", str(tmp_path / "part"), "--out", str(tmp_path / "out2")]
    assert reproduce.main(argv) == 0
    assert not os.path.exists(tmp_path / "out2" / "table2.json")
    assert os.path.isfile(tmp_path / "out2" / "table1.json") and os.path.isfile(tmp_path / "out2" / "context_horizon.png")
