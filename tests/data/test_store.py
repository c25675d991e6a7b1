import os

import numpy as np
import pytest
import zarr

from robomorph.core.inputs import InputsError
from robomorph.data.store import SchemaError, StoreDamagedError, create_store, open_store


def _make(path, n=5, steps=7, **kw):
    return create_store(str(path), n, steps, ["u0", "u1"], ["y0"], ["p0", "p1", "p2"],
                        {"dt": 0.1, "domain": "test"}, **kw)


def _rows(k, steps=7, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(k, steps, 2)).astype(np.float32), rng.normal(size=(k, steps, 1)).astype(np.float32),
            rng.normal(size=(k, 3)).astype(np.float32))


def test_round_trip(tmp_path):
    w = _make(tmp_path / "a.zarr", extras={"tag": ((), "int16")})
    u, y, p = _rows(5)
    w.append(u[:3], y[:3], p[:3], extras={"tag": np.arange(3, dtype=np.int16)})
    w.append(u[3:], y[3:], p[3:], extras={"tag": np.arange(3, 5, dtype=np.int16)})
    w.finalize(note="done")
    ds = open_store(str(tmp_path / "a.zarr"))
    np.testing.assert_array_equal(ds.read("u"), u)
    np.testing.assert_array_equal(ds.read("y"), y)
    np.testing.assert_array_equal(ds.read("params"), p)
    np.testing.assert_array_equal(ds.read("tag"), np.arange(5))
    np.testing.assert_array_equal(ds.read("u", np.array([4, 1])), u[[4, 1]])
    assert ds.u_names == ["u0", "u1"] and ds.y_names == ["y0"] and ds.dt == 0.1
    assert ds.attrs["note"] == "done" and ds.attrs["schema_version"] == 2


def test_incomplete_store_is_refused_unless_asked(tmp_path):
    w = _make(tmp_path / "a.zarr")
    u, y, p = _rows(2)
    w.append(u, y, p)
    with pytest.raises(SchemaError, match="incomplete"):
        open_store(str(tmp_path / "a.zarr"))
    ds = open_store(str(tmp_path / "a.zarr"), allow_incomplete=True)
    assert ds.n == 2 and ds.read("u").shape == (2, 7, 2)
    with pytest.raises(ValueError, match="cannot finalize"):
        w.finalize()


def test_wrong_shapes_are_refused(tmp_path):
    w = _make(tmp_path / "a.zarr")
    u, y, p = _rows(2)
    with pytest.raises(ValueError, match="u rows have shape"):
        w.append(u[:, :, :1], y, p)
    with pytest.raises(ValueError, match="row counts"):
        w.append(u, y[:1], p)
    with pytest.raises(ValueError, match="capacity"):
        w.append(*_rows(6))


def test_other_schema_and_files_are_never_overwritten(tmp_path):
    other = tmp_path / "other.zarr"
    g = zarr.open_group(str(other), mode="w")
    g.attrs["schema"] = "something.else"
    g.create_array("x", shape=(3,), dtype="f4")
    before = sorted(os.listdir(other))
    with pytest.raises(SchemaError, match="another schema"):
        _make(other, overwrite=True)
    assert sorted(os.listdir(other)) == before
    with pytest.raises(SchemaError, match="not a RoboMorph dataset"):
        open_store(str(other))

    f = tmp_path / "file.zarr"
    f.write_text("precious")
    with pytest.raises(FileExistsError, match="is a file"):
        _make(f)
    assert f.read_text() == "precious"

    with pytest.raises(FileNotFoundError):
        open_store(str(tmp_path / "missing.zarr"))


def test_existing_store_needs_overwrite(tmp_path):
    w = _make(tmp_path / "a.zarr")
    w.append(*_rows(5))
    w.finalize()
    with pytest.raises(FileExistsError, match="--overwrite"):
        _make(tmp_path / "a.zarr")
    _make(tmp_path / "a.zarr", overwrite=True)
    assert open_store(str(tmp_path / "a.zarr"), allow_incomplete=True).n == 0


def _filled(path, n=6, chunk=2, steps=400):
    w = _make(path, n=n, steps=steps, chunk=chunk)
    u, y, p = _rows(n, steps)
    w.append(u, y, p)
    w.finalize()
    return u, y


def _chunk_file(path, name, c):
    return os.path.join(str(path), name, "c", str(c), "0", "0")  # Zarr v3 default chunk keys


def test_a_truncated_chunk_names_the_array_chunk_and_trajectories(tmp_path):
    # It used to be "RuntimeError: error during blosc decompression", or, for data blosc
    # stored uncompressed (these random floats), garbage values without a word.
    path = tmp_path / "a.zarr"
    u, y = _filled(path)
    f = _chunk_file(path, "y", 1)
    data = open(f, "rb").read()
    with open(f, "wb") as out:
        out.write(data[: len(data) // 2])
    ds = open_store(str(path))
    with pytest.raises(StoreDamagedError, match=r"'y' chunk c/1/0/0 \(trajectories 2\.\.3\) truncated") as err:
        ds.read("y")
    assert "--overwrite" in str(err.value)
    with pytest.raises(StoreDamagedError, match="trajectories 2..3"):
        ds.read("y", np.array([0, 3]))
    np.testing.assert_array_equal(ds.read("y", slice(0, 2)), y[:2])  # the rest still reads
    np.testing.assert_array_equal(ds.read("u"), u)
    assert [d[:4] for d in ds.damaged_chunks()] == [("y", "c/1/0/0", 2, 3)]


def test_a_corrupt_chunk_that_cannot_be_decoded_is_named(tmp_path):
    path = tmp_path / "a.zarr"
    w = _make(path, n=4, steps=400, chunk=2)
    u, y, p = _rows(4, 400)
    w.append(np.zeros_like(u), y, p)  # compressible: blosc really compresses u
    w.finalize()
    f = _chunk_file(path, "u", 1)
    data = bytearray(open(f, "rb").read())
    data[16:] = b"\xff" * (len(data) - 16)  # same length, garbage inside
    open(f, "wb").write(bytes(data))
    with pytest.raises(StoreDamagedError, match=r"'u' chunk c/1/0/0 \(trajectories 2\.\.3\) cannot be decoded"):
        open_store(str(path)).read("u")


def test_missing_chunks_are_named(tmp_path):
    path = tmp_path / "a.zarr"
    _filled(path)
    assert open_store(str(path)).damaged_chunks() == []
    os.remove(_chunk_file(path, "u", 2))
    ds = open_store(str(path))
    assert ds.damaged_chunks() == [("u", "c/2/0/0", 4, 5, "missing")]
    with pytest.raises(StoreDamagedError, match=r"'u' chunk c/2/0/0 \(trajectories 4\.\.5\) missing"):
        ds.read("u")


def test_command_inputs_round_trip(tmp_path):
    w = _make(tmp_path / "a.zarr", u_cmd_names=["c0", "c1"])
    u, y, p = _rows(5)
    with pytest.raises(ValueError, match="u_cmd"):  # a row without its command is refused
        w.append(u, y, p)
    w.append(u, y, p, extras={"u_cmd": u - 1})
    w.finalize()
    ds = open_store(str(tmp_path / "a.zarr"))
    np.testing.assert_array_equal(ds.read_inputs("command"), u - 1)
    np.testing.assert_array_equal(ds.read_inputs("total"), u)
    assert ds.input_names("command") == ["c0", "c1"] and ds.input_names("total") == ["u0", "u1"]
    with pytest.raises(InputsError, match="one of total, command"):
        ds.read_inputs("cmd")


def test_schema_1_stores_stay_readable_and_say_to_regenerate_for_the_command(tmp_path):
    """A store written before u_cmd existed (schema 1: u, y, params only)."""
    path = tmp_path / "old.zarr"
    w = _make(path)
    u, y, p = _rows(5)
    w.append(u, y, p)
    w.finalize()
    zarr.open_group(str(path), mode="r+").attrs["schema_version"] = 1
    ds = open_store(str(path))
    np.testing.assert_array_equal(ds.read("u"), u)
    np.testing.assert_array_equal(ds.read_inputs("total"), u)
    assert not ds.has_inputs("command")
    with pytest.raises(InputsError, match="before schema 2.*[Rr]egenerate"):
        ds.read_inputs("command")
    zarr.open_group(str(path), mode="r+").attrs["schema_version"] = 99
    with pytest.raises(SchemaError, match="schema_version 99"):
        open_store(str(path))


def test_flipped_bytes_fail_the_checksum_and_name_the_chunk(tmp_path):
    path = tmp_path / "a.zarr"
    w = _make(path, n=4, steps=50, chunk=2)
    u, y, p = _rows(4, 50)
    w.append(u, y, p)
    w.finalize()
    f = _chunk_file(path, "y", 1)
    data = bytearray(open(f, "rb").read())
    data[len(data) // 2] ^= 0x01  # one bit inside the data, size unchanged
    open(f, "wb").write(bytes(data))
    ds = open_store(str(path))
    assert ds.describe_damage() is None  # same size: only reading it can tell
    np.testing.assert_array_equal(ds.read("y", slice(0, 2)), y[:2])  # the intact chunk still reads
    with pytest.raises(StoreDamagedError, match=r"'y' chunk c/1/0/0 \(trajectories 2\.\.3\) cannot be decoded: "
                                                r"it fails its checksum"):
        ds.read("y")


def test_a_truncated_chunk_with_a_checksum_is_found_without_decoding(tmp_path):
    path = tmp_path / "a.zarr"
    w = _make(path, n=4, steps=50, chunk=2)
    w.append(*_rows(4, 50))
    w.finalize()
    f = _chunk_file(path, "u", 0)
    data = open(f, "rb").read()
    assert open_store(str(path)).describe_damage() is None  # the trailing CRC is counted in the expected size
    open(f, "wb").write(data[:-9])
    assert "'u' chunk c/0/0/0 (trajectories 0..1) truncated" in open_store(str(path)).describe_damage()


def test_stores_written_without_checksums_still_read(tmp_path, monkeypatch):
    from zarr.codecs import BloscCodec

    import robomorph.data.store as store

    monkeypatch.setattr(store, "_COMPRESSORS", [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")])
    path = tmp_path / "old.zarr"
    w = _make(path, n=4, steps=50, chunk=2)
    u, y, p = _rows(4, 50)
    w.append(u, y, p)
    w.finalize()
    monkeypatch.undo()
    ds = open_store(str(path))
    assert [type(c).__name__ for c in ds.group["u"].metadata.codecs] == ["BytesCodec", "BloscCodec"]
    np.testing.assert_array_equal(ds.read("u"), u)
    assert ds.describe_damage() is None
    open(_chunk_file(path, "u", 1), "r+b").truncate(30)
    assert "truncated" in ds.describe_damage()


def test_new_stores_carry_crc32c_checksums(tmp_path):
    path = tmp_path / "a.zarr"
    w = _make(path, extras={"tag": ((), "int16")})
    w.append(*_rows(5), extras={"tag": np.arange(5, dtype=np.int16)})
    w.finalize()
    group = open_store(str(path)).group
    for name in ("u", "y", "params", "tag"):
        assert type(group[name].metadata.codecs[-1]).__name__ == "Crc32cCodec", name
