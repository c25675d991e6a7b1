import io

import numpy as np
import pytest
import torch

from robomorph.data.statistics import Stats
from robomorph.model.normalization import Normalizer


def _arrays(n=7, t=11, n_u=2, n_y=3, seed=0):
    rng = np.random.default_rng(seed)
    u = (rng.normal(size=(n, t, n_u)) * [1.0, 5.0] + [0.0, 3.0]).astype(np.float32)
    y = (rng.normal(size=(n, t, n_y)) * [0.1, 2.0, 30.0] + [1.0, -2.0, 50.0]).astype(np.float32)
    return u, y


def _stats():
    return Stats.from_arrays(*_arrays())


def _batch(b=4, tc=6, th=9, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, tc, 2, generator=g) * 5 + 3, torch.randn(b, tc, 3, generator=g) * 20 + 40,
            torch.randn(b, th, 2, generator=g) * 5 + 3, torch.randn(b, th, 3, generator=g) * 20 + 40)


def test_flat_channel_gives_eps_std_and_finite_values():
    u, y = _arrays()
    y[..., 1] = 7.0
    s = Stats.from_arrays(u, y, eps=1e-6)
    assert s.y_std[1] == 1e-6
    norm = Normalizer(s, recenter=True)
    u_ctx, y_ctx, u_q = torch.from_numpy(u[:, :5]), torch.from_numpy(y[:, :5]), torch.from_numpy(u[:, 5:])
    outs = (*norm.encode(u_ctx, y_ctx, u_q), norm.encode_target(torch.from_numpy(y[:, 5:]), y_ctx))
    assert all(torch.isfinite(o).all() for o in outs)


def test_encode_is_the_training_z_score():
    s = _stats()
    norm = Normalizer(s)
    u_ctx, y_ctx, u_q, y_q = _batch()
    u_ctx_n, y_ctx_n, u_q_n = norm.encode(u_ctx, y_ctx, u_q)
    um, us = torch.tensor(s.u_mean, dtype=torch.float32), torch.tensor(s.u_std, dtype=torch.float32)
    ym, ys = torch.tensor(s.y_mean, dtype=torch.float32), torch.tensor(s.y_std, dtype=torch.float32)
    torch.testing.assert_close(u_ctx_n, (u_ctx - um) / us)
    torch.testing.assert_close(u_q_n, (u_q - um) / us)
    torch.testing.assert_close(y_ctx_n, (y_ctx - ym) / ys)
    torch.testing.assert_close(norm.encode_target(y_q, y_ctx), (y_q - ym) / ys)


@pytest.mark.parametrize("recenter", [False, True])
def test_decode_inverts_encode_target(recenter):
    norm = Normalizer(_stats(), recenter=recenter)
    u_ctx, y_ctx, u_q, y_q = _batch()
    torch.testing.assert_close(norm.decode(norm.encode_target(y_q, y_ctx), y_ctx), y_q, rtol=1e-5, atol=1e-4)


def test_recenter_uses_the_context_only():
    norm = Normalizer(_stats(), recenter=True)
    u_ctx, y_ctx, u_q, y_q = _batch()
    u_ctx_n, y_ctx_n, u_q_n = norm.encode(u_ctx, y_ctx, u_q)
    # The context is centred per trajectory and channel...
    torch.testing.assert_close(y_ctx_n.mean(dim=1), torch.zeros(4, 3), atol=1e-3, rtol=0)
    torch.testing.assert_close(u_ctx_n.mean(dim=1), torch.zeros(4, 2), atol=1e-3, rtol=0)
    # ...and u_query is shifted by the context's u mean, not by its own.
    assert u_q_n.mean(dim=1).abs().max() > 1e-3
    pred = torch.randn(4, 9, 3)
    decoded = norm.decode(pred, y_ctx)
    # Changing the query outputs (the thing predicted) changes nothing the prediction sees.
    for y_q_other in (y_q * 100 + 5, torch.zeros_like(y_q)):
        torch.testing.assert_close(norm.decode(pred, y_ctx), decoded)
        assert not torch.allclose(norm.encode_target(y_q_other, y_ctx), norm.encode_target(y_q, y_ctx))
    # Changing the context does.
    y_ctx_other = y_ctx + 10
    assert not torch.allclose(norm.decode(pred, y_ctx_other), decoded)
    assert not torch.allclose(norm.encode_target(y_q, y_ctx_other), norm.encode_target(y_q, y_ctx))
    u_ctx_other = u_ctx + 3
    assert not torch.allclose(norm.encode(u_ctx_other, y_ctx, u_q)[2], u_q_n)


def test_without_recenter_context_does_not_shift_decode():
    norm = Normalizer(_stats(), recenter=False)
    _, y_ctx, _, _ = _batch()
    pred = torch.randn(4, 9, 3)
    torch.testing.assert_close(norm.decode(pred, y_ctx), norm.decode(pred, y_ctx + 10))


def test_gradients_flow_through_decode_and_encode():
    norm = Normalizer(_stats(), recenter=True)
    u_ctx, y_ctx, u_q, _ = _batch()
    pred = torch.randn(4, 9, 3, requires_grad=True)
    u_ctx.requires_grad_(True)
    (norm.decode(pred, y_ctx).sum() + norm.encode(u_ctx, y_ctx, u_q)[2].sum()).backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all()
    assert u_ctx.grad is not None and u_ctx.grad.abs().sum() > 0


def test_state_dict_carries_the_stats():
    s = _stats()
    src = Normalizer(s, recenter=True)
    assert set(src.state_dict()) == {"u_mean", "u_std", "y_mean", "y_std"}
    dst = Normalizer(n_u=2, n_y=3)
    torch.testing.assert_close(dst.u_std, torch.ones(2))
    dst.load_state_dict(src.state_dict())
    for k in ("u_mean", "u_std", "y_mean", "y_std"):
        np.testing.assert_allclose(getattr(dst, k).numpy(), getattr(s, k), rtol=1e-6)
    # Through a saved file, as a checkpoint would carry it.
    blob = io.BytesIO()
    torch.save(src.state_dict(), blob)
    blob.seek(0)
    dst2 = Normalizer(n_u=2, n_y=3)
    dst2.load_state_dict(torch.load(blob))
    torch.testing.assert_close(dst2.y_mean, src.y_mean)


def test_shapes_and_widths_are_checked():
    s = _stats()
    with pytest.raises(ValueError, match="n_u=5 disagrees"):
        Normalizer(s, n_u=5)
    with pytest.raises(ValueError, match="needs stats"):
        Normalizer()
    norm = Normalizer(s)
    with pytest.raises(ValueError, match="statistics have"):
        norm.set_stats(Stats(np.zeros(1), np.ones(1), np.zeros(3), np.ones(3)))
    u_ctx, y_ctx, u_q, _ = _batch()
    with pytest.raises(ValueError, match=r"y_ctx must be \(B, T, 3\)"):
        norm.encode(u_ctx, y_ctx[..., :2], u_q)
    with pytest.raises(ValueError, match="u_query"):
        norm.encode(u_ctx, y_ctx, u_q[0])


# --------------------------------------------------------------- paper_window (the paper's protocol)
def test_paper_window_is_the_z_score_of_each_whole_window():
    from robomorph.model.normalization import query_stats

    norm = Normalizer(_stats(), normalization="paper_window")
    u_ctx, y_ctx, u_q, y_q = _batch()
    u_ctx_n, y_ctx_n, u_q_n = norm.encode(u_ctx, y_ctx, u_q, query_stats(y_q))
    target = norm.encode_target(y_q, y_ctx)
    # Context and query together: zero mean and unit (population) std per trajectory and channel.
    for ctx_n, q_n in ((u_ctx_n, u_q_n), (y_ctx_n, target)):
        window = torch.cat([ctx_n, q_n], dim=1)
        torch.testing.assert_close(window.mean(dim=1), torch.zeros(4, window.shape[-1]), atol=1e-4, rtol=0)
        torch.testing.assert_close(window.std(dim=1, unbiased=False), torch.ones(4, window.shape[-1]), atol=1e-4, rtol=0)
    # Decoding with the same statistics inverts the target transform.
    torch.testing.assert_close(norm.decode(target, y_ctx, query_stats(y_q)), y_q, rtol=1e-5, atol=1e-4)


def test_pooled_moments_equal_the_moments_of_the_concatenated_window():
    from robomorph.model.normalization import pooled_moments, query_stats, window_moments

    _, y_ctx, _, y_q = _batch(tc=5, th=13)
    m, s = pooled_moments(y_ctx, *query_stats(y_q), y_q.shape[1])
    ref_m, ref_s = window_moments(torch.cat([y_ctx, y_q], dim=1))
    torch.testing.assert_close(m, ref_m, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(s, ref_s, rtol=1e-5, atol=1e-4)


def test_paper_window_prediction_depends_on_the_query_outputs():
    # The documented leak: the same normalized prediction decodes differently when the
    # query outputs (the answer) change, because their statistics set the scale.
    from robomorph.model.normalization import query_stats

    norm = Normalizer(_stats(), normalization="paper_window")
    _, y_ctx, _, y_q = _batch()
    pred = torch.randn(4, 9, 3)
    poisoned = y_q * 10 + 5
    assert not torch.allclose(norm.decode(pred, y_ctx, query_stats(y_q)), norm.decode(pred, y_ctx, query_stats(poisoned)))


def test_paper_window_needs_the_query_statistics_and_no_recenter():
    from robomorph.core.normalizations import NormalizationError

    norm = Normalizer(_stats(), normalization="paper_window")
    u_ctx, y_ctx, u_q, _ = _batch()
    with pytest.raises(NormalizationError, match="y_query_stats"):
        norm.encode(u_ctx, y_ctx, u_q)
    with pytest.raises(NormalizationError, match="y_query_stats"):
        norm.decode(torch.randn(4, 9, 3), y_ctx)
    with pytest.raises(NormalizationError, match="recenter: false"):
        Normalizer(_stats(), recenter=True, normalization="paper_window")
    with pytest.raises(NormalizationError, match="one of"):
        Normalizer(_stats(), normalization="per_window")
