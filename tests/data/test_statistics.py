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


def _still_joint(seed=0):
    """Four joint angles and four torques; joint 3 and torque 1 barely move."""
    rng = np.random.default_rng(seed)
    y = rng.normal(size=(6, 50, 4)) * [0.4, 0.5, 0.6, 1e-5]
    u = rng.normal(size=(6, 50, 4)) * [10.0, 1e-4, 20.0, 30.0]
    return u, y, ["tau0", "tau1", "tau2", "tau3"], ["q0", "q1", "q2", "q3"]


def test_a_channel_that_barely_moves_is_scaled_by_its_kind_not_its_own_spread():
    from robomorph.data.statistics import STD_FLOOR_FRACTION

    u, y, u_names, y_names = _still_joint()
    plain, floored = Stats.from_arrays(u, y), Stats.from_arrays(u, y, u_names=u_names, y_names=y_names)
    assert plain.y_std[3] < 1e-4 and plain.u_std[1] < 1e-3  # what a model divided by before the floor
    # Joint angles floored by the joint angles' median spread, torques by the torques'.
    np.testing.assert_allclose(floored.y_std[3], STD_FLOOR_FRACTION * np.median(plain.y_std), rtol=1e-9)
    np.testing.assert_allclose(floored.u_std[1], STD_FLOOR_FRACTION * np.median(plain.u_std), rtol=1e-9)
    # Channels that move keep their own spread, and the means are untouched.
    np.testing.assert_array_equal(floored.y_std[:3], plain.y_std[:3])
    np.testing.assert_array_equal(floored.u_std[[0, 2, 3]], plain.u_std[[0, 2, 3]])
    np.testing.assert_array_equal(floored.y_mean, plain.y_mean)


def test_channels_of_unknown_kinds_are_not_pooled():
    # u0/y0.. are a log's own columns: nothing says they share units, so none floors another.
    u, y, _, _ = _still_joint()
    named = Stats.from_arrays(u, y, u_names=[f"u{k}" for k in range(4)], y_names=[f"y{k}" for k in range(4)])
    np.testing.assert_array_equal(named.y_std, Stats.from_arrays(u, y).y_std)


def test_the_datamodule_floors_a_joint_its_training_split_barely_moves(tmp_path, store_factory):
    from robomorph.data.datamodule import RoboMorphDataModule

    u, y, u_names, y_names = _still_joint()
    store = store_factory(tmp_path / "still.zarr", u, y, u_names=u_names, y_names=y_names)
    dm = RoboMorphDataModule(stores=store, context_len=10, horizon=20, batch_size=4)
    dm.setup()
    assert dm.stats.y_std[3] > 0.01  # a tenth of the other joints' spread (about 0.05), not 1e-5
    assert dm.stats.u_std[1] > 0.5
