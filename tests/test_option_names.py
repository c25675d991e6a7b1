"""One option vocabulary: every command's parser (those ``robomorph.cli`` dispatches) is walked, and two
names for one meaning are refused, as is one name shared by commands without a meaning written down for it
(``robomorph.core.options.VOCABULARY``). An old name stays one release as a hidden alias that warns."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import re
from collections import defaultdict

import pytest

from robomorph.cli import COMMANDS, DOORS
from robomorph.core.options import RENAMED_ON, VOCABULARY, DeprecatedAlias, canonical

# Lightning's own option groups of fit: its vocabulary, not ours.
LIGHTNING = ("--trainer", "--optimizer", "--lr_scheduler", "--seed_everything", "--print_config", "--help")


def _parsers(name: str) -> list[argparse.ArgumentParser]:
    door = importlib.import_module(DOORS.get(name, f"robomorph.{name}"))
    if not hasattr(door, "build_parser"):
        return []
    return [door.build_parser()] + [getattr(door, a)() for a in sorted(vars(door)) if re.fullmatch(r"build_\w+_parser", a)]


def _fit_options() -> set[str]:
    """fit is a LightningCLI: its options are read from its --help."""
    from robomorph.fit import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(["--help"])
    found = set(re.findall(r"^\s+(--[\w.-]+)", out.getvalue(), flags=re.M))
    return {o for o in found if not o.startswith(LIGHTNING) and not o.endswith(".help") and o not in ("--data", "--model")}


@pytest.fixture(scope="module")
def options() -> dict[str, dict[str, list]]:
    """command -> {"advertised": [option strings], "aliases": [alias actions]}."""
    found = {}
    for name in COMMANDS:
        advertised, aliases = [], []
        for parser in _parsers(name):
            for action in parser._actions:
                if isinstance(action, DeprecatedAlias):
                    aliases.append((parser, action))
                elif action.help != argparse.SUPPRESS:
                    advertised += [o for o in action.option_strings if o.startswith("--") and o != "--help"]
        if name == "fit":
            advertised = sorted(_fit_options())
        found[name] = {"advertised": advertised, "aliases": aliases}
    return found


OLD_NAMES = {old: new for new, (_, olds) in VOCABULARY.items() for old in olds}


def test_the_vocabulary_is_one_name_per_meaning():
    assert not set(OLD_NAMES) & set(VOCABULARY), "an old name is also a current one"
    assert len(OLD_NAMES) == sum(len(olds) for _, olds in VOCABULARY.values()), "an old name of two options"
    meanings = [meaning for meaning, _ in VOCABULARY.values()]
    assert len(set(meanings)) == len(meanings)
    assert all(new in VOCABULARY for new in RENAMED_ON.values())
    assert not {old for _, old in RENAMED_ON} & set(VOCABULARY)


def test_no_command_advertises_an_old_name(options):
    """``evaluate --arm`` beside ``control --robot``, ``--context`` beside ``--context-len``, ``demo --out-dir``
    beside every other ``--out``, ``--samples`` meaning plotted trajectories on one command and MPPI candidates
    on another: each pair is one name now."""
    old = {canonical(o) for o in OLD_NAMES} | {o for _, o in RENAMED_ON}
    bad = {(name, o) for name, found in options.items() for o in found["advertised"] if canonical(o) in old}
    assert not bad, f"advertised under an old name: {sorted(bad)}"


def test_a_name_shared_by_commands_has_one_written_meaning(options):
    users = defaultdict(set)
    for name, found in options.items():
        for o in found["advertised"]:
            if name != "fit" or not o.startswith(("--data.", "--model.")):  # fit's config fields are its own
                users[canonical(o)].add(name)
    shared = {o: sorted(names) for o, names in users.items() if len(names) > 1}
    unwritten = {o: names for o, names in shared.items() if o not in VOCABULARY}
    assert not unwritten, f"options shared by commands with no meaning in core.options.VOCABULARY: {unwritten}"


def test_every_old_name_is_a_hidden_alias_of_its_new_name(options):
    seen = set()
    for name, found in options.items():
        for parser, action in found["aliases"]:
            (old,) = action.option_strings
            new = RENAMED_ON.get((name, old), OLD_NAMES.get(old))
            assert action.new == new, f"{name} {old} points at {action.new}, the vocabulary at {new}"
            (target,) = [a for a in parser._actions if new in a.option_strings]
            assert target.dest == action.dest and action.help == argparse.SUPPRESS
            seen.add((name, old))
    # The renamed options of this release, each still accepted where it was.
    for name, old in [("evaluate", "--arm"), ("evaluate", "--samples"), ("control", "--context"),
                      ("control", "--samples"), ("control", "--physics-mode"), ("priors", "--context"),
                      ("priors", "--batch"), ("demo", "--out-dir"), ("inspect", "--n-traj")]:
        assert (name, old) in seen, f"{name} {old} is not kept as an alias"


@pytest.mark.parametrize("name, old, new, value, dest", [
    ("evaluate", "--arm", "--robot", "panda", "robot"),
    ("evaluate", "--samples", "--plot-trajectories", "2", "plot_trajectories"),
    ("control", "--context", "--context-len", "40", "context_len"),
    ("control", "--samples", "--candidates", "16", "candidates"),
    ("priors", "--context", "--context-len", "40", "context_len"),
    ("priors", "--batch", "--batch-size", "4", "batch_size"),
    ("demo", "--out-dir", "--out", "x", "out"),
    ("inspect", "--n-traj", "--plot-trajectories", "2", "plot_trajectories"),
])
def test_an_old_name_still_works_and_says_which_to_use(name, old, new, value, dest, capsys):
    (parser, *_) = _parsers(name)
    required = {"evaluate": ["--data", "s.zarr"], "priors": ["s.zarr", "--out", "p.zarr"], "inspect": ["s.zarr"]}
    extra = required.get(name, [])
    by_new = parser.parse_args([*extra, new, value])
    assert capsys.readouterr().err == ""
    by_old = parser.parse_args([*extra, old, value])
    assert vars(by_old) == vars(by_new) and str(getattr(by_new, dest)) == value
    err = capsys.readouterr().err.strip()
    assert err == f"warning: {old} is deprecated and will be removed: use {new} (the same values)"
    assert old not in parser.format_help().split()
