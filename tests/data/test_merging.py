"""Merging shard stores: rows in shard order, counts summed, mismatched shards refused."""

import os

import numpy as np
import pytest

from robomorph.data.merging import merge
from robomorph.data.store import open_store


def _shard(store_factory, path, index, seed, count=2, **attrs):
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=(3, 5, 2)), rng.normal(size=(3, 5, 1))
    base = {"dt": 0.01, "config": {"task": "multisine"}, "shard": [index, count], "requested": 3, "attempted": 4,
            "rejected": {"unstable": index + 1}}
    return store_factory(path, u, y, params=rng.normal(size=(3, 2)), attrs={**base, **attrs}), u


def test_shards_concatenate_in_shard_order_with_summed_counts(store_factory, tmp_path):
    p1, u1 = _shard(store_factory, tmp_path / "s1.zarr", 1, seed=1)
    p0, u0 = _shard(store_factory, tmp_path / "s0.zarr", 0, seed=0)
    attrs = merge([p0, p1], str(tmp_path / "all.zarr"), chunk=2)
    ds = open_store(str(tmp_path / "all.zarr"))
    np.testing.assert_allclose(ds.read("u"), np.concatenate([u0, u1]).astype(np.float32))
    assert (attrs["n"], attrs["kept"], attrs["requested"], attrs["attempted"]) == (6, 6, 6, 8)
    assert attrs["rejected"] == {"unstable": 3} and attrs["merged_from"] == [[0, 2], [1, 2]]


def test_shards_of_different_recipes_or_the_same_shard_twice_are_refused(store_factory, tmp_path):
    p0, _ = _shard(store_factory, tmp_path / "s0.zarr", 0, seed=0)
    other, _ = _shard(store_factory, tmp_path / "o.zarr", 1, seed=1, config={"task": "chirp"})
    with pytest.raises(ValueError, match="differs .* in config"):
        merge([p0, other], str(tmp_path / "x.zarr"))
    again, _ = _shard(store_factory, tmp_path / "again.zarr", 0, seed=2)
    with pytest.raises(ValueError, match="duplicate shards"):
        merge([p0, again], str(tmp_path / "y.zarr"))
    with pytest.raises(ValueError, match="at least one"):
        merge([], str(tmp_path / "z.zarr"))


def test_an_output_that_is_or_holds_an_input_is_refused_before_anything_is_read(store_factory, tmp_path):
    from robomorph.data.merging import MergeError

    p0, u0 = _shard(store_factory, tmp_path / "s0.zarr", 0, seed=0)
    p1, _ = _shard(store_factory, tmp_path / "s1.zarr", 1, seed=1)
    os.symlink(p0, tmp_path / "alias.zarr")
    for out in (p0, p0 + "/", str(tmp_path / "alias.zarr"), os.path.join(p0, "inner.zarr")):
        with pytest.raises(MergeError, match="is one of the stores to merge"):
            merge([p0, p1], out, overwrite=True)
    np.testing.assert_allclose(open_store(p0).read("u"), u0.astype(np.float32))  # the input is intact
    assert sorted(os.listdir(p0)) == sorted(os.listdir(p1))
