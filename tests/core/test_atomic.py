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


def _checkpoint_bytes(tmp_path) -> bytes:
    import zipfile  # torch.save's format: a zip archive holding <name>/data.pkl

    path = tmp_path / "made.ckpt"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("made/data.pkl", b"\x80\x02}q\x00.")
    return path.read_bytes()


def test_a_writer_replaces_only_files_of_its_own_kind(tmp_path):
    from robomorph.core.atomic import check_replaceable
    from robomorph.core.errors import OutputExistsError

    ckpt = tmp_path / "best.ckpt"
    ckpt.write_bytes(_checkpoint_bytes(tmp_path))
    page = tmp_path / "report.html"
    page.write_text("<!DOCTYPE html>\n<html><body>old</body></html>\n")
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    (tmp_path / "empty.html").write_bytes(b"")
    check_replaceable(tmp_path / "new.html", "html")  # absent: fine
    check_replaceable(page, "html")
    check_replaceable(tmp_path / "empty.html", "html")  # nothing to lose
    check_replaceable(ckpt, "checkpoint")
    for path, kind, found in [(ckpt, "html", "a checkpoint"), (notes, "html", "a file of another kind"),
                              (page, "checkpoint", "an HTML page"), (tmp_path, "html", "a folder"),
                              (notes, "checkpoint", "a file of another kind")]:
        with pytest.raises(OutputExistsError, match=f"--out {path} is {found}") as err:
            check_replaceable(path, kind)
        assert "\n" not in str(err.value) and "choose another --out" in str(err.value)


def test_nothing_is_written_into_a_zarr_store(tmp_path):
    from robomorph.core.atomic import check_replaceable
    from robomorph.core.errors import OutputExistsError

    store = tmp_path / "ms.zarr"
    (store / "u").mkdir(parents=True)
    (store / "zarr.json").write_text('{"zarr_format": 3, "node_type": "group", "attributes": {}}')
    for path in (store / "report.html", store / "u" / "x.ckpt", store / "zarr.json", store):
        with pytest.raises(OutputExistsError, match=f"inside the Zarr store {store}|is a folder"):
            check_replaceable(path, "html" if path.suffix != ".ckpt" else "checkpoint")
    assert not (store / "report.html").exists()
