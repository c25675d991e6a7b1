"""The kinematic anchor (``--model.extrapolate velocity``): the network corrects constant-velocity
extrapolation from the last context sample, so a zero correction is ``y + v t`` to rounding, in
physical units, whatever the normalization; models without the option predict as before."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.core.velocity import estimate_velocity, velocity_weights
from robomorph.data.statistics import Stats
from robomorph.evaluation.baselines import constant_velocity
from robomorph.inference.checkpoint import ACCEL_SCALE, TrainedModel, load_trained
from robomorph.model.transformer import ModelConfig
from robomorph.predictor import Predictor
from robomorph.training.module import MetaModule, ModelSettingsError

CFG = ModelConfig(n_u=2, n_y=3, d_model=8, n_head=2, n_layer=1, patch=2, max_context=32, max_horizon=32)
STATS = Stats(np.array([0.5, -1.0]), np.array([2.0, 0.5]), np.array([0.1, 0.2, -0.3]), np.array([0.3, 1.5, 0.7]))


def _zeroed(recenter: bool = False, points: int = 2) -> TrainedModel:
    """A model whose network outputs exactly 0: what is left is the anchor alone."""
    torch.manual_seed(0)
    model = TrainedModel(CFG, recenter=recenter, extrapolate="velocity", velocity_points=points).double().eval()
    model.normalizer.set_stats(STATS)
    with torch.no_grad():
        for name, p in model.net.named_parameters():
            if name.endswith("head.weight") or name.endswith("head.bias"):
                p.zero_()
    return model


def _windows(seed: int = 3, B: int = 4, Tc: int = 12, Th: int = 10):
    rng = np.random.default_rng(seed)
    t = np.arange(Tc) * 0.05
    # Smooth motion plus noise, well away from the normalization's mean and scale.
    y = (np.sin(rng.uniform(1, 3, (B, 1, 3)) * t[None, :, None] + rng.uniform(0, 6, (B, 1, 3)))
         * rng.uniform(0.5, 2, (B, 1, 3)) + rng.normal(0, 0.01, (B, Tc, 3)) + 4.0)
    return rng.normal(size=(B, Tc, 2)), y, rng.normal(size=(B, Th, 2))


@pytest.mark.parametrize("recenter", [False, True])
def test_a_zero_correction_is_the_constant_velocity_baseline(recenter):
    model = _zeroed(recenter)
    u, y, q = _windows()
    with torch.no_grad():
        pred = model(*(torch.as_tensor(a) for a in (u, y, q))).numpy()
    np.testing.assert_allclose(pred, constant_velocity(u, y, q), rtol=0, atol=1e-6)


def test_more_points_extrapolate_with_the_fitted_velocity():
    model = _zeroed(points=6)
    u, y, q = _windows(seed=5)
    with torch.no_grad():
        pred = model(*(torch.as_tensor(a) for a in (u, y, q))).numpy()
    v = estimate_velocity(y, dt=1.0, points=6)  # per step
    expected = y[:, -1:] + np.arange(1, q.shape[1] + 1)[None, :, None] * v[:, None]
    np.testing.assert_allclose(pred, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("t,points", [(12, 2), (12, 6), (3, 6), (40, 4)])
def test_velocity_weights_are_the_fit_estimate_velocity_makes(t, points):
    q = np.random.default_rng(t).normal(size=(3, t, 2))
    w = velocity_weights(t, points)
    np.testing.assert_allclose(np.einsum("k,bkc->bc", w, q[:, -len(w):]), estimate_velocity(q, 1.0, points),
                               rtol=0, atol=1e-10)


def test_a_trained_velocity_module_predicts_through_the_predictor_as_it_trains(tmp_path):
    torch.manual_seed(0)
    m = MetaModule(n_u=2, n_y=3, d_model=8, n_head=2, n_layer=1, patch=2, max_context=32, max_horizon=32,
                   extrapolate="velocity", velocity_points=4).eval()
    m.normalizer.set_stats(STATS)
    m.stats_ready.fill_(True)
    path = str(tmp_path / "m.ckpt")
    torch.save({"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams)}, path)
    model, _ = load_trained(path)
    assert (model.extrapolate, model.velocity_points) == ("velocity", 4)
    u, y, q = (torch.as_tensor(a, dtype=torch.float32) for a in _windows())
    with torch.no_grad():
        torch.testing.assert_close(Predictor.from_checkpoint(path, device="cpu").simulate(u, y, q), m(u, y, q))


def test_models_written_before_the_option_have_no_kinematic_anchor(tmp_path):
    torch.manual_seed(0)
    m = MetaModule(n_u=2, n_y=3, d_model=8, n_head=2, n_layer=1, patch=2, max_context=32, max_horizon=32,
                   anchor=True).eval()
    hp = {k: v for k, v in dict(m.hparams).items() if k not in ("extrapolate", "velocity_points")}
    path = str(tmp_path / "old.ckpt")
    torch.save({"state_dict": m.state_dict(), "hyper_parameters": hp}, path)
    model, _ = load_trained(path)
    assert model.kinematic_points == 0 and model.anchor


@pytest.mark.parametrize("kw,match", [({"anchor": True}, "--model.anchor false"),
                                      ({"residual": True}, "no residual model"),
                                      ({"velocity_points": 1}, "--model.velocity_points"),
                                      ({"extrapolate": "acceleration"}, "--model.extrapolate")])
def test_settings_that_cannot_work_are_refused_naming_the_flag(kw, match):
    with pytest.raises(ModelSettingsError, match=match):
        MetaModule(n_u=2, n_y=3, **{"extrapolate": "velocity", **kw})


def test_the_training_step_learns_the_prediction_the_predictor_makes():
    torch.manual_seed(0)
    m = MetaModule(n_u=2, n_y=3, d_model=8, n_head=2, n_layer=1, patch=2, max_context=32, max_horizon=32,
                   extrapolate="velocity").eval()
    m.normalizer.set_stats(STATS)
    m.stats_ready.fill_(True)
    u, y, q = (torch.as_tensor(a, dtype=torch.float32) for a in _windows())
    y_query = torch.randn(q.shape[0], q.shape[1], 3)
    loss, pred_n, _, _ = m._losses({"u_ctx": u, "y_ctx": y, "u_query": q, "y_query": y_query})
    loss.backward()
    assert torch.isfinite(loss) and m.net.head.weight.grad.abs().sum() > 0
    with torch.no_grad():
        torch.testing.assert_close(m.normalizer.decode(pred_n.detach(), y), m(u, y, q))


def test_an_untrained_velocity_model_predicts_constant_velocity():
    torch.manual_seed(1)
    model = TrainedModel(CFG, extrapolate="velocity").double().eval()
    model.normalizer.set_stats(STATS)
    u, y, q = _windows(seed=7)
    with torch.no_grad():
        pred = model(*(torch.as_tensor(a) for a in (u, y, q))).numpy()
    np.testing.assert_allclose(pred, constant_velocity(u, y, q), rtol=0, atol=1e-6)


def test_with_integrate_the_correction_is_summed_twice_from_accelerations():
    # Zero accelerations: constant velocity; a constant output c: c ACCEL_SCALE k (k + 1) / 2 at step k,
    # so the first step moves by one ACCEL_SCALE only.
    torch.manual_seed(0)
    model = TrainedModel(CFG, extrapolate="velocity", integrate=True).double().eval()
    model.normalizer.set_stats(STATS)
    u, y, q = _windows(seed=9)
    args = [torch.as_tensor(a) for a in (u, y, q)]
    with torch.no_grad():
        np.testing.assert_allclose(model(*args).numpy(), constant_velocity(u, y, q), rtol=0, atol=1e-6)
        model.net.head.bias.fill_(2.0)
        moved = model(*args).numpy() - constant_velocity(u, y, q)
    k = np.arange(1, q.shape[1] + 1)[None, :, None]
    expected = np.broadcast_to(2.0 * ACCEL_SCALE * k * (k + 1) / 2 * STATS.y_std, moved.shape)
    np.testing.assert_allclose(moved, expected, rtol=1e-6, atol=1e-9)
