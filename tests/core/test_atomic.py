import json

import pytest

from robomorph.core.atomic import write_json, write_text


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    path = str(tmp_path / "table.json")
    write_json(path, {"r2": 0.5, "nan": float("nan")})
    before = open(path).read()
    assert json.loads(before)["r2"] == 0.5
    with pytest.raises(TypeError):
        write_json(path, {"r2": object()})  # not serializable: fails before anything is replaced
    assert open(path).read() == before
    write_text(path, "new\n")
    assert open(path).read() == "new\n" and not (tmp_path / "table.json.tmp").exists()
