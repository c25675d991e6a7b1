"""The LightningModule on its own: schedule, freezing, the context check, argument checks;
its losses, horizon weights, Gaussian output in physical units, and loading checkpoints
written before those options existed."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

from robomorph.core.errors import RoboMorphError
from robomorph.data.statistics import Stats
from robomorph.inference.checkpoint import INTEGRATE_SCALE, CheckpointError, predict_normalized_dist
from robomorph.predictor import Predictor
from robomorph.training.losses import elementwise_loss, horizon_weights
from robomorph.training.module import MetaModule, _lr_factor

TINY = {"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "n_layer": 1, "patch": 5, "max_context": 40, "max_horizon": 40}
DATA = os.path.join(os.path.dirname(__file__), "data")
STATS = Stats(np.array([0.5, -1.0]), np.array([2.0, 0.5]), np.array([0.1, 0.2, -0.3]), np.array([0.3, 1.5, 0.7]))


def _module(**kw) -> MetaModule:
    torch.manual_seed(0)
    m = MetaModule(**{"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "n_layer": 1, "patch": 2,
                      "max_context": 32, "max_horizon": 32, **kw}).eval()
    m.normalizer.set_stats(STATS)
    m.stats_ready.fill_(True)
    return m


def _batch(B=2, Tc=12, Th=9, seed=1) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {"u_ctx": torch.randn(B, Tc, 2, generator=g), "y_ctx": torch.randn(B, Tc, 3, generator=g),
            "u_query": torch.randn(B, Th, 2, generator=g), "y_query": torch.randn(B, Th, 3, generator=g)}


def _normalized(m: MetaModule, uc, yc, uq):
    """The module's normalized mean and log-variance, as its training step computes them."""
    return predict_normalized_dist(m.net, m.hparams.anchor, uc, yc, uq, m.hparams.integrate)


def _predictor(m: MetaModule, tmp_path) -> Predictor:
    """The module as inference sees it: written as a checkpoint, read back without Lightning."""
    path = str(tmp_path / "module.ckpt")
    torch.save({"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams)}, path)
    return Predictor.from_checkpoint(path, device="cpu")


def test_gaussian_nll_equals_a_hand_computation():
    m = _module(gaussian=True, loss="nll")
    pred = torch.tensor([[[1.0, 0.0, -2.0]]])
    logvar = torch.tensor([[[math.log(4.0), 0.0, math.log(0.25)]]])
    target = torch.tensor([[[3.0, 1.0, -2.5]]])
    # 0.5 * (log var + (y - mu)^2 / var + log(2 pi)), channel by channel
    hand = [0.5 * (math.log(4.0) + 4.0 / 4.0 + math.log(2 * math.pi)),
            0.5 * (0.0 + 1.0 + math.log(2 * math.pi)),
            0.5 * (math.log(0.25) + 0.25 / 0.25 + math.log(2 * math.pi))]
    torch.testing.assert_close(elementwise_loss(m.hparams.loss, pred, logvar, target)[0, 0], torch.tensor(hand))
    # The training loss is its mean over steps and channels (uniform horizon weights).
    b = _batch()
    with torch.no_grad():
        loss, mean, target = m._step(b)
        _, logvar = _normalized(m, *m.normalizer.encode(b["u_ctx"], b["y_ctx"], b["u_query"]))
    by_hand = 0.5 * (logvar + (target - mean) ** 2 / logvar.exp() + math.log(2 * math.pi))
    torch.testing.assert_close(loss, by_hand.mean())


def test_horizon_weights_favour_the_first_steps_and_weight_the_loss():
    m = _module(loss="mse", horizon_weight=4.0, horizon_tau=3.0)
    w = horizon_weights(9, m.hparams.horizon_weight, m.hparams.horizon_tau)
    t = torch.arange(9.0)
    hand = (1 + 4 * torch.exp(-t / 3)) / (1 + 4 * torch.exp(-t / 3)).mean()
    torch.testing.assert_close(w, hand)
    assert (w[1:] < w[:-1]).all()
    b = _batch()
    with torch.no_grad():
        loss, pred, target = m._step(b)
    torch.testing.assert_close(loss, (((pred - target) ** 2) * hand[:, None]).mean())
    torch.testing.assert_close(horizon_weights(9, _module().hparams.horizon_weight, 60.0), torch.ones(9))


def test_bad_loss_options_are_refused():
    with pytest.raises(RoboMorphError, match="gaussian=true"):
        MetaModule(loss="nll")
    with pytest.raises(RoboMorphError, match="loss must be one of"):
        MetaModule(loss="l1")
    with pytest.raises(RoboMorphError, match="horizon_tau"):
        MetaModule(horizon_tau=0)


def test_random_context_lengths_drop_the_oldest_steps_to_a_multiple_of_patch():
    m = _module(anchor=True, n_init=4)
    b = _batch(Tc=13)
    cut = {**b, "u_ctx": b["u_ctx"][:, 1:], "y_ctx": b["y_ctx"][:, 1:]}
    with torch.no_grad():
        torch.testing.assert_close(m._step(b)[1], m._step(cut)[1])


def test_predictor_std_is_in_physical_units(tmp_path):
    m = _module(gaussian=True, loss="nll", anchor=True, n_init=2, recenter=True)
    b = _batch()
    pred = _predictor(m, tmp_path)
    assert pred.has_std
    mean, std = pred.simulate(b["u_ctx"].numpy(), b["y_ctx"].numpy(), b["u_query"].numpy(), return_std=True)
    assert mean.shape == std.shape == (2, 9, 3) and (std > 0).all()
    np.testing.assert_allclose(mean, pred.simulate(b["u_ctx"].numpy(), b["y_ctx"].numpy(), b["u_query"].numpy()))
    with torch.no_grad():
        _, logvar = _normalized(m, *m.normalizer.encode(b["u_ctx"], b["y_ctx"], b["u_query"]))
    np.testing.assert_allclose(std, (torch.exp(0.5 * logvar) * torch.tensor(STATS.y_std).float()).numpy(), rtol=1e-5)
    single = pred.simulate(b["u_ctx"][0], b["y_ctx"][0], b["u_query"][0], return_std=True)
    torch.testing.assert_close(single[1], torch.as_tensor(std[0]))
    with pytest.raises(CheckpointError, match="no Gaussian head"):
        _predictor(_module(), tmp_path).simulate(b["u_ctx"], b["y_ctx"], b["u_query"], return_std=True)


def test_a_checkpoint_from_before_the_new_options_predicts_as_before():
    # pre_issue11.ckpt was written by the code of commit 5b37644 (recenter and anchor on,
    # patch 2) together with its predictions for fixed inputs (pre_issue11.npz).
    ref = np.load(os.path.join(DATA, "pre_issue11.npz"))
    pred = Predictor.from_checkpoint(os.path.join(DATA, "pre_issue11.ckpt"), device="cpu")
    assert not pred.has_std
    out = pred.simulate(ref["u_ctx"], ref["y_ctx"], ref["u_query"])
    np.testing.assert_allclose(out, ref["y_query"], rtol=0, atol=1e-6)


def test_integrate_sums_small_changes_from_the_last_context_output_causally():
    m = _module(integrate=True, n_init=2)
    b = _batch(Th=12)
    uc, yc, uq = m.normalizer.encode(b["u_ctx"], b["y_ctx"], b["u_query"])
    with torch.no_grad():
        raw = m.net(uc, yc, uq)
        pred = _normalized(m, uc, yc, uq)[0]
        uq2 = uq.clone()
        uq2[:, 6:] += 1.0  # patch 2: steps 6.. are patches 3..
        pred2 = _normalized(m, uc, yc, uq2)[0]
    torch.testing.assert_close(pred, yc[:, -1:] + INTEGRATE_SCALE * raw.cumsum(dim=1))
    torch.testing.assert_close(pred[:, 0], yc[:, -1] + INTEGRATE_SCALE * raw[:, 0])
    torch.testing.assert_close(pred[:, :6], pred2[:, :6])
    assert (pred[:, 6:] - pred2[:, 6:]).abs().amax() > 1e-4


def test_std_under_the_paper_window_protocol_scales_by_each_window():
    from robomorph.model.normalization import query_stats

    m = _module(gaussian=True, loss="nll", normalization="paper_window")
    b = _batch()
    qs = query_stats(b["y_query"])
    with torch.no_grad():
        mean, std = m.forward_dist(b["u_ctx"], b["y_ctx"], b["u_query"], qs)
        uc, yc, uq = m.normalizer.encode(b["u_ctx"], b["y_ctx"], b["u_query"], qs)
        _, logvar = _normalized(m, uc, yc, uq)
    window_std = torch.cat([b["y_ctx"], b["y_query"]], dim=1).std(dim=1, unbiased=False, keepdim=True)
    torch.testing.assert_close(std, torch.exp(0.5 * logvar) * window_std)
    torch.testing.assert_close(mean, m(b["u_ctx"], b["y_ctx"], b["u_query"], qs))


def test_lr_warms_up_linearly_then_decays_by_cosine_to_the_floor():
    warmup, total, floor = 10, 110, 0.1
    assert [_lr_factor(s, warmup, total, floor) for s in (0, 4, 9)] == [0.1, 0.5, 1.0]
    assert _lr_factor(10, warmup, total, floor) == pytest.approx(1.0)
    assert _lr_factor(60, warmup, total, floor) == pytest.approx(floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi / 2)))
    assert _lr_factor(110, warmup, total, floor) == pytest.approx(floor)
    assert _lr_factor(500, warmup, total, floor) == pytest.approx(floor)  # flat after the decay


@pytest.mark.parametrize("freeze, trainable", [
    ("none", {"encoder", "decoder", "head"}),
    ("encoder", {"decoder", "head"}),
    ("all_but_head", {"head"}),
])
def test_freeze_leaves_only_the_named_parts_trainable(freeze, trainable):
    module = MetaModule(**TINY, freeze=freeze)
    assert {n.split(".")[0] for n, p in module.net.named_parameters() if p.requires_grad} == trainable


def test_the_context_must_fit_the_patches_and_the_positional_table():
    assert MetaModule(**TINY, context_len=30).hparams.context_len == 30
    with pytest.raises(RoboMorphError, match="context_len 32 is not a multiple of --model.patch 5"):
        MetaModule(**TINY, context_len=32)
    with pytest.raises(RoboMorphError, match="max_context"):
        MetaModule(**TINY, context_len=45)


@pytest.mark.parametrize("bad, match", [({"loss": "l1"}, "loss"), ({"freeze": "decoder"}, "freeze"),
                                        ({"lr": 0.0}, "lr > 0"), ({"min_lr_ratio": 2.0}, "min_lr_ratio")])
def test_invalid_training_arguments_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        MetaModule(**{**TINY, **bad})


def test_forward_is_the_normalized_network_decoded():
    torch.manual_seed(0)
    module = MetaModule(**TINY).eval()
    u, y, q = torch.randn(2, 10, 2), torch.randn(2, 10, 3), torch.randn(2, 7, 2)
    with torch.no_grad():
        # identity statistics: the prediction is the network's output itself
        torch.testing.assert_close(module(u, y, q), module.net(u, y, q))
    assert module(u, y, q).shape == (2, 7, 3)


def test_without_channel_counts_there_is_no_network():
    module = MetaModule(d_model=16, n_head=2, n_layer=1)
    assert module.net is None and module.normalizer is None
