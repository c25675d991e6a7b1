"""One option name per concept across commands: control's physics mode is ``--physics``, as in evaluate
and calibrate; ``--physics-mode`` stays one release as a deprecated alias that says so."""

from __future__ import annotations

import pytest

from robomorph.control.cli import build_parser
from robomorph.core.names import PHYSICS_MODES


def test_physics_is_the_option_and_physics_mode_an_alias_that_warns(capsys):
    p = build_parser()
    assert p.parse_args(["--physics", "fused"]).physics_mode == "fused"
    assert capsys.readouterr().err == ""
    assert p.parse_args(["--physics-mode", "none"]).physics_mode == "none"  # the same destination
    err = capsys.readouterr().err.strip()
    assert err == "warning: --physics-mode is deprecated and will be removed: use --physics (the same values)"
    assert p.parse_args([]).physics_mode is None  # the model's default
    help_text = p.format_help()
    assert "--physics {" in help_text and "--physics-mode" not in help_text  # the old name is not advertised


def test_the_modes_are_the_shared_list_and_a_bad_one_is_one_line(capsys):
    p = build_parser()
    (physics,) = [a for a in p._actions if a.option_strings == ["--physics"]]
    assert tuple(physics.choices) == (*PHYSICS_MODES, "none")
    with pytest.raises(SystemExit) as exc:
        p.parse_args(["--physics", "bogus"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: robomorph control: argument --physics: invalid choice: 'bogus'") and "\n" not in err
