"""Every code example of README.md and docs/ works: Python blocks run, command lines parse.

- The Python blocks of each docs page run in order, sharing one namespace, in a fresh
  temporary folder (a page that needs a store or a model builds a tiny one in its first
  block, as the page shows). Blocks titled ``needs ...`` are only shown; they are listed by
  a test that keeps them few and says why each is skipped.
- The README's quick start runs end to end at a tiny size: its shell commands with size
  flags appended (argparse and LightningCLI take the last value of a repeated flag), then its
  Python block unchanged.
- Every ``robomorph <command> ...`` line of a shell block is parsed by that command's own
  parser (``fit``: its options are checked against its LightningCLI help).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import re
import sys
from pathlib import Path

import pytest

from tests.docs.examples import ROOT, blocks, command_lines, load_hook, pages

README = ROOT / "README.md"
# The README's Python block needs the model of its shell quick start: test_readme_quickstart_runs.
DOC_PAGES = [p for p in pages() if p != README and any(not b.skip_reason for b in blocks(p, "python"))]
MAX_SKIPPED = 6


@contextlib.contextmanager
def _inside(folder: Path):
    """cwd = ``folder``; sys.argv restored (``robomorph.cli.main`` sets it for the door it runs)."""
    before, argv = os.getcwd(), list(sys.argv)
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)
        sys.argv[:] = argv


def _run_blocks(page: Path, folder: Path) -> None:
    namespace: dict = {"__name__": "__docs__"}
    with _inside(folder):
        for block in blocks(page, "python"):
            if block.skip_reason:
                continue
            try:
                exec(compile(block.code, block.where, "exec"), namespace)
            except Exception as exc:
                raise AssertionError(f"the example at {block.where} failed: {exc!r}\n{block.code}") from exc


@pytest.mark.slow
@pytest.mark.parametrize("page", DOC_PAGES, ids=[p.relative_to(ROOT).as_posix() for p in DOC_PAGES])
def test_python_examples_of_the_docs_run(page, tmp_path):
    _run_blocks(page, tmp_path)


def test_skipped_examples_are_few_and_say_why():
    skipped = [(b.where, b.skip_reason) for p in pages() for b in blocks(p, "python") if b.skip_reason]
    print("\nshown but not run:\n" + "\n".join(f"  {where}: {why}" for where, why in skipped))
    assert len(skipped) <= MAX_SKIPPED, skipped
    assert all(len(why) > len("needs ") for _, why in skipped)


def test_docs_quickstart_example_is_the_readme_one():
    """The docs' copy is skipped because it is the README's, which runs (test_readme_quickstart_runs)."""
    (readme,) = [b for b in blocks(README, "python")]
    # The page's other block, the prediction with no training, runs (test_python_examples_of_the_docs_run).
    (docs,) = [b for b in blocks(ROOT / "docs" / "guide" / "quickstart.md", "python") if b.skip_reason]
    assert docs.code == readme.code


def test_fenced_blocks_are_closed():
    for page in pages():
        fences = [line for line in page.read_text().splitlines() if line.lstrip().startswith("```")]
        assert len(fences) % 2 == 0, page


# --- command lines ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def helps() -> dict[str, str]:
    """``--help`` text of the commands without an argparse parser (``fit``), as the command reference shows it."""
    return {line.split()[1]: text for line, _, text in load_hook().command_helps() if len(line.split()) == 2}


def _check_call(call: list[str], helps: dict[str, str]) -> None:
    from robomorph.cli import COMMANDS

    name, args = call[0], call[1:]
    assert name in COMMANDS, f"unknown command {name!r}"
    door = importlib.import_module(f"robomorph.{name}")
    sub = getattr(door, f"build_{args[0]}_parser", None) if args else None
    build = sub or getattr(door, "build_parser", None)
    if build is None:
        text = helps[name]
        for token in args:
            if token.startswith("--"):
                flag = token.split("=", 1)[0]
                assert re.search(rf"(^|[\s\[,]){re.escape(flag)}([\s\],=]|$)", text, re.M), f"{name}: no option {flag}"
        return
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            parser = build()
            parser.allow_abbrev = False  # the docs spell every option in full
            parser.parse_args(args[1:] if sub else args)
        except SystemExit as stop:
            assert stop.code == 0, f"robomorph {' '.join(call)}: {err.getvalue().strip()}"


def test_every_command_line_of_the_examples_parses(helps):
    checked = 0
    for page in pages():
        for block in blocks(page, "bash"):
            for call in command_lines(block.code):
                try:
                    _check_call(call, helps)
                except AssertionError as exc:
                    raise AssertionError(f"{block.where}: {exc}") from None
                checked += 1
    assert checked >= 40  # the guide's examples, not a parser that found nothing


def test_a_wrong_option_in_an_example_is_caught(helps):
    """Negative control of the check above: a misspelled option fails it, for argparse and for fit."""
    with pytest.raises(AssertionError, match="unrecognized arguments: --rob"):
        _check_call(["generate", "--rob", "3", "--out", "x.zarr"], helps)  # an abbreviation is refused too
    with pytest.raises(AssertionError, match="argument --gravity-compensation: invalid choice"):
        _check_call(["generate", "--gravity-compensation", "true", "--out", "x.zarr"], helps)
    with pytest.raises(AssertionError, match="no option --data.store"):
        _check_call(["fit", "--data.store", "x.zarr"], helps)


# --- the README -------------------------------------------------------------------------------------

# Flags appended to the README's quick start so that it runs in seconds (the last value of a flag wins).
TINY = {
    "generate": {"data/train.zarr": ["--robots", "12", "--workers", "1", "--quiet"],
                 "data/test.zarr": ["--robots", "4", "--workers", "1", "--quiet"]},
    "fit": ["--trainer.max_steps", "2", "--trainer.val_check_interval", "2", "--data.batch_size", "4",
            "--data.val_subset", "2", "--trainer.accelerator", "cpu", "--wandb", "disabled"],
    "evaluate": ["--n", "4", "--baselines", "hold", "--plot-trajectories", "1"],
    "report": [],
}


@pytest.mark.slow
def test_readme_quickstart_runs(tmp_path):
    from robomorph.cli import main

    (tmp_path / "datamodules").symlink_to(ROOT / "datamodules")
    shell = next(b for b in blocks(README, "bash") if "robomorph generate" in b.code)
    calls = command_lines(shell.code)
    assert [c[0] for c in calls] == ["generate", "generate", "fit", "evaluate", "report"]
    with _inside(tmp_path):
        for call in calls:
            extra = TINY[call[0]]
            if isinstance(extra, dict):
                extra = extra[call[call.index("--out") + 1]]
            assert main([*call, *extra]) == 0, call
    assert (tmp_path / "results/runs/quick/eval/test/metrics.json").is_file()
    assert (tmp_path / "results/report.html").is_file()
    _run_blocks(README, tmp_path)


def test_readme_is_the_front_door():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    (setup,) = [b for b in blocks(README, "bash") if "make demo" in b.code]
    assert [line.split("#")[0].strip() for line in setup.code.strip().splitlines()] == ["make demo", "make test"]
    assert "make docs" in text and "site/index.html" in text
    for target in re.findall(r"\]\(([^)#\s]+)", text):  # local links and the picture exist
        if "://" not in target:
            assert (ROOT / target).exists(), target


@pytest.mark.parametrize("section", ["## Headline result", "## Model-predictive control"])
def test_readme_headline_numbers_are_those_of_its_results_file(section):
    text = README.read_text().split(section, 1)[1].split("\n## ", 1)[0]
    # The sentence that introduces a table names its results file, and may name a second one for a row
    # measured on fewer windows (the headline's identified physics, 15 s a window on a busy machine).
    intro = re.search(r"From `results/.*?:\n", text, re.S).group(0)
    sources = re.findall(r"`(results/[^`]+\.md)`", intro)
    cells = {c for s in sources for c in re.findall(r"\|\s*([^|\n]*?)\s*(?=\|)", (ROOT / s).read_text())}
    numbers = re.findall(r"\|\s*(-?\d+(?:\.\d+)?)\s*(?=\|)", text)
    assert len(numbers) >= 20
    missing = [n for n in numbers if n not in cells]
    assert not missing, f"README numbers not in {sources}: {missing}"
