"""The one writer of result files (CSV and Markdown) and the one Markdown-table helper.

Every result file says where it came from: the command that wrote it, the git commit of
the code (``-dirty`` when the working tree had uncommitted changes), the date (UTC) and
the machine. A CSV carries it as ``# `` comment lines above the rows that command wrote
(an append from another command adds its own comment block before its rows); a Markdown
file carries it as a first line ``<!-- provenance: ... -->`` followed by a visible line.

    rows = ResultsCsv("results/benchmarks/x.csv")        # provenance of this process
    rows.append({"variant": "full", "r2": 0.61})          # header written on first use
    rows.append({"variant": "full", "r2": 0.61, "x": 1})  # refused: ResultsError

:func:`read_rows` reads such a CSV back (comment lines skipped). Appending rows whose
columns differ from the file's header is refused with one line, so a file never mixes
column layouts. torch-free (``core``): the machine line names a GPU only when torch is
already imported.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import io
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Iterable, Sequence

from robomorph.core.atomic import check_replaceable, write_text
from robomorph.core.errors import RoboMorphError

COMMENT = "# "
_REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class ResultsError(RoboMorphError, ValueError):
    """A result file that cannot take the rows given (another header) or cannot be read."""


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=_REPO, capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def git_commit() -> str:
    """The commit of the code that runs, ``-dirty`` when tracked files differ from it;
    ``unknown`` outside a git checkout (an installed wheel)."""
    head = _git("rev-parse", "--short=12", "HEAD")
    if not head:
        return "unknown"
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return f"{head}-dirty" if dirty else head


def machine() -> str:
    """CPU model and core count, OS, Python, and the GPU when torch is loaded and sees one."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    parts = [f"{cpu}, {os.cpu_count()} cores", f"{platform.system()} {platform.release()}",
             f"Python {platform.python_version()}"]
    torch = sys.modules.get("torch")
    if torch is not None:
        parts.append(f"torch {torch.__version__}")
        if torch.cuda.is_available():
            parts.append(f"GPU {torch.cuda.get_device_name(0)}")
    return "; ".join(parts)


def provenance(command: Sequence[str] | str | None = None) -> dict:
    """``{"command", "commit", "date", "machine"}`` of this process (``command``: default ``sys.argv``)."""
    if command is None:
        command = [os.path.relpath(sys.argv[0]) if sys.argv and sys.argv[0] else "python", *sys.argv[1:]]
    # The program may be a two-word name ("robomorph evaluate"): printed as is, the arguments quoted.
    if isinstance(command, str):
        cmd = command
    else:
        program, *args = [str(c) for c in command] or [""]
        cmd = f"{program} {shlex.join(args)}".rstrip()
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    return {"command": cmd, "commit": git_commit(), "date": date, "machine": machine()}


def provenance_lines(prov: dict) -> list[str]:
    """The provenance as ``key: value`` lines (the CSV comment block, without the ``# ``)."""
    return [f"{key}: {prov[key]}" for key in ("command", "commit", "date", "machine")]


def provenance_markdown(prov: dict) -> str:
    """One visible Markdown line naming the command, commit, date and machine."""
    return (f"*Produced by `{prov['command']}` at commit `{prov['commit']}` on {prov['date']}; "
            f"machine: {prov['machine']}.*")


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence], align: Sequence[str] | str | None = None,
                   floatfmt: str = ".4g") -> str:
    """A GitHub-flavoured (pipe) Markdown table: the one place tables are written.

    Args:
        headers: column titles.
        rows: cell values; strings are printed as given, numbers with ``floatfmt``, None empty.
        align: ``left``/``right``/``center`` for all columns or one per column (default:
            right for columns holding only numbers, left otherwise).

    Returns:
        The table, lines joined with ``\\n``, without a trailing newline.
    """
    from tabulate import tabulate  # noqa: PLC0415  (only writers of tables need it)

    rows = [list(r) for r in rows]
    numeric = [all(_is_number(r[i]) for r in rows if r[i] is not None and r[i] != "") and
               any(_is_number(r[i]) for r in rows) for i in range(len(headers))]
    cells = [[_cell(v, floatfmt) for v in r] for r in rows]
    if align is None:
        colalign = ["right" if n else "left" for n in numeric]
    else:
        colalign = [align] * len(headers) if isinstance(align, str) else list(align)
    if not cells:
        return "| " + " | ".join(headers) + " |\n|" + "|".join("---" for _ in headers) + "|"
    # disable_numparse: every cell is already text, printed as given ("0.10" stays "0.10").
    return tabulate(cells, headers=list(headers), tablefmt="pipe", colalign=colalign, disable_numparse=True)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _cell(v, floatfmt: str) -> str:
    if v is None:
        return ""
    text = format(v, floatfmt) if isinstance(v, float) else str(v)
    return text.replace("|", "\\|")


def write_markdown(path: str, text: str, prov: dict | None = None, flag: str = "--md") -> None:
    """Writes a Markdown result file (atomically) that opens with its provenance line.

    It replaces only an earlier result file (or an empty one), never a checkpoint, a page, a
    user's notes or anything in a Zarr store (:func:`robomorph.core.atomic.check_replaceable`);
    a script calls that check itself before its long work too, with its ``flag``.
    """
    check_replaceable(path, "markdown", flag)
    prov = prov or provenance()
    write_text(path, f"{provenance_markdown(prov)}\n\n{text.rstrip()}\n")


def _header(path: str) -> list[str] | None:
    """The column names of an existing CSV (its first line that is not a comment), or None."""
    if not os.path.isfile(path):
        return None
    with open(path, newline="") as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                return next(csv.reader([line]))
    return None


def read_rows(path: str) -> list[dict]:
    """The rows of a CSV written by :class:`ResultsCsv` (comment lines skipped), as dicts of strings."""
    if not os.path.isfile(path):
        raise ResultsError(f"result file not found: {path}")
    with open(path, newline="") as f:
        lines = [line for line in f if not line.startswith("#")]
    return list(csv.DictReader(lines))


def read_provenance(path: str) -> list[dict]:
    """Each provenance block of a CSV written by :class:`ResultsCsv`, in file order."""
    blocks, current = [], {}
    with open(path, newline="") as f:
        for line in f:
            if not line.startswith(COMMENT):
                current = {}
                continue
            key, _, value = line[len(COMMENT):].rstrip("\n").partition(": ")
            if key == "command":
                current = {}
                blocks.append(current)
            current[key] = value
    return blocks


class ResultsCsv:
    """Rows appended to one CSV, under one provenance block for this writer's rows.

    Args:
        path: the CSV (created with its folder when missing).
        overwrite: start the file afresh (default: append to what is there).
        prov: the provenance to record (default: :func:`provenance` of this process).
    """

    def __init__(self, path: str, overwrite: bool = False, prov: dict | None = None):
        self.path, self.prov, self.stamped = path, prov or provenance(), False
        check_replaceable(path, "csv", "--csv")  # never appended to a checkpoint, a page or a store's file
        if overwrite and os.path.exists(path):
            os.remove(path)

    def append(self, row: dict) -> None:
        self.extend([row])

    def extend(self, rows: Sequence[dict]) -> None:
        """Appends ``rows`` (all with the same columns, in order).

        Raises:
            ResultsError: rows of differing columns, or columns other than the file's header.
        """
        if not rows:
            return
        header = _header(self.path)
        text = _csv_text(self.path, rows, None if self.stamped else self.prov, header)
        os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)
        with open(self.path, "a", newline="") as f:
            f.write(text)
        self.stamped = True


def _csv_text(path: str, rows: Sequence[dict], prov: dict | None, header: list[str] | None) -> str:
    """``rows`` as CSV text: the provenance block (when ``prov``), the header (when the file has
    none yet), the rows; rows of differing columns, or columns other than ``header``, are refused."""
    columns = list(rows[0])
    if odd := [list(r) for r in rows if list(r) != columns]:
        raise ResultsError(f"rows for {path} differ in their columns: {columns} and {odd[0]}")
    if header is not None and header != columns:
        extra, missing = [c for c in columns if c not in header], [c for c in header if c not in columns]
        raise ResultsError(f"{path} has other columns than the rows to append (new: {extra or 'none'}; "
                           f"missing: {missing or 'none'}; or another order): write to another file or move "
                           "the old one away")
    buf = io.StringIO()
    if prov is not None:
        buf.writelines(f"{COMMENT}{line}\n" for line in provenance_lines(prov))
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    if header is None:
        writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def write_rows(path: str, rows: Sequence[dict], prov: dict | None = None) -> None:
    """Writes ``rows`` as a new CSV with its provenance, atomically (replacing an earlier CSV table
    there, never a checkpoint, a page or anything in a Zarr store; no rows: no file)."""
    check_replaceable(path, "csv", "--csv")
    if not rows:
        with contextlib.suppress(FileNotFoundError):
            os.remove(path)
        return
    write_text(path, _csv_text(path, rows, prov or provenance(), None))
