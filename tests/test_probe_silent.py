"""The hostile probe of issue 61, section 2, defects 11 to 26: what was silently wrong, and what was
reported unclearly or late. Each test names its defect.

A Predictor's constructor and ``configure`` validate completely or change nothing; a command's refusal
is one ``error:`` line with exit code 2, no traceback, and nothing written; where the fix is a note
rather than a refusal, the note is in the output and in the result file.
"""

from __future__ import annotations

import numpy as np
import pytest

from robomorph import Predictor
from robomorph.core.config import ConfigError
from robomorph.inference.catalogue import LimitsError, NoNetworkError
from robomorph.inference.settings import SettingsError
from tests.test_probe_new_commands import _one_error

C, H = 40, 20  # a context and a horizon of a few hundred milliseconds: from_arm predicts in well under a second


@pytest.fixture(scope="module")
def window(simulated_store):
    """One command window (u_ctx, y_ctx, u_query) of a simulated Panda."""
    from robomorph.data.store import open_store

    ds = open_store(simulated_store(robots=2, steps=C + H, seed=3))
    u, y = ds.read_inputs("command")[:1], ds.read("y")[:1]
    return u[:, :C], y[:, :C], u[:, C:]


# --- the Predictor: every constructor and configure validates completely, or changes nothing ---------------

def test_from_arm_refuses_a_sample_time_of_no_arm(window):
    """Defect 15: ``from_arm("panda", dt=1e9)`` was accepted and predicted poses up to 6.4e5."""
    for dt in (1e9, 2.0):
        with pytest.raises(ConfigError, match=rf"dt must be a sample time in seconds, > 0 and at most 1, got {dt}"):
            Predictor.from_arm("panda", dt=dt)
    assert Predictor.from_arm("panda", dt=0.01).data_info["dt"] == 0.01


def test_from_arm_refuses_torques_and_angles_in_the_wrong_units(window):
    """Defect 16: torques x1000 and joint angles in degrees returned plausible output."""
    uc, yc, uq = window
    pred = Predictor.from_arm("panda")
    with pytest.raises(LimitsError, match=r"^u_ctx reaches .* N m on 'cmd\d', .* times the panda's motor limit"):
        pred.simulate(uc * 1000, yc, uq, at_rest=True)
    with pytest.raises(LimitsError, match=r"^u_query reaches .* times the panda's motor limit .*give the torques in N m"):
        pred.simulate(uc, yc, uq * 1000, at_rest=True)
    degrees = np.concatenate([yc[..., :7], np.rad2deg(yc[..., 7:])], axis=-1)
    with pytest.raises(LimitsError, match=r"^y_ctx's joint angle 'q\d' reaches .* rad, outside the panda's joint "
                                          r"range .*radians \(not degrees\)"):
        pred.simulate(uc, degrees, uq, at_rest=True)
    mean = pred.simulate(uc, yc, uq, at_rest=True)  # the same window in its units: predicted
    assert mean.shape == (1, H, 14) and np.all(np.abs(mean) < 10)


def test_from_arm_refuses_a_robot_override_naming_another_arm():
    """Defect 17: ``from_arm("panda", robot="ur5e")`` built a UR5e predictor in silence."""
    with pytest.raises(NoNetworkError, match=r"^robot='ur5e' names another arm than 'panda'"):
        Predictor.from_arm("panda", robot="ur5e")
    assert Predictor.from_arm("panda", robot="panda").data_info["arm"] == "panda"  # the same arm twice: fine
    with pytest.raises(NoNetworkError, match=r"calibrated must be True or False, got 'yes'"):
        Predictor.from_arm("panda", calibrated="yes")


@pytest.mark.parametrize("changes, error, phrase", [
    ({"members": 10**9}, SettingsError, r"^members must be a whole number from 1 to 1024, got 1000000000"),
    ({"samples": 10**9}, SettingsError, r"^samples must be a whole number from 1 to"),
    ({"workers": 10**6}, SettingsError, r"^workers must be a whole number from 1 to 64"),
    ({"substeps": 10**9}, SettingsError, r"^substeps must be None or a whole number from 1 to 1000"),
    ({"iterations": 10**6}, SettingsError, r"^iterations must be a whole number from 1 to 100,"),
    ({"mode": "learned"}, NoNetworkError, r"^physics mode 'learned' reads a trained network"),
    ({"mode": "fused"}, NoNetworkError, r"^physics mode 'fused' reads a trained network"),
    ({"mode": "none"}, NoNetworkError, r"^physics mode 'none' reads a trained network"),
])
def test_configure_refuses_at_once_and_changes_nothing(window, changes, error, phrase):
    """Defect 20: ``configure(members=10**9)`` and, on from_arm, ``configure(mode='learned')`` passed, failed only
    at simulate, and stayed set, so that every later call failed."""
    pred = Predictor.from_arm("panda").configure(members=1, workers=1)
    before = pred.settings
    with pytest.raises(error, match=phrase):
        pred.configure(**changes)
    assert pred.settings == before
    (name, value), = changes.items()
    if hasattr(Predictor, f"physics_{name}"):  # the deprecated attribute goes through configure too
        with pytest.raises(error, match=phrase), pytest.warns(DeprecationWarning):
            setattr(pred, f"physics_{name}", value)
        assert pred.settings == before
    assert pred.simulate(*window, at_rest=True).shape == (1, H, 14)  # the next call predicts as before


# --- ingest --source: nothing silent, every refusal named as the user's files name it ---------------------

def _tiny_sources(root, length: int, nan_in: str | None = None) -> None:
    """The four public sources' layouts under ``root`` (as tests/data/test_public_logs.py writes them, far
    smaller), ``length`` samples per recording; ``nan_in``: a NaN in joint 3's angle of that source's test log."""
    import os

    import scipy.io

    from robomorph.data import public_logs

    rng = np.random.default_rng(0)
    kin = os.path.join(root, "dynamic-identification", "pyDynaMapp", "data", "kinova")
    header = ["Time"] + [f"{k}{j}" for k in ("Position", "Velocity", "Torque", "TorqueCur") for j in range(1, 8)]
    for folder, name in (("identification_data", "Trajectory1.csv"), ("validation_data", "opti_traj_testing1.csv")):
        rows = np.column_stack([np.arange(length), rng.uniform(-0.5, 0.5, (length, 28))])
        if nan_in == "kinova_gen3" and folder == "validation_data":
            rows[5, 3] = np.nan  # Position3
        os.makedirs(os.path.join(kin, folder), exist_ok=True)
        np.savetxt(os.path.join(kin, folder, name), rows, delimiter=",", header=",".join(header), comments="")
    ur5 = os.path.join(root, "ur5_modeling_force_estimate", "JointSpaceControl_Model_C_ForceEstim", "RecordedUR5Data")
    for movement in ("Movement_No1", "Movement_No6_Verify_Model"):
        folder = os.path.join(ur5, movement, "csv_files")
        os.makedirs(folder)
        t = 0.008 * np.arange(length)
        for name in ("log_q_actual.csv", "log_m_target.csv"):
            x = rng.uniform(-0.5, 0.5, (length, 6))
            if nan_in == "ur5" and "Verify" in movement and name == "log_q_actual.csv":
                x[5:, 2] = np.nan  # the third joint's column (the file's fourth, after time)
            np.savetxt(os.path.join(folder, name), np.column_stack([t, x]), delimiter=", ", fmt="%.6f")
    schunk = os.path.join(root, "AutoKoopman", "autoKoopman_codeocean", "data", "Robot")
    for m in (1, 2):
        folder = os.path.join(schunk, f"measurement_{m}")
        os.makedirs(folder)
        traj = rng.uniform(-0.5, 0.5, (length, 12))
        if nan_in == "schunk" and m == 2:  # run 2's input is used latest: the test run
            traj[5, 2] = np.nan
        np.savetxt(os.path.join(folder, "input.csv"), rng.normal(size=(length, 6)) + m, delimiter=",")
        np.savetxt(os.path.join(folder, "time.csv"), 0.004 * np.arange(length))
        np.savetxt(os.path.join(folder, "trajectory.csv"), traj, delimiter=",")
    mat = os.path.join(root, "Physics-Guided-Recurrent-State-Space-Neural-Networks", public_logs.INDUSTRIAL_MAT)
    os.makedirs(os.path.dirname(mat))
    arrays = {f"{k}_{split}": rng.normal(size=(6, length)) for k in "uy" for split in ("train", "val", "test")}
    if nan_in == "industrial_robot":
        arrays["y_test"][2, 5] = np.nan
    scipy.io.savemat(mat, arrays)


def _run(main, argv, capsys) -> tuple[int, str, str]:
    """``main(argv)``'s exit code (a parser's SystemExit too), its stdout and its stderr."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return int(code or 0), out.out, out.err


def _ingest(argv, capsys) -> tuple[int, str, str]:
    from robomorph.ingest import main

    return _run(main, argv, capsys)


@pytest.mark.parametrize("source", ["kinova_gen3", "ur5", "schunk", "industrial_robot"])
def test_ingest_source_with_every_recording_too_short_says_so(tmp_path, capsys, source):
    """Defect 11: every recording shorter than one window exited 0, printed nothing and wrote nothing."""
    _tiny_sources(str(tmp_path / "data"), length=40)
    code, _, err = _ingest(["--source", source, "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out")],
                           capsys)
    _one_error(code, err, "recording under", "holds one window of", "the longest has")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("source, where, column", [
    ("kinova_gen3", "validation_data/opti_traj_testing1.csv", "Position3"),
    ("ur5", "Movement_No6_Verify_Model/csv_files", "log_q_actual.csv column 4"),
    ("schunk", "measurement_2", "trajectory.csv column 3"),
    ("industrial_robot", "forward_identification_without_raw_data_shifted.mat", "y_test row 3"),
])
def test_a_nan_in_a_source_file_is_named_as_the_user_file_holds_it(tmp_path, capsys, source, where, column):
    """Defect 22: a NaN was reported against a deleted temporary ``.npz`` and a renamed column (``q2``)."""
    _tiny_sources(str(tmp_path / "data"), length=2100, nan_in=source)  # every recording holds a window
    code, _, err = _ingest(["--source", source, "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out")],
                           capsys)
    line = _one_error(code, err, where, column, "NaN")
    assert ".npz" not in line and "q2" not in line
    assert not (tmp_path / "out").exists()


# --- recipes: a realism scalar that compares false with everything --------------------------------------

@pytest.mark.parametrize("section, key, text", [("feedback", "ramp", ".nan"), ("friction", "smoothing_velocity", ".inf"),
                                                ("friction", "smoothing_velocity", ".nan")])
def test_a_realism_number_that_is_not_finite_is_refused(tmp_path, capsys, section, key, text):
    """Defect 18: ``feedback.ramp: .nan`` and ``friction.smoothing_velocity: .inf`` were accepted; the latter
    switched Coulomb friction off while the store recorded its drawn levels."""
    from robomorph import generate

    recipe = tmp_path / "r.yaml"
    extra = "    coulomb: [0.1, 0.2]\n" if section == "friction" else "    enabled: true\n"
    recipe.write_text(f"realism:\n  {section}:\n{extra}    {key}: {text}\n")
    code = generate.main(["--config", str(recipe), "--robots", "1", "--steps", "5", "--workers", "1", "--quiet",
                          "--out", str(tmp_path / "s.zarr")])
    _one_error(code, capsys.readouterr().err, f"realism.{section}.{key}", "finite")
    assert not (tmp_path / "s.zarr").exists()


# --- evaluate: a baseline fitted on what it is scored on, or on another arm ------------------------------

def _evaluate(argv, capsys) -> tuple[int, str, str]:
    from robomorph import evaluate

    return _run(evaluate.main, argv, capsys)


def _catalogue_eval(store, out, *extra) -> list[str]:
    return ["--robot", "panda", "--data", store, "--out", str(out), "--n", "2", "--context-len", str(C),
            "--horizon", str(H), "--plot-trajectories", "0", "--device", "cpu", *extra]


def test_an_arx_fitted_on_the_evaluated_store_is_reported_in_sample(simulated_store, tmp_path, capsys):
    """Defect 13: ``--arx-train-data <the test store>`` fitted on the robots it scored (0.048 against 0.12 mrad),
    with no note, and ``in_sample`` stayed false."""
    import json

    store = simulated_store(robots=2, steps=C + H, seed=3)
    code, out, err = _evaluate(_catalogue_eval(store, tmp_path / "ev", "--baselines", "hold,accel_arx_train",
                                               "--arx-train-data", store), capsys)
    assert code == 0, err
    assert f"accel_arx_train: in-sample: fitted on {store}" in out
    note = json.loads((tmp_path / "ev" / "metrics.json").read_text())["meta"]["baseline_notes"]["accel_arx_train"]
    assert note["in_sample"] is True and note["in_sample_store"] == store
    assert "Baseline `accel_arx_train` is in-sample" in (tmp_path / "ev" / "table.md").read_text()


def test_an_arx_train_store_of_another_arm_is_refused_before_anything_is_written(simulated_store, tmp_path, capsys):
    """Defect 23: ``--arx-train-data`` of another arm skipped the baseline with numpy's matmul text (rc 0)."""
    store = simulated_store(robots=2, steps=C + H, seed=3)
    other = simulated_store(robots=2, steps=C + H, seed=3, robot="ur5e")
    code, _, err = _evaluate(_catalogue_eval(store, tmp_path / "ev", "--baselines", "hold,accel_arx_train",
                                             "--arx-train-data", other), capsys)
    _one_error(code, err, f"--arx-train-data {other} holds arm ur5e, 6 inputs and 13 outputs",
               "holds arm panda, 7 inputs and 14 outputs")
    assert not (tmp_path / "ev").exists()


# --- a command hybrid calibrated or evaluated on what it was not made for --------------------------------

@pytest.fixture(scope="module")
def command_hybrid(simulated_store, tmp_path_factory) -> str:
    """A command-formulation hybrid trained two steps on a store of the generator's defaults (true_model)."""
    from robomorph.training.fitting import fit
    from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

    store = simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=3)
    return fit(tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "hybrid", steps=2, data={"inputs": "command"},
                             model={"physics": "amortized", "anchor": True})).best_ckpt


def _calibrate(argv, capsys) -> tuple[int, str, str]:
    from robomorph import calibrate

    return _run(calibrate.main, argv, capsys)


def test_calibrate_refuses_a_switch_the_calibrated_mode_does_not_use(command_hybrid, tmp_path, capsys):
    """Defect 14: ``calibrate --physics none --payload off`` changed the model's default switches as well: its
    default predictions moved by up to 2.8e-4 rad."""
    before = open(command_hybrid, "rb").read()
    code, _, err = _calibrate(["--ckpt", command_hybrid, "--physics", "none", "--payload", "off", "--device", "cpu"],
                              capsys)
    _one_error(code, err, "--payload off: physics mode none does not use the payload switch",
               "change the checkpoint's default predictions")
    assert open(command_hybrid, "rb").read() == before
    # In a mode that uses it the switch is taken, and the change of the checkpoint's defaults is said.
    code, out, err = _calibrate(["--ckpt", command_hybrid, "--payload", "off", "--out", str(tmp_path / "cal.ckpt"),
                                 "--n", "4", "--method", "coverage", "--device", "cpu"], capsys)
    assert code == 0, err
    assert "note: the checkpoint's default switches are now payload off" in out
    assert Predictor.from_checkpoint(str(tmp_path / "cal.ckpt"), device="cpu").settings.payload is False


def test_a_hybrid_scored_on_another_gravity_compensation_recipe_says_so(command_hybrid, simulated_store, tmp_path,
                                                                        capsys):
    """Defect 19: a command hybrid trained on one recipe was evaluated or calibrated on a store of another
    gravity-compensation recipe with no note (0.15 against 0.086 mrad at step 1)."""
    import json

    other = simulated_store(robots=4, steps=90, seed=5, gravity_compensation="nominal_model")
    code, out, err = _evaluate(["--ckpt", command_hybrid, "--data", other, "--out", str(tmp_path / "ev"), "--n", "2",
                                "--baselines", "hold", "--plot-trajectories", "0", "--device", "cpu"], capsys)
    assert code == 0, err
    phrase = "the hybrid was made for gravity compensation 'true_model' and this store's robots were simulated with " \
             "'nominal_model'"
    assert phrase in out
    assert phrase in json.loads((tmp_path / "ev" / "metrics.json").read_text())["meta"]["recipe_note"]
    assert phrase in (tmp_path / "ev" / "table.md").read_text()
    code, out, err = _calibrate(["--ckpt", command_hybrid, "--data", other, "--out", str(tmp_path / "cal.ckpt"),
                                 "--n", "4", "--method", "coverage", "--device", "cpu"], capsys)
    assert code == 0, err
    assert f"note: recipe: {phrase}" in out
    cal = Predictor.from_checkpoint(str(tmp_path / "cal.ckpt"), device="cpu").calibration
    assert phrase in cal.source["recipe_note"]  # kept with the calibration, in the checkpoint


def test_the_same_recipe_gets_no_note(command_hybrid, simulated_store, tmp_path, capsys):
    import json

    same = simulated_store(robots=4, steps=90, seed=5)
    code, out, err = _evaluate(["--ckpt", command_hybrid, "--data", same, "--out", str(tmp_path / "ev"), "--n", "2",
                                "--baselines", "hold", "--plot-trajectories", "0", "--device", "cpu"], capsys)
    assert code == 0, err
    assert "recipe:" not in out and "recipe_note" not in json.loads((tmp_path / "ev" / "metrics.json").read_text())["meta"]


# --- a residual run over priors of several hybrids ---------------------------------------------------------

def test_a_residual_run_refuses_priors_of_two_recipes(tmp_path):
    """Defect 12: a residual ``fit`` on prior stores of two hybrids (recipes) trained on both and recorded only
    the first's recipe."""
    from robomorph.data.priors import PriorError
    from tests.data.test_priors import _dm, prior_store

    true = prior_store(tmp_path / "a.zarr", recipe={"gravity_compensation": "true_model", "seed": 0})
    nominal = prior_store(tmp_path / "b.zarr", seed=1, recipe={"gravity_compensation": "nominal_model", "seed": 1})
    with pytest.raises(PriorError, match=r"b.zarr holds priors of another hybrid than .*a.zarr: their recipes differ in "
                                         r"gravity_compensation \('nominal_model' against 'true_model'\)"):
        _dm([true, nominal]).setup()
    again = prior_store(tmp_path / "c.zarr", seed=2, recipe={"gravity_compensation": "true_model", "seed": 2})
    _dm([true, again]).setup()  # one recipe drawn with two seeds: one hybrid


def _arm_prior_store(path, arm: str, seed: int) -> str:
    """A prior store in ``arm``'s channel layout (no simulation: random windows, the prior off by 0.1)."""
    from robomorph.sim import arms
    from tests.conftest import write_store

    spec, rng = arms.get(arm), np.random.default_rng(seed)
    u = rng.normal(size=(24, 50, spec.n_joint))
    y = 0.1 * rng.normal(size=(24, 50, 7 + spec.n_joint))
    record = {"source": "x", "source_n": 24, "source_seed": seed, "settings": "regression", "fields": {},
              "context": 30, "horizon": 20, "offsets": [0], "arm": arm, "inputs": "total", "recipe": {"robot": arm}}
    return write_store(path, u, y, None, list(spec.u_names), list(spec.y_names), [],
                       attrs={"dt": 1 / 60, "domain": arm, "prior": record},
                       extras={"prior": ((20, 7 + spec.n_joint), "float32", (y[:, 30:] + 0.1).astype(np.float32))})


def test_a_residual_run_over_two_arms_names_the_arms(tmp_path, capsys):
    """Defect 21: a residual fit on Panda and UR5e priors named channel masks and heads, not the mixed arms."""
    from robomorph import fit

    panda, ur5e = _arm_prior_store(tmp_path / "a.zarr", "panda", 0), _arm_prior_store(tmp_path / "b.zarr", "ur5e", 1)
    argv = ["--data.stores", f"[{panda},{ur5e}]", "--data.context_len", "30", "--data.horizon", "20",
            "--data.batch_size", "4", "--data.inputs", "total", "--model.d_model", "16", "--model.n_head", "2",
            "--model.n_layer", "1", "--model.patch", "5", "--trainer.max_steps", "1", "--trainer.accelerator", "cpu",
            "--runs_dir", str(tmp_path / "runs"), "--run", "r", "--wandb", "disabled"]
    code, _, err = _run(fit.main, argv, capsys)
    line = _one_error(code, err, "b.zarr holds priors of the ur5e", "a.zarr of the panda",
                      "one residual model per arm")
    assert "channel_mask" not in line


# --- priors: a dangling link, a context of two samples ---------------------------------------------------

def _priors(argv, capsys) -> tuple[int, str]:
    from robomorph import priors

    code, _, err = _run(priors.main, argv, capsys)
    return code, err


def test_priors_out_on_a_dangling_link_says_so(simulated_store, tmp_path, capsys):
    """Defect 24: ``priors --out`` on a dangling symlink said "File exists"."""
    import os

    store = simulated_store(robots=2, steps=C + H, seed=3)
    link = tmp_path / "p.zarr"
    link.symlink_to(tmp_path / "gone" / "p.zarr")
    code, err = _priors([store, "--out", str(link), "--context-len", str(C), "--horizon", str(H)], capsys)
    _one_error(code, err, f"--out {link} is a link to {tmp_path / 'gone' / 'p.zarr'}, which does not exist",
               "remove the link")
    assert os.path.islink(link) and sorted(os.listdir(tmp_path)) == ["p.zarr"]


def test_a_context_too_short_for_the_hybrid_is_named(simulated_store, window, tmp_path, capsys):
    """Defect 24: ``priors --context 2`` printed numpy's "zero-size array to reduction operation maximum"."""
    uc, yc, uq = window
    pred = Predictor.from_arm("panda").configure(members=1, workers=1)
    for steps in (1, 2):
        with pytest.raises(Exception, match=rf"^u_ctx has {steps} steps?: the hybrid identifies the robot from the "
                                            r"context's accelerations, which take at least 3 samples"):
            pred.simulate(uc[:, :steps], yc[:, :steps], uq, at_rest=True)
    store = simulated_store(robots=2, steps=C + H, seed=3)
    code, err = _priors([store, "--out", str(tmp_path / "p.zarr"), "--context-len", "2", "--horizon", str(H),
                         "--set", "members=1", "--set", "workers=1"], capsys)
    line = _one_error(code, err, "u_ctx has 2 steps", "at least 3 samples")
    assert "zero-size" not in line


# --- benchmarks/real_robots.py: a --model that cannot be read ----------------------------------------------

@pytest.mark.parametrize("kind", ["missing", "notes"])
def test_real_robots_refuses_a_model_that_is_no_checkpoint_before_the_run(tmp_path, kind):
    """Defect 25: ``real_robots.py --model x=<missing or not a checkpoint>`` was found only after the whole run,
    as a footnote, with exit code 0."""
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = tmp_path / "x.ckpt"
    if kind == "notes":
        path.write_text("notes, not a checkpoint\n")
    done = subprocess.run([sys.executable, os.path.join(root, "benchmarks", "real_robots.py"), "--data", str(tmp_path),
                           "--robots", "schunk", "--work", str(tmp_path / "work"), "--md", str(tmp_path / "t.md"),
                           "--model", f"x={path}"], capture_output=True, text=True, cwd=str(tmp_path), timeout=300)
    _one_error(done.returncode, done.stderr, f"--model x={path}: ")
    assert sorted(os.listdir(tmp_path)) == (["x.ckpt"] if kind == "notes" else [])


# --- control: a Ctrl-C with a pool of workers ---------------------------------------------------------------

def _group(pgid: int) -> list[int]:
    """The processes of process group ``pgid`` (from /proc: what a terminal's Ctrl-C reaches)."""
    import os

    pids = []
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":
                pids.append(int(name))
    return pids


@pytest.mark.skipif(not __import__("os").path.isdir("/proc"), reason="reads the process table from /proc")
def test_a_ctrl_c_stops_control_with_two_workers_promptly(tmp_path):
    """Defect 26: with ``--workers 2``, Ctrl-C did not stop ``control``: it finished its episodes, 136 s later, and
    only then said none was kept. A real SIGINT to the process group, as a terminal sends it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = tmp_path / "ctl"
    # Two MPC episodes of a minute each: minutes of work, far longer than the stop may take.
    proc = subprocess.Popen([sys.executable, "-m", "robomorph.control", "--controllers", "mpc:nominal_physics",
                             "--robots", "2", "--workers", "2", "--warmup", "0.5", "--duration", "60", "--out", str(out)],
                            cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "MUJOCO_GL": "disable", "PYTHONPATH": root})
    try:
        deadline = time.monotonic() + 240
        while len(_group(proc.pid)) < 3 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)  # the parent and its two workers
        assert len(_group(proc.pid)) >= 3, proc.communicate(timeout=60)
        time.sleep(5)  # the workers import, then run their episodes
        os.killpg(proc.pid, signal.SIGINT)
        sent = time.monotonic()
        _, err = proc.communicate(timeout=60)
        waited = time.monotonic() - sent
        # No worker left behind (multiprocessing's resource tracker, of the group too, ends a moment after the parent).
        left = time.monotonic() + 10
        while _group(proc.pid) and time.monotonic() < left:
            time.sleep(0.2)
        remaining = _group(proc.pid)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # whatever a failed run left, never a stray process
        except ProcessLookupError:
            pass
    assert waited < 20, waited  # seconds (measured: 0.2 s); the episodes last minutes
    assert proc.returncode == 130 and "stopped by Ctrl-C: no episode is kept" in err and "Traceback" not in err, err
    assert remaining == [] and not out.exists()


def test_configure_of_a_trained_hybrid_refuses_a_mode_it_cannot_run(command_hybrid, window):
    """Defect 20, the general fix: a mode the checkpoint lacks the weights for (``blend`` with no blend fitted) is
    refused at ``configure``, not at the first ``simulate``, and the settings stay as they were."""
    from robomorph.inference.hybrid import HybridError

    pred = Predictor.from_checkpoint(command_hybrid, device="cpu").configure(members=1, workers=1)
    before = pred.settings
    with pytest.raises(HybridError, match=r"physics mode 'blend' needs the blend's weights"):
        pred.configure(mode="blend")
    assert pred.settings == before
    assert pred.simulate(*window, at_rest=True).shape == (1, H, 14)
