"""A store as the DataModule reads it: same rows in memory and chunk by chunk, checks."""

import pickle

import numpy as np
import pytest

from robomorph.data.sources import Source, check_lengths, compatible, scan
from robomorph.data.statistics import StatsAccumulator


def _arrays(n=10, steps=8, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, steps, 2)).astype(np.float32), rng.normal(size=(n, steps, 3)).astype(np.float32)


def test_chunked_and_in_memory_reads_agree(store_factory, tmp_path):
    u, y = _arrays()
    path = store_factory(tmp_path / "s.zarr", u, y, chunk=3)
    lazy, loaded = Source(path), Source(path)
    loaded.load()
    assert (lazy.n, lazy.steps, lazy.n_blocks, lazy.nbytes) == (10, 8, 4, 10 * 8 * 5 * 4)
    for i in (0, 4, 9):
        for src in (lazy, loaded):
            uw, yw = src.window(i, 2, 6)
            np.testing.assert_array_equal(uw, u[i, 2:6])
            np.testing.assert_array_equal(yw, y[i, 2:6])
    # a pickled source (a DataLoader worker's copy) drops the handle and reopens the store
    copy = pickle.loads(pickle.dumps(lazy))
    np.testing.assert_array_equal(copy.window(7, 0, 8)[0], u[7])


def test_scan_feeds_training_rows_and_refuses_non_finite_values(store_factory, tmp_path):
    u, y = _arrays()
    src = Source(store_factory(tmp_path / "s.zarr", u, y, chunk=4))
    acc = StatsAccumulator(2, 3)
    scan(src, np.array([1, 5, 6]), 4, acc)
    assert acc.count == 3 * 4
    y[6, 3, 1] = np.nan
    bad = Source(store_factory(tmp_path / "bad.zarr", u, y, chunk=4))
    with pytest.raises(ValueError, match="trajectory 6 has NaN/inf values in 'y'"):
        scan(bad, np.array([0]), 4, None)


def test_stores_must_agree_and_be_long_enough(store_factory, tmp_path):
    u, y = _arrays()
    a = Source(store_factory(tmp_path / "a.zarr", u, y))
    b = Source(store_factory(tmp_path / "b.zarr", u, y, y_names=["p", "q", "r"]))
    c = Source(store_factory(tmp_path / "c.zarr", u, y, attrs={"dt": 0.02}))
    twin = Source(a.path)
    assert compatible([a, twin]) == [a, twin]
    with pytest.raises(ValueError, match="disagree on y_names"):
        compatible([a, b])
    with pytest.raises(ValueError, match="disagree on dt"):
        compatible([a, c])
    check_lengths([a], 3, 5)
    with pytest.raises(ValueError, match=r"T=8 steps, but context_len 4 \+ horizon 5 = 9"):
        check_lengths([a], 4, 5)
