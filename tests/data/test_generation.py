import os
import signal
import subprocess
import sys
import time

import mujoco
import numpy as np
import pytest
import yaml

from robomorph.data.generation import GenerationError, Shard, generate
from robomorph.data.merging import merge
from robomorph.data.store import DatasetWriter, open_store
from robomorph.generate import main
from robomorph.sim import panda
from robomorph.sim.filters import to_outputs
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import load_recipe

TINY = {"task": "multisine", "robots": 10, "steps": 40, "chunk": 4, "seed": 3}


def _arrays(path):
    ds = open_store(str(path))
    return {k: ds.read(k) for k in ds.arrays}


def _same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_workers_do_not_change_the_arrays(tmp_path):
    recipe = load_recipe(None, TINY)
    generate(recipe, str(tmp_path / "w1.zarr"), workers=1, progress=False)
    generate(recipe, str(tmp_path / "w2.zarr"), workers=2, progress=False)
    _same(_arrays(tmp_path / "w1.zarr"), _arrays(tmp_path / "w2.zarr"))
    attrs = open_store(str(tmp_path / "w1.zarr")).attrs
    assert attrs["kept"] == 10 and attrs["kept"] + sum(attrs["rejected"].values()) == attrs["attempted"]
    assert attrs["config"]["seed"] == 3 and attrs["status"] == "complete"


def test_chunk_size_does_not_change_the_arrays(tmp_path):
    generate(load_recipe(None, TINY), str(tmp_path / "a.zarr"), workers=1, progress=False)
    generate(load_recipe(None, {**TINY, "chunk": 7}), str(tmp_path / "b.zarr"), workers=1, progress=False)
    a, b = _arrays(tmp_path / "a.zarr"), _arrays(tmp_path / "b.zarr")
    _same(a, b)


def test_seed_changes_the_arrays(tmp_path):
    generate(load_recipe(None, TINY), str(tmp_path / "a.zarr"), workers=1, progress=False)
    generate(load_recipe(None, {**TINY, "seed": 4}), str(tmp_path / "b.zarr"), workers=1, progress=False)
    assert not np.allclose(_arrays(tmp_path / "a.zarr")["params"], _arrays(tmp_path / "b.zarr")["params"])


def test_recorded_params_reproduce_the_trajectory(tmp_path):
    """Re-simulating a stored robot from its stored params gives its stored y and u."""
    recipe = load_recipe(None, {**TINY, "robots": 2})
    generate(recipe, str(tmp_path / "a.zarr"), workers=1, progress=False)
    ds = open_store(str(tmp_path / "a.zarr"))
    model = panda.build_model()
    rnd = Randomizer(model, recipe.randomization)
    from robomorph.sim import episode

    row = 1
    params = ds.read("params")[row].astype(np.float64)
    rnd.apply(model, params)
    draw = episode.draw(recipe, rnd, int(ds.read("attempt")[row]))
    data = mujoco.MjData(model)
    data.qpos[:] = rnd.split(params)["qinit"]
    sens = []
    for k in range(recipe.steps):
        data.ctrl[:] = draw.ctrl[k]
        mujoco.mj_step(model, data)
        sens.append(data.sensordata.copy())
        mujoco.mj_step(model, data, nstep=recipe.substeps - 1)
    u, y = to_outputs(np.array(sens))
    np.testing.assert_allclose(ds.read("y")[row], y, atol=2e-4)  # params are stored as float32
    np.testing.assert_allclose(ds.read("u")[row], u, atol=2e-3)


def test_interrupted_run_resumes_to_the_same_arrays(tmp_path, monkeypatch):
    recipe = load_recipe(None, TINY)
    generate(recipe, str(tmp_path / "full.zarr"), workers=1, progress=False)

    real_append, calls = DatasetWriter.append, []

    def dying_append(self, *args, **kwargs):
        if len(calls) == 1:
            raise KeyboardInterrupt  # killed after the first chunk is on disk
        calls.append(1)
        return real_append(self, *args, **kwargs)

    monkeypatch.setattr(DatasetWriter, "append", dying_append)
    with pytest.raises(KeyboardInterrupt):
        generate(recipe, str(tmp_path / "cut.zarr"), workers=1, progress=False)
    monkeypatch.setattr(DatasetWriter, "append", real_append)
    cut = open_store(str(tmp_path / "cut.zarr"), allow_incomplete=True)
    assert cut.attrs["status"] == "in_progress" and cut.n == 4
    with pytest.raises(Exception, match="incomplete"):
        open_store(str(tmp_path / "cut.zarr"))
    generate(recipe, str(tmp_path / "cut.zarr"), workers=1, progress=False)  # same call resumes
    _same(_arrays(tmp_path / "full.zarr"), _arrays(tmp_path / "cut.zarr"))
    a, b = open_store(str(tmp_path / "full.zarr")).attrs, open_store(str(tmp_path / "cut.zarr")).attrs
    assert (a["attempted"], a["rejected"]) == (b["attempted"], b["rejected"])


@pytest.mark.slow
def test_sigkilled_cli_run_resumes_with_the_same_command(tmp_path):
    cfg = tmp_path / "r.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, "robots": 48, "steps": 600, "chunk": 8}))
    out = str(tmp_path / "k.zarr")
    cmd = [sys.executable, "-m", "robomorph.generate", "--config", str(cfg), "--out", out, "--workers", "1", "--quiet"]
    proc = subprocess.Popen(cmd, start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        try:
            if open_store(out, allow_incomplete=True).n >= 8:
                break
        except Exception:  # noqa: BLE001  (store not created yet)
            pass
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = open_store(out, allow_incomplete=True)
    assert partial.attrs["status"] == "in_progress" and 8 <= partial.n < 48
    assert subprocess.run(cmd).returncode == 0
    ref = str(tmp_path / "ref.zarr")
    assert main(["--config", str(cfg), "--out", ref, "--workers", "2", "--quiet"]) == 0
    _same(_arrays(ref), _arrays(out))


def test_shards_are_disjoint_and_merge(tmp_path):
    recipe = load_recipe(None, {**TINY, "robots": 9})
    parts = []
    for i in range(3):
        parts.append(str(tmp_path / f"p{i}.zarr"))
        generate(recipe, parts[-1], workers=1, shard=Shard(i, 3), progress=False)
    attempts = [set(open_store(p).read("attempt").tolist()) for p in parts]
    assert all(a % 3 == i for i, s in enumerate(attempts) for a in s)
    assert sum(len(s) for s in attempts) == len(set().union(*attempts)) == 9
    attrs = merge(parts, str(tmp_path / "all.zarr"))
    assert attrs["n"] == 9 and attrs["kept"] == 9
    merged = open_store(str(tmp_path / "all.zarr"))
    np.testing.assert_array_equal(merged.read("u")[:3], open_store(parts[0]).read("u"))
    with pytest.raises(ValueError, match="duplicate"):
        merge([parts[0], parts[0]], str(tmp_path / "dup.zarr"))


def test_too_low_valid_rate_stops_with_a_clear_error(tmp_path):
    # a 3 rad margin puts every joint "at its limit": nothing can be kept
    recipe = load_recipe(None, {**TINY, "filters": {"joint_margin": 3.0}, "max_attempts_factor": 2.0})
    with pytest.raises(GenerationError, match="valid rate too low.*joint_limit"):
        generate(recipe, str(tmp_path / "x.zarr"), workers=1, progress=False)
    ds = open_store(str(tmp_path / "x.zarr"), allow_incomplete=True)
    assert ds.attrs["status"] == "in_progress" and ds.n == 0


@pytest.mark.parametrize("args, message", [
    (["--task", "juggle"], "unknown task 'juggle'"),
    (["--steps", "0"], "steps must be >= 1"),
    (["--robots", "-3"], "robots must be >= 1"),
    (["--shard", "3/2"], "--shard"),
])
def test_bad_flags(tmp_path, capsys, args, message):
    out = tmp_path / "x.zarr"
    assert main([*args, "--out", str(out), "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("text, message", [
    ("task: [unclosed", "not valid YAML"),
    ("robots: 5\nwobble: 1\n", "unknown key(s) ['wobble']"),
    ("randomization:\n  damping: [10, 5]\n", "inverted range"),
    ("randomization:\n  stiffness: [-1, 0.1]\n", "below"),
    ("signal:\n  fm: fast\n", "expected a list"),
    ("- 1\n- 2\n", "must hold a mapping"),
])
def test_malformed_recipes(tmp_path, capsys, text, message):
    cfg = tmp_path / "r.yaml"
    cfg.write_text(text)
    assert main(["--config", str(cfg), "--out", str(tmp_path / "x.zarr"), "--quiet"]) == 2
    assert message in capsys.readouterr().err


def test_existing_outputs_are_never_clobbered(tmp_path, capsys):
    f = tmp_path / "file.zarr"
    f.write_text("precious")
    assert main(["--out", str(f), "--robots", "2", "--steps", "5", "--quiet"]) == 2
    assert f.read_text() == "precious"

    import zarr

    other = tmp_path / "other.zarr"
    zarr.open_group(str(other), mode="w").attrs["schema"] = "else"
    before = sorted(os.listdir(other))
    assert main(["--out", str(other), "--robots", "2", "--steps", "5", "--quiet", "--overwrite"]) == 2
    assert "another schema" in capsys.readouterr().err
    assert sorted(os.listdir(other)) == before

    ok = tmp_path / "ok.zarr"
    assert main(["--out", str(ok), "--robots", "2", "--steps", "5", "--quiet"]) == 0
    before = _arrays(ok)
    assert main(["--out", str(ok), "--robots", "3", "--steps", "5", "--quiet"]) == 2
    assert "different recipe" in capsys.readouterr().err
    _same(before, _arrays(ok))
    assert main(["--out", str(ok), "--robots", "2", "--steps", "5", "--quiet"]) == 0  # complete: a no-op


def test_osc_workers_do_not_change_the_arrays(tmp_path):
    """Closed-loop tasks go through worker processes; the arrays must not depend on them."""
    recipe = load_recipe(None, {**TINY, "task": {"circle": 1.0, "multisine": 1.0}, "robots": 6, "steps": 30})
    generate(recipe, str(tmp_path / "w1.zarr"), workers=1, progress=False)
    generate(recipe, str(tmp_path / "w2.zarr"), workers=2, progress=False)
    a, b = _arrays(tmp_path / "w1.zarr"), _arrays(tmp_path / "w2.zarr")
    _same(a, b)
    osc_rows = a["task_index"] == 0
    assert osc_rows.any() and (~osc_rows).any()  # the mixture exercised both engines
    assert np.all(np.isfinite(a["target"][osc_rows])) and np.all(np.isnan(a["target"][~osc_rows]))
    assert np.all(np.isfinite(a["kp"][osc_rows])) and np.all(np.isfinite(a["fm"][~osc_rows]))


@pytest.mark.parametrize("mode", ["nominal_model", "none"])
def test_gravity_modes(tmp_path, mode):
    base = {**TINY, "robots": 2, "steps": 30}
    generate(load_recipe(None, base), str(tmp_path / "true.zarr"), workers=1, progress=False)
    recipe = load_recipe(None, {**base, "gravity_compensation": mode, "max_attempts_factor": 50.0})
    generate(recipe, str(tmp_path / f"{mode}.zarr"), workers=1, progress=False)
    true, other = _arrays(tmp_path / "true.zarr"), _arrays(tmp_path / f"{mode}.zarr")
    tau_true = np.abs(true["u"][:, 0, 1]).min()
    tau_other = np.abs(other["u"][:, 0, 1]).max()
    if mode == "none":
        # u is the signal alone: far below the shoulder's gravity load at the first sample
        assert tau_other < 5 < tau_true
    else:
        # the catalogue robot's g(q) is in u: same order as the randomized robot's
        assert tau_other > 5


@pytest.mark.parametrize("task", ["multisine", "spiral"])
def test_one_step_trajectories_generate_and_complete(tmp_path, capsys, task):
    # --steps 1 used to fail with a numpy concatenation error and leave an in-progress
    # store that the same command could not finish.
    out = str(tmp_path / "one.zarr")
    assert main(["--task", task, "--robots", "2", "--steps", "1", "--out", out, "--quiet", "--workers", "1"]) == 0
    ds = open_store(out)
    assert ds.attrs["status"] == "complete" and ds.read("y").shape == (2, 1, 14)
    assert np.isfinite(ds.read("y")).all()


def test_out_under_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    assert main(["--task", "multisine", "--robots", "2", "--steps", "5", "--out", str(tmp_path / "afile" / "x.zarr"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "is a file" in err and len(err.strip().splitlines()) == 1


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_out_in_a_read_only_folder_is_one_line(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        assert main(["--task", "multisine", "--robots", "2", "--steps", "5", "--out", str(locked / "x.zarr"),
                     "--quiet"]) == 2
    finally:
        locked.chmod(0o755)
    err = capsys.readouterr().err
    assert "not writable" in err and len(err.strip().splitlines()) == 1


def _compensation(mode, recipe, params, q):
    """(T, 7) what the arm added to the command at each recorded joint state."""
    model = panda.build_model(recipe.substeps, recipe.dt, gravity_compensation=mode == "true_model")
    if mode == "true_model":  # the randomized robot's own g(q), through its actuators
        Randomizer(model, recipe.randomization).apply(model, params.astype(np.float64))
    data, out = mujoco.MjData(model), []
    for qt in q.astype(np.float64):
        data.qpos[:] = qt
        data.qvel[:] = 0
        mujoco.mj_forward(model, data)
        out.append((data.qfrc_gravcomp if mode == "true_model" else data.qfrc_bias)[:7].copy())
    return np.array(out) if mode != "none" else np.zeros_like(q)


@pytest.mark.parametrize("mode", ["true_model", "nominal_model", "none"])
def test_command_plus_the_gravity_compensation_is_the_total_torque(tmp_path, mode):
    """u = u_cmd + g(q) for open-loop and OSC rows (g: own, catalogue or none), within float32."""
    recipe = load_recipe(None, {**TINY, "task": {"circle": 1.0, "multisine": 1.0}, "robots": 4, "steps": 30,
                                "gravity_compensation": mode, "max_attempts_factor": 50.0})
    generate(recipe, str(tmp_path / "s.zarr"), workers=1, progress=False)
    ds = open_store(str(tmp_path / "s.zarr"))
    u, u_cmd, y, params = ds.read("u"), ds.read("u_cmd"), ds.read("y"), ds.read("params")
    assert ds.attrs["u_cmd_names"] == list(panda.U_CMD_NAMES) and mode in ds.attrs["gravity_compensation"]
    assert len(set(ds.read("task_index").tolist())) == 2  # both engines
    for row in range(len(u)):
        g = _compensation(mode, recipe, params[row], y[row, :, 7:])
        np.testing.assert_allclose(u_cmd[row] + g, u[row], atol=2e-4, rtol=0, err_msg=f"row {row}")
        if mode == "none":
            np.testing.assert_array_equal(u_cmd[row], u[row])
        else:  # the shoulder carries the arm: the compensation is far above the tolerance
            assert np.abs(g[:, 1]).min() > 5


def test_in_a_log_generate_prints_a_line_every_few_seconds_not_a_bar(tmp_path):
    """stderr a pipe (a log): lines with counts, rate and the rejections, not tqdm's carriage-return redraws."""
    env = {**os.environ, "MUJOCO_GL": "disable", "ROBOMORPH_PROGRESS_SECONDS": "0.05"}
    config = tmp_path / "small.yaml"
    config.write_text(yaml.safe_dump({"task": "multisine", "chunk": 1}))  # a chunk per robot: several updates
    done = subprocess.run([sys.executable, "-m", "robomorph.generate", "--config", str(config), "--robots", "4",
                           "--steps", "300", "--workers", "1", "--out", str(tmp_path / "s.zarr")],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("generate multisine: ")]
    assert lines and "\r" not in done.stderr, done.stderr[-2000:]
    assert any(" | attempted=" in line for line in lines)  # the bar's postfix: attempts, kept, rejections
    assert lines[-1].startswith("generate multisine: 4/4 robots in ")
