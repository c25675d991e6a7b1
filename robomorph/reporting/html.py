"""The page's pieces as data, and their rendering through Jinja2 templates.

The functions here turn ``metrics.json`` contents into plain values (:class:`Cell`,
:class:`Table`, fit-index colours, formatted numbers); the markup lives in the package's
``templates/`` folder, rendered by :func:`render` with autoescaping on, so every string
that comes from a file is escaped by the template engine and never by hand. Kept free of
matplotlib and of the file reading in :mod:`robomorph.reporting.dashboard`, so that
:func:`fit_colour` can be reused (e.g. to colour other tables).
"""

from __future__ import annotations

import base64
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jinja2

from robomorph.core.names import FIT, NRMSE, R2, RMSE
from robomorph.evaluation.fit_bands import FIT_BANDS

# Cells are painted with xcolor's ``colour!N`` (N% colour mixed with white, FIT_BANDS'
# strength) so the page looks the same on any background, not alpha blended.
METRICS = (R2, FIT, RMSE, NRMSE)  # the order the tables show them
DASH = "—"
# The overview leads with what predicts: joint error by horizon of the model beside the two predictions any
# model must beat (holding the last output, extrapolating the last velocity).
HORIZON_SOURCES = (("model", "model"), ("hold", "hold"), ("constant_velocity", "constant velocity"))
HORIZON_GROUP = "joints RMS [mrad] at step 1 / 0.25 s / 1 s"
HORIZON_HEADS = tuple(label for _, label in HORIZON_SOURCES)
QUIET_BADGE = "quiet in {k} of {n} windows"
LEAK_BADGE = "⚠ paper_window: uses query statistics"
_BETTER, _WORSE = "rgb(204, 235, 204)", "rgb(248, 209, 204)"


@dataclass(frozen=True)
class Cell:
    """One table cell: plain text (escaped when rendered), an optional background colour,
    CSS class, link target and badges (short warnings shown under the text)."""

    text: str
    colour: str | None = None
    cls: str = ""
    href: str | None = None
    badges: tuple[str, ...] = ()


@dataclass(frozen=True)
class Head:
    """A header cell of an extra header row (with its span)."""

    text: str
    cls: str = ""
    colspan: int = 1
    rowspan: int = 1


@dataclass(frozen=True)
class Row:
    cells: tuple[Cell, ...]
    cls: str = ""


@dataclass(frozen=True)
class Table:
    """A scrollable table: column heads, rows, and header rows above the heads."""

    head: tuple[str, ...]
    rows: tuple[Row, ...]
    head_rows: tuple[tuple[Head, ...], ...] = ()


@functools.cache
def environment() -> jinja2.Environment:
    """The template environment: the package's templates, autoescaping every value."""
    return jinja2.Environment(loader=jinja2.PackageLoader("robomorph.reporting", "templates"),
                              autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True,
                              lstrip_blocks=True, keep_trailing_newline=True)


def render(template: str, **context: Any) -> str:
    """``templates/<template>`` rendered with ``context``."""
    return environment().get_template(template).render(**context)


def _macro(name: str, *args: Any) -> str:
    return str(getattr(environment().get_template("macros.html.j2").module, name)(*args))


def fit_colour(fit: float | None) -> str | None:
    """CSS colour of a FIT value (percent) under the paper's fit-index convention.

    Args:
        fit: the fit index in percent (100 is perfect; it is unbounded below).

    Returns:
        An ``rgb(r, g, b)`` string, or None when ``fit`` is missing or not finite, so a
        missing value is never painted as a bad one.
    """
    if fit is None or not math.isfinite(fit):
        return None
    for low, rgb, strength, _, _ in FIT_BANDS:
        if fit >= low:
            # Integer arithmetic, halves rounded up: floats would turn 178.5 into 178.4999...
            r, g, b = ((c * strength + 255 * (100 - strength) + 50) // 100 for c in rgb)
            return f"rgb({r}, {g}, {b})"
    raise AssertionError("unreachable: the last band has no lower bound")


def legend() -> list[tuple[str, str]]:
    """(colour, label) of each fit-index band, best first."""
    return [(fit_colour(low if math.isfinite(low) else 0.0), label) for low, _, _, _, label in FIT_BANDS]


def num(value: Any) -> float | None:
    """``value`` as a float when it is a number (bool excluded), else None."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return None


def dig(tree: Any, *keys: str) -> Any:
    """``tree[k1][k2]...``, or None as soon as a level is not a dict or lacks the key."""
    for key in keys:
        if not isinstance(tree, dict):
            return None
        tree = tree.get(key)
    return tree


def stat(value: Any) -> tuple[float | None, float | None]:
    """(mean, std) of a metric stored as ``{"mean", "std"}`` (approach 1) or a number (approach 2)."""
    if isinstance(value, dict):
        return num(value.get("mean")), num(value.get("std"))
    return num(value), None


def mean_stat(source: Any, approach: str, metric: str) -> tuple[float | None, float | None]:
    """Mean over channels of ``metric``: the stored ``mean`` entry, else the average of channels.

    Approach 2 results carry no ``mean`` entry, so the plain average of the channel values
    stands in for it (std is then None).
    """
    stored = stat(dig(source, approach, "mean", metric))
    if stored[0] is not None:
        return stored
    channels = dig(source, approach, "channels")
    values = [stat(v.get(metric))[0] for v in channels.values() if isinstance(v, dict)] if isinstance(channels, dict) else []
    values = [v for v in values if v is not None and math.isfinite(v)]
    return (sum(values) / len(values), None) if values else (None, None)


def fmt(mean: float | None, std: float | None, metric: str) -> str:
    """Text of a metric: R² with 3 decimals, FIT with 1, errors with 3 significant digits."""
    if mean is None:
        return DASH
    spec = {"r2": ".3f", "fit": ".1f"}.get(metric, ".3g")
    text = format(mean, spec)
    return text if std is None else f"{text} ± {format(std, spec)}"


def sources(metrics: dict) -> list[tuple[str, Any]]:
    """The model's results followed by each baseline's, as (name, results) pairs."""
    baselines = metrics.get("baselines")
    named = sorted(baselines.items()) if isinstance(baselines, dict) else []
    return [("model", metrics)] + [(name, res) for name, res in named if isinstance(res, dict)]


def diverged_share(metrics: dict, name: str) -> tuple[int, int] | None:
    """(windows on which baseline ``name`` diverged and was held, windows scored), or None where it never did."""
    k, n = dig(metrics, "meta", "baseline_notes", name, "diverged_held"), dig(metrics, "meta", "n")
    return (int(k), int(n)) if isinstance(k, int) and k > 0 and isinstance(n, int) and n > 0 else None


def source_label(metrics: dict, name: str) -> str:
    """A source's name in the tables, marked where it diverged: ``arx (diverged on 14/64, held)``."""
    share = diverged_share(metrics, name)
    return f"{name} (diverged on {share[0]}/{share[1]}, held)" if share else name


def channel_names(metrics: dict) -> list[str]:
    """Every channel named by any source or approach, in first-seen order."""
    names: dict[str, None] = {}
    for _, src in sources(metrics):
        for approach in ("approach1", "approach2"):
            channels = dig(src, approach, "channels")
            if isinstance(channels, dict):
                names.update(dict.fromkeys(map(str, channels)))
    return list(names)


def score_cells(r2: tuple, fit: tuple, first: bool = False) -> tuple[Cell, Cell]:
    """R² and FIT cells of one source/approach, both coloured by FIT."""
    colour = fit_colour(fit[0])
    return Cell(fmt(*r2, "r2"), colour, "model" if first else ""), Cell(fmt(*fit, "fit"), colour)


def quiet_share(metrics: Any, channel: str) -> tuple[int, int] | None:
    """(windows where ``channel`` moves less than twice its noise, windows scored), or None where none is quiet
    or the evaluation predates the count (:func:`robomorph.evaluation.metrics.quiet_windows`)."""
    k, n = dig(metrics, "approach1", "quiet", "channels", channel), dig(metrics, "approach1", "quiet", "windows")
    return (k, n) if isinstance(k, int) and isinstance(n, int) and 0 < k and 0 < n else None


def mostly_quiet(metrics: Any, channel: str) -> bool:
    """True for a channel quiet in more than half the windows: left out of the means over channels."""
    share = quiet_share(metrics, channel)
    return share is not None and 2 * share[0] > share[1]


def a1_stat(entry: Any) -> tuple[float | None, float | None]:
    """An approach-1 score as the page shows it: the median over the windows where the channel moves (no std),
    or, for an evaluation written before medians were recorded, the mean ± std over windows."""
    if isinstance(entry, dict) and "median" in entry:
        return num(entry.get("median")), None
    return stat(entry)


def pooled(source: Any, metric: str, metrics: Any) -> tuple[float | None, None]:
    """Approach 2 (each channel's windows pooled into one series) averaged over the channels that are not
    quiet in most windows; the stored mean where the evaluation has no per-channel values."""
    channels = dig(source, "approach2", "channels")
    if not isinstance(channels, dict):
        return mean_stat(source, "approach2", metric)[0], None
    values = [num(dig(v, metric)) for name, v in channels.items() if not mostly_quiet(metrics, str(name))]
    values = [v for v in values if v is not None and math.isfinite(v)]
    return (sum(values) / len(values) if values else None), None


def overall_a1(source: Any, metric: str) -> tuple[float | None, float | None]:
    """Approach 1 over all channels: the median over windows of each window's mean over its moving channels,
    or (an older evaluation) the mean ± std of :func:`mean_stat`."""
    entry = dig(source, "approach1", "mean", metric)
    return a1_stat(entry) if isinstance(entry, dict) and "median" in entry else mean_stat(source, "approach1", metric)


def channel_grid(metrics: dict) -> Table:
    """Per-channel R² and FIT of the model and every baseline, for both approaches.

    Columns come in groups, one per source (model first), each with approach 1 (the median
    over the windows where the channel moves) and approach 2 (the windows pooled), so a row
    reads as "what the model adds" per channel. A channel quiet in some windows says so; one
    quiet in most is greyed and left out of the last row, the summary over channels.
    """
    srcs = sources(metrics)
    top = (Head("channel", "name", rowspan=2),
           *(Head(source_label(metrics, name), "model", colspan=4) for name, _ in srcs))
    rows = []
    for channel in channel_names(metrics):
        share = quiet_share(metrics, channel)
        marks = (QUIET_BADGE.format(k=share[0], n=share[1]),) if share else ()
        cells = [Cell(channel, cls="name", badges=marks)]
        for _, src in srcs:
            entry = dig(src, "approach1", "channels", channel)
            cells += score_cells(a1_stat(dig(entry, "r2")), a1_stat(dig(entry, "fit")), True)
            entry = dig(src, "approach2", "channels", channel)
            cells += score_cells(stat(dig(entry, "r2")), stat(dig(entry, "fit")))
        rows.append(Row(tuple(cells), "quiet" if mostly_quiet(metrics, channel) else ""))
    cells = [Cell("all moving channels", cls="name")]
    for _, src in srcs:
        cells += score_cells(overall_a1(src, "r2"), overall_a1(src, "fit"), True)
        cells += score_cells(pooled(src, "r2", metrics), pooled(src, "fit", metrics))
    rows.append(Row(tuple(cells), "mean"))
    return Table(("A1 R² median", "A1 FIT median", "A2 R² pooled", "A2 FIT pooled") * len(srcs), tuple(rows), (top,))


def channel_table(metrics: dict) -> str:
    """:func:`channel_grid` rendered as HTML."""
    return _macro("grid", channel_grid(metrics))


def _row_values(values: Any, width: int) -> list[float | None] | None:
    if not isinstance(values, list) or len(values) != width:
        return None
    return [num(v) for v in values]


def _horizon_rows(h: dict, width: int, metrics: dict) -> list[Row]:
    rms, rows = h["rms"], []
    for q, info in h["quantities"].items():
        unit = dig(info, "unit")
        label = Cell(f"{q} [{unit}]" if unit else str(q), cls="name")
        hold = _row_values(dig(rms, "hold", q), width)
        for src in ["model", *sorted(s for s in rms if s != "model")]:
            values = _row_values(dig(rms, src, q), width)
            if values is None:
                continue
            cells = [label, Cell(source_label(metrics, str(src)), cls="name")]
            for j, v in enumerate(values):
                colour = None
                if src == "model" and hold and v is not None and hold[j] is not None:
                    colour = _BETTER if v <= hold[j] else _WORSE
                cells.append(Cell(DASH if v is None else f"{v:.4g}", colour))
            rows.append(Row(tuple(cells)))
    for sigma, ideal in (("1sigma", 68.3), ("2sigma", 95.4)):
        values = _row_values(dig(h, "calibration", "all", sigma), width)
        if values is not None:
            cells = [Cell(f"inside ±{sigma[0]}σ [%] (ideal {ideal})", cls="name"), Cell("model", cls="name")]
            rows.append(Row(tuple(cells + [Cell(DASH if v is None else f"{100 * v:.1f}") for v in values])))
    # How well the std ranks the trajectories by their errors (horizons.skill; absent in older metrics files).
    values = _row_values(dig(h, "skill", "all"), width)
    if values is not None and any(v is not None for v in values):
        cells = [Cell("std-error rank corr. (1: ranks the errors)", cls="name"), Cell("model", cls="name")]
        rows.append(Row(tuple(cells + [Cell(DASH if v is None else f"{v:.2f}") for v in values])))
    return rows


def horizon_grid(metrics: dict) -> tuple[str, Table] | None:
    """The note and table of RMS error by horizon in physical units (rows: quantity and
    source; columns: steps), or None without a readable ``horizons`` entry.

    The model's cells are green where it beats ``hold`` (holding the last measured
    output, what any prediction must beat) and red where it does not; the model's ±1σ /
    ±2σ coverage follows when it predicted a standard deviation (ideal: 68 % / 95 %).
    """
    h = metrics.get("horizons")
    steps, seconds = dig(h, "steps"), dig(h, "seconds")
    if not (isinstance(steps, list) and isinstance(seconds, list) and isinstance(dig(h, "rms"), dict)
            and isinstance(dig(h, "quantities"), dict)):
        return None
    head = ("quantity", "source", *(f"step {k} ({num(t) or 0:.3g} s)" for k, t in zip(steps, seconds)))
    note = ("RMS error by horizon over the test trajectories, in physical units; step k is k dt after the last "
            "context sample (green: the model beats hold, red: it does not)."
            + _calibration_note(dig(metrics, "meta", "std_calibration")))
    return note, Table(head, tuple(_horizon_rows(h, len(steps), metrics)))


def horizon_table(metrics: dict) -> str:
    """:func:`horizon_grid` rendered as HTML; an empty string without a ``horizons`` entry."""
    found = horizon_grid(metrics)
    return _macro("horizons", *found) if found else ""


def _calibration_note(cal) -> str:
    """Where the scored standard deviation was recalibrated (``robomorph.calibrate``), if it was."""
    if not isinstance(cal, dict):
        return ""
    data = cal.get("data")
    where = ("the training run's validation robots" if cal.get("split") == "val"
             else ", ".join(map(str, data)) if isinstance(data, list) and data else "a held-out store")
    return (f" The standard deviation was recalibrated by horizon ({cal.get('method', '?')}) on "
            f"{cal.get('n', '?')} windows of {where}.")


def horizon_cells(metrics: dict) -> tuple[Cell, ...]:
    """The overview's lead: the joint RMS error at the first step, 0.25 s and 1 s (those of them that were
    reported) of the model, hold and constant velocity, one cell each (a dash where one is missing). The
    model's is green where it beats both at every step shown, red where it beats neither at any."""
    dashes = tuple(Cell(DASH) for _ in HORIZON_SOURCES)
    steps, seconds = dig(metrics, "horizons", "steps"), dig(metrics, "horizons", "seconds")
    if not (isinstance(steps, list) and isinstance(seconds, list) and len(steps) == len(seconds) and steps):
        return dashes
    rows = {name: _row_values(dig(metrics, "horizons", "rms", name, "joints"), len(steps)) for name, _ in HORIZON_SOURCES}
    pairs = [(num(k), num(t)) for k, t in zip(steps, seconds)]
    model = rows["model"]
    if model is None or any(k is None or t is None or k <= 0 for k, t in pairs):
        return dashes
    dt = pairs[0][1] / pairs[0][0]
    picks = [j for j, (k, t) in enumerate(pairs) if k == 1 or min(abs(t - 0.25), abs(t - 1.0)) < dt / 2]
    picks = [j for j in picks if model[j] is not None]
    if not picks:
        return dashes
    cells = []
    for name, _ in HORIZON_SOURCES:
        values = rows[name]
        if values is None or any(values[j] is None for j in picks):
            cells.append(Cell(DASH))
            continue
        cells.append(Cell(" / ".join(f"{values[j]:.3g}" for j in picks)))
    others = [rows[name] for name, _ in HORIZON_SOURCES[1:] if rows[name] is not None]
    if others and all(all(o[j] is not None for j in picks) for o in others):
        best = [min(o[j] for o in others) for j in picks]
        wins = [model[j] <= b for j, b in zip(picks, best)]
        colour = _BETTER if all(wins) else _WORSE if not any(wins) else None
        cells[0] = Cell(cells[0].text, colour)
    return tuple(cells)


def best_baseline(metrics: dict) -> tuple[str, float] | None:
    """(name, pooled FIT) of the baseline with the highest approach-2 FIT over the moving channels (:func:`pooled`).

    ``true_physics`` reads parameters no predictor gets (a ceiling), so it never competes; nor does a
    baseline that diverged on most windows (held there: its scores are mostly hold's, not its own).
    """
    scored = [(name, pooled(src, "fit", metrics)[0] if dig(src, "approach2") else overall_a1(src, "fit")[0])
              for name, src in sources(metrics)[1:] if name != "true_physics" and not _mostly_diverged(metrics, name)]
    scored = [(name, fit) for name, fit in scored if fit is not None and math.isfinite(fit)]
    return max(scored, key=lambda item: item[1]) if scored else None


def _mostly_diverged(metrics: dict, name: str) -> bool:
    share = diverged_share(metrics, name)
    return share is not None and 2 * share[0] > share[1]


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class FolderGuard:
    """Reads files of one folder (a run, a control folder), refusing any path that a symbolic
    link leads out of it.

    The report is meant to be shared: a ``sample_0.png`` (or ``config.yaml``) that links to
    ``/etc/passwd`` must not carry that file into the page. What is refused becomes a warning.
    """

    def __init__(self, folder: Path, warnings: list[str], what: str = "run folder"):
        self.root, self.warnings, self.what = Path(folder).resolve(), warnings, what

    def allows(self, path: Path) -> bool:
        """Whether ``path``, every link followed, stays inside the folder (warns if not)."""
        try:
            inside = path.resolve().is_relative_to(self.root)
        except (OSError, RuntimeError):  # a link loop
            inside = False
        if not inside:
            rel = path.relative_to(self.root) if path.is_relative_to(self.root) else path
            self.warnings.append(f"{rel}: a symbolic link leading outside the {self.what}; not read")
        return inside

    def file(self, path: Path) -> bool:
        return path.is_file() and self.allows(path)

    def files(self, folder: Path, pattern: str) -> list[Path]:
        return [p for p in sorted(folder.glob(pattern)) if self.file(p)]

    def png(self, path: Path, where: str) -> bytes | None:
        """The bytes of a real PNG file; a file of any other kind is left out with a warning."""
        data = path.read_bytes()
        if not data.startswith(PNG_MAGIC):
            self.warnings.append(f"{where}/{path.name} is not a PNG image; not embedded")
            return None
        return data


def png_uri(png: bytes) -> str:
    """A PNG as a ``data:`` URI, so the page needs no other file."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def leaks(metrics: Any) -> bool:
    """Whether scores used the query outputs' statistics (``"leaks_query_statistics"`` in a
    ``metrics.json``: the paper's normalization)."""
    return isinstance(metrics, dict) and bool(metrics.get("leaks_query_statistics"))


def badges(metrics: Any) -> tuple[str, ...]:
    """The overview's markers for an evaluation's scores (none for plain scores)."""
    return (LEAK_BADGE,) if leaks(metrics) else ()


def notes(metrics: Any) -> list[str]:
    """The warnings an evaluation section carries for what :func:`badges` marks."""
    if leaks(metrics):
        return ["Scored with the paper's normalization (paper_window): each window z-scored over its context and "
                "query, so the predictions used the query outputs' statistics; these are not the scores of a "
                "model that could be deployed."]
    return []


def page(title: str, body: str) -> str:
    """A whole document around ``body`` (markup, trusted), with the title escaped."""
    from markupsafe import Markup  # noqa: PLC0415  (jinja2's own dependency)

    return render("page.html.j2", title=title, body=Markup(body))
