import csv
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from robomorph.inference.checkpoint import CheckpointError, load_checkpoint_file
from robomorph.predictor import Predictor
from robomorph.training.fitting import fit
from robomorph.training.module import MetaModule
from tests.conftest import tiny_fit_args


@pytest.fixture(scope="module")
def store(simulated_store):
    return simulated_store(robots=40, steps=60, seed=1, chunk=20)


def _args(store, runs, run, steps=30, **extra):
    # This file's settings over the shared tiny model: the default patch, a faster lr, offline wandb.
    args = tiny_fit_args(store, runs, run, steps,
                         data={"context_len": 20, "horizon": 40, "val_subset": 8},
                         model={"patch": 10, "lr": 3e-3, "warmup_steps": 5},
                         trainer={"val_check_interval": 10})
    args["wandb"] = "offline"
    for key, value in extra.items():
        args[key].update(value)
    return args


def _log(run_dir, key):
    with open(os.path.join(run_dir, "logs", "metrics.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r.get(key)]
    return [(int(r["step"]), float(r[key])) for r in rows]


@pytest.fixture(scope="module")
def trained(store, tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    return fit(_args(store, runs, "base", steps=60)), runs


def test_fit_lowers_the_loss_and_writes_the_run(trained):
    result, _ = trained
    for rel in ("config.yaml", "checkpoints/last.ckpt", "checkpoints/best.ckpt", "logs/metrics.csv", "wandb"):
        assert os.path.exists(os.path.join(result.run_dir, rel)), rel
    losses = [v for _, v in _log(result.run_dir, "train/loss")]
    assert np.mean(losses[-2:]) < 0.7 * np.mean(losses[:2])
    assert {"val/loss", "val/r2", "val/fit"} <= set(result.metrics)
    assert result.global_step == 60
    assert _log(result.run_dir, "lr") and _log(result.run_dir, "val/r2")


def test_resume_continues_at_the_saved_step(store, tmp_path):
    first = fit(_args(store, tmp_path, "r", steps=20))
    assert load_checkpoint_file(first.last_ckpt)["global_step"] == 20
    second = fit(_args(store, tmp_path, "r", steps=40))  # same run: resumes from last.ckpt
    assert second.global_step == 40
    steps = [s for s, _ in _log(second.run_dir, "train/loss")]
    # one log across the resume: the first run's rows kept, no step logged twice
    assert min(steps) < 20 and max(steps) >= 30 and steps == sorted(set(steps))
    assert _log(second.run_dir, "val/loss")[0][0] < 20
    ckpt = load_checkpoint_file(second.last_ckpt)
    assert ckpt["global_step"] == 40 and ckpt["optimizer_states"][0]["state"]  # optimizer state carried
    # the schedule continued: the logged lr after resuming is not the warmup's start value
    lr_after = [v for s, v in _log(second.run_dir, "lr") if s > 20]
    assert lr_after and lr_after[0] < 3e-3 + 1e-12 and lr_after[0] > 3e-3 * 0.1 - 1e-12


def test_transfer_loads_weights_and_freeze_freezes(trained, store, tmp_path):
    base, _ = trained
    tuned = fit(_args(store, tmp_path, "ft", steps=10,
                      model={"init_ckpt": base.best_ckpt, "freeze": "all_but_head", "lr": 1e-2,
                             "normalization_from": "source"}))
    src = load_checkpoint_file(base.best_ckpt)["state_dict"]
    dst = load_checkpoint_file(tuned.last_ckpt)["state_dict"]
    frozen = [k for k in src if k.startswith("net.") and not k.startswith("net.head")]
    assert frozen and all(torch.equal(src[k], dst[k]) for k in frozen)
    assert any(not torch.equal(src[k], dst[k]) for k in src if k.startswith("net.head"))
    assert torch.equal(src["normalizer.y_mean"], dst["normalizer.y_mean"])  # the pretrained normalization


@pytest.fixture(scope="module")
def other_store(linear_store):
    return linear_store(n=20, steps=60, n_u=2, n_y=3)


def test_transfer_to_other_channels_needs_reinit_io(trained, other_store, tmp_path):
    base, _ = trained
    with pytest.raises(CheckpointError, match="reinit_io"):
        fit(_args(other_store, tmp_path, "bad", steps=2, model={"init_ckpt": base.best_ckpt}))
    ok = fit(_args(other_store, tmp_path, "io", steps=2, model={"init_ckpt": base.best_ckpt, "reinit_io": True}))
    assert ok.global_step == 2


@pytest.mark.slow
def test_ddp_with_two_cpu_processes(store, tmp_path):
    cmd = [sys.executable, "-m", "robomorph.fit", "--data.stores", store, "--data.context_len", "20",
           "--data.horizon", "40", "--data.batch_size", "4", "--data.val_subset", "8", "--model.d_model", "16",
           "--model.n_head", "2", "--model.n_layer", "1", "--trainer.max_steps", "6",
           "--trainer.val_check_interval", "3", "--trainer.accelerator", "cpu", "--trainer.devices", "2",
           "--trainer.strategy", "ddp", "--trainer.enable_progress_bar", "false", "--run", "ddp",
           "--runs_dir", str(tmp_path), "--wandb", "disabled"]
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ckpt = load_checkpoint_file(str(tmp_path / "ddp" / "checkpoints" / "last.ckpt"))
    assert ckpt["global_step"] == 6


def test_shipped_training_config_parses():
    proc = subprocess.run([sys.executable, "-m", "robomorph.fit", "--config", "datamodules/train_cpu.yaml",
                           "--print_config"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "patch: 10" in proc.stdout and "recenter: true" in proc.stdout


def test_invalid_model_config_is_refused(store, tmp_path):
    with pytest.raises(ValueError, match="n_head"):
        fit(_args(store, tmp_path, "bad", steps=1, model={"d_model": 18, "n_head": 4}))


def test_freeze_encoder_trains_only_the_rest(trained, store, tmp_path):
    base, _ = trained
    tuned = fit(_args(store, tmp_path, "fe", steps=10, model={"init_ckpt": base.best_ckpt, "freeze": "encoder", "lr": 1e-2}))
    src = load_checkpoint_file(base.best_ckpt)["state_dict"]
    dst = load_checkpoint_file(tuned.last_ckpt)["state_dict"]
    enc = [k for k in src if k.startswith("net.enc")]
    dec = [k for k in src if k.startswith("net.dec")]
    assert enc and dec and all(torch.equal(src[k], dst[k]) for k in enc)
    assert any(not torch.equal(src[k], dst[k]) for k in dec)


def test_training_step_predictions_never_see_the_query_outputs(store, tmp_path):
    # End to end through the LightningModule, with per-trajectory recentring on: changing
    # y_query changes the target and the loss, never the prediction.
    result = fit(_args(store, tmp_path, "rc", steps=5, data={"recenter": True}))
    module = MetaModule.load_from_checkpoint(result.last_ckpt, map_location="cpu").eval()
    assert module.hparams.recenter
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y = torch.as_tensor(ds.read("u", slice(0, 4))), torch.as_tensor(ds.read("y", slice(0, 4)))
    batch = {"u_ctx": u[:, :20], "y_ctx": y[:, :20], "u_query": u[:, 20:60], "y_query": y[:, 20:60]}
    poisoned = {**batch, "y_query": batch["y_query"] * 10 + 5}
    with torch.no_grad():
        loss, pred, target = module._step(batch)
        loss2, pred2, target2 = module._step(poisoned)
    assert torch.equal(pred, pred2)
    assert not torch.allclose(target, target2) and loss2 > loss


def test_issue11_options_train_end_to_end_and_never_see_the_query_outputs(store, tmp_path):
    # Initial-condition tokens, anchor, Gaussian head with NLL, horizon weights, random
    # lengths and offsets: fit runs, the checkpoint predicts a mean and a std, and poisoned
    # y_query changes the loss only.
    result = fit(_args(store, tmp_path, "all", steps=6,
                       data={"recenter": True, "context_min": 10, "horizon_min": 5, "window": "random"},
                       model={"n_init": 10, "anchor": True, "gaussian": True, "loss": "nll", "horizon_weight": 2.0}))
    pred = Predictor.from_checkpoint(result.last_ckpt, device="cpu")
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y = torch.as_tensor(ds.read("u", slice(0, 4))), torch.as_tensor(ds.read("y", slice(0, 4)))
    mean, std = pred.simulate(u[:, :20], y[:, :20], u[:, 20:60], return_std=True)
    assert mean.shape == std.shape == (4, 40, 14) and (std > 0).all() and torch.isfinite(mean).all()
    batch = {"u_ctx": u[:, :20], "y_ctx": y[:, :20], "u_query": u[:, 20:60], "y_query": y[:, 20:60]}
    poisoned = {**batch, "y_query": batch["y_query"] * 10 + 5}
    module = MetaModule.load_from_checkpoint(result.last_ckpt, map_location="cpu").eval()
    with torch.no_grad():
        loss, p1, _ = module._step(batch)
        loss2, p2, _ = module._step(poisoned)
    assert torch.equal(p1, p2) and loss2 > loss


def test_ckpt_path_last_resumes_a_named_run(store, tmp_path):
    fit(_args(store, tmp_path, "named", steps=10))
    args = _args(store, tmp_path, "named", steps=20)
    args["ckpt_path"] = "last"
    assert fit(args).global_step == 20


def _stats(ckpt):
    sd = load_checkpoint_file(ckpt)["state_dict"]
    return {k: sd[f"normalizer.{k}"].numpy() for k in ("u_mean", "u_std", "y_mean", "y_std")}


def _train_stats(path):
    from robomorph.data.datamodule import RoboMorphDataModule

    dm = RoboMorphDataModule(stores=path, context_len=20, horizon=40, batch_size=8, val_subset=8)
    dm.setup("fit")
    return dm.stats


@pytest.fixture(scope="module")
def scaled_store(tmp_path_factory, other_store):
    """other_store's channels with values far from mean 0, std 1 (a real arm's torques)."""
    from robomorph.data.store import create_store, open_store

    src = open_store(other_store)
    path = str(tmp_path_factory.mktemp("scaled") / "s.zarr")
    w = create_store(path, src.n, src.steps, src.u_names, src.y_names, [], {"dt": src.dt})
    w.append(src.read("u") * 5 - 6, src.read("y") * 3 + 2, np.zeros((src.n, 0), np.float32))
    w.finalize()
    return path


def test_reinit_io_takes_the_statistics_of_the_new_data(trained, other_store, tmp_path):
    # It used to keep mean 0, std 1 for every channel: the source's "statistics ready"
    # flag came along while its statistics (other channels) were dropped.
    base, _ = trained
    ok = fit(_args(other_store, tmp_path, "io", steps=2, model={"init_ckpt": base.best_ckpt, "reinit_io": True}))
    got, want = _stats(ok.last_ckpt), _train_stats(other_store)
    np.testing.assert_allclose(got["u_std"], want.u_std, rtol=1e-5)
    np.testing.assert_allclose(got["y_mean"], want.y_mean, rtol=1e-5, atol=1e-6)
    assert not np.allclose(got["u_std"], 1.0)
    with pytest.raises(CheckpointError, match="normalization_from"):
        fit(_args(other_store, tmp_path, "io-src", steps=2,
                  model={"init_ckpt": base.best_ckpt, "reinit_io": True, "normalization_from": "source"}))


def test_same_channels_take_the_statistics_the_user_chooses(other_store, scaled_store, tmp_path):
    src = fit(_args(other_store, tmp_path, "src", steps=2))
    target = fit(_args(scaled_store, tmp_path, "tgt", steps=2, model={"init_ckpt": src.last_ckpt}))
    kept = fit(_args(scaled_store, tmp_path, "kept", steps=2,
                     model={"init_ckpt": src.last_ckpt, "normalization_from": "source"}))
    want = _train_stats(scaled_store)
    np.testing.assert_allclose(_stats(target.last_ckpt)["u_mean"], want.u_mean, rtol=1e-5)  # the default
    for k in ("u_mean", "u_std", "y_mean", "y_std"):
        np.testing.assert_array_equal(_stats(kept.last_ckpt)[k], _stats(src.last_ckpt)[k])


@pytest.fixture(scope="module")
def paper_window(store, tmp_path_factory):
    runs = tmp_path_factory.mktemp("pw")
    return fit(_args(store, runs, "pw", steps=5, data={"normalization": "paper_window"}))


def _window_batch(store, n=4):
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y = torch.as_tensor(ds.read("u", slice(0, n))), torch.as_tensor(ds.read("y", slice(0, n)))
    return {"u_ctx": u[:, :20], "y_ctx": y[:, :20], "u_query": u[:, 20:60], "y_query": y[:, 20:60]}


def test_paper_window_is_recorded_and_its_predictions_see_the_query_outputs(paper_window, store):
    # The paper's protocol, as documented: poisoning the query outputs changes the prediction.
    ckpt = load_checkpoint_file(paper_window.last_ckpt)
    assert ckpt["hyper_parameters"]["normalization"] == "paper_window"
    module = MetaModule.load_from_checkpoint(paper_window.last_ckpt, map_location="cpu").eval()
    batch = _window_batch(store)
    with torch.no_grad():
        _, pred, _ = module._step(batch)
        _, pred2, _ = module._step({**batch, "y_query": batch["y_query"] * 10 + 5})
        yhat = module.normalizer.decode(pred, batch["y_ctx"], module._query_stats(batch))
    assert not torch.allclose(pred, pred2)
    assert torch.isfinite(yhat).all() and yhat.shape == batch["y_query"].shape


def test_predictor_refuses_paper_window_without_the_query_statistics(paper_window, trained, store):
    from robomorph.core.normalizations import NormalizationError, query_output_stats

    pred = Predictor.from_checkpoint(paper_window.last_ckpt, device="cpu")
    assert pred.normalization == "paper_window" and pred.leaks_query_statistics
    b = {k: v.numpy() for k, v in _window_batch(store).items()}
    with pytest.raises(NormalizationError, match="a deployed model cannot know"):
        pred.simulate(b["u_ctx"], b["y_ctx"], b["u_query"])
    y = pred.simulate(b["u_ctx"], b["y_ctx"], b["u_query"], y_query_stats=query_output_stats(b["y_query"]))
    poisoned = pred.simulate(b["u_ctx"], b["y_ctx"], b["u_query"],
                             y_query_stats=query_output_stats(b["y_query"] * 10 + 5))
    assert y.shape == b["y_query"].shape and not np.allclose(y, poisoned)
    # unbatched, with (n_y,) statistics
    single = pred.simulate(b["u_ctx"][1], b["y_ctx"][1], b["u_query"][1],
                           y_query_stats=query_output_stats(b["y_query"][1]))
    np.testing.assert_allclose(single, y[1], atol=1e-5)
    with pytest.raises(NormalizationError, match="must be finite"):
        pred.simulate(b["u_ctx"], b["y_ctx"], b["u_query"], y_query_stats=(np.zeros(3), np.ones(3)))
    base = Predictor.from_checkpoint(trained[0].best_ckpt, device="cpu")
    assert base.normalization == "train_stats" and not base.leaks_query_statistics
    with pytest.raises(NormalizationError, match="drop y_query_stats"):
        base.simulate(b["u_ctx"], b["y_ctx"], b["u_query"], y_query_stats=query_output_stats(b["y_query"]))


def test_paper_window_refuses_recenter_and_transfer_across_protocols(paper_window, trained, store, tmp_path):
    from robomorph.core.normalizations import NormalizationError

    with pytest.raises(NormalizationError, match="recenter"):
        fit(_args(store, tmp_path, "both", steps=1, data={"normalization": "paper_window", "recenter": True}))
    with pytest.raises(CheckpointError, match="normalization 'train_stats'"):
        fit(_args(store, tmp_path, "cross", steps=1, data={"normalization": "paper_window"},
                  model={"init_ckpt": trained[0].best_ckpt}))


def test_a_rerun_of_a_run_says_nothing_about_its_folders(store, tmp_path, recwarn, capfd):
    """Re-running fit on a run resumes it: its checkpoint and log folders exist by design, so Lightning's
    "directory exists and is not empty" warnings are noise (issue 61 §4) and are not shown; other warnings are."""
    fit(_args(store, tmp_path, "again", steps=10))
    capfd.readouterr()
    recwarn.clear()
    assert fit(_args(store, tmp_path, "again", steps=20)).global_step == 20
    said = [str(w.message) for w in recwarn] + capfd.readouterr().err.splitlines()
    assert not [s for s in said if "exists and is not empty" in s], said
    assert not [s for s in said if "unclosed file" in s and "wandb_id" in s], said  # the id is read and closed
