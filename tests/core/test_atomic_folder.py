"""The one atomic folder swap (:func:`robomorph.core.atomic.atomic_folder`): a reader sees the old folder or
the new one, whole; and no other module swaps files or folders with an ``os.replace`` of its own."""

from __future__ import annotations

import os
import pathlib
import re

import pytest

from robomorph.core.atomic import atomic_folder, set_aside

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _tree(path) -> dict:
    return {p.name: p.read_text() for p in sorted(pathlib.Path(path).iterdir())}


def test_a_clean_exit_replaces_the_folder_whole_and_leaves_no_temporaries(tmp_path):
    target = tmp_path / "model"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with atomic_folder(target) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path) and _tree(target) == {"old.txt": "old"}  # unseen until the end
        (pathlib.Path(tmp) / "new.txt").write_text("new")
    assert _tree(target) == {"new.txt": "new"}  # nothing of the old folder is left in it
    assert sorted(os.listdir(tmp_path)) == ["model"]


def test_an_error_inside_keeps_the_old_folder_as_it_was(tmp_path):
    target = tmp_path / "model"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_folder(target) as tmp:
        (pathlib.Path(tmp) / "half.txt").write_text("half")
        raise KeyboardInterrupt
    assert _tree(target) == {"old.txt": "old"} and sorted(os.listdir(tmp_path)) == ["model"]


def test_a_new_folder_is_made_and_a_link_is_followed(tmp_path):
    with atomic_folder(tmp_path / "a" / "new") as tmp:
        (pathlib.Path(tmp) / "x").write_text("1")
    assert _tree(tmp_path / "a" / "new") == {"x": "1"}
    (tmp_path / "link").symlink_to(tmp_path / "a" / "new")
    with atomic_folder(tmp_path / "link") as tmp:
        (pathlib.Path(tmp) / "y").write_text("2")
    assert (tmp_path / "link").is_symlink() and _tree(tmp_path / "a" / "new") == {"y": "2"}


def test_no_module_swaps_with_an_os_replace_of_its_own():
    """One atomic writer: the model-folder writer goes through it (robomorph.core.locks.output_folder), and so
    does the demo's set-aside of an earlier run folder (set_aside)."""
    allowed = {"robomorph/core/atomic.py"}
    found = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "robomorph").rglob("*.py")
                   if re.search(r"\bos\.(replace|rename)\(", p.read_text()) and str(p.relative_to(ROOT)) not in allowed)
    assert found == []
    assert "output_folder(" in (ROOT / "robomorph" / "model" / "files.py").read_text()


def test_set_aside_keeps_a_folder_or_file_under_the_first_free_name(tmp_path):
    run = tmp_path / "demo"
    run.mkdir()
    (run / "last.ckpt").write_text("old")
    (tmp_path / "demo.previous-1").mkdir()  # taken (by someone else's set-aside): never replaced
    (tmp_path / "demo.previous-1" / "keep").write_text("k")
    aside = set_aside(run)
    assert aside == str(tmp_path / "demo.previous-2") and not run.exists()
    assert _tree(aside) == {"last.ckpt": "old"} and _tree(tmp_path / "demo.previous-1") == {"keep": "k"}
    run.mkdir()
    assert set_aside(run) == str(tmp_path / "demo.previous-3")
    page = tmp_path / "page.html"
    page.write_text("x")
    assert set_aside(page) == str(page) + ".previous-1" and (tmp_path / "page.html.previous-1").read_text() == "x"


def test_a_failed_set_aside_leaves_no_claim(tmp_path):
    with pytest.raises(FileNotFoundError):
        set_aside(tmp_path / "missing")
    assert os.listdir(tmp_path) == []
