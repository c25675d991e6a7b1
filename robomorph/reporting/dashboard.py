"""``python -m robomorph.report RUNS_DIR --out results/report.html``: one page comparing runs.

Reads every run directory written by ``python -m robomorph.fit`` under ``RUNS_DIR``
(``config.yaml``, ``logs/metrics.csv``, ``checkpoints/*.ckpt`` and the evaluations in
``eval/<name>/`` written by ``robomorph.evaluate``) and writes one static HTML file that
opens offline: CSS inline, no script, every image embedded as a base64 ``data:`` URI.

The page has an overview (one row per run and evaluation) that leads with what predicts:
the joint error by horizon of the model beside holding the last output and extrapolating
the last velocity, then FIT and R² as medians over windows and over the pooled windows
(never means over per-window FITs, which one channel at rest rules), with channels that
move less than their noise marked and left out (:mod:`robomorph.evaluation.metrics`). Per
run follow its facts, checkpoints, config and evaluations, each with the error by horizon
and a per-channel table of the model beside every baseline, coloured with the paper's
fit-index convention (:func:`robomorph.reporting.html.fit_colour`); scores of the paper's
normalization are marked. The training curves come last, saying whose they are (the
network's decoder) and which evaluations read it. A file that cannot be read becomes a visible warning on the page
(and on stderr), never a crash: a report is most wanted exactly when some run went wrong.

The page is meant to be shared: no symbolic link is followed out of a run folder, and only
files that really are PNG images are embedded. The markup is the package's Jinja2
templates (``reporting/templates/``), rendered with autoescaping.
"""

from __future__ import annotations

import csv
import json
import os
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import yaml

from robomorph.core.atomic import check_replaceable, write_text
from robomorph.core.errors import RoboMorphError
from robomorph.core.rundir import RunDir
from robomorph.reporting import html as rh
from robomorph.reporting.curves import curves_figure, plot_curves, read_curves  # noqa: F401  (re-exported)
from robomorph.reporting.html import fit_colour

__all__ = ["build_report", "curves_figure", "default_out", "load_run", "read_curves", "ReportError", "RunData", "EvalData"]

# Run-level facts shown in the overview, looked up anywhere in the resolved config.
FACTS = ("d_model", "n_layer", "n_head", "patch", "context_len", "horizon", "normalization")


class ReportError(RoboMorphError, ValueError):
    """There is nothing to report: the runs folder is missing or holds no run."""


@dataclass
class EvalData:
    """One evaluation of a run: ``eval/<name>/``."""

    name: str
    metrics: dict | None = None
    pngs: list[tuple[str, bytes]] = field(default_factory=list)
    table_md: str | None = None
    warnings: list[str] = field(default_factory=list)


@dataclass
class RunData:
    """Everything the report shows about one run directory."""

    name: str
    path: Path
    config_text: str | None = None
    config: dict | None = None
    curves: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)
    checkpoints: list[tuple[str, int]] = field(default_factory=list)
    evals: list[EvalData] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def all_warnings(self) -> list[str]:
        """The run's warnings followed by those of its evaluations."""
        return self.warnings + [w for ev in self.evals for w in ev.warnings]

    def fact(self, key: str):
        """The first value named ``key`` in the config (breadth-first), or None."""
        level = [self.config] if isinstance(self.config, dict) else []
        while level:
            for node in level:
                if key in node and not isinstance(node[key], (dict, list)):
                    return node[key]
            level = [v for node in level for v in node.values() if isinstance(v, dict)]
        return None


_Guard = rh.FolderGuard


def _load_config(run: RunData, guard: _Guard) -> None:
    path = Path(RunDir(str(run.path)).config)
    if not path.is_file():
        run.notes.append("no config.yaml")
        return
    if not guard.allows(path):
        return
    run.config_text = path.read_text(errors="replace")
    try:
        parsed = yaml.safe_load(run.config_text)
    except yaml.YAMLError as e:
        run.warnings.append(f"config.yaml is not valid YAML ({e}); shown as text only")
        return
    if isinstance(parsed, dict):
        run.config = parsed
    else:
        run.warnings.append(f"config.yaml holds a {type(parsed).__name__}, not a mapping; shown as text only")


def _load_eval(path: Path, run_dir: Path) -> EvalData:
    ev = EvalData(name=path.name)
    guard = _Guard(run_dir, ev.warnings)
    pngs = [(p.name, guard.png(p, f"eval/{path.name}")) for p in guard.files(path, "*.png")]
    ev.pngs = [(name, data) for name, data in pngs if data is not None]
    if guard.file(path / "table.md"):
        ev.table_md = (path / "table.md").read_text(errors="replace")
    metrics_path = path / "metrics.json"
    if not metrics_path.is_file():
        ev.warnings.append(f"eval/{path.name} has no metrics.json")
        return ev
    if not guard.allows(metrics_path):
        return ev
    try:
        metrics = json.loads(metrics_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        ev.warnings.append(f"eval/{path.name}/metrics.json is malformed: {e}")
        return ev
    if not isinstance(rh.dig(metrics, "approach1", "channels"), dict):
        ev.warnings.append(f"eval/{path.name}/metrics.json is malformed: no 'approach1' → 'channels' mapping")
        return ev
    ev.metrics = metrics
    return ev


def load_run(path: Path) -> RunData:
    """Reads one run directory; whatever is missing or broken becomes a note or a warning.

    No symbolic link is followed out of ``path``, and only real PNG files are embedded.
    """
    run, layout = RunData(name=path.name, path=path), RunDir(str(path))
    guard = _Guard(path, run.warnings)
    _load_config(run, guard)
    csv_path = Path(layout.metrics_csv)
    if csv_path.is_file() and guard.allows(csv_path):
        try:
            run.curves, notes = read_curves(csv_path)
            run.notes.extend(notes)
        except (csv.Error, OSError, UnicodeDecodeError) as e:
            run.warnings.append(f"logs/metrics.csv is unreadable: {e}")
    elif not csv_path.is_file():
        run.notes.append("no logs/metrics.csv; no training curves")
    run.checkpoints = [(p.name, p.stat().st_size) for p in guard.files(Path(layout.checkpoints), "*.ckpt")]
    eval_dir = Path(layout.evals)
    if eval_dir.is_dir() and guard.allows(eval_dir):
        # Hidden folders are evaluations being written (robomorph.core.locks.output_folder), not results.
        run.evals = [_load_eval(p, path) for p in sorted(eval_dir.iterdir())
                     if p.is_dir() and not p.name.startswith(".") and guard.allows(p)]
    if not run.evals:
        run.notes.append("no evaluations (run `python -m robomorph.evaluate` to add some)")
    return run


def _outside(path: Path, root: Path) -> RunData:
    """A run folder that links out of the runs folder: shown by name, with nothing read."""
    return RunData(name=path.name, path=path,
                   warnings=[f"the run folder is a symbolic link leading outside {str(root)!r}; not read"])


def find_runs(runs_dir: str | os.PathLike) -> list[RunData]:
    """Loads every run under ``runs_dir``.

    Raises:
        ReportError: the directory is missing or holds no run, with what to do about it.
    """
    root = Path(runs_dir)
    if not root.is_dir():
        raise ReportError(f"runs directory {str(root)!r} does not exist; train a run first with "
                         "`python -m robomorph.fit ...` or pass the folder that holds the runs")
    dirs = [p for p in sorted(root.iterdir()) if p.is_dir() and RunDir(str(p)).looks_like_run()]
    if not dirs and RunDir(str(root)).looks_like_run():
        raise ReportError(f"{str(root)!r} looks like a single run; pass the folder that holds the runs "
                         f"(here {str(root.parent)!r})")
    if not dirs:
        raise ReportError(f"no runs found in {str(root)!r}: expected sub-folders <run>/ with config.yaml, "
                         "logs/metrics.csv, checkpoints/ or eval/ (as written by `python -m robomorph.fit`)")
    real = root.resolve()
    return [load_run(p) if p.resolve().is_relative_to(real) else _outside(p, root) for p in dirs]


def _size(n: float) -> str:
    if n < 1024:
        return f"{n:.0f} B"
    for unit in ("KiB", "MiB"):
        n /= 1024
        if n < 1024:
            return f"{n:.1f} {unit}"
    return f"{n / 1024:.1f} GiB"


def _anchor(i: int) -> str:
    return f"run-{i}"


SCORE_HEADS = ("R² median (A1)", "FIT median (A1)", "R² pooled (A2)", "FIT pooled (A2)", "best baseline (pooled FIT)")


def _score_cells(metrics: dict) -> tuple[rh.Cell, ...]:
    """R² and FIT of the model as medians over windows (approach 1) and over the pooled windows (approach 2),
    each over the channels that move (:func:`robomorph.reporting.html.pooled`), then the best baseline."""
    cells = []
    for r2, fit in ((rh.overall_a1(metrics, "r2"), rh.overall_a1(metrics, "fit")),
                    (rh.pooled(metrics, "r2", metrics), rh.pooled(metrics, "fit", metrics))):
        cells += rh.score_cells(r2, fit)
    best = rh.best_baseline(metrics)
    cells.append(rh.Cell(f"{best[0]}: {best[1]:.1f}", fit_colour(best[1])) if best else rh.Cell(rh.DASH))
    return tuple(cells)


def overview(runs: list[RunData]) -> rh.Table:
    """One row per run and evaluation, led by what predicts: the joint error by horizon of the model, hold and
    constant velocity, then FIT and R² as medians and over the pooled windows, then the run's facts."""
    head = (*rh.HORIZON_HEADS, *SCORE_HEADS)
    top = (rh.Head("run", "name", rowspan=2), rh.Head("evaluation", "name", rowspan=2),
           rh.Head(rh.HORIZON_GROUP, colspan=len(rh.HORIZON_HEADS)),
           rh.Head("the model's scores over the channels that move", colspan=len(SCORE_HEADS)),
           *(rh.Head(k, rowspan=2) for k in FACTS))
    rows = []
    for i, run in enumerate(runs):
        facts = tuple(rh.Cell(str(rh.DASH if run.fact(k) is None else run.fact(k))) for k in FACTS)
        link = rh.Cell(run.name, cls="name", href=f"#{_anchor(i)}")
        scored = [ev for ev in run.evals if ev.metrics is not None]
        if not scored:
            why = "no evaluation" if not run.evals else "no readable metrics.json"
            dashes = [rh.Cell(rh.DASH)] * (len(rh.HORIZON_HEADS) + len(SCORE_HEADS))
            rows.append(rh.Row((link, rh.Cell(why, cls="name"), *dashes, *facts)))
        for ev in scored:
            marks = rh.badges(ev.metrics) + ((IN_SAMPLE_BADGE,) if _in_sample(ev.metrics) else ())
            rows.append(rh.Row((link, rh.Cell(ev.name, cls="name", badges=marks), *rh.horizon_cells(ev.metrics),
                                *_score_cells(ev.metrics), *facts)))
    return rh.Table(head, tuple(rows), (top,))


def _plain(value) -> str:
    """A meta value as a reader would write it: lists comma-separated, dicts as ``k: v``."""
    if isinstance(value, list):
        return ", ".join(map(str, value))
    if isinstance(value, dict):
        return "; ".join(f"{k}: {v}" for k, v in value.items())
    return str(value)


IN_SAMPLE_BADGE = "in-sample"


def _in_sample(metrics) -> str | None:
    """The training store an evaluation scored the model on (``meta.in_sample``), or None."""
    meta = metrics.get("meta") if isinstance(metrics, dict) else None
    if not isinstance(meta, dict) or not meta.get("in_sample"):
        return None
    return str(meta.get("in_sample_store") or "a training store")


# How each physics mode predicts, for the reader of an evaluation (robomorph.inference.hybrid.MODES).
_READS_DECODER = {"blend": "its simulation and the network's decoder weighted by step",
                  "smoothed": "its simulation smoothed against the network's decoder",
                  "learned": "the robot read from the context by the network's parameter head, then simulated",
                  "fused": "the robot identified from the context (the network's parameter head as prior), then simulated"}


def _mode(metrics) -> str | None:
    """The hybrid's physics mode that predicted an evaluation, or None (the network's decoder)."""
    meta = metrics.get("meta") if isinstance(metrics, dict) else None
    physics = meta.get("physics") if isinstance(meta, dict) else None
    return physics.get("mode") if isinstance(physics, dict) and physics.get("mode") else None


def predictor_note(metrics) -> str:
    """Which part of the run predicted an evaluation: the hybrid (and whether it read the network) or the decoder."""
    mode = _mode(metrics)
    if not mode:
        return ("Predicted by the network's decoder (the black-box model): the training curves below are its "
                "validation scores.")
    if mode in _READS_DECODER:
        return f"Predicted by the hybrid, physics mode {mode}: {_READS_DECODER[mode]}."
    return (f"Predicted by the hybrid, physics mode {mode}: the robot identified from each context by linear solves, "
            "then simulated. It reads no network: the training curves below are the decoder's, not this prediction's.")


def curves_caption(runs: list[RunData]) -> str:
    """Whose the training curves are: each run's decoder, and for each run whether its evaluations read it."""
    whose = []
    for run in runs:
        if not run.curves:
            continue
        modes = sorted({_mode(ev.metrics) or "decoder" for ev in run.evals if ev.metrics is not None})
        if not modes or modes == ["decoder"]:
            read = "its evaluations are the decoder's predictions" if modes else "not evaluated"
        elif all(m in _READS_DECODER or m == "decoder" for m in modes):
            read = f"its evaluations ({', '.join(modes)}) read the decoder"
        else:
            read = (f"its evaluations were predicted by the hybrid ({', '.join(modes)}), which does not read the "
                    "decoder: these curves do not score them")
        whose.append(f"{run.name}: {read}")
    return ("The network's training, as fit logged it: train/loss, val/loss (log scale where every value is "
            "positive, linear otherwise) and val/r2 against step, all of the network's decoder (its black-box "
            "head) on the run's validation windows. " + "; ".join(whose) + ".")


def diverged_notes(metrics) -> list[str]:
    """``"baseline arx diverged on k of n windows ..."`` for a baseline that fell back to hold on any window."""
    from robomorph.evaluation.tables import diverged_note  # noqa: PLC0415

    meta = metrics.get("meta") if isinstance(metrics, dict) else None
    notes = meta.get("baseline_notes") if isinstance(meta, dict) else None
    if not isinstance(notes, dict):
        return []
    out = []
    for name, note in notes.items():
        text = diverged_note(note, meta.get("n", "?")) if isinstance(note, dict) else ""
        if text:
            out.append(f"Baseline {name}: {text} (its scores are hold's on those; read them with that in mind).")
    return out


def eval_view(ev: EvalData) -> dict:
    """What the template shows of one evaluation: warnings, meta, tables, plots, table.md."""
    store = _in_sample(ev.metrics)
    in_sample = [f"In-sample: {store} is a training store of this model; these scores include robots it was "
                 "trained on, not how it generalizes."] if store else []
    view = {"name": ev.name, "warnings": ev.warnings + rh.notes(ev.metrics) + in_sample + diverged_notes(ev.metrics),
            "predictor": predictor_note(ev.metrics) if ev.metrics is not None else None, "meta": [], "skipped": [],
            "channels": None, "horizons": None, "table_md": ev.table_md,
            "figures": [(rh.png_uri(png), name) for name, png in ev.pngs]}
    if ev.metrics is not None:
        meta, skipped = ev.metrics.get("meta"), ev.metrics.get("skipped_baselines")
        if isinstance(meta, dict):
            view["meta"] = [(k, _plain(v)) for k, v in meta.items() if v not in (None, "", [], {})]
        if isinstance(skipped, dict):
            view["skipped"] = list(skipped.items())
        view["channels"], view["horizons"] = rh.channel_grid(ev.metrics), rh.horizon_grid(ev.metrics)
    return view


def run_view(run: RunData, index: int) -> dict:
    """What the template shows of one run."""
    return {"anchor": _anchor(index), "name": run.name, "path": str(run.path), "warnings": run.warnings,
            "notes": run.notes, "checkpoints": [(name, _size(size)) for name, size in run.checkpoints],
            "config_text": run.config_text, "evals": [eval_view(ev) for ev in run.evals]}


def render(runs: list[RunData], title: str, runs_dir: str, control: str | None = None) -> str:
    """The whole page for ``runs`` (templates/report.html.j2), with the closed-loop control
    section of the ``control`` folder when it holds a ``metrics.json``."""
    from robomorph.reporting.control_view import control_view  # noqa: PLC0415

    curves = plot_curves(runs)
    return rh.render("report.html.j2", title=title, runs_dir=str(runs_dir),
                     stamp=datetime.now().strftime("%Y-%m-%d %H:%M"),
                     warnings=[f"{run.name}: {w}" for run in runs for w in run.all_warnings],
                     legend=rh.legend(), overview=overview(runs), curves=rh.png_uri(curves) if curves else None,
                     curves_caption=curves_caption(runs),
                     runs=[run_view(run, i) for i, run in enumerate(runs)], control=control_view(control))


def build_report(runs_dir: str, out: str, title: str = "RoboMorph training report", control: str | None = None) -> str:
    """Writes the report of every run under ``runs_dir`` to ``out``.

    Args:
        runs_dir: the folder holding one sub-folder per run.
        out: the HTML file to write (its folder is created).
        title: the page title.
        control: a ``robomorph control`` output folder to show (None or a folder without
            ``metrics.json``: no control section).

    Returns:
        The path written.

    Raises:
        ReportError: ``runs_dir`` is missing or holds no run.
        OutputExistsError: ``out`` is a folder, lies in a store or holds something other
            than an HTML page (a checkpoint, a log): it is never replaced.
    """
    check_replaceable(out, "html", "--out")
    runs = find_runs(runs_dir)
    for run in runs:
        for w in run.all_warnings:
            print(f"report: warning: {run.name}: {w}", file=sys.stderr)
    write_text(out, render(runs, title, str(runs_dir), control))
    return str(out)


def default_out(runs_dir: str) -> str:
    """``report.html`` beside the runs folder (``results/runs`` -> ``results/report.html``)."""
    return os.path.join(os.path.dirname(os.path.abspath(runs_dir)), "report.html")
