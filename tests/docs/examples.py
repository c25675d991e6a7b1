"""The code examples of README.md and docs/: fenced blocks and the command lines in them."""

from __future__ import annotations

import importlib.util
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
HOOK = DOCS / "hooks" / "robomorph_docs.py"

# A Python block whose fence has a title starting with "needs" is shown, not run: it needs
# something a test cannot build in seconds (the title says what). The tests list them.
SKIP_TITLE = re.compile(r'title="(needs [^"]*)"')
_FENCE = re.compile(r"^(\s*)(```+|~~~+)\s*([\w+-]*)(.*)$")


@dataclass(frozen=True)
class Block:
    page: str  # relative to the repository root
    line: int  # of the opening fence, 1-based
    lang: str
    info: str  # what follows the language on the fence line
    code: str

    @property
    def skip_reason(self) -> str | None:
        match = SKIP_TITLE.search(self.info)
        return match.group(1) if match else None

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def pages() -> list[Path]:
    """README.md and every Markdown page of the docs (not the hook's folder)."""
    return [ROOT / "README.md", *sorted(p for p in DOCS.rglob("*.md") if "hooks" not in p.relative_to(DOCS).parts)]


def blocks(page: Path, lang: str | None = None) -> list[Block]:
    """The fenced code blocks of ``page`` (indented fences too), optionally of one language."""
    found, lines, i = [], page.read_text().splitlines(), 0
    while i < len(lines):
        match = _FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        indent, fence, language, info = match.groups()
        body, j = [], i + 1
        while j < len(lines) and not lines[j].strip().startswith(fence):
            body.append(lines[j][len(indent):] if lines[j].startswith(indent) else lines[j].lstrip())
            j += 1
        if lang is None or language == lang:
            found.append(Block(page.relative_to(ROOT).as_posix(), i + 1, language, info.strip(), "\n".join(body) + "\n"))
        i = j + 1
    return found


def command_lines(code: str) -> list[list[str]]:
    """The ``robomorph <command> ...`` calls of a shell block, as argument lists after ``robomorph``.

    Continuation lines are joined and comments dropped. ``python -m robomorph.<command>`` and
    ``.venv/bin/robomorph`` count too. Lines that use shell variables (``$i``) are left out:
    their arguments are only known when the shell runs them.
    """
    calls = []
    for line in code.replace("\\\n", " ").splitlines():
        if "$" in line:
            continue
        tokens = shlex.split(line, comments=True)
        while tokens and tokens[-1] in ("&", ";", "done;", "wait"):
            tokens.pop()
        if len(tokens) >= 3 and tokens[0].endswith("python") and tokens[1] == "-m" and tokens[2].startswith("robomorph."):
            calls.append([tokens[2].removeprefix("robomorph."), *tokens[3:]])
        elif tokens and tokens[0].endswith("robomorph") and len(tokens) > 1 and not tokens[1].startswith("-"):
            calls.append(tokens[1:])
    return calls


def load_hook():
    """The MkDocs hook module (it is not part of the package)."""
    spec = importlib.util.spec_from_file_location("robomorph_docs_hook", HOOK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
