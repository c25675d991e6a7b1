"""MkDocs hook: pages written from the code and the committed results, so they cannot go stale.

Markers in a page's Markdown (HTML comments, so a page reads sensibly without the hook):

- ``<!-- robomorph:commands -->``: one section per command of ``robomorph.cli.COMMANDS``
  with its ``--help`` text, taken from the command itself (``build_parser()`` of the door,
  any ``build_<sub>_parser()`` for its subcommands, or its ``main(["--help"])``, which is
  how the LightningCLI of ``fit`` prints its options). A command added to ``COMMANDS``
  appears here without touching the docs.
- ``<!-- robomorph:vocabulary -->``: the table of option names that several commands share, with
  their one meaning and their names before (``robomorph.core.options.VOCABULARY``).
- ``<!-- robomorph:include PATH -->``: the file ``PATH`` (relative to the repository root)
  inside the page, under a heading that names it and its last commit: Markdown with its
  headings moved below the page's, CSV as a table, text as a code block, PNG as an image.
- ``<!-- robomorph:include-dir PATH -->``: every result file of a folder, the same way,
  Markdown first, then figures, then tables without a Markdown page of their own; files
  too large to show (long per-step CSV curves, JSON) are linked for download.

Every data file and figure under ``results/`` is also copied into the site as
``raw/results/...``, so pages can show its figures and link its data. A marker naming a file that does not exist stops
the build with the path named.
"""

from __future__ import annotations

import contextlib
import csv
import importlib
import io
import os
import posixpath
import re
import subprocess
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
RESULTS = "results"
RAW = "raw"  # where the results files land in the site
HELP_COLUMNS = "80"
MAX_TABLE_ROWS, MAX_TABLE_COLUMNS = 40, 20
SHOWN = {".md", ".csv", ".txt", ".png"}
# Markdown files are shown inside the pages, not copied (MkDocs would build them as pages).
COPIED = {".csv", ".txt", ".png", ".json", ".tex", ".log"}

_MARKER = re.compile(r"<!--\s*robomorph:(commands|vocabulary|include-dir|include)\s*([^>]*?)\s*-->")
_FENCE = re.compile(r"^\s*(```|~~~)")
_HEADING = re.compile(r"^(#{1,6})(\s+.*)$")


# --- the command reference -------------------------------------------------------------------


def _capture_help(call) -> str:
    """Runs ``call`` with stdout captured and a fixed terminal width; returns what it printed."""
    out = io.StringIO()
    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS
    try:
        with contextlib.redirect_stdout(out):
            try:
                call()
            except SystemExit as stop:  # --help exits 0 once printed
                if stop.code not in (0, None):
                    raise PluginError(f"--help exited with code {stop.code}:\n{out.getvalue()}") from None
    finally:
        if before is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = before
    return out.getvalue().rstrip()


def command_helps() -> list[tuple[str, str, str]]:
    """``(command line, one-line summary, --help text)`` for every command and subcommand."""
    from robomorph.cli import COMMANDS, DOORS

    found = []
    for name, what in COMMANDS.items():
        door = importlib.import_module(DOORS.get(name, f"robomorph.{name}"))
        if hasattr(door, "build_parser"):
            found.append((f"robomorph {name}", what, _capture_help(lambda d=door: d.build_parser().print_help())))
        else:
            found.append((f"robomorph {name}", what, _capture_help(lambda d=door: d.main(["--help"]))))
        for attr in sorted(vars(door)):
            sub = re.fullmatch(r"build_(\w+)_parser", attr)
            if sub:
                text = _capture_help(lambda f=getattr(door, attr): f().print_help())
                found.append((f"robomorph {name} {sub.group(1)}", f"the `{sub.group(1)}` subcommand of `{name}`", text))
    return found


def commands_markdown() -> str:
    helps = command_helps()
    rows = ["| command | what it does |", "|---|---|"]
    rows += [f"| [`{line}`](#{_slug(line)}) | {what} |" for line, what, _ in helps]
    sections = []
    for line, what, text in helps:
        sections.append(f"## `{line}` {{#{_slug(line)}}}\n\n{what[:1].upper()}{what[1:]}.\n\n```text\n{text}\n```\n")
    return "\n".join(rows) + "\n\n" + "\n".join(sections)


def vocabulary_markdown() -> str:
    """The options that several commands take, each with its one meaning and the names it had before."""
    from robomorph.core.options import RENAMED_ON, VOCABULARY

    old_on = {new: [f"`{old}` ({name})" for (name, old), n in RENAMED_ON.items() if n == new] for new in VOCABULARY}
    rows = ["| option | means, on every command that takes it | its name before |", "|---|---|---|"]
    for option, (meaning, olds) in VOCABULARY.items():
        before = ", ".join([f"`{o}`" for o in olds] + old_on[option]) or "—"
        rows.append(f"| `{option}` | {meaning} | {before} |")
    return "\n".join(rows) + "\n"


# --- results files ---------------------------------------------------------------------------


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def _last_commit(rel: str) -> str:
    """``abc1234, 2026-01-31`` for the file's last commit, or why there is none."""
    try:
        done = subprocess.run(["git", "log", "-1", "--format=%h, %cs", "--", rel], cwd=ROOT, capture_output=True,
                              text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return "no git history here"
    return done.stdout.strip() or "not committed yet"


def _raw_link(rel: str, page_uri: str) -> str:
    """The site-relative link from the page to the copy of ``rel`` under raw/."""
    return posixpath.relpath(f"{RAW}/{rel}", posixpath.dirname(page_uri) or ".")


def _demote(markdown: str, by: int) -> tuple[str | None, str]:
    """Splits off the first H1 (the file's title) and moves the other headings down ``by`` levels.

    Lines inside fenced code blocks are left alone: a ``# comment`` there is shell, not a heading.
    """
    title, out, fenced = None, [], False
    for line in markdown.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
        match = None if fenced else _HEADING.match(line)
        if match and title is None and len(match.group(1)) == 1 and not out:
            title = match.group(2).strip()
            continue
        if match:
            line = "#" * min(6, len(match.group(1)) + by) + match.group(2)
        out.append(line)
    return title, "\n".join(out).strip()


def _csv_table(path: Path) -> tuple[list[str], str]:
    """Comment lines (``# ...``, provenance) and the CSV as a Markdown table."""
    text = path.read_text()
    notes = [line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")]
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#")))
    if not rows:
        return notes, "*(empty)*"
    width = max(len(r) for r in rows)
    rows = [r + [""] * (width - len(r)) for r in rows]

    def cell(value: str) -> str:
        # Long floats as 4 significant digits: the table is for reading, the file keeps all.
        if re.fullmatch(r"-?\d+\.\d{5,}(e[-+]?\d+)?", value):
            value = f"{float(value):.4g}"
        return value.replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(cell(v) for v in rows[0]) + " |", "|" + "---|" * width]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows[1:]]
    return notes, "\n".join(lines)


def _shows_as_table(path: Path) -> bool:
    with path.open(newline="") as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))]
    return 1 < len(rows) <= MAX_TABLE_ROWS + 1 and max(len(r) for r in rows) <= MAX_TABLE_COLUMNS


def include_file(rel: str, level: int, page_uri: str, root: str = RESULTS) -> str:
    """The Markdown that shows the results file ``rel`` under a heading of ``level``.

    Its anchor is the file's path under ``root`` without the suffix, slugged
    (``results/benchmarks/robots30.md`` under ``results/benchmarks``: ``#robots30``).
    """
    path = ROOT / rel
    if not path.is_file():
        raise PluginError(f"robomorph:include: {rel} does not exist (included by {page_uri})")
    suffix = path.suffix.lower()
    heading_id = _slug(posixpath.relpath(rel, root).rsplit(".", 1)[0])
    title, body, notes = None, "", []
    if suffix == ".md":
        title, body = _demote(path.read_text(), level)
    elif suffix == ".csv":
        notes, body = _csv_table(path)
    elif suffix == ".txt":
        body = f"```text\n{path.read_text().rstrip()}\n```"
    elif suffix == ".png":
        body = f"![{path.name}]({_raw_link(rel, page_uri)})"
    else:
        raise PluginError(f"robomorph:include: cannot show {rel} (only {', '.join(sorted(SHOWN))})")
    link = "" if suffix == ".md" else f"[file]({_raw_link(rel, page_uri)}); "
    source = f"`{rel}` ({link}last commit {_last_commit(rel)})"
    note = "".join(f"\n\n{n}" for n in notes)
    return f"{'#' * level} {title or path.name} {{#{heading_id}}}\n\n*{source}*{note}\n\n{body}\n"


def _companion_md(path: Path) -> bool:
    """A CSV that a Markdown page of its folder already presents (``robots30_1024.csv`` -> ``robots30.md``)."""
    return any(path.stem.startswith(md.stem) for md in path.parent.glob("*.md"))


def include_dir(rel: str, level: int, page_uri: str, root: str | None = None) -> str:
    root = root or rel
    folder = ROOT / rel
    if not folder.is_dir():
        raise PluginError(f"robomorph:include-dir: {rel} is not a folder (included by {page_uri})")
    files = sorted(p for p in folder.iterdir() if p.is_file())
    readme = [p for p in files if p.name.lower() == "readme.md"]
    pages = readme + [p for p in files if p.suffix == ".md" and p not in readme]
    figures = [p for p in files if p.suffix == ".png"]
    texts = [p for p in files if p.suffix == ".txt"]
    tables = [p for p in files if p.suffix == ".csv" and not _companion_md(p) and _shows_as_table(p)]
    shown = pages + texts + figures + tables
    parts = [include_file(p.relative_to(ROOT).as_posix(), level, page_uri, root) for p in shown]
    others = [p for p in files if p not in shown and p.suffix.lower() in COPIED]
    if others:
        links = ", ".join(f"[`{p.name}`]({_raw_link(p.relative_to(ROOT).as_posix(), page_uri)})" for p in others)
        parts.append(f"Data files of `{rel}/` (download): {links}.\n")
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        sub_rel = sub.relative_to(ROOT).as_posix()
        parts.append(f"{'#' * level} `{sub_rel}/` {{#{_slug(posixpath.relpath(sub_rel, root))}}}\n")
        parts.append(include_dir(sub_rel, min(level + 1, 6), page_uri, root))
    return "\n".join(parts)


# --- MkDocs events ---------------------------------------------------------------------------


def on_files(files, config):
    """Copies every committed-results file into the site under raw/ (figures, tables, data)."""
    for path in sorted((ROOT / RESULTS).rglob("*")):
        parts = path.relative_to(ROOT / RESULTS).parts
        # Runs, sweeps and the dashboard are local outputs (gitignored), not committed results.
        if path.is_file() and path.suffix.lower() in COPIED and parts[0] not in ("runs", "sweeps"):
            rel = path.relative_to(ROOT).as_posix()
            files.append(File.generated(config, f"{RAW}/{rel}", abs_src_path=str(path)))
    return files


def on_page_markdown(markdown, page, config, files):
    def expand(match: re.Match) -> str:
        kind, arg = match.group(1), match.group(2).strip()
        level = _level_before(markdown, match.start())
        if kind == "commands":
            return commands_markdown()
        if kind == "vocabulary":
            return vocabulary_markdown()
        if kind == "include":
            return include_file(arg, level, page.file.src_uri)
        return include_dir(arg.rstrip("/"), level, page.file.src_uri)

    return _MARKER.sub(expand, markdown)


def _level_before(markdown: str, pos: int) -> int:
    """One below the last heading before ``pos`` (2 when there is only the page title)."""
    levels, fenced = [1], False
    for line in markdown[:pos].splitlines():
        if _FENCE.match(line):
            fenced = not fenced
        match = None if fenced else _HEADING.match(line)
        if match:
            levels.append(len(match.group(1)))
    return min(6, levels[-1] + 1)
