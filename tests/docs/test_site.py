"""The documentation site: strict build, generated pages, offline viewing, a screenshot."""

from __future__ import annotations

import importlib
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from matplotlib.image import imread
from mkdocs.exceptions import PluginError

from tests.docs.examples import ROOT, load_hook

ENV = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's banner about MkDocs 2 is not a build warning


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(config),
                           "--site-dir", str(site)], cwd=ROOT, capture_output=True, text=True, timeout=600, env=ENV)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site as `make docs` builds it (strict), in a temporary folder."""
    out = tmp_path_factory.mktemp("site") / "site"
    done = _build(ROOT / "mkdocs.yml", out)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout}{done.stderr}"
    return out


@pytest.mark.slow
def test_strict_build_writes_every_page_of_the_nav(site):
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]

    def leaves(items):
        for item in items:
            for value in item.values():
                yield from leaves(value) if isinstance(value, list) else [value]

    pages = list(leaves(nav))
    assert "reference/commands.md" in pages and "reference/api.md" in pages
    for page in pages:
        assert (site / page.replace(".md", ".html")).is_file(), page
    assert not (site / "hooks").exists()  # the hook is excluded from the site


@pytest.mark.slow
def test_command_reference_has_every_command_and_option(site):
    from robomorph.cli import COMMANDS

    html = (site / "reference" / "commands.html").read_text()
    for name in COMMANDS:
        assert f'id="robomorph-{name}"' in html, name
        door = importlib.import_module(f"robomorph.{name}")
        if hasattr(door, "build_parser"):
            for action in door.build_parser()._actions:
                for option in action.option_strings:
                    assert option in html, f"{name} {option}"
    # fit's options come from its LightningCLI, sweep's subcommand from its own parser
    for option in ("--data.stores", "--model.d_model", "--trainer.max_steps", "--run"):
        assert option in html
    assert 'id="robomorph-sweep-summary"' in html


@pytest.mark.slow
def test_result_pages_show_the_committed_files(site):
    html = (site / "results" / "benchmarks.html").read_text()
    # A line of a committed results page, a table rendered from a CSV, and a figure copied into the site
    first_row = next(line for line in (ROOT / "results/benchmarks/eval1000/table.md").read_text().splitlines()
                     if line.startswith("| joints"))
    assert first_row.split("|")[3].strip() in html
    assert 'id="formulations"' in html and "joint_rms_mrad_step60" in html
    assert (site / "raw/results/benchmarks/eval1000/error_growth.png").is_file()
    assert "last commit" in html
    paper = (site / "results" / "paper.html").read_text()
    assert 'id="small-table1"' in paper and "test0" in paper


@pytest.mark.slow
def test_api_reference_is_generated_from_docstrings(site):
    html = (site / "reference" / "api.html").read_text()
    for name in ("robomorph.predictor.Predictor", "robomorph.data.store.open_store", "robomorph.training.fitting.fit",
                 "robomorph.evaluation.scoring.score_windows", "robomorph.model.transformer.MetaModel"):
        assert f'id="{name}"' in html, name
    assert "simulate" in html and "from_checkpoint" in html


@pytest.mark.slow
def test_site_loads_nothing_from_the_network(site):
    """No stylesheet, script, font or image of any page comes from another host."""
    fetched = re.compile(r'<(?:link|script|img|iframe|source)\b[^>]*\b(?:src|href)="(https?:)?//', re.I)
    for page in site.rglob("*.html"):
        text = page.read_text()
        assert not fetched.search(text), page
        assert "fonts.googleapis" not in text and "fonts.gstatic" not in text, page


@pytest.mark.slow
def test_screenshot_of_the_home_page(site, tmp_path):
    out = tmp_path / "home.png"
    done = subprocess.run(["bash", str(ROOT / "tools" / "docs_screenshot.sh"), str(site), str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env=ENV)
    assert done.returncode == 0, done.stdout + done.stderr
    pixels = imread(io.BytesIO(out.read_bytes()), format="png")[..., :3]
    assert pixels.shape[:2] == (1000, 1280)
    colours = np.unique((pixels.reshape(-1, 3) * 255).astype(np.uint8), axis=0)
    assert len(colours) > 200  # text, the header bar and the figure; a blank or error page has a handful
    # The header bar is the theme's indigo, so the stylesheet loaded from the site itself.
    r, g, b = (pixels[20, 640] * 255).astype(int)
    assert b > r + 60 and b > g + 60


def test_strict_settings_refuse_a_broken_link_and_a_missing_anchor(tmp_path):
    """The validation settings of mkdocs.yml turn a bad link into a failed build (a tiny site)."""
    ours = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# Home\n\n[fine](other.md#a-heading)\n")
    (docs / "other.md").write_text("# Other\n\n## A heading\n")
    config = tmp_path / "mkdocs.yml"
    base = {"site_name": "t", "docs_dir": str(docs), "strict": ours["strict"], "validation": ours["validation"],
            "nav": ["index.md", "other.md"]}
    config.write_text(yaml.safe_dump(base))
    assert _build(config, tmp_path / "ok").returncode == 0
    for bad in ("[gone](missing.md)", "[gone](other.md#no-such-heading)"):
        (docs / "index.md").write_text(f"# Home\n\n{bad}\n")
        done = _build(config, tmp_path / "bad")
        assert done.returncode != 0 and "WARNING" in done.stderr, bad


def test_include_of_a_missing_results_file_stops_the_build():
    hook = load_hook()
    with pytest.raises(PluginError, match="results/benchmarks/nope.md does not exist"):
        hook.include_file("results/benchmarks/nope.md", 2, "results/benchmarks.md")


def test_included_markdown_keeps_code_comments_and_moves_headings_down(tmp_path, monkeypatch):
    hook = load_hook()
    monkeypatch.setattr(hook, "ROOT", tmp_path)
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "r.md").write_text("# Title\n\nCommand:\n\n```bash\n# a comment\nrun\n```\n\n## Part\n")
    (tmp_path / "results" / "t.csv").write_text("# made by: bench.py --x 1\na,b\n1.234567891,x|y\n")
    md = hook.include_file("results/r.md", 2, "results/index.md")
    assert md.startswith("## Title {#r}") and "\n# a comment\n" in md and "\n#### Part" in md
    table = hook.include_file("results/t.csv", 3, "results/index.md")
    assert "made by: bench.py --x 1" in table and "| 1.235 | x\\|y |" in table and "[file](../raw/results/t.csv)" in table


def test_dir_include_shows_pages_figures_and_tables_and_links_the_rest(tmp_path, monkeypatch):
    hook = load_hook()
    monkeypatch.setattr(hook, "ROOT", tmp_path)
    folder = tmp_path / "results" / "bench"
    (folder / "sub").mkdir(parents=True)
    (folder / "README.md").write_text("# Index\n")
    (folder / "run.md").write_text("# Run\n")
    (folder / "run_curves.csv").write_text("step,x\n1,2\n")  # presented by run.md: linked, not shown
    (folder / "alone.csv").write_text("a,b\n1,2\n")
    (folder / "fig.png").write_bytes(b"\x89PNG")
    (folder / "sub" / "table.md").write_text("# Sub table\n")
    md = hook.include_dir("results/bench", 2, "results/bench.md")
    assert md.index("## Index") < md.index("## Run") < md.index("## fig.png") < md.index("## alone.csv")
    assert "![fig.png](../raw/results/bench/fig.png)" in md
    assert "[`run_curves.csv`](../raw/results/bench/run_curves.csv)" in md
    assert "## `results/bench/sub/` {#sub}" in md and "### Sub table {#sub-table}" in md
