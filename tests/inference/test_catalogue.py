"""A prediction with no training: Predictor.from_arm is the trained command hybrid's regression, with no network."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph import Predictor
from robomorph.inference.catalogue import NoNetworkError
from tests.conftest import CKPT_CONTEXT as C
from tests.conftest import CKPT_HORIZON as H
from tests.conftest import tiny_fit_args


@pytest.fixture(scope="module")
def store(simulated_store):
    return simulated_store(robots=24, steps=C + H, seed=3)


def _windows(store: str, n: int = 3):
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y = ds.read_inputs("command")[:n], ds.read("y")[:n]
    return u[:, :C], y[:, :C], u[:, C:], y[:, C:], dict(ds.attrs)


def test_it_predicts_what_a_trained_command_hybrid_predicts_to_the_bit(store, tmp_path):
    from robomorph.training.fitting import fit

    ckpt = fit(tiny_fit_args(store, tmp_path / "runs", "hybrid", steps=2, data={"inputs": "command"},
                             model={"physics": "amortized", "anchor": True})).best_ckpt
    trained = Predictor.from_checkpoint(ckpt, device="cpu")
    uc, yc, uq, _, attrs = _windows(store)
    # The recipe the store was generated with; calibrated=False: the raw spread, as the uncalibrated checkpoint's.
    arm = Predictor.from_arm("panda", calibrated=False, **attrs["config"])
    assert (arm.settings.mode, arm.inputs) == (trained.settings.mode, trained.inputs) == ("regression", "command")
    want = trained.simulate(uc, yc, uq, return_std=True, at_rest=True)
    got = arm.simulate(uc, yc, uq, return_std=True, at_rest=True)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert arm.calibration is None and trained.calibration is None  # neither was calibrated
    # By default the shipped calibration scales that same spread (the store's recipe is the one it was fitted on).
    shipped = Predictor.from_arm("panda", **attrs["config"])
    mean, std = shipped.simulate(uc, yc, uq, return_std=True, at_rest=True)
    np.testing.assert_array_equal(mean, want[0])
    np.testing.assert_allclose(std, shipped.calibration.scaled(want[1]), rtol=1e-5)


def test_with_the_generators_defaults_it_follows_the_recorded_robot_far_better_than_hold(store):
    uc, yc, uq, yq, _ = _windows(store)
    pred = Predictor.from_arm("panda")  # nothing from the store: the arm and the generator's default recipe
    mean, std = pred.simulate(uc, yc, uq, return_std=True, at_rest=True)
    assert mean.shape == std.shape == yq.shape and np.all(np.isfinite(mean)) and np.all(std > 0)
    joints = slice(7, 14)
    err = np.sqrt(np.mean((mean[..., joints] - yq[..., joints]) ** 2))
    hold = np.sqrt(np.mean((yc[:, -1:, joints] - yq[..., joints]) ** 2))
    assert err < 0.05 * hold, (err, hold)
    one = pred.simulate(uc[0], yc[0], uq[0], at_rest=True)  # one window: (T, n_y) in and out
    np.testing.assert_array_equal(one, mean[0])


def test_what_needs_a_network_is_refused_in_one_line(store):
    uc, yc, uq, _, _ = _windows(store, n=1)
    pred = Predictor.from_arm("panda")
    for mode in ("none", "blend", "smoothed", "learned", "fused"):  # the decoder's and the parameter head's
        with pytest.raises(NoNetworkError, match=rf"^physics mode '{mode}' reads a trained network") as exc:
            pred.use_physics(mode)  # refused where it is asked for, and the settings stay as they were
        assert "\n" not in str(exc.value) and pred.settings.mode == "regression"
    pred.use_physics("refined")  # reads no network either
    assert pred.simulate(uc, yc, uq).shape == uq.shape[:2] + (14,)
    with pytest.raises(NoNetworkError, match=r"unknown arm 'ur6'.*choose one of panda, ur5e"):
        Predictor.from_arm("ur6")


# --- the shipped calibrations of the std ---------------------------------------------------------------

# The recipes benchmarks/arm_calibration.py was run on for the Panda: one file each, <arm>-<recipe>.json.
SHIPPED = ("multisine", "realistic")
# What the realistic recipe's calibration covers on held-out robots, as recorded (±1σ low, high, ±2σ low, high). Issue
# 54's goal, 68 ± 5 / 95 ± 3 %, is missed there: ±1σ covers 67-75 % from the start and 75-82 % from random offsets,
# ±2σ 86-92 %. The errors have heavier tails than a Gaussian's about the spread (a share of the windows, most of
# them of the torque chirp and the OSC tasks, misses by several spreads), so no scale of the std meets both levels;
# floors under the std did not move it either (docs/guide/predicting.md, CHANGELOG).
REALISTIC_COVERAGE = (0.60, 0.85, 0.84, 0.97)


def _shipped(recipe: str) -> dict:
    import json

    from robomorph.inference.catalogue import calibration_path

    with open(calibration_path("panda", recipe)) as f:
        return json.load(f)


def test_the_shipped_calibration_scales_the_std_and_records_where_it_was_fitted(store):
    uc, yc, uq, _, _ = _windows(store)
    raw = Predictor.from_arm("panda", calibrated=False)
    pred = Predictor.from_arm("panda")  # the quick start's: the generator's defaults, the recipe it was fitted on
    assert raw.calibration is None and pred.calibration is not None
    mean_raw, std_raw = raw.simulate(uc, yc, uq, return_std=True, at_rest=True)
    mean, std = pred.simulate(uc, yc, uq, return_std=True, at_rest=True)
    np.testing.assert_array_equal(mean, mean_raw)  # the mean is untouched
    np.testing.assert_allclose(std, pred.calibration.scaled(std_raw), rtol=1e-5)
    assert not np.allclose(std, std_raw)
    doc = _shipped("multisine")
    src = pred.calibration.source
    assert (src["arm"], src["recipe"], src["offset"]) == ("panda", "multisine", "start")
    assert src["robots"] >= 128 and src["seed"] not in (0, 1)  # not the seeds of the docs' and the demo's stores
    assert doc["provenance"]["commit"] and "arm_calibration.py" in doc["provenance"]["command"]
    assert set(doc["calibrations"]) == {"start", "random"}  # windows that open their trajectory, and the others


@pytest.mark.parametrize("recipe", SHIPPED)
def test_each_recipes_calibration_is_found_for_that_recipe_with_from_arms_default_settings(recipe):
    from robomorph.inference.calibration import calibration_key

    pred = Predictor.from_arm("panda", recipe)
    key = pred.settings_in_effect.calibration_key  # fitted with the switches from_arm runs with, keyed by them
    kinds = set(_shipped(recipe)["calibrations"])  # start, and random where windows from random offsets were fitted
    assert "start" in kinds and set(pred.model.calibrations) == {key if k == "start" else f"{key}/moving" for k in kinds}
    assert {c.source["recipe"] for c in pred.model.calibrations.values()} == {recipe}
    assert pred.calibration is pred.model.calibrations[key] and calibration_key(pred.calibration) == key
    # The sampling fields (robots, seed, steps) do not change the robots drawn: a store of 8 robots of seed 1 of
    # the recipe, as the demo trains on, takes the same calibration.
    again = Predictor.from_arm("panda", recipe, robots=8, seed=1, steps=300)
    assert again.calibration.to_dict() == pred.calibration.to_dict()


def test_a_recipes_calibration_is_not_found_for_another_recipe():
    clean, realistic = Predictor.from_arm("panda", "multisine"), Predictor.from_arm("panda", "realistic")
    assert clean.calibration.source["recipe"] == "multisine" and realistic.calibration.source["recipe"] == "realistic"
    # The realistic robots' noise, payload and friction make another spread: not the clean robots' calibration.
    assert realistic.calibration.to_dict() != clean.calibration.to_dict()
    # A recipe with one realism term changed is not the one fitted on, nor is one whose robots are clean but
    # compensated by the nominal model as the realistic recipe's are.
    assert Predictor.from_arm("panda", "realistic", realism={"widen": 1.0}).calibration is None
    assert Predictor.from_arm("panda", gravity_compensation="nominal_model").calibration is None


def test_a_calibration_file_is_taken_by_its_scope_not_its_name(tmp_path, monkeypatch):
    """Read-compatible: the first release's <arm>.json is read as any other; a file's name never decides."""
    import json

    from robomorph.inference import catalogue

    clean, realistic = _shipped("multisine"), _shipped("realistic")
    monkeypatch.setattr(catalogue, "CALIBRATION_DIR", str(tmp_path))
    assert Predictor.from_arm("panda").calibration is None  # no file at all
    (tmp_path / "ur5e-multisine.json").write_text(json.dumps(clean))  # the Panda's, under another arm's name
    assert Predictor.from_arm("panda").calibration is None
    (tmp_path / "panda.json").write_text(json.dumps(clean))
    (tmp_path / "panda-other.json").write_text(json.dumps(realistic))
    assert Predictor.from_arm("panda").calibration.source["recipe"] == "multisine"
    assert Predictor.from_arm("panda", "realistic").calibration.source["recipe"] == "realistic"
    assert catalogue.shipped_calibration_file(catalogue.arm_record("panda", "spiral")) is None


@pytest.mark.parametrize("recipe", SHIPPED)
def test_the_shipped_calibration_records_its_held_out_coverage(recipe):
    """Recorded by benchmarks/arm_calibration.py on robots of another seed than those it was fitted on: the
    joints' ±1σ / ±2σ coverage at the first step, 0.25 s, 1 s, 5 s and 10 s, before and after. The clean recipe's
    is near a Gaussian's shares at every step; the realistic one's: see REALISTIC_COVERAGE."""
    from robomorph.inference.calibration import StdCalibration

    doc = _shipped(recipe)
    for kind, entry in doc["calibrations"].items():
        held = StdCalibration.from_dict(entry).source["held_out"]
        assert held["n"] >= 48 and held["seed"] != entry["source"]["seed"], kind
        one, two = held["after"]["1sigma"], held["after"]["2sigma"]
        low1, high1, low2, high2 = (0.58, 0.78, 0.88, 0.99) if recipe == "multisine" else REALISTIC_COVERAGE
        assert all(low1 <= c <= high1 for c in one) and all(low2 <= c <= high2 for c in two), (kind, one, two)
        before = held["before"]["1sigma"]
        assert max(abs(c - 0.6827) for c in one) < max(abs(c - 0.6827) for c in before), kind


def test_another_recipe_arm_or_formulation_is_uncalibrated():
    assert Predictor.from_arm("panda").calibration is not None
    assert Predictor.from_arm("panda", dt=0.01).calibration is None  # another physics step: another spread
    assert Predictor.from_arm("panda", "spiral").calibration is None  # fitted on multi-sine torques only
    assert Predictor.from_arm("panda", inputs="total", gravity_compensation="none").calibration is None
    assert Predictor.from_arm("ur5e").calibration is None  # no calibration shipped for it
    assert Predictor.from_arm("ur5e", "realistic").calibration is None  # the Panda's realistic one is the Panda's


def test_the_quick_starts_first_prediction_runs_as_written(tmp_path, monkeypatch, capsys):
    """docs/guide/quickstart.md's first block, exactly as shown: a prediction with no training, in seconds."""
    import sys

    from tests.docs.examples import ROOT, blocks

    (first, *_) = blocks(ROOT / "docs" / "guide" / "quickstart.md", "python")
    assert "Predictor.from_arm" in first.code and not first.skip_reason
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", list(sys.argv))  # robomorph.cli.main sets it for the door it runs
    namespace: dict = {"__name__": "__quickstart__"}
    exec(compile(first.code, first.where, "exec"), namespace)
    shape, rms = capsys.readouterr().out.strip().splitlines()[-2:]  # after generate's one line
    assert shape == "(4, 200, 14)"
    assert float(rms) < 1.0  # joint RMS error [mrad]: "a fraction of one", as the page says
    assert namespace["pred"].calibration is not None and np.all(namespace["std"] > 0)


def test_from_arm_is_a_method_of_the_predictor_and_the_catalogue_holds_its_pieces():
    """Issue 61 §4: ``from_arm`` was a module function of the catalogue taking ``cls``, attached to the class from
    outside; it is the Predictor's classmethod, beside from_checkpoint, and builds the same Predictor."""
    from robomorph.inference import catalogue

    method = vars(Predictor)["from_arm"]
    assert isinstance(method, classmethod) and method.__func__.__qualname__ == "Predictor.from_arm"
    assert method.__func__.__module__ == "robomorph.inference.predictor" and not hasattr(catalogue, "from_arm")
    pred = Predictor.from_arm("panda")
    assert type(pred) is Predictor and isinstance(pred.model, catalogue.NoNetwork) and pred.settings.mode == "regression"
    assert pred.limits == catalogue.ArmLimits.of("panda")
