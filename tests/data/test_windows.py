"""Splits, windows and the training sampler: disjoint, seeded, within bounds."""

import numpy as np
import pytest

from robomorph.data.sources import Source
from robomorph.data.windows import MixtureSampler, WindowDataset, pairs, split_rows


def test_splits_are_disjoint_cover_every_row_and_follow_the_seed():
    a = split_rows(50, (0.8, 0.1, 0.1), seed=3, store_index=0)
    assert [len(a[k]) for k in ("train", "val", "test")] == [40, 5, 5]
    rows = np.concatenate([a["train"], a["val"], a["test"]])
    assert sorted(rows.tolist()) == list(range(50))
    b = split_rows(50, (0.8, 0.1, 0.1), seed=3, store_index=0)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    # another store of the same run, or another seed, is split independently
    assert not np.array_equal(a["val"], split_rows(50, (0.8, 0.1, 0.1), seed=3, store_index=1)["val"])
    assert not np.array_equal(a["val"], split_rows(50, (0.8, 0.1, 0.1), seed=4, store_index=0)["val"])


def test_pairs_name_store_and_trajectory():
    got = pairs([np.array([2, 5]), np.array([], dtype=np.int64), np.array([0])])
    assert got.dtype == np.int64 and got.tolist() == [[0, 2], [0, 5], [2, 0]]
    assert pairs([]).shape == (0, 2)


def _sampler(seed=0, random_window=True, lengths=(10, 10, 20, 20)):
    # Trajectories of 35 and 30 steps: windows of 10 + 20 leave offsets 0..5 and 0.
    return MixtureSampler(base=np.array([0, 10]), counts=np.array([10, 4]), probs=np.array([0.25, 0.75]),
                          steps=np.array([35, 30]), n_samples=400, seed=seed, random_window=random_window,
                          lengths=lengths, batch_size=16)


def test_the_sampler_is_seeded_per_epoch_and_stays_in_bounds():
    s = _sampler()
    s.set_epoch(2)
    first = list(s)
    s.set_epoch(2)
    assert list(s) == first
    s.set_epoch(3)
    assert list(s) != first
    rows, offsets, ctx, hor = np.array(first).T
    assert set(ctx) == {10} and set(hor) == {20}  # fixed lengths
    in_second = rows >= 10
    assert rows.min() >= 0 and rows.max() < 14
    assert 0.65 < in_second.mean() < 0.85  # the weights, 0.75 for the second store
    assert offsets[in_second].max() == 0 and 0 <= offsets[~in_second].min() and offsets[~in_second].max() <= 5
    assert set(np.array(list(_sampler(random_window=False))).T[1]) == {0}


def test_the_sampler_draws_lengths_per_batch_and_offsets_that_fit_them():
    keys = np.array(list(_sampler(lengths=(4, 10, 5, 20))))
    rows, offsets, ctx, hor = keys.T
    for b in range(0, len(keys), 16):  # one (context, horizon) pair per batch, so a batch stacks
        assert len(set(ctx[b:b + 16])) == 1 and len(set(hor[b:b + 16])) == 1
    assert 4 <= ctx.min() and ctx.max() <= 10 and 5 <= hor.min() and hor.max() <= 20 and len(set(ctx)) > 1
    steps = np.where(rows >= 10, 30, 35)
    assert (offsets + ctx + hor <= steps).all()


def test_a_window_dataset_cuts_context_and_query(store_factory, tmp_path):
    u = np.arange(3 * 12 * 2, dtype=np.float32).reshape(3, 12, 2)
    y = -np.arange(3 * 12 * 1, dtype=np.float32).reshape(3, 12, 1)
    src = Source(store_factory(tmp_path / "w.zarr", u, y))
    ds = WindowDataset([src], pairs([np.array([0, 2])]), context_len=4, horizon=5)
    item = ds[(1, 3)]  # trajectory 2 from step 3
    short = ds[(1, 3, 2, 4)]  # drawn lengths: 2 context + 4 query steps
    assert short["u_ctx"].shape == (2, 2) and short["y_query"].shape == (4, 1)
    np.testing.assert_array_equal(short["y_query"].numpy(), y[2, 5:9])
    np.testing.assert_array_equal(item["u_ctx"].numpy(), u[2, 3:7])
    np.testing.assert_array_equal(item["y_query"].numpy(), y[2, 7:12])
    assert len(ds) == 2 and ds[0]["u_query"].shape == (5, 2)
    with pytest.raises(IndexError):
        ds[5]
