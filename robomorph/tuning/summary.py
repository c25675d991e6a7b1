"""``python -m robomorph.sweep summary``: a study's trials, best parameters and importances.

    python -m robomorph.sweep summary --study-name architecture-cpu [--storage URL]

Prints a markdown table and writes it (``summary.md``) with ``trials.csv`` beside the
study's runs, into ``<runs_dir>/<study>-summary/`` (``study.json`` there records which
study of which storage the folder holds, so a same-named study of another storage never
overwrites it). The same storage opens in the Optuna dashboard::

    optuna-dashboard sqlite:///results/sweeps/optuna.db
"""

from __future__ import annotations

import csv
import json
import math
import os

import optuna

from robomorph.core.atomic import atomic_open, write_json, write_text
from robomorph.core.results import markdown_table
from robomorph.tuning.space import SpaceError
from robomorph.tuning.storage import open_storage, storage_identity

COLUMNS = ("number", "state", "value", "duration_s", "run_dir")


def trial_rows(study: optuna.Study) -> list[dict]:
    """One dict per trial: number, state, value, duration, run directory and every parameter."""
    rows = []
    for t in study.get_trials(deepcopy=False):
        dur = (t.datetime_complete - t.datetime_start).total_seconds() if t.datetime_complete and t.datetime_start else None
        retried = t.system_attrs.get("failed_trial")  # set by the heartbeat retry callback
        rows.append({"number": t.number, "state": t.state.name, "value": t.value,
                     "duration_s": None if dur is None else round(dur, 1), "run_dir": t.user_attrs.get("run_dir", ""),
                     "retry_of": retried if retried is not None else "", **t.params})
    return rows


def importances(study: optuna.Study) -> dict[str, float] | str:
    """fANOVA importances of the completed trials, or the reason there are none."""
    complete = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE]
    if len(complete) < 2:
        return f"needs at least 2 complete trials ({len(complete)} so far)"
    try:
        return optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError) as exc:  # e.g. a parameter that never varied
        return str(exc)


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return "" if v is None else str(v)


def summarize(study: optuna.Study, out_dir: str | None = None) -> str:
    """The summary text (markdown); with ``out_dir``, also ``summary.md`` and ``trials.csv``."""
    rows = trial_rows(study)
    params = sorted({k for r in rows for k in r} - set(COLUMNS) - {"retry_of"})
    head = [*COLUMNS[:4], "retry_of", *params, "run_dir"]
    counts = {s: sum(r["state"] == s for r in rows) for s in ("COMPLETE", "PRUNED", "FAIL", "RUNNING", "WAITING")}
    lines = [f"# Study `{study.study_name}` ({study.direction.name.lower()})", "",
             "trials: " + ", ".join(f"{k.lower()} {v}" for k, v in counts.items() if v), "",
             markdown_table(head, [[_fmt(r.get(k)) for k in head] for r in rows])]
    try:
        best = study.best_trial
        lines += ["", f"**best**: trial {best.number}, value {_fmt(best.value)}, params {best.params}, "
                      f"run {best.user_attrs.get('run_dir', '')}"]
    except ValueError:
        lines += ["", "**best**: no complete trial yet"]
    imp = importances(study)
    lines += ["", "parameter importances (fANOVA): " + (imp if isinstance(imp, str) else
                                                        ", ".join(f"{k} {v:.3f}" for k, v in imp.items()))]
    text = "\n".join(lines) + "\n"
    if out_dir:
        os.makedirs(out_dir, exist_ok=True)
        write_text(os.path.join(out_dir, "summary.md"), text)
        with atomic_open(os.path.join(out_dir, "trials.csv")) as f:
            w = csv.DictWriter(f, fieldnames=head, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
    return text


def summary_dir(runs_dir: str, study_name: str) -> str:
    """Where a study's summary goes: beside its runs (``<runs_dir>/<study>-summary``)."""
    return os.path.join(runs_dir, f"{study_name}-summary")


def runs_dir_of(study: optuna.Study, default: str = "results/runs") -> str:
    """The folder the study's trials ran in (from their recorded run directories)."""
    for t in study.get_trials(deepcopy=False):
        if t.user_attrs.get("run_dir"):
            return os.path.dirname(t.user_attrs["run_dir"])
    return default


def claim_summary_dir(out_dir: str, study_name: str, storage_url: str | None) -> None:
    """Records in ``out_dir/study.json`` which study it summarizes; refuses another study's folder.

    Raises:
        SpaceError: ``out_dir`` already holds the summary of a study of that name in another
            storage (or of another study).
    """
    ident = {"study_name": study_name, "storage": storage_identity(storage_url)}
    marker = os.path.join(out_dir, "study.json")
    if os.path.isfile(marker):
        try:
            with open(marker) as f:
                held = json.load(f)
        except (OSError, ValueError):
            held = None
        if held != ident:
            raise SpaceError(
                f"{out_dir} holds the summary of another study ({held}); this is study {study_name!r} of "
                f"{ident['storage']}: pass another --runs-dir (or --out for the summary) or --study-name")
        return
    if os.path.isfile(os.path.join(out_dir, "summary.md")):
        raise SpaceError(f"{out_dir} holds a summary of unknown origin (no study.json); pass another "
                         "--runs-dir (or --out) or remove that folder")
    os.makedirs(out_dir, exist_ok=True)
    write_json(marker, ident)


def load_study(study_name: str, storage_url: str | None = None) -> optuna.Study:
    """The study ``study_name`` of a storage (default: the local SQLite one).

    Raises:
        SpaceError: the storage cannot be opened or holds no such study (its studies are named).
    """
    storage = open_storage(storage_url)
    try:
        return optuna.load_study(study_name=study_name, storage=storage)
    except KeyError:
        names = [s.study_name for s in optuna.get_all_study_summaries(storage)]
        raise SpaceError(f"no study {study_name!r} in this storage; it holds {names}") from None
