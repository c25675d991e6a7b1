import json
import os

import pytest

from robomorph.core.atomic import atomic_open, write_bytes, write_json, write_text


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    path = str(tmp_path / "table.json")
    write_json(path, {"r2": 0.5, "nan": float("nan")})
    before = open(path).read()
    assert json.loads(before)["r2"] == 0.5
    with pytest.raises(TypeError):
        write_json(path, {"r2": object()})  # not serializable: fails before anything is replaced
    assert open(path).read() == before
    write_text(path, "new\n")
    assert open(path).read() == "new\n" and os.listdir(tmp_path) == ["table.json"]


def test_an_error_mid_write_leaves_no_part_and_no_temporary(tmp_path):
    path = tmp_path / "sub" / "model.ckpt"  # the folder is created
    write_bytes(path, b"old")
    with pytest.raises(RuntimeError):
        with atomic_open(path, "wb") as f:
            f.write(b"half of the new")
            raise RuntimeError("killed mid-save")
    assert path.read_bytes() == b"old" and os.listdir(path.parent) == ["model.ckpt"]


def test_only_whole_file_modes(tmp_path):
    with pytest.raises(ValueError, match="mode 'w' or 'wb'"):
        with atomic_open(tmp_path / "x", "a"):
            pass
