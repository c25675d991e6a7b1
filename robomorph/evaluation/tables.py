"""``metrics.csv``, ``horizons.csv`` and ``table.md`` from an evaluation's ``metrics.json`` content."""

from __future__ import annotations

import os

from robomorph.core.atomic import write_text
from robomorph.core.normalizations import leaks_query_statistics, normalization_label
from robomorph.core.results import markdown_table, provenance_markdown, write_rows
from robomorph.evaluation.fit_bands import FIT_BANDS, fit_band
from robomorph.evaluation.horizons import horizon_markdown

# A hybrid's std points (robomorph.inference.hybrid_std) in a table's note.
POINTS_TEXT = {"columns": "one robot per column of the estimate's covariance", "draws": "random parameter draws",
               "observed": "one robot per column of the estimate's covariance and the observer's start velocity"}


def _sources(result: dict):
    yield "model", {"approach1": result["approach1"], "approach2": result["approach2"]}
    yield from result.get("baselines", {}).items()


def normalization_markdown(normalization: str | None) -> str:
    """The normalization line of a markdown table header; a leaking one is bold and flagged."""
    text = normalization_label(normalization)
    return f"**⚠ {text}**" if leaks_query_statistics(normalization) else text


def csv_rows(result: dict) -> list[dict]:
    """One row per source, approach, channel (or ``mean``) and metric, each with the normalization."""
    norm = result.get("meta", {}).get("normalization") or "train_stats"
    rows = []
    for src, res in _sources(result):
        a1, a2 = res["approach1"], res["approach2"]
        for ch, vals in [*a1["channels"].items(), ("mean", a1["mean"])]:
            rows += [{"source": src, "approach": 1, "channel": ch, "metric": m, "value": v["mean"], "std": v["std"],
                      "normalization": norm} for m, v in vals.items()]
        for ch, vals in [*a2["channels"].items(), ("mean", a2["mean"])]:
            rows += [{"source": src, "approach": 2, "channel": ch, "metric": m, "value": v, "std": "",
                      "normalization": norm} for m, v in vals.items()]
    return rows


def write_csv(path: str, result: dict) -> None:
    write_rows(path, csv_rows(result), result.get("provenance"))


def _fit(v: float) -> str:
    return f"{FIT_BANDS[fit_band(v)].mark} {v:.1f}"


def diverged_note(note: dict, n: int) -> str:
    """``"k of n trajectories diverged: held instead"`` for a baseline that fell back to hold."""
    k = note.get("diverged_held", 0)
    return f"{k} of {n} trajectories diverged: held instead" if k else ""


def cost_note(note: dict) -> str:
    """``"fit 4.2 s per window (max 7.9 s), 10 iterations"`` for a baseline that fits each window."""
    if "seconds_per_window" not in note:
        return ""
    return (f"fit {note['seconds_per_window']:.3g} s per window (max {note['seconds_per_window_max']:.3g} s), "
            f"{note['iterations_mean']:.3g} iterations")


def smoothing_note(report: dict | None) -> str:
    """What the smoothed physics did out of its depth (:func:`robomorph.identification.smoother.new_report`), or ""."""
    if not report or not (report["staged"] or report["handed_from"]):
        return ""
    n, handed = report["windows"], report["handed_from"]
    return (f"smoothed physics: {report['staged']} of {n} windows solved in stages (the decoder far from any path "
            f"the physics allows), {len(handed)} handed to the decoder where the smoothed arm would have left its "
            f"joint range" + (f" (from steps {min(handed)}-{max(handed)})" if handed else "")
            + ": inputs unlike the decoder's training data")


def table_markdown(result: dict) -> str:
    """Per-channel R^2 and FIT (approaches 1 and 2) of the model, FIT of each baseline."""
    meta, a1, a2 = result["meta"], result["approach1"], result["approach2"]
    base = result.get("baselines", {})
    head = ["channel", "R² (1)", "FIT (1)", "R² (2)", "FIT (2)"] + [f"{b} FIT (1)" for b in base]
    rows = []
    for ch in a1["channels"]:
        r, f = a1["channels"][ch]["r2"], a1["channels"][ch]["fit"]
        rows.append([ch, f"{r['mean']:.3f} ± {r['std']:.3f}", f"{_fit(f['mean'])} ± {f['std']:.1f}",
                     f"{a2['channels'][ch]['r2']:.3f}", _fit(a2["channels"][ch]["fit"]),
                     *(_fit(b["approach1"]["channels"][ch]["fit"]["mean"]) for b in base.values())])
    m = a1["mean"]
    rows.append(["**mean**", f"{m['r2']['mean']:.3f} ± {m['r2']['std']:.3f}",
                 f"{_fit(m['fit']['mean'])} ± {m['fit']['std']:.1f}", f"{a2['mean']['r2']:.3f}", _fit(a2["mean"]["fit"]),
                 *(_fit(b["approach1"]["mean"]["fit"]["mean"]) for b in base.values())])
    lines = [*([provenance_markdown(result["provenance"]), ""] if "provenance" in result else []),
             f"Model `{os.path.basename(meta['ckpt'])}` on `{meta['data']}`: {meta['n']} trajectories, "
             f"context {meta['context_len']}, horizon {meta['horizon']} steps. (1): approach 1, mean ± std over "
             "trajectories; (2): approach 2, trajectories concatenated.", "",
             normalization_markdown(meta.get("normalization")), "",
             *([f"**⚠ In-sample: `{meta.get('in_sample_store')}` is a training store of this model; these scores "
                "include robots it was trained on.**", ""] if meta.get("in_sample") else []),
             *([f"**⚠ {meta['recipe_note']}.**", ""] if meta.get("recipe_note") else []),
             markdown_table(head, rows)]
    legend = ", ".join(f"{b.mark} {b.label}" for b in FIT_BANDS)
    lines += ["", f"FIT colour convention (the paper's Table 3): {legend}."]
    notes = meta.get("baseline_notes", {})
    if (seconds := meta.get("seconds_per_window")) is not None:
        lines.append(f"Model: {1e3 * seconds:.3g} ms per window, its predictions alone (wall time on this machine).")
    for b in base:
        if note := diverged_note(notes.get(b, {}), meta["n"]):
            lines.append(f"Baseline `{b}`: {note} (its scores include those held predictions).")
        if note := cost_note(notes.get(b, {})):
            lines.append(f"Baseline `{b}`: {note}.")
        if notes.get(b, {}).get("in_sample"):
            lines.append(f"**⚠ Baseline `{b}` is in-sample: fitted on `{notes[b].get('in_sample_store')}`, which holds "
                         "the robots it is scored on.**")
    for b, why in result.get("skipped_baselines", {}).items():
        lines.append(f"Skipped baseline `{b}`: {why}")
    if phys := meta.get("physics"):
        lines += ["", f"Model predicted on its physics backbone: mode `{phys['mode']}`"
                  + (", horizons from the observer's start velocity" if phys.get("observer") else "")
                  + (", the joints' springs identified" if phys.get("springs") else "")
                  + (", the regression's bias taken off" if phys.get("debias") else "")
                  + (f", friction mixture of {phys['members']} robots" if phys.get("mixture") else "")
                  + (f", std over {POINTS_TEXT[phys['points']]}" if phys.get("points") in POINTS_TEXT else "") + "."]
    if note := smoothing_note(meta.get("smoothing")):
        lines += ["", f"**Model: {note}.**"]
    if "horizons" in result:
        lines += ["", "RMS error by horizon over the trajectories, in physical units (step k is k dt after the last "
                  f"context sample; windows from offset `{meta.get('offset', 'start')}`):", "",
                  horizon_markdown(result["horizons"]).rstrip("\n")]
    return "\n".join(lines) + "\n"


def write_table(path: str, result: dict) -> None:
    write_text(path, table_markdown(result))


def horizon_rows(h: dict) -> list[dict]:
    """One row per source, quantity and step (``rms``), then the model's coverage (``inside_1sigma`` ...)."""
    rows = []
    for src, by_q in h["rms"].items():
        for q, values in by_q.items():
            rows += [{"source": src, "quantity": q, "unit": h["quantities"][q]["unit"], "step": k, "seconds": t,
                      "metric": "rms", "value": v} for k, t, v in zip(h["steps"], h["seconds"], values)]
    for q, by_sigma in h.get("calibration", {}).items():
        for sigma, values in by_sigma.items():
            rows += [{"source": "model", "quantity": q, "unit": "fraction", "step": k, "seconds": t,
                      "metric": f"inside_{sigma}", "value": v} for k, t, v in zip(h["steps"], h["seconds"], values)]
    return rows


def write_horizons_csv(path: str, h: dict, prov: dict | None = None) -> None:
    write_rows(path, horizon_rows(h), prov)
