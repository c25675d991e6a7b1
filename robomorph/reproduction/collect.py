"""Table 1 from the evaluations already in a work folder: no data, training or evaluation.

For a reproduction cut short after some runs were scored (a GPU lease that ended before the
improved row trained), or whose ``<work>/runs`` came back from another machine without their
checkpoints and stores. The rows are the runs of this scale's budget (``table1-L<depth>-s<steps>``,
``table1-improved-L<depth>-s<steps>``) scored on all three test stores; a depth with no such
evaluations is left out and named. The header's provenance is the evaluations' own (the
command that ran them, its commit, date and machine), with this command beside it.
"""

from __future__ import annotations

import datetime
import os

from robomorph.core.errors import MissingInputError
from robomorph.reproduction import skip
from robomorph.reproduction.improved import IMPROVED
from robomorph.reproduction.tables import table1_rows, write_table1


def _scored(run_dir: str, tests: tuple[str, ...]) -> dict[str, dict] | None:
    """``{test: metrics.json content}`` when ``run_dir`` holds an evaluation on every test store."""
    paths = {t: os.path.join(run_dir, "eval", t, "metrics.json") for t in tests}
    if not all(os.path.isfile(p) for p in paths.values()):
        return None
    return {t: skip.read_json(p) for t, p in paths.items()}


def collect_table1(plan, tests: tuple[str, ...]) -> dict:
    """Writes ``<out>/table1.*`` from the Table 1 evaluations in ``<work>/runs``; returns its JSON.

    Raises MissingInputError (naming the folder and the command that makes them) when no depth
    has been scored on every test store."""
    s, runs = plan.scale, plan.path("runs")
    paper = {d: _scored(os.path.join(runs, plan.run_name(f"table1-L{d}-s{s.train_steps}")), tests) for d in s.depths}
    improved = _scored(os.path.join(runs, plan.run_name(f"table1-{IMPROVED}-L{s.transfer_depth}-s{s.train_steps}")),
                       tests) if plan.normalization == "train_stats" else None
    found = {d: r for d, r in paper.items() if r is not None}
    if not found:
        raise MissingInputError(f"{runs}: no Table 1 run of scale {s.name} ({s.train_steps} steps) was scored on "
                                f"{', '.join(tests)}: run `python -m robomorph.reproduce table1 --scale {s.name}` first")
    rows = table1_rows(found) + (table1_rows({s.transfer_depth: improved}, IMPROVED) if improved else [])
    first = next(iter(next(iter(found.values())).values()))["provenance"]
    missing = [str(d) for d in s.depths if paper[d] is None] + ([] if improved or plan.normalization != "train_stats"
                                                                   else [f"{s.transfer_depth} ({IMPROVED})"])
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    info = {"scale": s.name, "command": first["command"], "normalization": plan.normalization,
            "date": first["date"], "machine": f"{first['machine']}; commit {first['commit']}",
            "budgets": s.budgets(), "inputs": plan.inputs,
            "collected": {"command": plan.command, "date": now, "missing": missing}}
    return write_table1(plan.out, rows, info)
