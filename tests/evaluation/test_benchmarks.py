"""Every benchmark script runs end to end at a tiny setting, so none of them can rot.

The figures they print are not checked (they measure this machine); what is checked is
that each runs, scores through the one scoring path, and writes result files that carry
their provenance and the steps they say (1-based).
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from robomorph.core.results import read_provenance, read_rows

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
pytestmark = pytest.mark.slow
# A tiny model and window on top of datamodules/train_cpu.yaml (horizon-aware ranges shrunk to fit).
TINY = ["model.d_model=16", "model.n_head=2", "model.n_layer=1", "model.warmup_steps=1", "data.batch_size=4",
        "data.val_subset=2", "data.context_min=10", "data.horizon_min=10", "trainer.val_check_interval=1",
        "data.split=[0.75, 0.25, 0.0]"]


def run(script: str, *args: str, ok: bool = True) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, os.path.join("benchmarks", script), *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, env=env, timeout=600)
    if ok:
        assert done.returncode == 0, done.stderr[-3000:]
    return done


def sets(*items: str) -> list[str]:
    return [part for item in items for part in ("--set", item)]


def test_horizon_ablation_and_its_table(tmp_path):
    csv = tmp_path / "ablation.csv"
    common = ["--train", tmp_path / "train.zarr", "--test", tmp_path / "test.zarr", "--robots", 12, "--held-out", 4,
              "--trajectory-steps", 100, "--context", 30, "--random-horizon", 20, "--runs-dir", tmp_path / "runs",
              "--csv", csv, "--threads", 1]
    done = run("horizon_ablation.py", *common, "--horizon", 40, "--variants", "default,full", "--steps", 2,
               "--score-every", 1, *sets(*TINY))
    assert done.stdout.startswith("*Produced by `benchmarks/horizon_ablation.py")
    rows = read_rows(str(csv))
    assert [r["variant"] for r in rows] == ["nominal_physics[total]", "default", "default", "full", "full"]
    assert [r["steps"] for r in rows[1:]] == ["1", "2", "1", "2"]  # --score-every 1, then the end
    assert {"model_mrad_step1", "model_mrad_step15", "model_mrad_step40", "random_model_mrad_step20"} <= set(rows[0])
    assert rows[-1]["cover1sigma"] and not rows[2]["cover1sigma"]  # full has a Gaussian head, default none
    assert read_provenance(str(csv))[0]["command"].startswith("benchmarks/horizon_ablation.py")
    curves = read_rows(str(tmp_path / "ablation_curves.csv"))
    assert [int(r["step"]) for r in curves] == list(range(1, 41))
    config = (tmp_path / "runs" / "full" / "config.yaml").read_text()
    assert "max_steps: 2" in config and "warmup_steps: 1" in config  # the schedule that ran is the one recorded
    # Other steps are other columns: appending them to this file is refused in one line.
    again = run("horizon_ablation.py", *common, "--horizon", 30, "--variants", "default", "--steps", 1,
                *sets(*TINY), ok=False)
    errors = [line for line in again.stderr.splitlines() if line.startswith("error: ")]
    assert again.returncode == 2 and len(errors) == 1 and "Traceback" not in again.stderr
    assert "other columns than the rows to append" in errors[0]
    assert len(read_rows(str(csv))) == len(rows)
    table = run("confirm_table.py", csv, "--out", tmp_path / "t.md")
    text = (tmp_path / "t.md").read_text()
    assert table.returncode == 0 and text.startswith("*Produced by") and "catalogue physics" in text
    assert "benchmarks/horizon_ablation.py" in text.split("Rows from:")[1]


def test_quality_vs_time_measures_train_cpu_yaml_and_calibration_scores_it(tmp_path):
    out = tmp_path / "q"
    run("quality_vs_time.py", "--out", out, "--robots", 12, "--held-out", 4, "--trajectory-steps", 100,
        "--minutes", 2, "--offset-horizon", 20, "--name", "tiny",
        *sets(*TINY, "trainer.max_steps=2", "data.context_len=30", "data.horizon=40"))
    config = (out / "runs" / "tiny" / "config.yaml").read_text()
    for line in ("loss: nll", "anchor: true", "n_init: 20", "gaussian: true", "max_steps: 2"):  # train_cpu.yaml's
        assert line in config, line
    start = read_rows(str(out / "quality_horizons_start.csv"))
    assert len(start) == 1 and "joints_model_step15_mrad" in start[0] and "joints_below_hold_fraction" in start[0]
    assert read_provenance(str(out / "quality_horizons_random.csv"))
    assert len(read_rows(str(out / "tiny.csv"))) == 2
    ckpt = next((out / "runs" / "tiny" / "checkpoints").glob("*.ckpt"))
    done = run("calibration.py", "--ckpt", f"tiny={ckpt}", "--test", out / "ms_heldout.zarr", "--csv",
               tmp_path / "cal.csv", "--random-horizon", 20, "--threads", 1)
    rows = read_rows(str(tmp_path / "cal.csv"))
    assert [(r["offset"], r["method"]) for r in rows] == [(o, m) for o in ("start", "random")
                                                           for m in ("none", "nll", "quantile", "coverage", "power")]
    assert rows[0]["steps"] == "1/15/40" and rows[0]["dnll_vs_raw"] == "0.0"
    assert "ΔNLL vs head" in done.stdout
    # Fitted on another store's robots, one method, start windows only.
    run("calibration.py", "--ckpt", f"tiny={ckpt}", "--test", out / "ms_heldout.zarr", "--csv", tmp_path / "cal2.csv",
        "--cal-data", out / "ms_heldout.zarr", "--n", 3, "--methods", "power", "--offsets", "start", "--threads", 1)
    rows = read_rows(str(tmp_path / "cal2.csv"))
    assert [(r["offset"], r["method"]) for r in rows] == [("start", "none"), ("start", "power")]


def test_formulations(tmp_path):
    run("formulations.py", "--out", tmp_path / "f", "--csv", tmp_path / "f.csv", "--robots", 12, "--held-out", 4,
        "--trajectory-steps", 100, "--context", 30, "--horizon", 40, "--steps", 2, "--max-minutes", 2,
        "--val-subset", 2, "--d-model", 16, "--n-layer", 1, "--patch", 5, "--batch", 4,
        *sets("model.n_head=2", "data.context_min=10", "data.horizon_min=10", "data.split=[0.75, 0.25, 0.0]"))
    rows = read_rows(str(tmp_path / "f.csv"))
    assert [(r["inputs"], r["predictor"]) for r in rows] == [
        (i, p) for i in ("total", "command") for p in ("model", "hold", "nominal_physics", "true_physics")]
    assert "joint_rms_mrad_step40" in rows[0]


@pytest.mark.parametrize("script,args", [
    ("generate.py", ["--robots", 4, "--osc-robots", 2, "--steps", 40, "--workers", 1]),
    ("model_speed.py", ["--iters", 1, "--no-big", "--threads", 1]),
    ("predict.py", ["--repeats", 1, "--threads", 1]),
    ("train.py", ["--steps", 1, "--batch", 2, "--context", 20, "--horizon", 20, "--threads", 1]),
    ("substeps.py", ["--robots", 2, "--steps", 20, "--ref", 4, "--substeps", "2"]),
    ("predictability.py", ["--robots", 2, "--steps", 60, "--modes", "true_model", "--workers", 1, "--data", "{tmp}"]),
    ("real_log_fixture.py", ["--out", "{tmp}", "--lengths", "30,20"]),
])
def test_printing_benchmarks_run_at_a_tiny_setting(script, args, tmp_path):
    done = run(script, *(str(a).format(tmp=tmp_path) for a in args))
    assert done.stdout.strip()
    if script != "real_log_fixture.py":  # a data fixture, not a result
        assert done.stdout.startswith("*Produced by")


def test_hybrid_benchmark_scores_modes_and_baselines_on_the_same_windows(tmp_path, simulated_store):
    from robomorph.training.fitting import fit
    from tests.conftest import tiny_fit_args

    store = simulated_store(robots=8, steps=90, seed=6)
    args = tiny_fit_args(store, tmp_path / "runs", "hyb", steps=2, data={"inputs": "command"},
                         model={"physics": "amortized"})
    ckpt = fit(args).best_ckpt
    csv, lat = tmp_path / "hybrid.csv", tmp_path / "latency.csv"
    done = run("hybrid.py", "--ckpt", ckpt, "--test", store, "--n", 2, "--offsets", "start",
               "--modes", "learned,regression,regression~1/2", "--baselines",
               "hold,identified_physics,identified_physics_springs", "--csv", csv,
               "--md", tmp_path / "h.md",
               "--latency", "--repeats", 1, "--latency-csv", lat, "--std")
    assert done.stdout.startswith("*Produced by `benchmarks/hybrid.py")
    rows = read_rows(str(csv))
    assert [r["source"] for r in rows] == ["hold", "identified_physics", "identified_physics_springs", "learned",
                                           "regression", "regression~1/2"]
    assert float(rows[2]["s_per_window"]) > 0  # its own cost, as identified physics' (it fits 7 more parameters)
    assert all(float(r["step1"]) > 0 for r in rows)
    # Window by window against identified physics: shares in [0, 1] and positive ratios for all but itself.
    below = [float(r["below_ref1"]) for r in rows]
    assert np.isnan(below[1]) and all(0.0 <= b <= 1.0 for i, b in enumerate(below) if i != 1)
    assert all(float(r["ratio_ref1"]) > 0 for i, r in enumerate(rows) if i != 1)
    assert "Window by window against identified_physics" in (tmp_path / "h.md").read_text()
    rows = [rows[0]] + rows[3:]
    # Coverage at the reported steps: the mean lies within the lowest and highest step's (none for hold).
    cover = [[float(r[f"cover1{k}"]) for k in ("_min", "", "_max")] for r in rows]
    assert np.isnan(cover[0]).all() and all(lo <= mean <= hi for lo, mean, hi in cover[1:])
    assert read_provenance(str(csv))[0]["command"].startswith("benchmarks/hybrid.py")
    assert {r["mode"] for r in read_rows(str(lat))} == {"learned", "regression", "regression~1/2", "none"}


def test_horizon_step_benchmark_is_exact_at_the_generators_step_and_in_the_first_second(tmp_path, simulated_store):
    store = simulated_store(robots=3, steps=90, seed=6)
    csv = tmp_path / "step.csv"
    done = run("horizon_step.py", "--test", store, "--n", 3, "--context", 20, "--horizon", 70, "--csv", csv)
    assert done.stdout.startswith("*Produced by `benchmarks/horizon_step.py")
    rows = read_rows(str(csv))
    assert len(rows) == 4 and "(default)" in rows[2]["setting"]
    exact, everywhere, default = ({k: float(v) for k, v in r.items() if k.startswith("step")} for r in rows[:3])
    assert max(exact.values()) < 1e-3  # the recorded robot, to float32 storage [mrad]
    assert default["step1"] == exact["step1"] and default["step60"] == exact["step60"]
    assert everywhere["step60"] > 10 * exact["step60"]  # a coarse step is a real change, and would show
    assert int(rows[2]["physics_steps"]) < int(rows[0]["physics_steps"])
    done = run("horizon_step.py", "--test", store, "--n", 3, "--horizon", 800, ok=False)
    assert done.returncode == 2 and "fewer than --context + --horizon" in done.stderr


def test_candidates_benchmark_is_exact_for_the_reference_and_linear_without_friction(tmp_path, simulated_store):
    store = simulated_store(robots=2, steps=90, seed=6)
    csv, md = tmp_path / "cand.csv", tmp_path / "cand.md"
    done = run("candidates.py", "--test", store, "--n", 2, "--context", 20, "--candidates", 8, "--sigma", "0.001,0.5",
               "--csv", csv, "--md", md)
    assert done.stdout.startswith("*Produced by `benchmarks/candidates.py")
    rows = read_rows(str(csv))
    assert len(rows) == 2 * 2 * 7 and md.read_text().startswith("*Produced by")
    err = {(float(r["sigma"]), r["robot"], r["method"]): float(r["step60"]) for r in rows}
    for b in ("0", "1"):
        assert err[(0.5, b, "exact (reference)")] == 0.0
        # Without dry friction the tangent follows the exact candidates (second order in the deviation);
        # a coarser step is a real change, which the comparison would show.
        assert err[(0.001, b, "tangent-linear, no friction loss")] < 1e-3
        assert err[(0.5, b, "exact, 1 physics steps per sample")] > err[(0.5, b, "exact, 4 physics steps per sample")]
        # Dry friction's switches corrected: closer to the exact candidates than the plain tangent.
        assert err[(0.5, b, "tangent-linear, dry friction corrected")] < 0.7 * err[(0.5, b, "tangent-linear")]
    done = run("candidates.py", "--test", store, "--context", 60, ok=False)
    assert done.returncode == 2 and "fewer than --context + 60" in done.stderr


def test_nuisance_sets_each_kind_back_to_the_catalogue_in_turn(tmp_path, simulated_store):
    """benchmarks/nuisance.py: the true robot, then each kind at the catalogue's; a randomized kind costs error."""
    store = simulated_store(robots=2, steps=60, seed=6)
    run("nuisance.py", "--data", store, "--n", 2, "--context-len", 20, "--horizon", 30, "--md", tmp_path / "n.md")
    rows = read_rows(str(tmp_path / "n.csv"))
    assert [r["at_catalogue"] for r in rows] == ["none", "mass", "com", "damping", "stiffness", "armature",
                                                 "frictionloss"]
    assert float(rows[3]["step_15"]) > 10 * float(rows[0]["step_15"])  # the damping's range moves the arm


def test_spread_benchmark_reads_its_cache_back_for_the_same_windows_only(tmp_path, simulated_store):
    from robomorph.training.fitting import fit
    from tests.conftest import tiny_fit_args

    cal, test = simulated_store(robots=6, steps=90, seed=8), simulated_store(robots=6, steps=90, seed=9)
    args = tiny_fit_args(cal, tmp_path / "runs", "hyb", steps=2, data={"inputs": "command"},
                         model={"physics": "amortized"})
    ckpt = fit(args).best_ckpt
    cache = tmp_path / "pred.npz"
    common = ["--ckpt", ckpt, "--cal", cal, "--test", test, "--n", 4, "--points", "columns", "--cache", cache]
    first = run("spread.py", *common, "--md", tmp_path / "a.md")
    assert cache.exists() and "predicting again" not in first.stderr
    again = run("spread.py", *common, "--md", tmp_path / "b.md")
    assert "model:" not in again.stderr  # read back: no prediction ran
    body = lambda p: p.read_text().split("\n", 2)[2]  # noqa: E731  (past the provenance line)
    assert body(tmp_path / "a.md") == body(tmp_path / "b.md")
    other = run("spread.py", *common[:6], "--n", 3, "--points", "columns", "--cache", cache, "--md", tmp_path / "c.md")
    assert "holds other windows; predicting again" in other.stderr
    # The single robot (the fast setting) is other predictions: not read from the mixture's cache.
    single = run("spread.py", *common, "--members", 1, "--md", tmp_path / "s.md")
    assert "holds other windows; predicting again" in single.stderr
    assert "physics mode regression, 1 friction member)" in (tmp_path / "s.md").read_text()
    # Side by side, each variant is scored with its own mean (the springs move it): as when run alone.
    both = tmp_path / "both.csv"
    run("spread.py", *common[:8], "--points", "columns,columns+springs", "--md", tmp_path / "d.md", "--csv", both)
    alone = tmp_path / "alone.csv"
    run("spread.py", *common[:8], "--points", "columns+springs", "--md", tmp_path / "e.md", "--csv", alone)
    strip = lambda r: {k: v for k, v in r.items() if k != "points"}  # noqa: E731
    assert strip(read_rows(str(both))[1]) == strip(read_rows(str(alone))[0])
