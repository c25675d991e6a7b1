"""The tables and the figure from the evaluations already in a work folder: no data, training or evaluation.

For a reproduction cut short after some runs were scored (a GPU lease that ended before the
improved row trained), or whose ``<work>/runs`` came back from another machine without their
checkpoints and stores (``metrics.json`` files alone are enough). Each output is written from
the runs of this scale's budgets, named as the pipeline names them:

- Table 1: ``table1-L<depth>-s<steps>`` (and ``table1-improved-...``) scored on all three test
  stores; a depth without them is left out and named under the table;
- Table 2: the pre-trained, fine-tuned and scratch runs scored on ``spiral_test``, all three;
- the context figure: Table 1's middle model scored with the sweeps (``test0-sweeps``).

The headers' provenance is the evaluations' own (the command that ran them, its commit, date and
machine), with this command beside it.
"""

from __future__ import annotations

import datetime
import os

from robomorph.core.errors import MissingInputError
from robomorph.core.names import REGIMES
from robomorph.reproduction import skip
from robomorph.reproduction.improved import IMPROVED
from robomorph.reproduction.runs import (SPIRAL_EVAL, SWEEPS_EVAL, improved_run, table1_run, table2_run,
                                         table2_titles)
from robomorph.reproduction.tables import table1_rows, table2_data, write_table1, write_table2


def _scored(plan, run: str, tests) -> dict[str, dict] | None:
    """``{test: metrics.json content}`` when ``run`` holds an evaluation on every test store."""
    paths = {t: os.path.join(plan.path("runs"), plan.run_name(run), "eval", t, "metrics.json") for t in tests}
    if not all(os.path.isfile(p) for p in paths.values()):
        return None
    return {t: skip.read_json(p) for t, p in paths.items()}


def _info(plan, evaluation: dict, missing: list[str]) -> dict:
    """A header's provenance: the evaluation's (command, commit, date, machine) and this command's."""
    first = evaluation["provenance"]
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return {"scale": plan.scale.name, "command": first["command"], "normalization": plan.normalization,
            "date": first["date"], "machine": f"{first['machine']}; commit {first['commit']}",
            "budgets": plan.scale.budgets(), "inputs": plan.inputs,
            "collected": {"command": plan.command, "date": now, "missing": missing}}


def collect_table1(plan, tests: tuple[str, ...]) -> dict | None:
    """Writes ``<out>/table1.*`` from the Table 1 evaluations in ``<work>/runs``; None when no depth was scored."""
    s = plan.scale
    paper = {d: _scored(plan, table1_run(s, d), tests) for d in s.depths}
    leak_free = plan.normalization == "train_stats"  # the improved row is measured leak-free only
    improved = _scored(plan, improved_run(s), tests) if leak_free else None
    found = {d: r for d, r in paper.items() if r is not None}
    if not found:
        return None
    rows = table1_rows(found) + (table1_rows({s.transfer_depth: improved}, IMPROVED) if improved else [])
    missing = [str(d) for d in s.depths if paper[d] is None]
    missing += [] if improved or not leak_free else [f"{s.transfer_depth} ({IMPROVED})"]
    return write_table1(plan.out, rows, _info(plan, next(iter(next(iter(found.values())).values())), missing))


def collect_table2(plan) -> dict | None:
    """Writes ``<out>/table2.*`` when the three regimes were scored on the spiral; None otherwise."""
    results = {g: _scored(plan, table2_run(plan.scale, g), (SPIRAL_EVAL,)) for g in REGIMES}
    if any(r is None for r in results.values()):
        return None
    results = {g: r[SPIRAL_EVAL] for g, r in results.items()}
    return write_table2(plan.out, table2_data(results), table2_titles(plan.scale), _info(plan, results["zero_shot"], []))


def collect_context(plan) -> dict | None:
    """Writes ``<out>/context_horizon.*`` when Table 1's middle model was scored with the sweeps; None otherwise."""
    from robomorph.reproduction.figures import write_context_figure  # noqa: PLC0415  (matplotlib only when drawing)

    res = _scored(plan, table1_run(plan.scale, plan.scale.transfer_depth), (SWEEPS_EVAL,))
    if res is None:
        return None
    res = res[SWEEPS_EVAL]
    return write_context_figure(plan.out, res["sweeps"], res["meta"], _info(plan, res, []))


def collect(plan, tests: tuple[str, ...]) -> dict[str, dict]:
    """Writes what the evaluations in ``<work>/runs`` allow; returns ``{output: its JSON}``.

    Raises MissingInputError (naming the folder and the command that makes them) when they allow nothing."""
    done = {name: doc for name, doc in (("table1", collect_table1(plan, tests)), ("table2", collect_table2(plan)),
                                        ("context", collect_context(plan))) if doc is not None}
    if not done:
        s = plan.scale
        raise MissingInputError(f"{plan.path('runs')}: no Table 1 run of scale {s.name} ({s.train_steps} steps) was "
                                f"scored on {', '.join(tests)}, and no Table 2 or context evaluation is there: run "
                                f"`python -m robomorph.reproduce table1 --scale {s.name}` first")
    return done
