"""HTML pieces of the training report: the fit-index colours, metric cells and tables.

Kept free of matplotlib and of the file reading in :mod:`robomorph.reporting.dashboard`, so that
:func:`fit_colour` can be reused (e.g. to colour other tables) at the cost of an import of
the standard library only. Every string that comes from a file goes through :func:`esc`.
"""

from __future__ import annotations

import base64
import html
import math
from typing import Any, Iterable

from robomorph.core.names import FIT, NRMSE, R2, RMSE
from robomorph.evaluation.fit_bands import FIT_BANDS

# Cells are painted with xcolor's ``colour!N`` (N% colour mixed with white, FIT_BANDS'
# strength) so the page looks the same on any background, not alpha blended.
METRICS = (R2, FIT, RMSE, NRMSE)  # the order the tables show them
DASH = "—"

CSS = """
:root { color-scheme: light; }
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, Helvetica, Arial, sans-serif;
       margin: 0 auto; padding: 1rem 2rem 3rem; max-width: 1500px; color: #1f2328; background: #fff;
       line-height: 1.4; }
h1 { margin-bottom: .2rem; } h2 { border-bottom: 2px solid #d0d7de; padding-bottom: .2rem; margin-top: 2.2rem; }
h3 { margin-top: 1.6rem; } h4 { margin: 1.2rem 0 .4rem; }
.sub, .meta, .note { color: #57606a; font-size: .92rem; }
.leak { color: #cf222e; }
.warn { background: #fff8c5; border: 1px solid #d4a72c; border-radius: 6px; padding: .4rem .7rem; margin: .4rem 0; }
nav a { margin-right: .8rem; }
code, pre { font-family: ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; font-size: .85rem; }
pre { background: #f6f8fa; border: 1px solid #d0d7de; border-radius: 6px; padding: .6rem; overflow: auto;
      max-height: 32rem; }
details { margin: .5rem 0; } summary { cursor: pointer; color: #0969da; }
.scroll { overflow-x: auto; }
table { border-collapse: collapse; margin: .5rem 0 1rem; font-size: .88rem; }
th, td { border: 1px solid #d0d7de; padding: .25rem .5rem; text-align: right; white-space: nowrap; }
th { background: #f6f8fa; position: sticky; top: 0; text-align: center; }
td.name, th.name { text-align: left; }
tr.mean td { font-weight: 600; border-top: 2px solid #8c959f; }
th.model, td.model { border-left: 2px solid #57606a; }
.legend span { display: inline-block; padding: .15rem .6rem; margin-right: .4rem; border: 1px solid #d0d7de;
               border-radius: 4px; font-size: .85rem; }
figure { display: inline-block; margin: .5rem 1rem .5rem 0; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #d0d7de; }
figcaption { font-size: .85rem; color: #57606a; }
"""


def esc(value: Any) -> str:
    """HTML-escapes ``str(value)``, quotes included, so it is safe in text and attributes."""
    return html.escape(str(value), quote=True)


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


def legend_html() -> str:
    """A one-line legend of the fit-index colours."""
    spans = "".join(
        f'<span style="background:{fit_colour(low if math.isfinite(low) else 0.0)}">{esc(label)}</span>'
        for low, _, _, _, label in FIT_BANDS
    )
    return f'<p class="legend">Fit-index colours (paper, Table 3): {spans}</p>'


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


def td(text: str, colour: str | None = None, cls: str = "") -> str:
    """A table cell; ``text`` must already be escaped."""
    style = f' style="background:{colour}"' if colour else ""
    klass = f' class="{cls}"' if cls else ""
    return f"<td{klass}{style}>{text}</td>"


def table(head: Iterable[str], rows: Iterable[str], head_rows: Iterable[str] = ()) -> str:
    """A scrollable table from escaped header cells and already-built ``<tr>`` rows."""
    extra = "".join(head_rows)
    ths = "".join(f"<th>{h}</th>" for h in head)
    return f'<div class="scroll"><table><thead>{extra}<tr>{ths}</tr></thead><tbody>{"".join(rows)}</tbody></table></div>'


def sources(metrics: dict) -> list[tuple[str, Any]]:
    """The model's results followed by each baseline's, as (name, results) pairs."""
    baselines = metrics.get("baselines")
    named = sorted(baselines.items()) if isinstance(baselines, dict) else []
    return [("model", metrics)] + [(name, res) for name, res in named if isinstance(res, dict)]


def channel_names(metrics: dict) -> list[str]:
    """Every channel named by any source or approach, in first-seen order."""
    names: dict[str, None] = {}
    for _, src in sources(metrics):
        for approach in ("approach1", "approach2"):
            channels = dig(src, approach, "channels")
            if isinstance(channels, dict):
                names.update(dict.fromkeys(map(str, channels)))
    return list(names)


def _pair_cells(r2: tuple, fit: tuple, first: bool) -> str:
    """R² and FIT cells of one source/approach, both coloured by FIT."""
    colour = fit_colour(fit[0])
    cls = "model" if first else ""
    return td(esc(fmt(*r2, "r2")), colour, cls) + td(esc(fmt(*fit, "fit")), colour)


def channel_table(metrics: dict) -> str:
    """Per-channel R² and FIT of the model and every baseline, for both approaches.

    Columns come in groups, one per source (model first), each with approach 1 (mean ± std
    over the test set) and approach 2, so a row reads as "what the model adds" per channel.
    The last row is the mean over channels.
    """
    srcs = sources(metrics)
    top = '<th class="name" rowspan="2">channel</th>' + "".join(
        f'<th class="model" colspan="4">{esc(name)}</th>' for name, _ in srcs
    )
    sub = ["A1 R²", "A1 FIT", "A2 R²", "A2 FIT"] * len(srcs)
    rows = []
    for channel in channel_names(metrics):
        cells = ""
        for _, src in srcs:
            for i, approach in enumerate(("approach1", "approach2")):
                entry = dig(src, approach, "channels", channel)
                cells += _pair_cells(stat(dig(entry, "r2")), stat(dig(entry, "fit")), i == 0)
        rows.append(f'<tr>{td(esc(channel), cls="name")}{cells}</tr>')
    cells = ""
    for _, src in srcs:
        for i, approach in enumerate(("approach1", "approach2")):
            cells += _pair_cells(mean_stat(src, approach, "r2"), mean_stat(src, approach, "fit"), i == 0)
    rows.append(f'<tr class="mean">{td("mean", cls="name")}{cells}</tr>')
    return table(sub, rows, head_rows=[f"<tr>{top}</tr>"])


_BETTER, _WORSE = "rgb(204, 235, 204)", "rgb(248, 209, 204)"


def _row_values(values: Any, width: int) -> list[float | None] | None:
    if not isinstance(values, list) or len(values) != width:
        return None
    return [num(v) for v in values]


def horizon_table(metrics: dict) -> str:
    """RMS error by horizon in physical units (rows: quantity and source; columns: steps).

    The model's cells are green where it beats ``hold`` (holding the last measured
    output, what any prediction must beat) and red where it does not; the model's ±1σ /
    ±2σ coverage follows when it predicted a standard deviation (ideal: 68 % / 95 %).
    Returns an empty string when ``metrics`` has no readable ``horizons`` entry.
    """
    h = metrics.get("horizons")
    steps, seconds = dig(h, "steps"), dig(h, "seconds")
    rms, quantities = dig(h, "rms"), dig(h, "quantities")
    if not (isinstance(steps, list) and isinstance(seconds, list) and isinstance(rms, dict) and isinstance(quantities, dict)):
        return ""
    width = len(steps)
    head = ["quantity", "source"] + [esc(f"step {k} ({num(t) or 0:.3g} s)") for k, t in zip(steps, seconds)]
    rows = []
    for q, info in quantities.items():
        unit = dig(info, "unit")
        label = esc(f"{q} [{unit}]" if unit else q)
        hold = _row_values(dig(rms, "hold", q), width)
        for src in ["model", *sorted(s for s in rms if s != "model")]:
            values = _row_values(dig(rms, src, q), width)
            if values is None:
                continue
            cells = ""
            for j, v in enumerate(values):
                colour = None
                if src == "model" and hold and v is not None and hold[j] is not None:
                    colour = _BETTER if v <= hold[j] else _WORSE
                cells += td(DASH if v is None else esc(f"{v:.4g}"), colour)
            rows.append(f'<tr>{td(label, cls="name")}{td(esc(src), cls="name")}{cells}</tr>')
    for sigma, ideal in (("1sigma", 68.3), ("2sigma", 95.4)):
        values = _row_values(dig(h, "calibration", "all", sigma), width)
        if values is not None:
            cells = "".join(td(DASH if v is None else esc(f"{100 * v:.1f}")) for v in values)
            label = esc(f"inside ±{sigma[0]}σ [%] (ideal {ideal})")
            rows.append(f'<tr>{td(label, cls="name")}{td("model", cls="name")}{cells}</tr>')
    note = ('<p class="note">RMS error by horizon over the test trajectories, in physical units; step k is k dt '
            "after the last context sample (green: the model beats hold, red: it does not)."
            + _calibration_note(dig(metrics, "meta", "std_calibration")) + "</p>")
    return note + table(head, rows)


def _calibration_note(cal) -> str:
    """Where the scored standard deviation was recalibrated (``robomorph.calibrate``), if it was."""
    if not isinstance(cal, dict):
        return ""
    where = "the training run's validation robots" if cal.get("split") == "val" else "a held-out store"
    return esc(f" The standard deviation was recalibrated by horizon ({cal.get('method', '?')}) on "
               f"{cal.get('n', '?')} windows of {where}.")


HORIZON_HEAD = "joints RMS [mrad] first step / 0.25 s / 1 s (hold)"


def horizon_cell(metrics: dict) -> str:
    """The overview's cell: the model's joint RMS error at the first step, 0.25 s and 1 s
    (those of them that were reported), hold's in brackets; a dash without them."""
    steps, seconds = dig(metrics, "horizons", "steps"), dig(metrics, "horizons", "seconds")
    if not (isinstance(steps, list) and isinstance(seconds, list) and len(steps) == len(seconds) and steps):
        return td(DASH)
    model = _row_values(dig(metrics, "horizons", "rms", "model", "joints"), len(steps))
    hold = _row_values(dig(metrics, "horizons", "rms", "hold", "joints"), len(steps))
    pairs = [(num(k), num(t)) for k, t in zip(steps, seconds)]
    if model is None or any(k is None or t is None or k <= 0 for k, t in pairs):
        return td(DASH)
    dt = pairs[0][1] / pairs[0][0]
    picks = [j for j, (k, t) in enumerate(pairs) if k == 1 or min(abs(t - 0.25), abs(t - 1.0)) < dt / 2]
    picks = [j for j in picks if model[j] is not None]
    if not picks:
        return td(DASH)
    text = " / ".join(f"{model[j]:.3g}" for j in picks)
    if hold and all(hold[j] is not None for j in picks):
        text += " (" + " / ".join(f"{hold[j]:.3g}" for j in picks) + ")"
    return td(esc(text))


def best_baseline(metrics: dict) -> tuple[str, float] | None:
    """(name, mean approach-1 FIT) of the baseline with the highest such FIT, if any has one.

    ``true_physics`` reads parameters no predictor gets (a ceiling), so it never competes.
    """
    scored = [(name, mean_stat(src, "approach1", "fit")[0]) for name, src in sources(metrics)[1:]
              if name != "true_physics"]
    scored = [(name, fit) for name, fit in scored if fit is not None and math.isfinite(fit)]
    return max(scored, key=lambda item: item[1]) if scored else None


def img_tag(png: bytes, alt: str) -> str:
    """An ``<img>`` with the PNG embedded as a data: URI, so the page needs no other file."""
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{esc(alt)}">'


def figure(png: bytes, caption: str) -> str:
    """An embedded image with its caption."""
    return f"<figure>{img_tag(png, caption)}<figcaption>{esc(caption)}</figcaption></figure>"


def leak_badge(metrics: Any) -> str:
    """A marker for scores that used the query outputs' statistics (``"leaks_query_statistics"``
    in a ``metrics.json``: the paper's normalization); empty otherwise."""
    leaks = isinstance(metrics, dict) and bool(metrics.get("leaks_query_statistics"))
    return '<br><b class="leak">⚠ paper_window: uses query statistics</b>' if leaks else ""


def leak_note(metrics: Any) -> str:
    """The warning an evaluation section carries when :func:`leak_badge` marks it; empty otherwise."""
    return warn("Scored with the paper's normalization (paper_window): each window z-scored over its context and "
                "query, so the predictions used the query outputs' statistics; these are not the scores of a "
                "model that could be deployed.") if leak_badge(metrics) else ""


def warn(text: str) -> str:
    """A visible warning box."""
    return f'<div class="warn">⚠ {esc(text)}</div>'


def page(title: str, body: str) -> str:
    """The whole document: inline CSS, no script, no external resource of any kind."""
    # The empty data: icon stops the browser looking for a favicon next to the file.
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>{esc(title)}</title><link rel="icon" href="data:,"><style>{CSS}</style></head>\n'
        f"<body>\n{body}\n</body></html>\n"
    )
