"""The hostile-user probe table: every case runs through the real CLI and must end in exit
code 2 with exactly one ``error:`` line on stderr and no traceback; then the cases where
the answer must not be silently wrong (in-sample scores, a copied training store, a partial
merge, inputs in the wrong units).

Read-only and full file systems are real ones: root ignores permission bits, so as root a
read-only or tiny tmpfs is mounted (skipped where mounting is not permitted); other users
get a ``chmod 555`` folder. A path through a regular file (ENOTDIR) and ``/proc`` need
neither.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import zarr

from robomorph.cli import main as cli_main
from tests.conftest import linear_system, tiny_fit_args, write_store

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _mount_tmpfs(path, options: str) -> bool:
    if not shutil.which("mount"):
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)],
                          capture_output=True).returncode == 0


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder nobody may write into: a read-only tmpfs as root, ``chmod 555`` otherwise."""
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() != 0:
        d.chmod(0o555)
        yield d
        d.chmod(0o755)
        return
    if not _mount_tmpfs(d, "ro,size=64k"):
        pytest.skip("root without permission to mount: no way to make a folder read-only for root")
    yield d
    subprocess.run(["umount", str(d)], capture_output=True)


@pytest.fixture
def full_dir(tmp_path):
    """A folder on a 48 KiB file system: anything larger fails with ENOSPC (root only)."""
    d = tmp_path / "full"
    d.mkdir()
    if os.geteuid() != 0 or not _mount_tmpfs(d, "size=48k"):
        pytest.skip("needs root with permission to mount a tiny tmpfs")
    yield d
    subprocess.run(["umount", str(d)], capture_output=True)


@pytest.fixture(scope="module")
def other_model(tmp_path_factory):
    """A Gaussian-head checkpoint trained on a linear store (channels u0,u1 -> y0..y2) and that store."""
    from robomorph.training.fitting import fit

    tmp = tmp_path_factory.mktemp("other")
    u, y = linear_system(24, 90, seed=3)
    store = write_store(tmp / "lin.zarr", u, y)
    result = fit(tiny_fit_args(store, tmp / "runs", "gauss", model={"gaussian": True, "loss": "nll"}))
    return result.best_ckpt, store


@pytest.fixture(scope="module")
def sim(simulated_store, tiny_checkpoint):
    """The tiny checkpoint and its own training store."""
    from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON

    return tiny_checkpoint, simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1)


def _refused(argv: list[str], capsys) -> str:
    """Runs ``robomorph <argv>``; asserts exit 2 and one ``error:`` line; returns that line."""
    code = cli_main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    assert len([line for line in lines if line.startswith("error:")]) == 1, err
    return next(line for line in lines if line.startswith("error:"))


def _eval(ckpt, data, out, *extra):
    return [str(a) for a in ("evaluate", "--ckpt", ckpt, "--data", data, "--out", out, "--baselines", "hold",
                             "--plot-trajectories", "1", "--device", "cpu", *extra)]


def _fit(store, runs_dir, *extra):
    return ["fit", "--data.stores", store, "--runs_dir", runs_dir, "--run", "x", "--data.context_len", "30",
            "--data.horizon", "60", "--data.batch_size", "8", "--model.d_model", "16", "--model.n_head", "2",
            "--model.n_layer", "1", "--model.max_context", "64", "--model.max_horizon", "64",
            "--trainer.max_steps", "2", "--trainer.enable_progress_bar", "false", "--wandb", "disabled", *extra]


def _dt_copy(store, path, dt):
    shutil.copytree(store, path)
    zarr.open_group(str(path), mode="r+").attrs["dt"] = dt
    return str(path)


# ---------------------------------------------------------------- one line, never a traceback

def test_outputs_under_a_file_or_in_proc_are_one_line(sim, other_model, tmp_path, capsys):
    ckpt, store = sim
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    assert "Not a directory" in _refused(_eval(ckpt, store, afile / "ev"), capsys)
    assert "/proc/robomorph-ev" in _refused(_eval(ckpt, store, "/proc/robomorph-ev"), capsys)
    gauss, lin = other_model
    line = _refused(["calibrate", "--ckpt", gauss, "--out", afile / "c.ckpt", "--device", "cpu"], capsys)
    assert str(afile) in line and ("Not a directory" in line or "a file where a folder is needed" in line)
    assert "Not a directory" in _refused(_fit(store, afile / "runs", "--trainer.accelerator", "cpu"), capsys)


def test_read_only_outputs_are_one_line(sim, other_model, readonly_dir, tmp_path, capsys):
    ckpt, store = sim
    gauss, _ = other_model
    line = _refused(_eval(ckpt, store, readonly_dir / "ev"), capsys)
    assert str(readonly_dir / "ev") in line and ("Read-only" in line or "Permission denied" in line)
    assert not os.path.exists(readonly_dir / "ev")
    _refused(["calibrate", "--ckpt", gauss, "--out", readonly_dir / "c.ckpt", "--device", "cpu"], capsys)
    _refused(_fit(store, readonly_dir / "runs", "--trainer.accelerator", "cpu"), capsys)
    # report: a runs folder with one evaluated run, the page asked for on the read-only folder
    runs = os.path.dirname(os.path.dirname(os.path.dirname(ckpt)))
    _refused(["report", runs, "--out", readonly_dir / "report.html"], capsys)


def test_a_full_disk_is_one_line_and_loses_nothing(sim, full_dir, capsys):
    _, store = sim
    line = _refused(["generate", "--task", "multisine", "--robots", "16", "--steps", "200", "--workers", "1",
                     "--quiet", "--out", full_dir / "g.zarr"], capsys)
    assert "No space left on device" in line and "disk is full" in line
    _refused(_fit(store, full_dir / "runs", "--trainer.accelerator", "cpu"), capsys)


@pytest.mark.parametrize("device, pattern", [("cuda", "CUDA is not available"), ("tpu9", "'tpu9' is not a device"),
                                             ("cuda:7", "CUDA")])
def test_unavailable_or_unknown_devices_are_one_line(sim, tmp_path, capsys, device, pattern):
    import torch

    if device.startswith("cuda") and torch.cuda.is_available() and device == "cuda":
        pytest.skip("this machine has CUDA")
    ckpt, store = sim
    assert pattern in _refused([*_eval(ckpt, store, tmp_path / "ev")[:-2], "--device", device], capsys)
    assert not os.path.exists(tmp_path / "ev")


@pytest.mark.parametrize("flag, pattern", [("--trainer.accelerator=gpu", "--trainer:"),
                                           ("--trainer.profiler=bogus", "profiler")])
def test_trainer_options_lightning_refuses_are_one_line(sim, tmp_path, capsys, flag, pattern):
    import torch

    if "gpu" in flag and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    _, store = sim
    assert pattern in _refused(_fit(store, tmp_path / "runs", flag), capsys)


def test_compare_name_clash_and_other_channels_are_one_line_and_write_nothing(sim, other_model, tmp_path, capsys):
    ckpt, store = sim
    gauss, _ = other_model
    out = tmp_path / "ev"
    assert "'hold' names a baseline" in _refused(_eval(ckpt, store, out, "--compare", f"hold={ckpt}"), capsys)
    assert not out.exists()
    assert "trained on other channels" in _refused(_eval(ckpt, store, out, "--compare", f"lin={gauss}"), capsys)
    assert not out.exists()  # refused before the output folder is made


def test_dollar_signs_in_channel_names_are_drawn_as_written(tmp_path, capsys):
    u, y = linear_system(4, 30)
    store = write_store(tmp_path / "d.zarr", u, y, u_names=["tau$1", "tau$2"], y_names=["p$\\frac$", "$x$", "y$"])
    assert cli_main(["inspect", store, "--plot", str(tmp_path / "d.png")]) == 0, capsys.readouterr().err
    assert (tmp_path / "d.png").stat().st_size > 0

    from robomorph.evaluation import plots

    yq = np.zeros((2, 5, 3))
    names = ["p$\\frac$", "$\\alpha", "$q_{$"]
    plots.plot_samples(str(tmp_path / "s.png"), yq, yq, {"model": yq, "m$\\frac$": yq}, names, 0.1, 0)
    plots.plot_r2_distribution(str(tmp_path / "r.png"), yq, {"model": yq}, names)
    assert (tmp_path / "s.png").exists() and (tmp_path / "r.png").exists()


def test_a_zarr_error_of_a_concurrent_writer_is_one_line(tmp_path, monkeypatch, capsys):
    import robomorph.data.store as store_module

    def taken(*args, **kwargs):  # what a second generate meets when the first created the arrays
        raise zarr.errors.ContainsArrayError("An array exists in store LocalStore at path 'u'.")

    monkeypatch.setattr(store_module, "_create_arrays", taken)
    line = _refused(["generate", "--task", "multisine", "--robots", "2", "--steps", "20", "--workers", "1", "--quiet",
                     "--out", tmp_path / "g.zarr"], capsys)
    assert "another command writing it at the same time" in line


def test_the_real_entry_point_prints_one_line(tmp_path):
    """The same contract through ``python -m robomorph`` in a fresh process."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    u, y = linear_system(4, 30)
    store = write_store(tmp_path / "s.zarr", u, y)
    proc = subprocess.run([sys.executable, "-m", "robomorph", "inspect", store, "--plot", str(afile / "p.png")],
                          capture_output=True, text=True, cwd=ROOT, env={**os.environ, "MUJOCO_GL": "disable"})
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ") and str(afile) in proc.stderr


# ---------------------------------------------------------------- nothing silently wrong

def test_evaluate_refuses_a_store_at_another_sample_time(sim, tmp_path, capsys):
    ckpt, store = sim
    other = _dt_copy(store, tmp_path / "slow.zarr", 0.02)
    line = _refused(_eval(ckpt, other, tmp_path / "ev"), capsys)
    assert "sampled at dt=0.02 s but the checkpoint was trained at dt=0.0166667 s" in line and "--resample" in line


def test_scores_on_the_training_store_or_a_copy_are_marked_in_sample(sim, tmp_path, capsys):
    ckpt, store = sim
    copy = tmp_path / "elsewhere" / "copy.zarr"
    shutil.copytree(store, copy)
    for data, out in ((store, tmp_path / "own"), (str(copy), tmp_path / "copy")):
        assert cli_main(_eval(ckpt, data, out)) == 0
        printed = capsys.readouterr().out
        assert "in-sample: this store is one the model was trained on" in printed
        meta = json.loads((out / "metrics.json").read_text())["meta"]
        assert meta["in_sample"] is True and meta["in_sample_store"] == store
        assert "In-sample" in (out / "table.md").read_text()

    from robomorph.reporting.dashboard import IN_SAMPLE_BADGE, EvalData, eval_view, overview

    metrics = json.loads((tmp_path / "copy" / "metrics.json").read_text())
    view = eval_view(EvalData("copy", metrics))
    assert any(w.startswith("In-sample:") for w in view["warnings"])
    from robomorph.reporting.dashboard import RunData

    table = overview([RunData("r", tmp_path, evals=[EvalData("copy", metrics)])])
    assert IN_SAMPLE_BADGE in table.rows[0].cells[1].badges


def test_held_out_robots_are_not_marked_in_sample(sim, simulated_store, tmp_path, capsys):
    ckpt, _ = sim
    held_out = simulated_store(robots=4, steps=90, seed=7)
    assert cli_main(_eval(ckpt, held_out, tmp_path / "ev")) == 0
    assert "in-sample" not in capsys.readouterr().out
    meta = json.loads((tmp_path / "ev" / "metrics.json").read_text())["meta"]
    assert meta["in_sample"] is False and "In-sample" not in (tmp_path / "ev" / "table.md").read_text()


def test_calibrate_refuses_a_byte_identical_copy_of_the_training_store(other_model, tmp_path, capsys):
    gauss, lin = other_model
    copy = tmp_path / "renamed.zarr"
    shutil.copytree(lin, copy)
    line = _refused(["calibrate", "--ckpt", gauss, "--data", copy, "--out", tmp_path / "c.ckpt", "--device", "cpu"],
                    capsys)
    assert "is a training store of this checkpoint" in line
    assert not (tmp_path / "c.ckpt").exists()


def _shard(tmp_path, name, index, count=2, seed=0):
    u, y = linear_system(4, 20, seed=seed)
    attrs = {"dt": 0.01, "config": {"task": "multisine"}, "shard": [index, count], "requested": 4, "attempted": 4,
             "rejected": {}}
    return write_store(tmp_path / name, u, y, attrs=attrs)


def test_a_partial_set_of_shards_is_refused_or_marked_partial(tmp_path, capsys):
    s0 = _shard(tmp_path, "s0.zarr", 0, count=3)
    s2 = _shard(tmp_path, "s2.zarr", 2, count=3, seed=2)
    out = tmp_path / "m.zarr"
    line = _refused(["merge", s0, s2, "--out", out], capsys)
    assert "shards [1] are missing" in line and "--allow-partial" in line
    assert not out.exists()
    assert cli_main(["merge", s0, s2, "--out", str(out), "--allow-partial"]) == 0
    assert "partial: shards [1] missing" in capsys.readouterr().out
    from robomorph.data.store import open_store

    attrs = open_store(str(out)).attrs
    assert attrs["partial"] is True and attrs["missing_shards"] == [1] and attrs["n"] == 8
    complete = tmp_path / "all.zarr"
    s1 = _shard(tmp_path, "s1.zarr", 1, count=3, seed=1)
    assert cli_main(["merge", s0, s1, s2, "--out", str(complete)]) == 0
    assert open_store(str(complete)).attrs["partial"] is False


# ---------------------------------------------------------------- the Python API

@pytest.fixture(scope="module")
def predictor(tiny_checkpoint):
    from robomorph.predictor import Predictor

    return Predictor.from_checkpoint(tiny_checkpoint, device="cpu")


def _arrays(p, tc=30, th=20, b=None, seed=0):
    rng = np.random.default_rng(seed)
    shape = (lambda t, c: (t, c)) if b is None else (lambda t, c: (b, t, c))
    nz = p.model.normalizer
    u = lambda t: (nz.u_mean.numpy() + nz.u_std.numpy() * rng.normal(size=shape(t, p.n_u))).astype(np.float32)  # noqa: E731
    y = (nz.y_mean.numpy() + nz.y_std.numpy() * rng.normal(size=shape(tc, p.n_y))).astype(np.float32)
    return u(tc), y, u(th)


@pytest.mark.parametrize("case", ["empty_context", "horizon_0", "not_a_patch_multiple", "batches_differ",
                                  "over_the_tables"])
def test_simulate_refuses_bad_shapes_with_prediction_error(predictor, case):
    from robomorph.core.errors import RoboMorphError
    from robomorph.predictor import PredictionError

    u_ctx, y_ctx, u_q = _arrays(predictor, b=2)
    if case == "empty_context":
        u_ctx, y_ctx = u_ctx[:, :0], y_ctx[:, :0]
    elif case == "horizon_0":
        u_q = u_q[:, :0]
    elif case == "not_a_patch_multiple":
        u_ctx, y_ctx = u_ctx[:, :-1], y_ctx[:, :-1]
    elif case == "batches_differ":
        u_q = u_q[:1]
    else:
        u_ctx, y_ctx, u_q = _arrays(predictor, tc=30, th=predictor.model.config.max_horizon + 5, b=2)
    with pytest.raises(PredictionError) as info:
        predictor.simulate(u_ctx, y_ctx, u_q)
    assert isinstance(info.value, RoboMorphError) and isinstance(info.value, ValueError)


def test_simulate_refuses_inputs_far_outside_the_training_range(predictor):
    from robomorph.predictor import MAX_INPUT_STDS, PredictionError

    u_ctx, y_ctx, u_q = _arrays(predictor)
    assert predictor.simulate(u_ctx, y_ctx, u_q).shape == (20, predictor.n_y)  # in range: answered
    nz = predictor.model.normalizer
    wrong_units = nz.u_mean.numpy() + (u_q - nz.u_mean.numpy()) * 1000  # mN m given for N m
    with pytest.raises(PredictionError, match=r"training standard deviations \(channel .*refused above 100"):
        predictor.simulate(u_ctx, y_ctx, wrong_units)
    assert MAX_INPUT_STDS == 100
    predictor.max_input_std = None  # the documented way out
    try:
        assert np.isfinite(predictor.simulate(u_ctx, y_ctx, wrong_units)).all()
    finally:
        predictor.max_input_std = MAX_INPUT_STDS
