"""The hostile probe of the newer commands (issue 56): ``control``, ``export`` and model
folders, ``evaluate``'s output folder, the ``Predictor``'s arrays and settings, and the
control section of ``report``.

Each test names the probe's case it covers. A refusal is one ``error:`` line with exit code 2,
no traceback, and leaves every file as it was.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import threading

import numpy as np
import pytest

from robomorph.control import cli as control_cli
from robomorph.core.locks import exclusive
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, linear_system, tiny_fit_args, write_store

# A control run of the catalogue OSC alone on one robot, a few frames long: seconds.
QUICK = ["--controllers", "osc", "--robots", "1", "--warmup", "0.1", "--duration", "0.1", "--workers", "1"]


def _files(root) -> dict[str, bytes | None]:
    """Every path under ``root`` with its bytes (None for folders, the target for links)."""
    seen = {}
    for folder, dirs, names in os.walk(root):
        for n in dirs + names:
            p = os.path.join(folder, n)
            seen[p] = os.readlink(p).encode() if os.path.islink(p) else (
                open(p, "rb").read() if os.path.isfile(p) else None)
    return seen


def _call(main, argv, capsys) -> tuple[int, str]:
    """``main(argv)``'s exit code (a parser's SystemExit too) and its stderr."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return int(code or 0), capsys.readouterr().err


def _one_error(code: int, err: str, *phrases: str) -> str:
    assert code == 2 and "Traceback" not in err, (code, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    return lines[0]


@pytest.fixture
def no_episodes(monkeypatch):
    """Fails a test whose control run gets as far as running episodes."""
    def refuse(*_a, **_k):
        raise AssertionError("episodes ran before the output folder was checked")

    monkeypatch.setattr(control_cli, "_episodes", refuse, raising=False)
    monkeypatch.setattr("robomorph.control.runner.run_job", refuse)


def _eval_folder(path) -> dict:
    path.mkdir(parents=True)
    (path / "metrics.json").write_text(json.dumps({"approach1": {}, "meta": {"n": 3}}))
    (path / "table.md").write_text("# another command's table\n")
    return _files(path)


def test_control_refuses_another_commands_folder_before_any_episode(tmp_path, capsys, no_episodes):
    """Case 2: ``control --out`` an evaluation folder replaced its metrics.json and table.md."""
    before = _eval_folder(tmp_path / "ev")
    code, err = _call(control_cli.main, [*QUICK, "--out", str(tmp_path / "ev")], capsys)
    _one_error(code, err, "evaluation folder", "choose another --out")
    assert _files(tmp_path / "ev") == before


def test_control_refuses_a_folder_another_run_writes(tmp_path, capsys, no_episodes):
    """Case 3: two ``control`` runs on one --out both exited 0 and the first's results were lost."""
    out = tmp_path / "ctl"
    with exclusive(out, "output folder"):
        code, err = _call(control_cli.main, [*QUICK, "--out", str(out)], capsys)
    _one_error(code, err, "being written by another process")
    assert not out.exists()


def test_writers_of_folders_refuse_a_zarr_store(tmp_path, capsys, tiny_checkpoint, simulated_store, no_episodes):
    """Case 4: ``control --out STORE/control``, ``export --out STORE/model`` and ``evaluate --out
    STORE`` wrote into a Zarr store."""
    from robomorph import evaluate, export

    u, y = linear_system(4, 20)
    store = write_store(tmp_path / "s.zarr", u, y)
    before = _files(store)
    code, err = _call(control_cli.main, [*QUICK, "--out", os.path.join(store, "control")], capsys)
    _one_error(code, err, "Zarr store")
    code, err = _call(export.main, ["--ckpt", tiny_checkpoint, "--out", os.path.join(store, "model")], capsys)
    _one_error(code, err, "Zarr store")
    test = str(tmp_path / "t.zarr")  # a copy of the training store: the one store the checkpoint takes
    shutil.copytree(simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1), test)
    before_t = _files(test)
    code, err = _call(evaluate.main, ["--ckpt", tiny_checkpoint, "--data", test, "--out", test,
                                      "--baselines", "hold", "--plot-trajectories", "0"], capsys)
    _one_error(code, err, "Zarr store")
    assert _files(store) == before and _files(test) == before_t


def test_export_through_a_link_keeps_the_link_and_leaves_nothing_beside_it(tmp_path, capsys, tiny_checkpoint):
    """Case 5: ``export --out LINK`` replaced the link by a folder and left ``.LINK.<pid>.old``."""
    from robomorph import export

    (tmp_path / "real").mkdir()
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "real", target_is_directory=True)
    code, err = _call(export.main, ["--ckpt", tiny_checkpoint, "--out", str(link)], capsys)
    assert code == 0, err
    assert link.is_symlink() and sorted(os.listdir(tmp_path / "real")) == ["config.json", "model.safetensors"]
    assert sorted(n for n in os.listdir(tmp_path) if not n.endswith((".lock", ".holder"))) == ["link", "real"]


def test_a_full_disk_during_control_leaves_no_half_written_folder(tmp_path, capsys, monkeypatch):
    """Case 6: a full disk while ``control`` wrote left the half-written folder."""
    from robomorph.control import outputs

    def full(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "ctl" / "paths.png"))

    monkeypatch.setattr(outputs, "plot_paths", full)
    code, err = _call(control_cli.main, [*QUICK, "--out", str(tmp_path / "ctl")], capsys)
    _one_error(code, err, "No space left")
    assert not (tmp_path / "ctl").exists()
    assert [n for n in os.listdir(tmp_path) if not n.endswith((".lock", ".holder"))] == []


@pytest.mark.parametrize("args, phrase", [
    (["--controllers", "osc,osc"], "more than once"),  # case 7
    (["--noise", "inf"], "--noise"),  # case 8
    (["--noise", "nan"], "--noise"),
    (["--temperature", "inf"], "--temperature"),
    (["--plan-substeps", "1000000"], "--plan-substeps"),
    (["--physics-mode", "bogus"], "--physics-mode"),
    (["--robots", "1000000000"], "--robots"),  # case 17
    (["--warmup", "inf"], "--warmup"),
    (["--duration", "inf"], "--duration"),
    (["--duration", "1e9"], "--duration"),
    (["--seed", "-1"], "--seed"),
])
def test_control_options_are_checked_at_parsing(args, phrase, tmp_path, capsys, no_episodes):
    """Cases 7, 8 and 17: duplicated controllers ran every episode twice; non-finite or huge
    numbers and an unknown physics mode were accepted (or raised a traceback)."""
    code, err = _call(control_cli.main, [*QUICK, *args, "--out", str(tmp_path / "ctl")], capsys)
    _one_error(code, err, phrase)
    assert not (tmp_path / "ctl").exists()


def test_a_context_between_patches_is_refused_for_a_decoder(tiny_checkpoint):
    """Case 16: ``control --context-len 37`` on a black-box model was cut to 35 without a word."""
    from robomorph.control.dynamics import ControlError
    from robomorph.control.runner import ControlConfig
    from robomorph.inference.predictor import Predictor

    p = Predictor.from_checkpoint(tiny_checkpoint)
    p.inputs = "command"  # the rest of the checks are what the test is about
    p.n_u, p.n_y = 7, 14
    patch = p.model.config.patch
    context = 4 * patch + 2
    with pytest.raises(ControlError, match=f"multiple of {patch}"):
        control_cli.check_model(p, ControlConfig(context=context, warmup=2.0, duration=0.5), "m")
    control_cli.check_model(p, ControlConfig(context=4 * patch, warmup=2.0, duration=0.5), "m")


def test_zero_seconds_is_refused_as_a_horizon():
    """Case 16: ``--horizons 0s`` became step 1, although ``--horizons 0`` is refused."""
    from robomorph.evaluation.horizons import parse_horizons

    with pytest.raises(Exception, match="0s"):
        parse_horizons("0s", 60, 1 / 60)


def test_ctrl_c_during_control_stops_cleanly(tmp_path, capsys, monkeypatch):
    """Case 18: a Ctrl-C during ``control`` printed a KeyboardInterrupt traceback."""
    def interrupt(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr("robomorph.control.runner.run_job", interrupt)
    code, err = _call(control_cli.main, [*QUICK, "--out", str(tmp_path / "ctl")], capsys)
    assert code == 130 and "Traceback" not in err and err.startswith("stopped by Ctrl-C"), err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "ctl").exists()


def test_control_writes_its_folder_and_may_replace_its_own(tmp_path, capsys):
    """The writer's own earlier folder is replaced whole (cases 2-6 refuse only others')."""
    out = tmp_path / "ctl"
    for _ in range(2):
        code, err = _call(control_cli.main, [*QUICK, "--out", str(out)], capsys)
        assert code == 0, err
    assert sorted(os.listdir(out)) == ["errors.png", "metrics.json", "paths.png", "table.md"]


# -- the dashboard's control section ------------------------------------------------------------

def _control_folder(path) -> None:
    path.mkdir()
    (path / "metrics.json").write_text(json.dumps({"osc": {"ee_rms_mm": 1.0, "episodes": 1, "failed_episodes": 0},
                                                   "_config": {"task": "circle", "controllers": ["osc"]}}))


def test_the_control_section_never_embeds_a_file_outside_its_folder(tmp_path):
    """Case 1 (security): ``report --control DIR`` embedded a PNG linked from outside the folder."""
    from robomorph.reporting.control_view import control_view

    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG\r\n\x1a\nSECRET")
    _control_folder(tmp_path / "ctl")
    (tmp_path / "ctl" / "errors.png").symlink_to(secret)
    view = control_view(tmp_path / "ctl")
    assert view["figures"] == []
    assert any("outside the control folder" in w for w in view["warnings"]), view["warnings"]


def test_a_control_metrics_file_of_another_shape_is_a_warning(tmp_path):
    """Case 22: ``report --control DIR`` whose metrics.json is a list raised AttributeError."""
    from robomorph.reporting.control_view import control_view

    (tmp_path / "ctl").mkdir()
    (tmp_path / "ctl" / "metrics.json").write_text("[1, 2]")
    view = control_view(tmp_path / "ctl")
    assert view["table"] is None and any("list" in w for w in view["warnings"]), view


# -- model files --------------------------------------------------------------------------------

def _exported(tmp_path, ckpt) -> str:
    from robomorph.model.files import export

    out = str(tmp_path / "model")
    export(ckpt, out)
    return out


def _edit_config(folder: str, edit) -> None:
    path = os.path.join(folder, "config.json")
    config = json.load(open(path))
    edit(config)
    open(path, "w").write(json.dumps(config))


@pytest.mark.parametrize("edit, phrase", [
    (lambda c: c.update(weights="x"), "SHA-256"),
    (lambda c: c["weights"].pop("sha256"), "SHA-256"),
])
def test_a_model_folder_without_its_digest_is_refused(edit, phrase, tmp_path, tiny_checkpoint):
    """Case 20: ``"weights": "x"`` raised AttributeError; deleting ``weights.sha256`` skipped the
    integrity check."""
    from robomorph.inference.checkpoint import CheckpointError
    from robomorph.inference.predictor import Predictor

    folder = _exported(tmp_path, tiny_checkpoint)
    _edit_config(folder, edit)
    with pytest.raises(CheckpointError, match=phrase):
        Predictor.from_pretrained(folder)


@pytest.mark.parametrize("key, value", [("d_model", 10**9), ("max_context", 10**9), ("n_layer", 10**6),
                                        ("max_context", 10**6)])
def test_declared_sizes_are_checked_before_the_network_is_built(key, value, tmp_path, tiny_checkpoint):
    """Case 20: sizes such as d_model 10^9 built the network before the weights were checked."""
    import hashlib

    from robomorph.inference.checkpoint import CheckpointError
    from robomorph.inference.predictor import Predictor

    folder = _exported(tmp_path, tiny_checkpoint)
    digest = hashlib.sha256(open(os.path.join(folder, "model.safetensors"), "rb").read()).hexdigest()
    _edit_config(folder, lambda c: (c["hyper_parameters"].update({key: value}), c["weights"].update(sha256=digest)))
    done: list = []
    worker = threading.Thread(target=lambda: done.append(_refusal(Predictor.from_pretrained, folder)), daemon=True)
    worker.start()
    worker.join(60)
    assert done and isinstance(done[0], CheckpointError), done


def _refusal(fn, *args):
    try:
        fn(*args)
    except Exception as exc:  # noqa: BLE001  (the test inspects which)
        return exc
    return None


def test_a_refused_pickle_never_relays_the_advice_to_load_it_unsafely(tmp_path):
    """Case 28: a refused pickle was "not a readable checkpoint (corrupt or truncated?)" with
    torch's advice to re-run with ``weights_only=False``."""
    import torch

    from robomorph.model.files import CheckpointError, load_checkpoint_file

    class Payload:
        def __reduce__(self):
            return (os.getcwd, ())

    path = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": {}, "x": Payload()}, path)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint_file(str(path))
    text = str(info.value)
    assert "not allowed" in text and "weights_only" not in text and "corrupt" not in text, text


# -- the Predictor's arrays and settings ----------------------------------------------------------

def _window(p, batch: int = 2, tc: int = CKPT_CONTEXT, th: int = CKPT_HORIZON):
    n = p.model.normalizer
    rng = np.random.default_rng(1)
    u = (n.u_mean.numpy() + n.u_std.numpy() * rng.standard_normal((batch, tc + th, p.n_u))).astype(np.float32)
    y = (n.y_mean.numpy() + n.y_std.numpy() * rng.standard_normal((batch, tc, p.n_y))).astype(np.float32)
    return u[:, :tc], y, u[:, tc:]


def test_context_outputs_in_the_wrong_units_are_refused(tiny_checkpoint):
    """Case 12: context outputs x1000 (a unit error) gave plausible outputs."""
    from robomorph.inference.predictor import PredictionError, Predictor

    p = Predictor.from_checkpoint(tiny_checkpoint)
    u_ctx, y_ctx, u_q = _window(p)
    assert p.simulate(u_ctx, y_ctx, u_q).shape == (2, CKPT_HORIZON, p.n_y)
    with pytest.raises(PredictionError, match="context outputs"):
        p.simulate(u_ctx, y_ctx * 1000, u_q)


@pytest.mark.parametrize("cut, phrase", [
    (lambda u, y, q: (u[:, :0], y[:, :0], q), "no time steps"),
    (lambda u, y, q: (u, y[:1], q), "windows"),
    (lambda u, y, q: (u, y, q[:, :0]), "no time steps"),
    (lambda u, y, q: (u[:, :-5], y, q), "steps but y_ctx"),
])
def test_arrays_of_the_wrong_size_are_prediction_errors(cut, phrase, tiny_checkpoint):
    """Cases 11 and 19: an empty context, mismatched batch sizes (IndexError) and a query of
    zero steps (one step returned)."""
    from robomorph.inference.predictor import PredictionError, Predictor

    p = Predictor.from_checkpoint(tiny_checkpoint)
    with pytest.raises(PredictionError, match=phrase):
        p.simulate(*cut(*_window(p)))


@pytest.fixture(scope="module")
def hybrid_predictor(simulated_store, tmp_path_factory):
    from robomorph.inference.predictor import Predictor
    from robomorph.training.fitting import fit

    store = simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=3)
    args = tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "hybrid", steps=3,
                         data={"inputs": "command"}, model={"physics": "amortized", "anchor": True})
    return Predictor.from_checkpoint(fit(args).best_ckpt)


@pytest.mark.parametrize("setting, value", [("mode", None), ("mode", "bogus"), ("members", 0), ("members", -1),
                                            ("samples", 0), ("substeps", 0), ("workers", 1.5), ("observer", "yes"),
                                            ("points", "sigma"), ("bogus", 1)])
def test_the_hybrids_settings_are_checked(setting, value, hybrid_predictor):
    """Cases 11 and 19: ``physics_members`` 0 or -1 behaved like 1; ``physics_mode = None``
    raised a TypeError. Each is refused in one line naming it where it is set, and the settings stay."""
    from robomorph.inference.predictor import PredictionError

    p = hybrid_predictor
    kept = p.settings
    with pytest.raises(PredictionError, match=setting) as exc:
        p.configure(**{setting: value})
    assert "\n" not in str(exc.value) and p.settings is kept
    p.simulate(*_window(p, batch=1))  # still predicts with the settings it had


def test_the_hybrids_query_of_zero_steps_is_refused(hybrid_predictor):
    """Case 11: the hybrid's simulate with a query of zero steps returned one step."""
    from robomorph.inference.predictor import PredictionError

    u, y, q = _window(hybrid_predictor, batch=1)
    with pytest.raises(PredictionError, match="no time steps"):
        hybrid_predictor.simulate(u, y, q[:, :0])


# -- ingest ---------------------------------------------------------------------------------------

def _log(tmp_path, n: int = 400) -> str:
    t = np.arange(n) * 0.001
    path = tmp_path / "log.npz"
    np.savez(path, t=t, tau1=np.sin(7 * t), q1=np.cos(5 * t))
    return str(path)


def test_a_sample_time_that_overflows_the_time_axis_is_refused(tmp_path, capsys):
    """Case 14: ``ingest --dt 1e308`` was accepted and the time axis overflowed to inf."""
    from robomorph.ingest import main

    out = tmp_path / "s.zarr"
    code, err = _call(main, [_log(tmp_path), "--u-cols", "tau1", "--y-cols", "q1", "--dt", "1e308", "--steps", "50",
                             "--out", str(out)], capsys)
    _one_error(code, err, "--dt")
    assert not out.exists()


def test_an_upsampling_rate_beyond_the_ratio_limit_is_refused(tmp_path, capsys):
    """Case 21: ``ingest --resample 1e9``: the ratio's limit applied to its denominator only."""
    from robomorph.ingest import main

    out = tmp_path / "s.zarr"
    code, err = _call(main, [_log(tmp_path), "--u-cols", "tau1", "--y-cols", "q1", "--dt", "0.001", "--steps", "50",
                             "--resample", "1e9", "--out", str(out)], capsys)
    _one_error(code, err, "cannot resample")
    assert not out.exists()


def test_dollars_in_channel_names_and_units_are_drawn_verbatim(tmp_path):
    """Case 25: ``$`` in a channel name or unit crashed evaluate's error-growth plot (mathtext)."""
    from robomorph.evaluation.plots import plot_error_growth

    rng = np.random.default_rng(0)
    y = rng.standard_normal((3, 20, 2))
    path = plot_error_growth(str(tmp_path / "growth.png"), y, {"model": y + 0.1}, 0.01, ["q$1", "cost $\\frac"],
                             [1, 10], ["$\\alpha", "k$"])
    assert os.path.getsize(path) > 0


def test_inspect_names_a_chunk_whose_bytes_were_flipped(tmp_path, capsys):
    """Case 26: ``inspect`` of a store with a flipped chunk exited 0 and never named the chunk."""
    from robomorph.inspect import main

    u, y = linear_system(8, 50)
    store = write_store(tmp_path / "s.zarr", u, y)
    chunk = os.path.join(store, "y", "c", "0", "0", "0")
    data = bytearray(open(chunk, "rb").read())
    data[len(data) // 2] ^= 0x01  # same length: only its checksum tells
    open(chunk, "wb").write(bytes(data))
    code, err = _call(main, [store], capsys)
    _one_error(code, err, "'y' chunk c/0/0/0", "checksum")


# -- full disks -----------------------------------------------------------------------------------

@pytest.fixture
def small_disk(tmp_path):
    """A folder on a 160 KiB file system: a tiny run's logs fit, its checkpoint does not (root only)."""
    import subprocess

    d = tmp_path / "small"
    d.mkdir()
    mounted = shutil.which("mount") and os.geteuid() == 0 and subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=160k", "tmpfs", str(d)], capture_output=True).returncode == 0
    if not mounted:
        pytest.skip("needs root with permission to mount a tiny tmpfs")
    yield d
    subprocess.run(["umount", str(d)], capture_output=True)


def test_a_torch_file_on_a_full_disk_is_one_line_and_leaves_nothing(small_disk):
    """Case 23: torch's zip writer reported a full disk as ``RuntimeError: unexpected pos``
    (``fit``'s checkpoints and ``calibrate --out`` write through this one writer)."""
    import torch

    from robomorph.core.errors import FileSystemError
    from robomorph.model.files import save_torch

    with pytest.raises(FileSystemError, match="disk full"):
        save_torch({"w": torch.zeros(200_000)}, str(small_disk / "x.ckpt"))
    assert os.listdir(small_disk) == []


def test_fit_on_a_full_disk_is_one_line(small_disk, simulated_store, capsys):
    """Case 23: ``fit`` on a full disk ended in ``RuntimeError: unexpected pos`` from torch's zip writer."""
    from robomorph import fit

    store = simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1)
    argv = ["--data.stores", store, "--data.context_len", str(CKPT_CONTEXT), "--data.horizon", str(CKPT_HORIZON),
            "--data.batch_size", "8", "--data.val_subset", "4", "--model.d_model", "64", "--model.n_head", "2",
            "--model.n_layer", "2", "--model.patch", "5", "--model.max_context", "64", "--model.max_horizon", "64",
            "--trainer.max_steps", "2", "--trainer.val_check_interval", "2", "--trainer.accelerator", "cpu",
            "--run", "full", "--runs_dir", str(small_disk), "--wandb", "disabled"]
    code, err = _call(fit.main, argv, capsys)
    errors = [line for line in err.splitlines() if line.startswith("error: ")]  # after fit's progress lines
    assert code == 2 and "Traceback" not in err and len(errors) == 1 and "disk full" in errors[0], err


@pytest.mark.parametrize("setting, phrase", [("trainer.profiler=bogus", "--trainer"),
                                             ("trainer.accelerator=gpu", "--trainer")])
def test_a_trainer_setting_lightning_refuses_stops_a_sweep_in_one_line(setting, phrase, simulated_store, tmp_path):
    """Case 24: ``sweep`` with ``trainer.profiler: bogus`` or ``trainer.accelerator: gpu`` in a
    space ended in a MisconfigurationException traceback (the runner caught RuntimeError only)."""
    import torch

    import subprocess
    import sys

    if "gpu" in setting and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    store = simulated_store(robots=40, steps=90, seed=1)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    res = subprocess.run([sys.executable, "-m", "robomorph", "sweep", os.path.join(root, "sweeps", "ci.yaml"),
                          "--n-trials", "1", "--storage", f"sqlite:///{tmp_path / 's.db'}", "--runs-dir",
                          str(tmp_path / "runs"), "--wandb", "disabled", "--set", f"data.stores={store}", "--set",
                          setting], capture_output=True, text=True, timeout=600, cwd=root)
    code, err = res.returncode, res.stderr
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert code == 2 and "Traceback" not in err and len(errors) == 1 and phrase in errors[0], err


@pytest.mark.parametrize("args", [["--train-robots", "4"], ["--minutes", "inf"], ["--robots", "0"]])
def test_demo_options_are_checked_before_anything_runs(args, capsys, monkeypatch):
    """Case 27: ``demo --train-robots 4`` failed after about 60 s with advice to pass ``--data``,
    a flag the demo does not have."""
    from robomorph import demo

    def refuse(*_a, **_k):
        raise AssertionError("the demo ran before its options were checked")

    monkeypatch.setattr(demo.demo, "run_demo", refuse)
    code, err = _call(demo.main, args, capsys)
    _one_error(code, err, args[0])


def _interrupted(args: list[str], started) -> tuple[int, str]:
    """Runs ``robomorph ARGS`` in its own process group, sends it a Ctrl-C (SIGINT to the whole
    group, as a terminal does) once ``started()`` holds, and returns its exit code and stderr."""
    import signal
    import subprocess
    import sys
    import time

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-m", "robomorph", *args], cwd=root, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "MUJOCO_GL": "disable", "WANDB_MODE": "disabled"})
    deadline = time.monotonic() + 240
    while not started() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def test_ctrl_c_during_generate_stops_cleanly_and_the_store_resumes(tmp_path):
    """Case 18: a Ctrl-C during ``generate`` printed KeyboardInterrupt tracebacks (its workers' too)."""
    out = tmp_path / "g.zarr"
    code, err = _interrupted(["generate", "--robots", "400", "--steps", "400", "--workers", "2", "--out", str(out),
                              "--quiet"], lambda: (out / "zarr.json").exists())
    assert code == 130 and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert [line for line in err.splitlines() if line.strip()][-1].startswith("stopped by Ctrl-C: ")
    assert "resume" in err


def test_ctrl_c_during_control_with_workers_stops_cleanly(tmp_path):
    """Case 18: a Ctrl-C during ``control`` (episodes in worker processes) printed tracebacks."""
    out = tmp_path / "ctl"
    code, err = _interrupted(["control", "--controllers", "osc,mpc:nominal_physics", "--robots", "4", "--workers",
                              "2", "--out", str(out)],
                             lambda: any(n.startswith(".ctl.") and n.endswith(".tmp") for n in os.listdir(tmp_path)))
    assert code == 130 and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert not out.exists() and not [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]


# -- one arm's model on another arm ----------------------------------------------------------------

def test_fit_records_the_arms_it_trained_on(tiny_checkpoint):
    """Cases 9 and 10: what lets control and evaluate tell a model's arm (a Panda store here)."""
    from robomorph.inference.predictor import Predictor

    assert Predictor.from_checkpoint(tiny_checkpoint).data_info["arms"] == ["panda"]


def test_control_refuses_a_model_of_another_arm(tiny_checkpoint):
    """Case 9: a Kinova3 model planned the Panda (``control --controllers mpc:model``)."""
    from robomorph.control.dynamics import ControlError
    from robomorph.control.runner import ControlConfig
    from robomorph.inference.predictor import Predictor

    p = Predictor.from_checkpoint(tiny_checkpoint)
    p.inputs, p.n_u, p.n_y = "command", 7, 14  # the checks before the arm's pass
    p.data_info = {**p.data_info, "arms": ["kinova3"]}
    with pytest.raises(ControlError, match="kinova3"):
        control_cli.check_model(p, ControlConfig(context=4 * p.model.config.patch, warmup=2.0, duration=0.5), "m")


def test_evaluate_refuses_a_store_of_another_arm(tiny_checkpoint, simulated_store, tmp_path, capsys):
    """Case 10: ``evaluate`` of a Panda model on a Kinova3 store said nothing (719 mm at step 1)."""
    import zarr

    from robomorph import evaluate

    test = str(tmp_path / "kinova.zarr")
    shutil.copytree(simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1), test)
    zarr.open_group(test, mode="r+").attrs["domain"] = "kinova3"  # the channels have the same names
    code, err = _call(evaluate.main, ["--ckpt", tiny_checkpoint, "--data", test, "--out", str(tmp_path / "ev"),
                                      "--baselines", "hold", "--plot-trajectories", "0"], capsys)
    _one_error(code, err, "kinova3", "panda")
    assert not (tmp_path / "ev").exists()


def test_a_store_holding_training_robots_is_in_sample(tiny_checkpoint, simulated_store, tmp_path):
    """Case 15: a store generated with the training seed and more robots holds the training
    robots bit for bit; ``evaluate`` reported ``in_sample: false`` (the fingerprint was of the
    whole store)."""
    from robomorph.evaluation.evaluator import in_sample
    from robomorph.inference.predictor import Predictor

    info = Predictor.from_checkpoint(tiny_checkpoint).data_info
    more = simulated_store(robots=30, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1)
    assert in_sample(info, more)["in_sample"]
    other = simulated_store(robots=30, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=2)
    assert not in_sample(info, other)["in_sample"]


@pytest.mark.parametrize("scale, refused", [(180 / np.pi, True), (1.0, False)])
def test_joint_angles_in_degrees_are_refused_for_an_arm_layout(scale, refused, tmp_path, capsys):
    """Case 13: ``ingest --layout panda`` of joint angles in degrees (up to 106 "rad") was
    accepted, and the EE pose computed from them looked plausible."""
    from robomorph.ingest import main

    n = 300
    t = np.arange(n) * 0.01
    home = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
    q = (home + 0.3 * np.sin(t)[:, None]) * scale
    cols = {**{f"tau{k}": np.sin(t + k) for k in range(7)}, **{f"q{k}": q[:, k] for k in range(7)}}
    log = tmp_path / "panda.npz"
    np.savez(log, **cols)
    out = tmp_path / "s.zarr"
    code, err = _call(main, [str(log), "--u-cols", ",".join(f"tau{k}" for k in range(7)), "--y-cols",
                             ",".join(f"q{k}" for k in range(7)), "--dt", "0.01", "--steps", "50", "--layout", "panda",
                             "--out", str(out)], capsys)
    if refused:
        _one_error(code, err, "degrees")
        assert not out.exists()
    else:
        assert code == 0, err


def test_the_dashboard_leaves_out_an_evaluation_being_written(tiny_checkpoint, tmp_path):
    """Cases 2-6: an evaluation is written in a hidden folder beside its target until complete;
    the dashboard shows finished evaluations only."""
    from pathlib import Path

    from robomorph.reporting.dashboard import load_run

    run = tmp_path / "runs" / "r"
    shutil.copytree(Path(tiny_checkpoint).parents[1], run)
    (run / "eval" / ".store.123.tmp").mkdir(parents=True)
    (run / "eval" / ".store.123.tmp" / "table.md").write_text("half\n")
    assert load_run(run).evals == []
