"""The multi-arm meta-model as a free-run simulator: where a 6-joint robot's channels land, its free run
reads the warm-up alone (across chunks too), fine-tuning is deterministic under a seed and keeps its best
validation state, and bad settings are refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.model.channels import pad
from robomorph.training import free_run as fr
from robomorph.training.meta_free_run import ChannelMap, MetaSim

SHIPPED = "realistic-arms-60hz"


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _toy(n, length=60, seed=0):
    """Six joints driven by six torques: y_t = y_{t-1} + 0.05 (u_t - 0.2 y_{t-1})."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        u = rng.normal(size=(length, 6))
        y = np.zeros((length, 6))
        for t in range(1, length):
            y[t] = y[t - 1] + 0.05 * (u[t] - 0.2 * y[t - 1])
        out.append((u, y))
    return out


def test_a_six_joint_robot_fills_tau0_to_5_and_q0_to_5_the_rest_absent():
    sim = MetaSim.from_pretrained(SHIPPED, 6, 6)
    assert sim.channels == ChannelMap(tuple(range(6)), tuple(range(7, 13)))  # outputs: 7 EE pose channels, q0..q6
    _, padded, _ = pad([torch.ones(1, 3, 6)] * 3, sim.columns, sim.n_u, sim.n_y)  # what each pass feeds the model
    assert torch.isnan(padded[..., :7]).all() and torch.isnan(padded[..., 13]).all()
    assert torch.equal(padded[..., 7:13], torch.ones(1, 3, 6))
    # the data arrive z-scored by the robot's training split: the model's own normalizer is the identity
    assert torch.equal(sim.model.normalizer.y_std, torch.ones(14)) and not sim.model.normalizer.u_mean.any()


def test_the_free_run_reads_the_warm_up_alone_across_chunks():
    torch.manual_seed(0)
    sim = MetaSim.from_pretrained(SHIPPED, 6, 6, chunk=30).eval()
    u, y = torch.randn(2, 100, 6), torch.randn(2, 100, 6)
    with torch.no_grad():
        a = fr.simulate(sim, u, y[:, :3])
        changed = y.clone()
        changed[:, 3:] += 100.0  # every output after the warm-up
        b = fr.simulate(sim, u, changed[:, :3])
        c = fr.simulate(sim, u[:, :60], y[:, :3])  # the inputs after step 60 cannot reach steps before 50
    assert a.shape == (2, 100, 6) and torch.isfinite(a).all() and torch.equal(a, b)
    assert torch.equal(a[:, :3], y[:, :3])
    torch.testing.assert_close(a[:, :50], c[:, :50], rtol=0, atol=1e-5)  # patch 10: causal between patches


def test_pretrained_weights_differ_from_scratch_and_scratch_is_seeded():
    pre = MetaSim.from_pretrained(SHIPPED, 6, 6)
    torch.manual_seed(1)
    s1 = MetaSim.from_pretrained(SHIPPED, 6, 6, scratch=True)
    torch.manual_seed(1)
    s2 = MetaSim.from_pretrained(SHIPPED, 6, 6, scratch=True)
    key = "model.net.encoder.embed.weight"
    assert torch.equal(s1.state_dict()[key], s2.state_dict()[key])
    assert not torch.equal(pre.state_dict()[key], s1.state_dict()[key])


def test_fine_tuning_is_deterministic_under_a_seed_and_keeps_its_best_validation_state():
    train, val = _toy(4, seed=1), _toy(2, seed=2)
    cfg = fr.FreeRunConfig(warmup=3, window_min=30, tbptt=60, batch=4, iterations=4, val_every=2, patience=5,
                           lr=1e-3, seed=3)
    runs = []
    for _ in range(2):
        sim = MetaSim.from_pretrained(SHIPPED, 6, 6, chunk=25)
        norm = fr.Normalizer.of(train)
        before = fr.validation_loss(sim, [(torch.as_tensor(norm.u(u), dtype=torch.float32),
                                           torch.as_tensor(norm.y(y), dtype=torch.float32)) for u, y in val])
        rec = fr.fit(sim, train, val, cfg)
        runs.append((sim.state_dict(), rec))
        assert rec["best_val"] <= before
    (a, ra), (b, rb) = runs
    assert all(torch.equal(a[k], b[k]) for k in a) and ra["best_val"] == rb["best_val"]
    pred = fr.predictor(MetaSim.from_pretrained(SHIPPED, 6, 6), fr.Normalizer.of(train))
    u, y = val[0]
    out = pred(u, y[:1])
    assert out.shape == y.shape and np.array_equal(out[:1], y[:1])


@pytest.mark.parametrize("kwargs,message", [(dict(context=15), "multiple of the patch"),
                                            (dict(context=10), "at least 20"),
                                            (dict(chunk=0), "chunk 0"), (dict(chunk=5000), "chunk 5000")])
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(fr.FreeRunError, match=message):
        MetaSim.from_pretrained(SHIPPED, 6, 6, **kwargs)


def test_a_robot_with_more_joints_than_the_model_is_refused():
    with pytest.raises(fr.FreeRunError, match="no output channel q7"):
        MetaSim.from_pretrained(SHIPPED, 7, 8)
    with pytest.raises(fr.FreeRunError, match="9 inputs"):
        MetaSim.from_pretrained(SHIPPED, 9, 6)
