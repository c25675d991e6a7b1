"""Training-split statistics: exact over trajectories and steps, streamed, refusing bad input."""

import numpy as np
import pytest

from robomorph.data.statistics import Stats, StatsAccumulator


def _arrays(n=7, t=11, n_u=2, n_y=3, seed=0):
    rng = np.random.default_rng(seed)
    u = (rng.normal(size=(n, t, n_u)) * [1.0, 5.0] + [0.0, 3.0]).astype(np.float32)
    y = (rng.normal(size=(n, t, n_y)) * [0.1, 2.0, 30.0] + [1.0, -2.0, 50.0]).astype(np.float32)
    return u, y


def test_stats_equal_numpy_over_trajectories_and_steps():
    u, y = _arrays()
    s = Stats.from_arrays(u, y)
    np.testing.assert_allclose(s.u_mean, u.astype(np.float64).mean(axis=(0, 1)), rtol=1e-12)
    np.testing.assert_allclose(s.u_std, u.astype(np.float64).std(axis=(0, 1)), rtol=1e-12)
    np.testing.assert_allclose(s.y_mean, y.astype(np.float64).mean(axis=(0, 1)), rtol=1e-12)
    np.testing.assert_allclose(s.y_std, y.astype(np.float64).std(axis=(0, 1)), rtol=1e-12)
    assert s.u_mean.dtype == np.float64 and (s.n_u, s.n_y) == (2, 3)


def test_streaming_blocks_match_one_pass():
    u, y = _arrays(n=300, t=5, seed=3)
    whole = Stats.from_arrays(u, y)
    acc = StatsAccumulator(2, 3)
    for a, b in ((0, 1), (1, 40), (40, 41), (41, 300)):
        acc.update(u[a:b], y[a:b])
    assert acc.count == 300 * 5
    streamed = acc.finalize()
    for k in ("u_mean", "u_std", "y_mean", "y_std"):
        np.testing.assert_allclose(getattr(streamed, k), getattr(whole, k), rtol=1e-10, atol=1e-12)


def test_no_samples_and_bad_stats_are_refused():
    with pytest.raises(ValueError, match="no samples"):
        StatsAccumulator(2, 3).finalize()
    with pytest.raises(ValueError, match="positive"):
        Stats(np.zeros(2), np.array([1.0, 0.0]), np.zeros(1), np.ones(1))
