import shutil

import zarr
from zarr.storage import LocalStore

from robomorph.data.fingerprints import fingerprint, recorded_match
from tests.data.test_store import _make, _rows


def _store(path, seed=0):
    w = _make(path, n=6, steps=20, chunk=2)
    w.append(*_rows(6, 20, seed=seed))
    w.finalize()
    return str(path)


def test_fingerprint_matches_a_copy_and_not_another_store(tmp_path):
    a = _store(tmp_path / "a.zarr")
    copy = tmp_path / "elsewhere" / "copy.zarr"
    shutil.copytree(a, copy)
    b = _store(tmp_path / "b.zarr", seed=1)
    assert fingerprint(str(copy)) == fingerprint(a) != fingerprint(b)
    recorded = {a: fingerprint(a)}
    assert recorded_match(str(copy), [a], recorded) == a
    assert recorded_match(str(copy), [a], None) is None  # old checkpoints: by path only
    assert recorded_match(a, [a], None) == a
    assert recorded_match(b, [a], recorded) is None


def test_fingerprint_ignores_when_and_by_which_version_a_store_was_written(tmp_path):
    a = _store(tmp_path / "a.zarr")
    before = fingerprint(a)
    group = zarr.open_group(LocalStore(a), mode="r+")
    group.attrs.update({"created": "2000-01-01T00:00:00+00:00", "package_version": "0.0.0"})
    assert fingerprint(a) == before
    group.attrs.update({"seed": 12345})  # a recorded fact of the data, not of the write
    assert fingerprint(a) != before


def test_a_path_that_is_no_store_matches_nothing(tmp_path):
    a = _store(tmp_path / "a.zarr")
    recorded = {a: fingerprint(a)}
    (tmp_path / "empty").mkdir()
    assert recorded_match(str(tmp_path / "empty"), [a], recorded) is None
    assert recorded_match(str(tmp_path / "missing.zarr"), [a], recorded) is None
