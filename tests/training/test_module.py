"""The LightningModule on its own: schedule, freezing, the context check, argument checks."""

import math

import pytest
import torch

from robomorph.core.errors import RoboMorphError
from robomorph.training.module import MetaModule, _lr_factor

TINY = {"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "n_layer": 1, "patch": 5, "max_context": 40, "max_horizon": 40}


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
