"""A residual MetaModel: the prior as decoder input, a zero correction untrained, causality, old models unchanged."""

from __future__ import annotations

import pytest
import torch

from robomorph.core.config import ConfigError
from robomorph.inference.checkpoint import predict_normalized_dist
from robomorph.model.transformer import MetaModel, ModelConfig

CFG = dict(n_u=2, n_y=3, d_model=16, n_head=2, n_layer=1, patch=5, max_context=40, max_horizon=40)


def _inputs(seed: int = 0, b: int = 2, tc: int = 20, th: int = 17):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, tc, 2, generator=g), torch.randn(b, tc, 3, generator=g),
            torch.randn(b, th, 2, generator=g), torch.randn(b, th, 3, generator=g))


def test_an_untrained_residual_model_predicts_its_prior():
    torch.manual_seed(0)
    net = MetaModel(ModelConfig(**CFG, residual=True)).eval()
    uc, yc, uq, prior = _inputs()
    mean, logvar = predict_normalized_dist(net, False, uc, yc, uq, prior=prior)
    assert logvar is None and torch.equal(mean, prior)


def test_the_correction_is_counted_in_prior_scale():
    torch.manual_seed(0)
    net = MetaModel(ModelConfig(**CFG, residual=True)).eval()
    torch.nn.init.normal_(net.head.weight)
    uc, yc, uq, prior = _inputs()
    correction = net(uc, yc, uq, prior)
    net.prior_scale.fill_(0.5)
    mean, _ = predict_normalized_dist(net, False, uc, yc, uq, prior=prior)
    assert torch.allclose(mean, prior + 0.5 * correction)


def test_a_residual_model_needs_its_prior_and_another_refuses_one():
    uc, yc, uq, prior = _inputs()
    with pytest.raises(ValueError, match="needs the prior"):
        MetaModel(ModelConfig(**CFG, residual=True))(uc, yc, uq)
    with pytest.raises(ValueError, match=r"prior must have shape \(B, Th, n_y\) = \(2, 17, 3\)"):
        MetaModel(ModelConfig(**CFG, residual=True))(uc, yc, uq, prior[:, :5])
    with pytest.raises(ValueError, match="takes no prior"):
        MetaModel(ModelConfig(**CFG))(uc, yc, uq, prior)


def test_the_prior_of_later_patches_cannot_reach_earlier_steps():
    torch.manual_seed(1)
    net = MetaModel(ModelConfig(**CFG, residual=True)).eval()
    torch.nn.init.normal_(net.head.weight)
    uc, yc, uq, prior = _inputs()
    changed = prior.clone()
    changed[:, 10:] += 5.0  # patches 2 and 3 (steps 10..16)
    a, b = net(uc, yc, uq, prior), net(uc, yc, uq, changed)
    assert torch.allclose(a[:, :10], b[:, :10], atol=1e-6)
    assert not torch.allclose(a[:, 10:], b[:, 10:])


def test_a_model_without_residual_keeps_its_weights_and_outputs():
    torch.manual_seed(2)
    old = MetaModel(ModelConfig(**CFG))
    assert old.decoder.embed.in_features == 5 * 2 and "prior_scale" not in old.state_dict()
    res = MetaModel(ModelConfig(**CFG, residual=True))
    assert res.decoder.embed.in_features == 5 * (2 + 3)
    assert set(res.state_dict()) - set(old.state_dict()) == {"prior_scale"}


def test_residual_refuses_what_it_cannot_go_with():
    for other in ({"gaussian": True}, {"channel_mask": True}, {"n_params": 29}):
        with pytest.raises(ConfigError, match="residual"):
            ModelConfig(**CFG, residual=True, **other)
