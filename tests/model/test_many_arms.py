"""One model for several arms: a 6-joint UR5e store and a 7-joint Panda store in one run.

The model's channels are the Panda's (the UR5e's are a subset by name); UR5e windows are
padded with NaN, which the network reads as absent and the loss skips; statistics are per
channel role; the Predictor takes either arm's own arrays; unmappable channels are refused.
"""

import importlib.util
import math

import numpy as np
import pytest
import torch

from robomorph.core.channels import ChannelError, union
from robomorph.data.datamodule import DataError, RoboMorphDataModule
from robomorph.data.statistics import Stats
from robomorph.data.store import open_store
from robomorph.inference.predictor import Predictor
from robomorph.model.transformer import MetaModel, ModelConfig
from robomorph.training.losses import horizon_weights, masked_loss
from tests.conftest import tiny_fit_args, write_store

pytestmark = pytest.mark.skipif(importlib.util.find_spec("robosuite") is None,
                                reason="robosuite (the `arms` extra) is not installed")

CTX, H = 20, 40  # windows of 60 steps (patch 5)
PANDA_U = [f"tau{i}" for i in range(7)]
PANDA_Y = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]


@pytest.fixture(scope="module")
def stores(simulated_store) -> dict[str, str]:
    return {robot: simulated_store(robots=8, steps=CTX + H, seed=3, robot=robot) for robot in ("ur5e", "panda")}


@pytest.fixture(scope="module")
def trained(stores, tmp_path_factory):
    from robomorph.training.fitting import fit

    args = tiny_fit_args([stores["ur5e"], stores["panda"]], tmp_path_factory.mktemp("runs"), "arms", steps=4,
                         data={"context_len": CTX, "horizon": H})
    return fit(args)


def _dm(stores, order=("ur5e", "panda"), **kw) -> RoboMorphDataModule:
    dm = RoboMorphDataModule(stores=[stores[r] for r in order], context_len=CTX, horizon=H, batch_size=4,
                             **{"split": (0.8, 0.2, 0.0), **kw})
    dm.setup("fit")
    return dm


def test_channel_set_is_the_widest_arms_and_statistics_are_per_role(stores):
    dm = _dm(stores)
    assert dm.u_names == PANDA_U and dm.y_names == PANDA_Y and dm.channel_mask
    assert dm.layouts[0]["u_names"] == PANDA_U[:6] and len(dm.layouts) == 2
    assert union([PANDA_U[:6], PANDA_U]) == PANDA_U
    # Each channel's statistics over the training trajectories of the stores that have it.
    arrays = {}
    for k, robot in enumerate(("ur5e", "panda")):
        ds, rows = open_store(stores[robot]), dm.splits[k]["train"]
        arrays[robot] = (ds.read("u")[rows, :CTX + H], ds.read("y")[rows, :CTX + H])
    shared = Stats.from_arrays(np.concatenate([arrays["ur5e"][0], arrays["panda"][0][..., :6]]),
                               np.concatenate([arrays["ur5e"][1], arrays["panda"][1][..., :13]]))
    panda = Stats.from_arrays(*arrays["panda"])
    np.testing.assert_allclose(dm.stats.u_mean[:6], shared.u_mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(dm.stats.u_std[:6], shared.u_std, rtol=1e-9)
    np.testing.assert_allclose(dm.stats.y_std[:13], shared.y_std, rtol=1e-9)
    # tau6 and q6: the Panda's alone (a column index would have mixed in the UR5e's zeros)
    np.testing.assert_allclose(dm.stats.u_mean[6], panda.u_mean[6], rtol=1e-9)
    np.testing.assert_allclose(dm.stats.y_std[13], panda.y_std[13], rtol=1e-9)
    assert not math.isclose(dm.stats.u_std[0], panda.u_std[0], rel_tol=1e-3)  # both arms did count
    # the order of the stores changes nothing (all trajectories in training: the same ones either way)
    both = [_dm(stores, order=order, split=(1.0, 0.0, 0.0)) for order in (("ur5e", "panda"), ("panda", "ur5e"))]
    assert both[1].u_names == PANDA_U
    np.testing.assert_allclose(both[1].stats.u_std, both[0].stats.u_std, rtol=1e-9)


def test_windows_of_the_smaller_arm_are_padded_with_the_absent_mark(stores):
    dm = _dm(stores)
    by_store = {int(s): k for k, (s, _) in enumerate(dm.train_set.pairs)}
    ur, pa = dm.train_set[by_store[0]], dm.train_set[by_store[1]]
    assert ur["u_ctx"].shape == (CTX, 7) and ur["y_query"].shape == (H, 14)
    assert torch.isnan(ur["u_ctx"][:, 6]).all() and torch.isnan(ur["y_query"][:, 13]).all()
    assert torch.isfinite(ur["u_ctx"][:, :6]).all() and torch.isfinite(ur["y_ctx"][:, :13]).all()
    assert all(torch.isfinite(v).all() for v in pa.values())
    # one arm alone: nothing padded, no mask (single-arm runs are unchanged)
    single = RoboMorphDataModule(stores=stores["panda"], context_len=CTX, horizon=H, batch_size=4)
    assert not single.channel_mask and single.u_names == PANDA_U


def test_absent_outputs_do_not_change_the_loss():
    g = torch.Generator().manual_seed(0)
    pred, target = torch.randn(3, H, 14, generator=g, requires_grad=True), torch.randn(3, H, 14, generator=g)
    target[0, :, 13] = float("nan")  # trajectory 0 is a 6-joint arm's
    w = horizon_weights(H, 1.0, 10.0)
    loss = masked_loss("huber", pred, None, target, w)
    other = pred.detach().clone()
    other[0, :, 13] += 100.0  # whatever the network predicts for the absent channel
    assert torch.equal(masked_loss("huber", other, None, target, w), loss.detach())
    other[1, :, 13] += 100.0  # a present channel does count (the test can fail)
    assert not torch.equal(masked_loss("huber", other, None, target, w), loss.detach())
    loss.backward()
    assert torch.isfinite(pred.grad).all() and (pred.grad[0, :, 13] == 0).all()
    # the mean over the present entries, as if the absent channel had never been there
    present = ~torch.isnan(target)
    by_hand = (torch.nn.functional.huber_loss(pred, target.nan_to_num(), reduction="none") * w[:, None])[present]
    assert torch.allclose(loss, by_hand.mean())


def test_the_network_reads_the_absent_mask():
    torch.manual_seed(0)
    net = MetaModel(ModelConfig(n_u=7, n_y=14, d_model=16, n_head=2, n_layer=1, patch=5, max_context=64,
                                max_horizon=64, channel_mask=True)).eval()
    uc, yc, uq = torch.randn(2, CTX, 7), torch.randn(2, CTX, 14), torch.randn(2, H, 7)
    uc[0, :, 6], yc[0, :, 13], uq[0, :, 6] = float("nan"), float("nan"), float("nan")
    out = net(uc, yc, uq)
    assert out.shape == (2, H, 14) and torch.isfinite(out).all()
    zeros = net(uc.nan_to_num(), yc.nan_to_num(), uq.nan_to_num())
    assert not torch.allclose(out[0], zeros[0])  # a missing channel is not a measured 0
    assert torch.allclose(out[1], zeros[1])  # the full trajectory beside it is untouched
    assert "encoder.absent.weight" in dict(net.named_parameters())
    assert "encoder.absent.weight" not in dict(MetaModel(ModelConfig()).named_parameters())  # old checkpoints load


def test_one_model_predicts_both_arms_with_their_shapes(stores, trained):
    pred = Predictor.from_checkpoint(trained.best_ckpt, device="cpu")
    assert (pred.n_u, pred.n_y, pred.model.config.channel_mask) == (7, 14, True)
    assert np.isfinite(trained.metrics["val/loss"])
    arrays = {r: (open_store(s).read("u")[:3], open_store(s).read("y")[:3]) for r, s in stores.items()}
    u, y = arrays["ur5e"]
    out = pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:])
    assert out.shape == (3, H, 13) and np.isfinite(out).all()
    one = pred.simulate(u[0, :CTX], y[0, :CTX], u[0, CTX:])  # unbatched
    np.testing.assert_allclose(one, out[0], rtol=1e-5, atol=1e-6)
    # naming the channels gives the same prediction as finding them by width
    pred.channels = (PANDA_U[:6], PANDA_Y[:13])
    np.testing.assert_allclose(pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:]), out, rtol=1e-6)
    pred.channels = None
    u, y = arrays["panda"]
    assert pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:]).shape == (3, H, 14)


def test_channels_the_model_cannot_map_are_refused_in_one_line(stores, trained, tmp_path, capsys):
    from robomorph.evaluate import main as evaluate_main

    pred = Predictor.from_checkpoint(trained.best_ckpt, device="cpu")
    u, y = open_store(stores["ur5e"]).read("u")[:2], open_store(stores["ur5e"]).read("y")[:2]
    with pytest.raises(ChannelError, match="no layout this model was trained on") as info:
        pred.simulate(u[:, :CTX, :5], y[:, :CTX, :12], u[:, CTX:, :5])
    assert "\n" not in str(info.value)
    pred.channels = (PANDA_U[:5] + ["wrist_tau"], PANDA_Y[:13])
    with pytest.raises(ChannelError, match=r"\['wrist_tau'\] that the model cannot map"):
        pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:])
    # the data side: a store whose names are not all in the widest store's
    ds = open_store(stores["ur5e"])
    odd = write_store(tmp_path / "odd.zarr", ds.read("u"), ds.read("y"), y_names=PANDA_Y[:12] + ["gripper"],
                      u_names=PANDA_U[:6], attrs={"dt": ds.dt})
    with pytest.raises(DataError, match=r"disagree on y_names.*odd\.zarr"):
        _dm({"ur5e": odd, "panda": stores["panda"]})
    # through the command: one line on stderr, exit code 2
    code = evaluate_main(["--ckpt", trained.best_ckpt, "--data", odd, "--out", str(tmp_path / "eval"),
                          "--context-len", str(CTX), "--horizon", str(H), "--baselines", "none"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "cannot map" in err and "gripper" in err and len(err.splitlines()) == 1


def test_the_many_arm_model_fine_tunes_on_one_arm_with_its_channel_set(stores, trained, tmp_path):
    from robomorph.training.fitting import fit

    args = tiny_fit_args(stores["ur5e"], tmp_path, "ft", steps=2, data={
        "context_len": CTX, "horizon": H, "channels": {"u": PANDA_U, "y": PANDA_Y}},
        model={"init_ckpt": trained.best_ckpt})
    pred = Predictor.from_checkpoint(fit(args).best_ckpt, device="cpu")
    assert (pred.n_u, pred.n_y, pred.model.config.channel_mask) == (7, 14, True)
    u, y = open_store(stores["ur5e"]).read("u")[:2], open_store(stores["ur5e"]).read("y")[:2]
    assert pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:]).shape == (2, H, 13)


def test_joint_dropout_hides_the_last_joint_of_some_training_windows_only(stores):
    plain = RoboMorphDataModule(stores=stores["panda"], context_len=CTX, horizon=H, batch_size=4)
    plain.setup("fit")
    dm = RoboMorphDataModule(stores=stores["panda"], context_len=CTX, horizon=H, batch_size=4, joint_dropout=0.5)
    dm.setup("fit")
    assert dm.channel_mask and not plain.channel_mask
    assert {"u_names": PANDA_U[:6], "y_names": PANDA_Y[:13]} in dm.layouts and len(dm.layouts) == 2
    keys, plain_keys = list(dm.train_sampler), list(plain.train_sampler)
    assert [k[:4] for k in keys] == plain_keys  # the same windows: the flag is drawn after the rest
    assert {k[4] for k in keys} == {True, False}
    again = RoboMorphDataModule(stores=stores["panda"], context_len=CTX, horizon=H, batch_size=4, joint_dropout=0.5)
    again.setup("fit")
    assert list(again.train_sampler) == keys  # seeded
    for key, plain_key in zip(keys, plain_keys):
        w, p = dm.train_set[key], plain.train_set[plain_key]
        hidden = torch.isnan(w["u_ctx"][:, 6]).all() and torch.isnan(w["y_query"][:, 13]).all()
        assert bool(hidden) == key[4]
        assert torch.equal(w["u_query"][:, :6], p["u_query"][:, :6]) and torch.equal(w["y_ctx"][:, :13], p["y_ctx"][:, :13])
    assert not any(torch.isnan(dm.val_set[i]["y_query"]).any() for i in range(len(dm.val_set)))
    with pytest.raises(DataError, match="joint_dropout must be a probability"):
        RoboMorphDataModule(stores=stores["panda"], joint_dropout=1.0)


def test_a_model_of_seven_joint_arms_with_joint_dropout_reads_a_six_joint_arm(stores, tmp_path):
    from robomorph.training.fitting import fit

    args = tiny_fit_args(stores["panda"], tmp_path, "jd", steps=3,
                         data={"context_len": CTX, "horizon": H, "joint_dropout": 0.3})
    pred = Predictor.from_checkpoint(fit(args).best_ckpt, device="cpu")
    assert pred.model.config.channel_mask
    u, y = open_store(stores["ur5e"]).read("u")[:3], open_store(stores["ur5e"]).read("y")[:3]
    out = pred.simulate(u[:, :CTX], y[:, :CTX], u[:, CTX:])
    assert out.shape == (3, H, 13) and np.isfinite(out).all()


def test_fine_tuning_the_many_arm_model_keeps_its_channel_set(stores, trained, tmp_path):
    from robomorph.training.fitting import fit
    from robomorph.training.pretrained import inherited_channels

    full = {"u": PANDA_U, "y": PANDA_Y}
    assert inherited_channels(trained.best_ckpt, False, [stores["panda"]], "total") == full
    assert inherited_channels(trained.best_ckpt, False, [stores["ur5e"]], "total") == full
    assert inherited_channels(trained.best_ckpt, True, [stores["panda"]], "total") is None  # new channels asked for
    # a 7-joint arm (no padding of its own) fine-tunes in the model's set: nothing re-initialized
    args = tiny_fit_args(stores["panda"], tmp_path, "ft-7", steps=2, model={"init_ckpt": trained.best_ckpt},
                         data={"context_len": CTX, "horizon": H})
    pred = Predictor.from_checkpoint(fit(args).best_ckpt, device="cpu")
    assert pred.model.config.channel_mask and (pred.n_u, pred.n_y) == (7, 14)
    assert pred.data_info["u_names"] == PANDA_U
    # a single-arm model passes nothing on
    single = tiny_fit_args(stores["panda"], tmp_path, "single", steps=2, data={"context_len": CTX, "horizon": H})
    assert inherited_channels(fit(single).best_ckpt, False, [stores["ur5e"]], "total") is None
