"""``python -m robomorph.report RUNS_DIR --out results/report.html``: one page comparing runs.

Reads every run directory written by ``python -m robomorph.fit`` under ``RUNS_DIR``
(``config.yaml``, ``logs/metrics.csv``, ``checkpoints/*.ckpt`` and the evaluations in
``eval/<name>/`` written by ``robomorph.evaluate``) and writes one static HTML file that
opens offline: CSS inline, no script, every image embedded as a base64 ``data:`` URI.

The page has an overview (one row per run and evaluation), the training curves of all
runs in shared figures, and per run its facts, checkpoints, config and evaluations, each
with a per-channel table of the model beside every baseline, coloured with the paper's
fit-index convention (:func:`robomorph.reporting.html.fit_colour`); scores of the paper's
normalization are marked. A file that cannot be read becomes a visible warning on the page
(and on stderr), never a crash: a report is most wanted exactly when some run went wrong.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import yaml

from robomorph.reporting import html as rh
from robomorph.reporting.html import fit_colour

__all__ = ["build_report", "load_run", "main", "read_curves", "RunData", "EvalData"]

CURVES = ("train/loss", "val/loss", "val/r2")
# Run-level facts shown in the overview, looked up anywhere in the resolved config.
FACTS = ("d_model", "n_layer", "n_head", "patch", "context_len", "horizon", "normalization")
RUN_MARKERS = ("config.yaml", "logs", "checkpoints", "eval")


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


def read_curves(path: Path) -> tuple[dict[str, tuple[list[float], list[float]]], list[str]]:
    """The (steps, values) of each of :data:`CURVES` in a Lightning CSVLogger file.

    Rows are sparse (each row holds the keys logged at that moment), so a point is kept
    only where both ``step`` and the value are present and finite.

    Returns:
        The curves found, and notes on what is missing or unreadable.
    """
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        rows, header = list(reader), set(reader.fieldnames or ())
    if "step" not in header:
        return {}, [f"{path.name} has no 'step' column; no curves"]
    curves, notes, bad = {}, [], 0
    for key in CURVES:
        if key not in header:
            notes.append(f"{path.name} has no '{key}' column")
            continue
        steps, values = [], []
        for row in rows:
            try:
                step, value = float(row["step"] or "nan"), float(row[key] or "nan")
            except (TypeError, ValueError):
                bad += 1
                continue
            if math.isfinite(step) and math.isfinite(value):
                steps.append(step)
                values.append(value)
        if steps:
            curves[key] = (steps, values)
        else:
            notes.append(f"{path.name}: '{key}' has no values yet")
    if bad:
        notes.append(f"{path.name}: skipped {bad} non-numeric cells")
    return curves, notes


def _load_config(run: RunData) -> None:
    path = run.path / "config.yaml"
    if not path.is_file():
        run.notes.append("no config.yaml")
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


def _load_eval(path: Path) -> EvalData:
    ev = EvalData(name=path.name)
    ev.pngs = [(p.name, p.read_bytes()) for p in sorted(path.glob("*.png"))]
    if (path / "table.md").is_file():
        ev.table_md = (path / "table.md").read_text(errors="replace")
    metrics_path = path / "metrics.json"
    if not metrics_path.is_file():
        ev.warnings.append(f"eval/{path.name} has no metrics.json")
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
    """Reads one run directory; whatever is missing or broken becomes a note or a warning."""
    run = RunData(name=path.name, path=path)
    _load_config(run)
    csv_path = path / "logs" / "metrics.csv"
    if csv_path.is_file():
        try:
            run.curves, notes = read_curves(csv_path)
            run.notes.extend(notes)
        except (csv.Error, OSError, UnicodeDecodeError) as e:
            run.warnings.append(f"logs/metrics.csv is unreadable: {e}")
    else:
        run.notes.append("no logs/metrics.csv; no training curves")
    run.checkpoints = [(p.name, p.stat().st_size) for p in sorted((path / "checkpoints").glob("*.ckpt"))]
    eval_dir = path / "eval"
    if eval_dir.is_dir():
        run.evals = [_load_eval(p) for p in sorted(eval_dir.iterdir()) if p.is_dir()]
    if not run.evals:
        run.notes.append("no evaluations (run `python -m robomorph.evaluate` to add some)")
    return run


def find_runs(runs_dir: str | os.PathLike) -> list[RunData]:
    """Loads every run under ``runs_dir``.

    Raises:
        ValueError: the directory is missing or holds no run, with what to do about it.
    """
    root = Path(runs_dir)
    if not root.is_dir():
        raise ValueError(f"runs directory {str(root)!r} does not exist; train a run first with "
                         "`python -m robomorph.fit ...` or pass the folder that holds the runs")
    dirs = [p for p in sorted(root.iterdir()) if p.is_dir() and any((p / m).exists() for m in RUN_MARKERS)]
    if not dirs and any((root / m).exists() for m in RUN_MARKERS):
        raise ValueError(f"{str(root)!r} looks like a single run; pass the folder that holds the runs "
                         f"(here {str(root.parent)!r})")
    if not dirs:
        raise ValueError(f"no runs found in {str(root)!r}: expected sub-folders <run>/ with config.yaml, "
                         "logs/metrics.csv, checkpoints/ or eval/ (as written by `python -m robomorph.fit`)")
    return [load_run(p) for p in dirs]


def plot_curves(runs: list[RunData]) -> bytes | None:
    """One PNG with a panel per curve in :data:`CURVES`, a line per run; None without curves."""
    if not any(run.curves for run in runs):
        return None
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0 * len(CURVES), 4.0), layout="constrained")
    axes = fig.subplots(1, len(CURVES))
    colours = colormaps["tab10"]
    for ax, key in zip(axes, CURVES):
        log = key.endswith("loss")
        for i, run in enumerate(runs):
            if key not in run.curves:
                continue
            steps, values = run.curves[key]
            if log:  # a log axis cannot show non-positive losses
                kept = [(s, v) for s, v in zip(steps, values) if v > 0]
                steps, values = [s for s, _ in kept], [v for _, v in kept]
            ax.plot(steps, values, color=colours(i % 10), label=run.name, lw=1.4, marker="." if len(steps) < 30 else None)
        if log:
            ax.set_yscale("log")
        elif ax.has_data() and ax.get_ylim()[0] < -1.0 < ax.get_ylim()[1]:
            # Early R² can be hugely negative; clipping keeps the useful range readable.
            ax.set_ylim(bottom=-1.0)
        ax.set(title=key, xlabel="step")
        ax.grid(alpha=0.3)
    handles, labels = [], []
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    fig.legend(handles, labels, loc="outside right upper", fontsize="small")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


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


def overview_html(runs: list[RunData]) -> str:
    """One row per run and evaluation: model size, windows, mean approach-1 scores."""
    head = ["run", "evaluation", *FACTS, "A1 R²", "A1 FIT", "A1 RMSE", "best baseline (A1 FIT)", rh.HORIZON_HEAD]
    rows = []
    for i, run in enumerate(runs):
        facts = "".join(rh.td(rh.esc(rh.DASH if run.fact(k) is None else run.fact(k))) for k in FACTS)
        link = rh.td(f'<a href="#{_anchor(i)}">{rh.esc(run.name)}</a>', cls="name")
        scored = [ev for ev in run.evals if ev.metrics is not None]
        if not scored:
            why = "no evaluation" if not run.evals else "no readable metrics.json"
            rows.append(f"<tr>{link}{rh.td(rh.esc(why), cls='name')}{facts}" + rh.td(rh.DASH) * 5 + "</tr>")
        for ev in scored:
            r2, fit, rmse = (rh.mean_stat(ev.metrics, "approach1", m) for m in ("r2", "fit", "rmse"))
            best = rh.best_baseline(ev.metrics)
            best_cell = rh.td(rh.esc(f"{best[0]}: {best[1]:.1f}"), fit_colour(best[1])) if best else rh.td(rh.DASH)
            colour = fit_colour(fit[0])
            rows.append(
                f"<tr>{link}{rh.td(rh.esc(ev.name) + rh.leak_badge(ev.metrics), cls='name')}{facts}"
                f"{rh.td(rh.esc(rh.fmt(*r2, 'r2')), colour)}{rh.td(rh.esc(rh.fmt(*fit, 'fit')), colour)}"
                f"{rh.td(rh.esc(rh.fmt(*rmse, 'rmse')))}{best_cell}{rh.horizon_cell(ev.metrics)}</tr>"
            )
    return rh.table([rh.esc(h) for h in head], rows)


def _plain(value) -> str:
    """A meta value as a reader would write it: lists comma-separated, dicts as ``k: v``."""
    if isinstance(value, list):
        return ", ".join(map(str, value))
    if isinstance(value, dict):
        return "; ".join(f"{k}: {v}" for k, v in value.items())
    return str(value)


def eval_html(ev: EvalData) -> str:
    """One evaluation: summary line, warnings, per-channel table, plots, raw table.md."""
    parts = [f"<h4>Evaluation <code>{rh.esc(ev.name)}</code></h4>"]
    parts += [rh.warn(w) for w in ev.warnings] + [rh.leak_note(ev.metrics)]
    if ev.metrics is not None:
        meta = ev.metrics.get("meta")
        if isinstance(meta, dict):
            shown = {k: v for k, v in meta.items() if v not in (None, "", [], {})}
            items = " · ".join(f"{rh.esc(k)}: <code>{rh.esc(_plain(v))}</code>" for k, v in shown.items())
            parts.append(f'<p class="meta">{items}</p>')
        skipped = ev.metrics.get("skipped_baselines")
        if isinstance(skipped, dict):
            parts += [f'<p class="note">baseline <b>{rh.esc(k)}</b> skipped: {rh.esc(v)}</p>' for k, v in skipped.items()]
        parts += [rh.channel_table(ev.metrics), rh.horizon_table(ev.metrics)]
    parts += [rh.figure(png, name) for name, png in ev.pngs]
    if ev.table_md:
        parts.append(f"<details><summary>table.md</summary><pre>{rh.esc(ev.table_md)}</pre></details>")
    return "\n".join(parts)


def run_html(run: RunData, index: int) -> str:
    """The section of one run."""
    parts = [f'<section id="{_anchor(index)}"><h3>Run <code>{rh.esc(run.name)}</code></h3>',
             f'<p class="meta">{rh.esc(run.path)}</p>']
    parts += [rh.warn(w) for w in run.warnings]
    parts += [f'<p class="note">{rh.esc(n)}</p>' for n in run.notes]
    if run.checkpoints:
        items = "".join(f"<li><code>{rh.esc(name)}</code> — {_size(size)}</li>" for name, size in run.checkpoints)
        parts.append(f"<p>Checkpoints:</p><ul>{items}</ul>")
    if run.config_text is not None:
        parts.append(f"<details><summary>config.yaml</summary><pre>{rh.esc(run.config_text)}</pre></details>")
    parts += [eval_html(ev) for ev in run.evals]
    parts.append("</section>")
    return "\n".join(parts)


def render(runs: list[RunData], title: str, runs_dir: str) -> str:
    """The whole page for ``runs``."""
    warnings = [f"{run.name}: {w}" for run in runs for w in run.all_warnings]
    stamp = datetime.now().strftime("%Y-%m-%d %H:%M")
    nav = " ".join(f'<a href="#{_anchor(i)}">{rh.esc(run.name)}</a>' for i, run in enumerate(runs))
    curves = plot_curves(runs)
    parts = [
        f"<header><h1>{rh.esc(title)}</h1><p class='sub'>{len(runs)} run(s) in <code>{rh.esc(runs_dir)}</code>"
        f" · generated {stamp}</p><nav>{nav}</nav></header>",
        *(rh.warn(w) for w in warnings),
        "<h2>Overview</h2>", rh.legend_html(),
        '<p class="note">A1: approach 1, mean (± std) over test trajectories; A2: approach 2. '
        "FIT and R² cells are coloured by FIT.</p>",
        overview_html(runs),
        "<h2>Training curves</h2>",
        rh.figure(curves, "train/loss, val/loss (log scale) and val/r2 against step") if curves
        else '<p class="note">No run has a logs/metrics.csv with curves.</p>',
        "<h2>Runs</h2>",
        *(run_html(run, i) for i, run in enumerate(runs)),
    ]
    return rh.page(title, "\n".join(parts))


def _write_atomic(path: Path, text: str) -> None:
    """Writes ``text`` so that a reader never sees a half-written page."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # A plain open() (not mkstemp) so the page gets the usual umask permissions, not 0600.
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def build_report(runs_dir: str, out: str, title: str = "RoboMorph training report") -> str:
    """Writes the report of every run under ``runs_dir`` to ``out``.

    Args:
        runs_dir: the folder holding one sub-folder per run.
        out: the HTML file to write (its folder is created).
        title: the page title.

    Returns:
        The path written.

    Raises:
        ValueError: ``runs_dir`` is missing or holds no run.
    """
    runs = find_runs(runs_dir)
    for run in runs:
        for w in run.all_warnings:
            print(f"report: warning: {run.name}: {w}", file=sys.stderr)
    _write_atomic(Path(out), render(runs, title, str(runs_dir)))
    return str(out)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry point; see the module docstring."""
    parser = argparse.ArgumentParser(prog="python -m robomorph.report", description=__doc__.splitlines()[0])
    parser.add_argument("runs_dir", nargs="?", default="results/runs", help="folder of run directories (default: %(default)s)")
    parser.add_argument("--out", help="HTML file to write (default: <runs_dir>/../report.html)")
    parser.add_argument("--title", default="RoboMorph training report", help="page title")
    args = parser.parse_args(argv)
    out = args.out or os.path.join(os.path.dirname(os.path.abspath(args.runs_dir)), "report.html")
    try:
        path = build_report(args.runs_dir, out, args.title)
    except ValueError as e:
        parser.error(str(e))
    print(path)


if __name__ == "__main__":
    main()
