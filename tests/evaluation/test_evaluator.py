import json
import os
import re

import numpy as np
import pytest

from robomorph.core.metrics import METRICS
from robomorph.core.results import read_provenance, read_rows
from robomorph.data.store import create_store
from robomorph.evaluate import main
from robomorph.evaluation.evaluator import evaluate, parse_range
from robomorph.evaluation.requests import EvaluateConfig
from robomorph.predictor import Predictor
from tests.conftest import CKPT_CONTEXT as C
from tests.conftest import CKPT_HORIZON as H
from tests.conftest import tiny_fit_args, write_store


@pytest.fixture(scope="module")
def setup(tiny_checkpoint, simulated_store):
    """The shared tiny checkpoint (trained on 24 robots, seed 1) and 6 unseen robots (seed 2)."""
    return None, tiny_checkpoint, simulated_store(robots=6, steps=C + H, seed=2)


def test_checkpoint_records_its_training_data(setup):
    _, ckpt, _ = setup
    info = Predictor.from_checkpoint(ckpt, device="cpu").data_info
    assert info["context_len"] == C and info["horizon"] == H
    assert info["y_names"][:3] == ["ee_x", "ee_y", "ee_z"] and len(info["u_names"]) == 7


def test_evaluate_writes_every_file_with_the_documented_shape(setup, tmp_path):
    _, ckpt, test = setup
    out = str(tmp_path / "ev")
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=out,
                                  sweep_horizon_spec="20:60:20", sweep_context_spec="10,30", samples=2,
                                  arx_orders=(1, 1)))
    names = res["meta"]["y_names"]
    for f in ("metrics.json", "metrics.csv", "horizons.csv", "table.md", "error_growth.png", "r2_distribution.png",
              "sweep_horizon.png", "sweep_context.png"):
        assert os.path.getsize(os.path.join(out, f)) > 0, f
    assert len([f for f in os.listdir(out) if f.startswith("sample_")]) == 2
    with open(os.path.join(out, "metrics.json")) as f:
        disk = json.load(f)
    assert disk["approach1"] == res["approach1"]
    assert set(disk["approach1"]["channels"]) == set(names) and len(names) == 14
    for ch in names:
        assert set(disk["approach1"]["channels"][ch]) == set(METRICS)
        assert set(disk["approach1"]["channels"][ch]["r2"]) == {"mean", "std", "median"}
        assert set(disk["approach2"]["channels"][ch]) == set(METRICS)
    assert set(disk["baselines"]) == {"hold", "constant_velocity", "constant_acceleration", "arx", "arx_train",
                                      "nominal_physics"}
    for b in disk["baselines"].values():
        assert set(b) == {"approach1", "approach2"} and set(b["approach1"]["channels"]) == set(names)
    assert disk["meta"]["n"] == 6 and disk["meta"]["context_len"] == C and disk["meta"]["horizon"] == H
    # The model's cost per window (its predictions alone), beside the baselines' fits where they fit.
    assert disk["meta"]["seconds_per_window"] > 0
    with open(os.path.join(out, "table.md")) as f:
        assert "ms per window, its predictions alone" in f.read()
    assert [r["horizon"] for r in disk["sweeps"]["horizon"]] == [20, 40, 60]
    assert [r["context_len"] for r in disk["sweeps"]["context"]] == [10, 30]
    # The full-horizon sweep point is the main evaluation.
    assert disk["sweeps"]["horizon"][-1]["model"]["r2"] == pytest.approx(disk["approach1"]["mean"]["r2"]["mean"])
    with open(os.path.join(out, "metrics.csv")) as f:
        rows = [line for line in f.read().splitlines() if not line.startswith("#")]
    # per source (the model and 6 baselines): approach 1 (14 channels + mean) and 2 (same), 4 metrics each
    assert len(rows) == 1 + 7 * 2 * 15 * 4
    table = open(os.path.join(out, "table.md")).read()
    first_cells = [line.strip("|").split("|")[0].strip() for line in table.splitlines() if line.startswith("|")]
    assert set(names) <= set(first_cells) and "colour convention" in table
    # The folder says what made it: the command, commit, date and machine, in the JSON and atop the table.
    assert set(disk["provenance"]) == {"command", "commit", "date", "machine"}
    assert table.startswith("*Produced by `") and disk["provenance"]["commit"] in table.splitlines()[0]
    for csv_file in ("metrics.csv", "horizons.csv"):
        assert read_provenance(os.path.join(out, csv_file)) == [disk["provenance"]]


def test_hold_baseline_scores_match_a_direct_computation(setup, tmp_path):
    _, ckpt, test = setup
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "h"), baselines=("hold",), samples=0))
    from robomorph.core import metrics
    from robomorph.data.store import open_store

    y = open_store(test).read("y").astype(np.float64)
    ref = metrics.fit_index(y[:, C:], np.repeat(y[:, C - 1:C], H, axis=1)).mean(-1).mean()
    assert res["baselines"]["hold"]["approach1"]["mean"]["fit"]["mean"] == pytest.approx(ref)
    assert set(res["baselines"]) == {"hold"}


def test_shorter_windows_and_cli(setup, tmp_path, capsys):
    _, ckpt, test = setup
    out = str(tmp_path / "cli")
    main(["--ckpt", ckpt, "--data", test, "--out", out, "--context-len", "20", "--horizon", "40",
          "--baselines", "hold,arx", "--plot-trajectories", "1", "--n", "3"])
    text = capsys.readouterr().out
    assert "3 trajectories, context 20, horizon 40" in text and "hold" in text
    meta = json.load(open(os.path.join(out, "metrics.json")))["meta"]
    assert (meta["n"], meta["context_len"], meta["horizon"]) == (3, 20, 40)


def test_real_logs_skip_nominal_physics_with_the_reason(setup, tmp_path):
    _, ckpt, test = setup
    from robomorph.data.store import open_store

    ds = open_store(test)
    path = write_store(tmp_path / "real.zarr", ds.read("u"), ds.read("y"), u_names=ds.u_names, y_names=ds.y_names,
                       attrs={"dt": ds.dt, "domain": "real"})
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=path, out=str(tmp_path / "r"), samples=0,
                                  baselines=("hold", "nominal_physics", "true_physics")))
    assert set(res["baselines"]) == {"hold"}
    assert "domain" in res["skipped_baselines"]["nominal_physics"]
    assert "domain" in res["skipped_baselines"]["true_physics"]
    sim = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "t"), samples=0, baselines=("true_physics",)))
    assert set(sim["baselines"]) == {"true_physics"}


def _other_store(path, names, steps=C + H, n=3, nan=False):
    rng = np.random.default_rng(0)
    u_names, y_names = names
    y = rng.normal(size=(n, steps, len(y_names)))
    if nan:
        y[1, 5, 0] = np.nan
    return write_store(path, rng.normal(size=(n, steps, len(u_names))), y, u_names=u_names, y_names=y_names,
                       attrs={"dt": 1 / 60, "domain": "real"})


def test_bad_input_gives_clear_errors(setup, tmp_path, capsys):
    _, ckpt, test = setup
    from robomorph.data.store import open_store

    ds = open_store(test)
    u_names, y_names = list(ds.u_names), list(ds.y_names)
    cases = [
        (_other_store(str(tmp_path / "names.zarr"), (u_names, y_names[:-1] + ["other"])), "y_names"),
        (_other_store(str(tmp_path / "nu.zarr"), (u_names[:3], y_names)), "u_names"),
        (_other_store(str(tmp_path / "nan.zarr"), (u_names, y_names), nan=True), r"trajectories \[1\]"),
        (_other_store(str(tmp_path / "short.zarr"), (u_names, y_names), steps=50), "must fit"),
        (str(tmp_path / "missing.zarr"), "missing|not found|No such|does not exist"),
    ]
    empty = str(tmp_path / "empty.zarr")
    create_store(empty, 4, C + H, u_names, y_names, [], {"dt": 1 / 60})
    cases.append((empty, "no trajectories"))
    for store, msg in cases:
        with pytest.raises((ValueError, FileNotFoundError), match=msg):
            evaluate(EvaluateConfig(ckpt=ckpt, data=store, out=str(tmp_path / "bad"), samples=0))
    with pytest.raises(ValueError, match="must fit"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "bad"), horizon=500, samples=0))
    with pytest.raises(ValueError, match=r"multiples of the model's patch \(5 steps per token\): \[12\]"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "bad"), sweep_context_spec="10,12", samples=0))
    with pytest.raises(ValueError, match="unknown baseline"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "bad"), baselines=("oracle",)))
    for argv, message in [
        (["--horizon", "999"], "must fit"),
        (["--offset", "later"], "--offset takes 'start', 'random' or a step number"),
        (["--offset", "5"], r"--offset 5 \+ context_len \+ horizon = 95 steps exceeds"),
        (["--horizons", "1,2s"], "--horizons item '2s' is step 120, outside"),
    ]:
        assert main(["--ckpt", ckpt, "--data", test, *argv, "--out", str(tmp_path / "bad")]) == 2
        assert re.match(f"error: .*{message}.*\n$", capsys.readouterr().err)
    assert not os.path.exists(os.path.join(tmp_path, "bad", "metrics.json"))


def test_parse_range():
    assert parse_range("200:800:200", 1, 800, "horizon") == [200, 400, 600, 800]
    assert parse_range("5,10", 1, 800, "context") == [5, 10]
    with pytest.raises(ValueError, match="within"):
        parse_range("0:900:100", 1, 800, "horizon")
    with pytest.raises(ValueError, match="start:stop:step"):
        parse_range("a:b", 1, 800, "horizon")


def test_arx_train_is_fitted_on_the_checkpoints_training_split(setup, tmp_path):
    _, ckpt, test = setup
    from robomorph.data.splits import split_rows

    train_store = Predictor.from_checkpoint(ckpt, device="cpu").data_info["stores"][0]

    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "a"),
                                  baselines=("arx_train",), samples=0, arx_orders=(1, 1)))
    train_rows = split_rows(24, (0.8, 0.1, 0.1), 0, 0)["train"]  # the fit's stores, split and seed
    assert res["meta"]["baseline_notes"]["arx_train"]["trajectories"] == len(train_rows) < 24
    assert set(res["baselines"]) == {"arx_train"}
    whole = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "b"),
                                    baselines=("arx_train",), samples=0, arx_orders=(1, 1),
                                    arx_train_data=[train_store]))
    assert whole["meta"]["baseline_notes"]["arx_train"]["trajectories"] == 24
    gone = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "c"), baselines=("hold", "arx_train"), samples=0,
                                   arx_train_data=[str(tmp_path / "moved.zarr")]))
    assert set(gone["baselines"]) == {"hold"} and "--arx-train-data" in gone["skipped_baselines"]["arx_train"]


def test_a_diverged_baseline_says_so_in_the_printed_table(setup, tmp_path):
    _, ckpt, test = setup
    from robomorph.evaluation.evaluator import summary_text
    from robomorph.evaluation.tables import table_markdown

    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "d"),
                                  baselines=("hold", "arx"), samples=0, arx_orders=(1, 1)))
    res["meta"]["baseline_notes"]["arx"]["diverged_held"] = 0
    assert "diverged" not in summary_text(res, "x") and "diverged" not in table_markdown(res)
    res["meta"]["baseline_notes"]["arx"]["diverged_held"] = 2  # as ARX reports two blow-ups
    arx_line = next(line for line in summary_text(res, "x").splitlines() if line.strip().startswith("arx"))
    assert arx_line.endswith("(2 of 6 trajectories diverged: held instead)")
    assert "Baseline `arx`: 2 of 6 trajectories diverged: held instead" in table_markdown(res)


def test_plots_label_channels_with_the_stores_units(setup, tmp_path, monkeypatch):
    _, ckpt, test = setup
    from matplotlib.figure import Figure

    from robomorph.data.store import open_store

    ds = open_store(test)
    path = str(tmp_path / "units.zarr")
    units = ["m"] * 3 + [""] * 4 + ["rad"] * 7
    w = create_store(path, ds.n, ds.steps, ds.u_names, ds.y_names, [], {"dt": ds.dt, "y_units": units})
    w.append(ds.read("u"), ds.read("y"), np.zeros((ds.n, 0), np.float32))
    w.finalize()
    titles, save = [], Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (titles.extend(ax.get_title() for ax in fig.axes),
                                                                save(fig, *a, **k))[1])
    evaluate(EvaluateConfig(ckpt=ckpt, data=path, out=str(tmp_path / "u"), baselines=("hold",), samples=1))
    assert {"ee_x [m]", "ee_qx", "q0 [rad]"} <= set(titles)


def test_compare_scores_another_checkpoint_beside_the_baselines(setup, tmp_path):
    _, ckpt, test = setup
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "c"),
                                  baselines=("hold",), samples=0, compare={"again": ckpt}))
    assert set(res["baselines"]) == {"hold", "again"} and res["meta"]["baseline_notes"]["again"]["ckpt"] == ckpt
    assert res["baselines"]["again"]["approach1"] == res["approach1"]  # the same model scores the same
    with pytest.raises(ValueError, match="names a baseline"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "d"), baselines=(), samples=0, compare={"hold": ckpt}))
@pytest.mark.parametrize("flag, value", [("--context-len", "0"), ("--context-len", "-5"), ("--horizon", "0"),
                                         ("--n", "0"), ("--batch-size", "0")])
def test_non_positive_lengths_are_refused(setup, tmp_path, flag, value, capsys):
    # --context-len 0 used to run silently with the checkpoint's length.
    _, ckpt, test = setup
    assert main(["--ckpt", ckpt, "--data", test, flag, value, "--out", str(tmp_path / "bad"), "--baselines", "none"]) == 2
    assert re.match(f"error: {flag} {value}: .*positive", capsys.readouterr().err)
    assert not os.path.exists(tmp_path / "bad")


def test_overflowing_predictions_are_refused(setup):
    from robomorph.data.store import open_store
    from robomorph.predictor import PredictionError

    _, ckpt, test = setup
    ds = open_store(test)
    u, y = ds.read("u", slice(0, 2)), ds.read("y", slice(0, 2))
    pred = Predictor.from_checkpoint(ckpt, device="cpu")
    assert np.isfinite(pred.simulate(u[:, :C], y[:, :C], u[:, C:])).all()
    big = u * np.float32(1e30)
    assert np.isfinite(big).all()  # finite inputs; the model's arithmetic overflows
    with pytest.raises(PredictionError, match="non-finite|training standard deviations"):
        pred.simulate(big[:, :C], y[:, :C], big[:, C:])


def test_evaluate_reports_errors_by_horizon_from_random_offsets(setup, tmp_path):
    _, ckpt, test = setup
    from robomorph.data.store import open_store

    out = str(tmp_path / "off")
    res = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=out, context_len=20, horizon=30, baselines=("hold",), samples=1,
                                  horizons_spec="1,0.25s,end", offset="random", seed=4))
    starts = np.array(res["window_starts"])
    assert res["meta"]["offset"] == "random" and len(starts) == 6
    assert starts.min() >= 0 and starts.max() <= C + H - 50 and len(set(starts.tolist())) > 1
    h = res["horizons"]
    assert h["steps"] == [1, 15, 30] and set(h["rms"]) == {"model", "hold"} and "calibration" not in h
    # The hold error at the first step, by hand: joints against the last context sample, in mrad.
    y = open_store(test).read("y").astype(np.float64)
    last = np.stack([y[i, s + 19, 7:] for i, s in enumerate(starts)])
    first = np.stack([y[i, s + 20, 7:] for i, s in enumerate(starts)])
    assert h["rms"]["hold"]["joints"][0] == pytest.approx(np.sqrt(((first - last) ** 2).mean()) * 1e3)
    assert json.load(open(os.path.join(out, "metrics.json")))["horizons"] == h
    rows = [line for line in open(os.path.join(out, "horizons.csv")).read().splitlines() if not line.startswith("#")]
    assert rows[0] == "source,quantity,unit,step,seconds,metric,value" and len(rows) == 1 + 2 * 3 * 3
    assert "RMS error by horizon" in open(os.path.join(out, "table.md")).read()
    with pytest.raises(ValueError, match="outside the evaluated horizon"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "bad"), horizon=30, horizons_spec="5s", samples=0))


class StandIn:
    """A predictor with a Gaussian head in miniature: mean = last context output + 0.01, std 0.01."""

    n_u, n_y, device = 7, 14, "cpu"

    def simulate(self, u_ctx, y_ctx, u_query, return_std=False):
        mean = np.repeat(y_ctx[:, -1:], u_query.shape[1], axis=1) + 0.01
        return (mean, np.full_like(mean, 0.01)) if return_std else mean


class NoStd(StandIn):
    def simulate(self, u_ctx, y_ctx, u_query):
        return super().simulate(u_ctx, y_ctx, u_query)


def test_calibration_of_a_predicted_std_equals_a_direct_count(setup, tmp_path):
    from robomorph.data.store import open_store
    from robomorph.evaluation.plots import write_all
    from robomorph.evaluation.scoring import score_windows
    from robomorph.evaluation.sources import gives_std
    from robomorph.evaluation.windows import load_window

    _, _, test = setup
    ds = open_store(test)
    w = load_window(test, C, H, None, None, 7, 14)
    s = score_windows(StandIn(), w, ("hold",), [1, 10, H], batch_size=4)
    res, preds, std = s.result, s.preds, s.std
    assert std is not None and res["meta"]["std"] is True
    y_q = w.y[:, C:].astype(np.float64)
    mean = np.repeat(w.y[:, C - 1:C], H, axis=1) + 0.01
    cal = res["horizons"]["calibration"]
    for j, k in enumerate([1, 10, H]):
        err = np.abs(y_q[:, k - 1] - mean[:, k - 1])
        assert cal["all"]["1sigma"][j] == pytest.approx(np.count_nonzero(err <= 0.01) / err.size)
        assert cal["all"]["2sigma"][j] == pytest.approx(np.count_nonzero(err <= 0.02) / err.size)
        assert cal["joints"]["1sigma"][j] == pytest.approx(np.count_nonzero(err[:, 7:] <= 0.01) / err[:, 7:].size)
    paths = write_all(str(tmp_path), w.y[:, :C], y_q, preds, list(ds.y_names), ds.dt, 1, std=std)
    assert all(os.path.getsize(p) > 0 for p in paths)
    assert not gives_std(NoStd(), w.u[:, :C], w.y[:, :C], w.u[:, C:])
    s = score_windows(NoStd(), w, (), [1], batch_size=4)
    res, std = s.result, s.std
    assert std is None and "calibration" not in res["horizons"]


def test_nominal_physics_from_offsets_anchors_the_springs_where_the_robot_started(setup):
    from robomorph.data.store import open_store
    from robomorph.evaluation.physics import NominalPhysics
    from robomorph.evaluation.sources import nominal_params
    from robomorph.evaluation.windows import load_window

    _, _, test = setup
    ds = open_store(test)
    sim = NominalPhysics(ds.attrs)
    w = load_window(test, 20, 30, None, None, 7, 14, offset="random", seed=4)
    assert w.starts.any()
    params = nominal_params(sim, w)
    first_q = ds.read("y")[:, 0, 7:14].astype(np.float64)
    assert np.allclose(params[:, -7:], first_q)  # the parameter vector ends with the spring anchor
    assert np.allclose(params, np.stack([sim.params(q) for q in first_q]))
    assert nominal_params(sim, load_window(test, 20, 30, None, None, 7, 14)) is None


@pytest.fixture(scope="module")
def paper_window_ckpt(simulated_store, tmp_path_factory):
    """A tiny model of the paper's protocol, trained on the same store as the shared checkpoint."""
    from robomorph.training.fitting import fit

    store = simulated_store(robots=24, steps=C + H, seed=1)
    args = tiny_fit_args(store, tmp_path_factory.mktemp("pw"), "pw", steps=4, data={"normalization": "paper_window"},
                         trainer={"val_check_interval": 2})
    return fit(args).best_ckpt


def test_paper_window_evaluation_says_it_leaks_everywhere(setup, paper_window_ckpt, tmp_path):
    _, ckpt, test = setup
    out = str(tmp_path / "pw")
    res = evaluate(EvaluateConfig(ckpt=paper_window_ckpt, data=test, out=out, baselines=("hold",), samples=0,
                                  sweep_horizon_spec="30,60"))
    disk = json.load(open(os.path.join(out, "metrics.json")))
    assert disk["leaks_query_statistics"] is True and disk["meta"]["normalization"] == "paper_window"
    assert np.isfinite(res["approach1"]["mean"]["r2"]["mean"]) and len(disk["sweeps"]["horizon"]) == 2
    table = open(os.path.join(out, "table.md")).read()
    assert "**⚠ Normalization paper_window (the paper's protocol)" in table.split("| channel")[0]
    assert {r["normalization"] for r in read_rows(os.path.join(out, "metrics.csv"))} == {"paper_window"}
    clean = evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "ts"), baselines=("hold",), samples=0))
    assert clean["leaks_query_statistics"] is False and clean["meta"]["normalization"] == "train_stats"
    assert "Normalization train_stats" in open(tmp_path / "ts" / "table.md").read()
    from robomorph.core.normalizations import NormalizationError

    with pytest.raises(NormalizationError, match="trained with normalization 'train_stats', not 'paper_window'"):
        evaluate(EvaluateConfig(ckpt=ckpt, data=test, out=str(tmp_path / "x"), normalization="paper_window", samples=0))


@pytest.mark.parametrize("normalization", ["train_stats", "paper_window"])
def test_poisoned_query_outputs_change_the_scored_prediction_only_under_paper_window(
        setup, paper_window_ckpt, normalization):
    from robomorph.data.store import open_store
    from robomorph.evaluation.sources import predict

    _, ckpt, test = setup
    pred = Predictor.from_checkpoint(paper_window_ckpt if normalization == "paper_window" else ckpt, device="cpu")
    ds = open_store(test)
    u, y = ds.read("u"), ds.read("y")
    args = (pred, u[:, :C], y[:, :C], u[:, C:C + H], 4)
    clean = predict(*args, y_query=y[:, C:C + H])
    poisoned = predict(*args, y_query=y[:, C:C + H] * 10 + 5)
    assert np.allclose(clean, poisoned) == (normalization == "train_stats")


@pytest.fixture(scope="module")
def cmd_ckpt(simulated_store, tmp_path_factory):
    """A (barely trained) model of the command formulation, on the same training store."""
    from robomorph.training.fitting import fit

    store = simulated_store(robots=24, steps=C + H, seed=1)
    args = tiny_fit_args(store, tmp_path_factory.mktemp("cmd"), "cmd", steps=2, data={"inputs": "command"},
                         trainer={"val_check_interval": 2})
    return fit(args).best_ckpt


def test_a_checkpoint_refuses_the_other_input_formulation(setup, cmd_ckpt, tmp_path):
    from robomorph.core.inputs import InputsError

    _, total_ckpt, test = setup
    total, cmd = Predictor.from_checkpoint(total_ckpt, device="cpu"), Predictor.from_checkpoint(cmd_ckpt, device="cpu")
    assert (total.inputs, cmd.inputs) == ("total", "command")
    assert cmd.data_info["u_names"] == [f"cmd{i}" for i in range(7)]
    u, y = np.zeros((C, 7), np.float32), np.zeros((C, 14), np.float32)
    assert cmd.simulate(u, y, u[:10], inputs="command").shape == (10, 14)
    with pytest.raises(InputsError, match="trained on inputs=command.*given inputs=total"):
        cmd.simulate(u, y, u[:10], inputs="total")
    with pytest.raises(InputsError, match="trained on inputs=total"):
        evaluate(EvaluateConfig(ckpt=total_ckpt, data=test, out=str(tmp_path / "no"), baselines=(), inputs="command"))
    res = evaluate(EvaluateConfig(ckpt=cmd_ckpt, data=test, out=str(tmp_path / "ev"),
                                  baselines=("hold", "true_physics"), samples=0))
    assert res["meta"]["inputs"] == "command" and res["meta"]["u_names"][0] == "cmd0"
    # true_physics simulates the command on the arm compensating its own gravity: near exact.
    assert res["baselines"]["true_physics"]["approach1"]["mean"]["r2"]["mean"] > 0.99


def test_a_command_checkpoint_says_to_regenerate_a_store_without_u_cmd(setup, cmd_ckpt, tmp_path):
    from robomorph.core.inputs import InputsError
    from robomorph.data.store import open_store

    test = setup[2]
    src = open_store(test)
    old = str(tmp_path / "old.zarr")  # the same data, as a schema-1 store would hold it
    keep = {k: v for k, v in src.attrs.items() if k not in ("u_cmd_names", "schema", "schema_version")}
    w = create_store(old, src.n, src.steps, src.u_names, src.y_names, src.param_names, keep)
    w.append(src.read("u"), src.read("y"), src.read("params"))
    w.finalize()
    with pytest.raises(InputsError, match="no command inputs.*[Rr]egenerate"):
        evaluate(EvaluateConfig(ckpt=cmd_ckpt, data=old, out=str(tmp_path / "ev"), baselines=()))


def test_evaluate_backtests_the_model_on_its_contexts_and_says_so(setup, tmp_path, capsys):
    from robomorph.evaluation.evaluator import context_check, context_check_note
    from robomorph.evaluation.windows import load_window

    _, ckpt, test = setup
    main(["--ckpt", ckpt, "--data", test, "--out", str(tmp_path / "ev"), "--baselines", "hold"])
    printed = capsys.readouterr().out
    assert "context check (6 contexts backtested on themselves): model / constant velocity step 1" in printed
    with open(tmp_path / "ev" / "metrics.json") as f:
        check = json.load(f)["meta"]["context_check"]
    assert check["windows"] == 6 and set(check["winner"]) == {str(k) for k in check["steps"]}
    # Torques 1000 times too large (another formulation or other units): the model no longer explains its contexts.
    pred = Predictor.from_checkpoint(ckpt, device="cpu")
    pred.max_input_std = None
    w = load_window(test, C, H, None, pred.data_info, pred.n_u, pred.n_y)
    w.u = w.u * 1000.0
    bad = context_check(pred, w)
    assert bad["unexplained"] > 0 and "WARNING" in context_check_note(bad)
