"""The results writer: provenance in every file, one header per CSV, one Markdown-table helper."""

import subprocess
import sys

import pytest

from robomorph.core.results import (
    ResultsCsv,
    ResultsError,
    markdown_table,
    provenance,
    read_provenance,
    read_rows,
    write_markdown,
    write_rows,
)

PROV = {"command": "python benchmarks/x.py --fast", "commit": "abc123", "date": "2030-01-01 00:00:00 UTC",
        "machine": "test box"}


def test_a_csv_records_its_provenance_above_its_rows_and_reads_back(tmp_path):
    path = str(tmp_path / "sub" / "r.csv")
    w = ResultsCsv(path, prov=PROV)
    w.append({"variant": "a", "r2": 0.5})
    w.append({"variant": "b", "r2": 0.25})
    text = open(path).read().splitlines()
    assert text[:4] == ["# command: python benchmarks/x.py --fast", "# commit: abc123",
                        "# date: 2030-01-01 00:00:00 UTC", "# machine: test box"]
    assert text[4:] == ["variant,r2", "a,0.5", "b,0.25"]  # one provenance block for one writer
    assert read_rows(path) == [{"variant": "a", "r2": "0.5"}, {"variant": "b", "r2": "0.25"}]
    ResultsCsv(path, prov={**PROV, "command": "second run"}).append({"variant": "c", "r2": 1})
    assert [r["variant"] for r in read_rows(path)] == ["a", "b", "c"]
    assert [b["command"] for b in read_provenance(path)] == ["python benchmarks/x.py --fast", "second run"]


def test_appending_rows_of_another_header_is_refused_and_nothing_is_written(tmp_path):
    path = str(tmp_path / "r.csv")
    write_rows(path, [{"a": 1, "b": 2}], prov=PROV)
    before = open(path).read()
    with pytest.raises(ResultsError, match=r"other columns than the rows to append \(new: \['c'\]; missing: \['b'\]"):
        ResultsCsv(path, prov=PROV).append({"a": 1, "c": 3})
    with pytest.raises(ResultsError, match="another order"):
        ResultsCsv(path, prov=PROV).append({"b": 2, "a": 1})
    with pytest.raises(ResultsError, match="differ in their columns"):
        ResultsCsv(str(tmp_path / "new.csv"), prov=PROV).extend([{"a": 1}, {"b": 1}])
    assert open(path).read() == before and not (tmp_path / "new.csv").exists()
    write_rows(path, [{"c": 1}], prov=PROV)  # a new file may have any header
    assert read_rows(path) == [{"c": "1"}]


def test_a_refused_append_is_one_error_line_through_the_cli_wrapper(tmp_path):
    path = tmp_path / "r.csv"
    write_rows(str(path), [{"a": 1}], prov=PROV)
    code = ("import sys; from robomorph.core.errors import run_command; from robomorph.core.results import ResultsCsv; "
            f"sys.exit(run_command(lambda: ResultsCsv({str(path)!r}).append({{'b': 1}})))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith("error: ") and len(done.stderr.strip().splitlines()) == 1


def test_provenance_names_command_commit_date_and_machine():
    p = provenance(["python", "benchmarks/x.py", "--name", "a b"])
    assert p["command"] == "python benchmarks/x.py --name 'a b'"
    assert p["commit"] and p["machine"] and p["date"].endswith("UTC")
    # A two-word program name (the robomorph dispatcher's) is printed as the user typed it.
    assert provenance(["robomorph evaluate", "--data", "d.zarr"])["command"] == "robomorph evaluate --data d.zarr"


def test_a_markdown_result_opens_with_its_provenance(tmp_path):
    path = tmp_path / "t.md"
    write_markdown(str(path), markdown_table(["a", "b"], [["x", 1.23456]]), prov=PROV)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("*Produced by `python benchmarks/x.py --fast` at commit `abc123`")
    assert "test box" in lines[0] and lines[2].startswith("| a")


def test_markdown_table_formats_numbers_keeps_text_and_escapes_pipes():
    rows = [[c.strip() for c in line.strip("|").split("|")]
            for line in markdown_table(["name", "value", "note"], [["x", 0.123456, "0.10"], ["y", 12, None]]).splitlines()]
    assert rows[0] == ["name", "value", "note"] and set(rows[1][1]) <= set("-:") and rows[1][1].endswith(":")
    assert rows[2] == ["x", "0.1235", "0.10"] and rows[3] == ["y", "12", ""]
    assert "x\\|y" in markdown_table(["a"], [["x|y"]])
    assert markdown_table(["a", "b"], []).splitlines() == ["| a | b |", "|---|---|"]
