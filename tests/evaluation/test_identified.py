import json
import os

import numpy as np
import pytest

from robomorph.data.store import open_store
from robomorph.evaluate import main
from robomorph.evaluation.identified import IdentifiedPhysics, predict_windows
from robomorph.evaluation.physics import NotApplicable
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.sources import check_baselines
from robomorph.evaluation.tables import cost_note, table_markdown
from robomorph.evaluation.windows import load_window
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, write_store
from tests.identification.test_identify import DAMPING_ONLY

CONTEXT, HORIZON = 60, 60


@pytest.fixture(scope="module")
def damping_store(simulated_store):
    """Two robots that differ from the catalogue only in their joint damping."""
    return simulated_store(robots=2, steps=CONTEXT + HORIZON, seed=3, randomization=DAMPING_ONLY)


@pytest.fixture(scope="module")
def damping_scores(damping_store):
    w = load_window(damping_store, CONTEXT, HORIZON, None, None, 7, 14, inputs="command")
    return w, score_windows(None, w, ("hold", "nominal_physics", "identified_physics"), [1, 15, 60])


def test_identified_physics_beats_nominal_physics_where_only_the_damping_differs(damping_scores):
    w, s = damping_scores
    assert s.preds["identified_physics"].shape == (2, HORIZON, 14)
    assert s.result["skipped_baselines"] == {}
    for k in (15, 60):
        identified, nominal = s.at("identified_physics", "joints", k), s.at("nominal_physics", "joints", k)
        assert identified < 0.05 * nominal and identified < 0.5  # mrad
    assert s.at("identified_physics", "ee_pos", 60) < 0.05 * s.at("nominal_physics", "ee_pos", 60)
    assert s.summary("identified_physics")["r2"] > s.summary("nominal_physics")["r2"]


def test_its_cost_per_window_is_reported(damping_scores):
    _, s = damping_scores
    note = s.result["meta"]["baseline_notes"]["identified_physics"]
    assert note["windows"] == 2 and note["converged"] == 2
    assert 0 < note["seconds_per_window"] <= note["seconds_per_window_max"]
    assert note["seconds_total"] == pytest.approx(2 * note["seconds_per_window"])
    assert note["rollouts_per_window"] >= 7 * note["iterations_mean"] > 0  # 7 damping columns per Jacobian
    assert note["parameters"] == [f"damping_q{j}" for j in range(7)]
    assert note["context_rms_mrad"]["identified"] < 0.01 * note["context_rms_mrad"]["catalogue"]
    text = cost_note(note)
    assert text.startswith("fit ") and " s per window (max " in text and "iterations" in text
    assert cost_note({}) == ""


def test_identified_physics_is_deterministic(damping_store, damping_scores):
    w, s = damping_scores
    again, _ = predict_windows(w)
    np.testing.assert_array_equal(again, s.preds["identified_physics"])


def test_the_springs_baseline_fits_them_through_the_scoring_path(simulated_store):
    """``identified_physics_springs``: the same fit with the joints' stiffness too; on robots whose springs are far
    from the catalogue's (and that differ nowhere else) it fits them and beats the fit without them late on."""
    springs_only = {**DAMPING_ONLY, "damping": [7.5, 7.5], "stiffness": [1.0, 5.0]}
    store = simulated_store(robots=2, steps=CONTEXT + HORIZON, seed=6, randomization=springs_only)
    w = load_window(store, CONTEXT, HORIZON, None, None, 7, 14, inputs="command")
    s = score_windows(None, w, ("identified_physics", "identified_physics_springs"), [1, 60])
    notes = s.result["meta"]["baseline_notes"]
    assert [p for p in notes["identified_physics_springs"]["parameters"] if p.startswith("stiffness")] \
        == [f"stiffness_q{j}" for j in range(7)]
    assert not any(p.startswith("stiffness") for p in notes["identified_physics"]["parameters"])
    assert s.at("identified_physics_springs", "joints", 60) < 0.5 * s.at("identified_physics", "joints", 60)


def test_the_name_is_accepted_but_never_run_by_default():
    from robomorph.evaluation.baselines import BASELINES

    check_baselines(["identified_physics", "identified_physics_springs"])
    assert "identified_physics" not in BASELINES  # each window is a fit: only when named
    assert "identified_physics_springs" not in BASELINES


def test_real_logs_are_refused_with_one_line(damping_store, tmp_path):
    ds = open_store(damping_store)
    path = write_store(tmp_path / "real.zarr", ds.read_inputs("command"), ds.read("y"), u_names=ds.u_names,
                       y_names=ds.y_names, attrs={"dt": ds.dt, "domain": "real"})
    with pytest.raises(NotApplicable, match="domain") as info:
        IdentifiedPhysics(open_store(path).attrs, "command")
    assert "\n" not in str(info.value)
    w = load_window(path, CONTEXT, HORIZON, None, None, 7, 14)
    s = score_windows(None, w, ("hold", "identified_physics"), [1])
    assert set(s.preds) == {"hold"}
    why = s.result["skipped_baselines"]["identified_physics"]
    assert "domain" in why and "\n" not in why


def test_evaluate_reports_identified_physics_and_its_cost(tiny_checkpoint, simulated_store, tmp_path, capsys):
    """The door: fully randomized robots (29 parameters fitted), the total-torque checkpoint."""
    test = simulated_store(robots=6, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=2)
    out = str(tmp_path / "ev")
    assert main(["--ckpt", tiny_checkpoint, "--data", test, "--out", out, "--n", "2", "--plot-trajectories", "0",
                 "--baselines", "hold,nominal_physics,identified_physics"]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("identified_physics"))
    assert "s per window" in line
    res = json.load(open(os.path.join(out, "metrics.json")))
    assert "identified_physics" in res["baselines"] and "identified_physics" in res["horizons"]["rms"]
    note = res["meta"]["baseline_notes"]["identified_physics"]
    assert note["windows"] == 2 and len(note["parameters"]) == 29
    assert "Baseline `identified_physics`: fit " in table_markdown(res)
    assert "Baseline `identified_physics`: fit " in open(os.path.join(out, "table.md")).read()


def test_the_demo_closes_with_identified_physics_and_its_cost(damping_scores):
    from robomorph.reproduction.demo import horizon_summary

    w, s = damping_scores
    res = {**s.result, "meta": {**s.result["meta"], "n": 2}}
    text = horizon_summary(res)
    sources = [line.strip("|").split("|")[1].strip() for line in text.splitlines() if line.startswith("| joints")]
    assert sources == ["hold", "nominal_physics", "identified_physics"]  # no model scored here
    assert "identified_physics: fit " in text and " s per window" in text
