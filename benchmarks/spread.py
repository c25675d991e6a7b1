"""Does a model's spread tell which windows will miss? And would another per-window signal?

A calibration scales every window's spread at a step alike (``robomorph calibrate``), so the
shares inside ±1σ and ±2σ can both be right only where the spread ranks the windows by their
errors. Where it does not, the windows whose spread was too small stay so and the errors look
heavy-tailed: a scale that gives ±1σ its 68 % leaves ±2σ short. This script measures, on the
same windows:

- the **skill** of each candidate spread: the rank correlation across windows between it and the
  joints' absolute error, at the reported steps (median over the joints;
  :func:`robomorph.evaluation.horizons.spread_skill`, what ``calibrate`` prints);
- the joints' ±1σ / ±2σ coverage on the test windows after a ``power`` calibration fitted on the
  calibration windows (``--knots``: log-spaced, as dense at the horizon's end as at its start, or both
  side by side), with the model's spread and with the spread times a candidate signal to a
  power (``q``), the largest miss in units of its tolerance (5 and 3 points; 1 or less: both goal
  bands met).

The candidates (where the model has them): ``spread`` (the model's own std, uncalibrated);
``decoder`` (a hybrid's black-box decoder's std, per step and channel); ``identification``
(the trace of the regression's estimate covariance, one number per window: how well the
context pins the robot down); ``gap`` (a blend's distance from its decoder, ``w |physics -
decoder|`` per step and channel: where the two members disagree, one of them is far off).
A candidate enters the spread as a factor (``spread × signal^q``), the gap as a term instead (it
is 0 wherever the blend's weight is 0): ``spread ⊕ b·gap``, the root of the sum of squares, the gap
scaled by ``b`` times the ratio of the medians of the spread and the gap on the calibration
windows at each step and channel (``b = 1``: the two terms weigh alike in a typical window). Measured
on the total-torque blend (``spread_total.md``): it ranks the late steps' errors a little better (skill
0.26 / 0.23 at 5 / 13.3 s with ``b = 0.5``, against 0.21 / 0.20), the early ones worse, and the
coverage's largest miss grew (1.53-1.59 tolerances against 1.46), so the blend has no such term.

    python benchmarks/spread.py --ckpt data/quality/blend/best.ckpt --cal data/demo/ms_cal256.zarr \\
        --test data/demo/ms_test256.zarr --n 256 --md results/benchmarks/spread_total.md
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import torch
from common import check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.evaluation.calibrating import dense_at_end, moving_windows
from robomorph.evaluation.horizons import coverage, groups_for, spread_skill
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.windows import load_window, start_joints
from robomorph.inference.calibration import band_miss, fit
from robomorph.inference.predictor import Predictor

POWERS = (0.5, 1.0)  # of a candidate signal multiplied into the spread
TERMS = (0.5, 1.0, 2.0)  # weights b of the gap added to the spread (in units of their medians' ratio)


def _windows(pred: Predictor, store: str, n: int, offset: str, horizon: int | None):
    info = pred.data_info
    horizon = horizon or (info["horizon"] if offset == "start" else 600)
    w = load_window(store, info["context_len"], horizon, n, info, pred.n_u, pred.n_y, offset, 0, pred.inputs)
    return w if offset == "start" else moving_windows(w, offset)


@torch.no_grad()
def candidates(pred: Predictor, w, batch: int, mean: np.ndarray) -> dict:
    """name -> (N, H, n_y) or (N, 1, 1) per-window signals beside the model's spread (``mean``: its prediction)."""
    u_ctx, y_ctx, u_q, _ = w.split()
    out = {}
    if pred.physics and getattr(pred.model, "gaussian", False):
        parts = [pred.model.forward_dist_raw(*(torch.as_tensor(a[i:i + batch]) for a in (u_ctx, y_ctx, u_q)))
                 for i in range(0, len(u_ctx), batch)]
        out["decoder"] = torch.cat([s for _, s in parts]).double().numpy()
        if pred.settings.mode == "blend":
            out["gap"] = np.abs(mean - torch.cat([m for m, _ in parts]).double().numpy())
    if pred.physics:
        hybrid, anchor, traces = pred.hybrid(), start_joints(w), []
        for i in range(0, len(u_ctx), batch):
            hybrid.identify(torch.as_tensor(u_ctx[i:i + batch]), torch.as_tensor(y_ctx[i:i + batch]), "regression",
                            anchor=None if anchor is None else anchor[i:i + batch], at_rest=not w.starts.any())
            traces += [np.trace(c) for c in hybrid.covariances]
        out["identification"] = np.asarray(traces)[:, None, None]
    return out


def _predict(pred: Predictor, w, steps, batch: int, others: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    with pred.raw_std():
        s = score_windows(pred, w, (), steps, batch_size=batch)
    if s.std is None:
        raise SystemExit(f"error: the model predicts no standard deviation (physics mode {pred.settings.mode!r})")
    return s.y, s.preds["model"], s.std, candidates(pred, w, batch, s.preds["model"]) if others else {}


def _spread(part: tuple, name: str, q: float, ref: np.ndarray, kind: str = "factor") -> np.ndarray:
    """A prediction's (``(y, mean, std, signals)``) spread, times its signal ``name`` over ``ref`` to the power ``q``
    (``kind`` factor), or with ``q * ref`` times the signal added in quadrature (``kind`` term)."""
    if name == "spread":
        return part[2]
    if kind == "term":
        return np.sqrt(part[2] ** 2 + (q * ref * part[3][name]) ** 2)
    return part[2] * (part[3][name] / ref) ** q


def _load_cache(path: str, key: str) -> dict:
    """The predictions ``--cache`` holds for these windows (``{points: (cal, test)}``), or none."""
    try:
        f = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return {}
    if str(f["key"]) != key:
        print(f"spread: {path} holds other windows; predicting again", file=sys.stderr)
        return {}
    names = [str(n) for n in f["points"]]
    return {n: tuple((f[f"{n}/{part}/y"], f[f"{n}/{part}/mean"], f[f"{n}/{part}/std"], {}) for part in ("cal", "test"))
            for n in names}


def _save_cache(path: str, key: str, spreads: dict) -> None:
    arrays = {f"{n}/{part}/{what}": v[i] for n, pair in spreads.items() for part, v in zip(("cal", "test"), pair)
              for i, what in enumerate(("y", "mean", "std"))}
    np.savez(path, key=np.array(key), points=np.array(list(spreads)), **arrays)


def _label(row: dict) -> str:
    if row["signal"] == "spread":
        return "spread"
    if row["kind"] == "term":
        return f"spread ⊕ {row['power']:g}·{row['signal']}"
    return f"spread × {row['signal']}^{row['power']:g}"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True)
    p.add_argument("--cal", required=True, help="held-out store the calibrations are fitted on")
    p.add_argument("--test", required=True, help="held-out store they are scored on (other robots)")
    p.add_argument("--n", type=int, default=256, help="windows of each store")
    p.add_argument("--n-test", type=int, default=None, help="windows of the test store (default: --n)")
    p.add_argument("--knots", default=None, help="comma-separated knot layouts to fit the model's own spread on: "
                   "log (log-spaced) and end (as dense at the horizon's end as at its start); default: calibrate's")
    p.add_argument("--points", default=None, help="comma-separated robots a hybrid's spread is taken over, side by "
                   "side (POINTS[+springs][+debias]: columns or draws, robomorph.inference.hybrid_std; +springs: the "
                   "regression fits the joints' springs too; +debias: its bias taken off, robomorph.inference.debias), "
                   "its own spread alone; default: its own points and the candidates")
    p.add_argument("--offset", default="start", help="start, random or a step, as in evaluate")
    p.add_argument("--horizon", type=int, default=None, help="default: the training horizon (600 off the start)")
    p.add_argument("--physics", default=None, help="a hybrid's physics mode (default: its default)")
    p.add_argument("--members", type=int, default=None, help="a hybrid's friction mixture members (1: the single "
                   "robot, the fast setting; default: the model's)")
    p.add_argument("--substeps", type=int, default=None, help="a hybrid's physics steps per sample after the first "
                   "second (Predictor.settings.substeps; 2: the fast setting's)")
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--cache", default=None, help="with --points: an .npz the predictions are kept in and read back "
                   "from for the same windows, so that calibrations can be compared again without predicting")
    p.add_argument("--md", default="results/benchmarks/spread.md")
    p.add_argument("--csv", default=None, help="default: --md with .csv")
    a = p.parse_args(argv)
    check_outputs(md=a.md, csv=a.csv)
    if a.knots and set(a.knots.split(",")) - {"log", "end"}:
        p.error(f"--knots takes log and end, got {a.knots!r}")
    prov = provenance()
    print_provenance()
    pred = Predictor.from_checkpoint(a.ckpt, device="cpu")
    pred.use_physics(a.physics)
    if a.members is not None:
        if a.members < 1:
            p.error(f"--members must be 1 or more, got {a.members}")
        pred.configure(members=a.members)
    pred.configure(substeps=a.substeps)
    cal_w, test_w = _windows(pred, a.cal, a.n, a.offset, a.horizon), _windows(pred, a.test, a.n_test or a.n, a.offset,
                                                                              a.horizon)
    steps = sorted({s for s in (1, 15, 60, 300, 800) if s <= cal_w.horizon} | {cal_w.horizon})
    joints = list(next(g for g in groups_for(cal_w.y_names) if g.name == "joints").channels)
    points = a.points.split(",") if a.points else [None]
    layouts = a.knots.split(",") if a.knots else ["end" if dense_at_end(pred) else "log"]
    rows, spreads = [], {}
    # The same windows whatever folder the command runs from: the files' real paths.
    real = [os.path.realpath(f) for f in (a.ckpt, a.cal, a.test)]
    key = repr((*real, len(cal_w.u), len(test_w.u), a.offset, cal_w.horizon, a.physics, a.members)
               + ((a.substeps,) if a.substeps is not None else ()))  # caches written before --substeps stay valid
    cached = _load_cache(a.cache, key) if a.cache and a.points else {}
    for p in points:  # the model's own spread over each kind of points; the candidates beside the first's
        if p in cached:
            spreads[p] = cached[p]
            continue
        if p is not None:  # POINTS[+springs][+debias]: the regression fits the joints' springs too; its bias taken off
            name, *extra = p.split("+")
            if set(extra) - {"springs", "debias"}:
                raise SystemExit(f"error: --points takes POINTS[+springs][+debias], got {p!r}")
            pred.configure(points=name, springs="springs" in extra, debias="debias" in extra)
        spreads[p] = tuple(_predict(pred, w, steps, a.batch, others=not a.points) for w in (cal_w, test_w))
    if a.cache and a.points:
        _save_cache(a.cache, key, spreads)
    cal = spreads[points[0]][0]
    for name in ("spread", *cal[3]):
        ref = None if name == "spread" else np.median(cal[3][name], axis=0, keepdims=True)
        if name == "spread":
            variants = [(0.0, k, "factor", p) for p in points for k in layouts]
        elif name == "gap":  # a term only (the gap is 0 where the weight is 0): b times the medians' ratio
            ref = np.median(cal[2], axis=0, keepdims=True) / np.where(ref > 0, ref, np.inf)
            variants = [(b, layouts[0], "term", points[0]) for b in TERMS]
        else:
            variants = [(q, layouts[0], "factor", points[0]) for q in POWERS]
        for q, knots, kind, p in variants:
            cal_p, test_p = spreads[p]
            y, mean = test_p[:2]  # each variant's own mean: the springs move it, not only the spread
            spread = _spread(test_p, name, q, ref, kind)
            skill = spread_skill(y[..., joints], mean[..., joints], np.broadcast_to(spread, y.shape)[..., joints], steps)
            c = fit(cal_p[0], cal_p[1], _spread(cal_p, name, q, ref, kind), "power", end=knots == "end")
            cover = coverage(y, mean, c.scaled(spread), steps, tuple(joints))
            one, two = cover["1sigma"], cover["2sigma"]
            miss = float(np.max(band_miss(one, two)))
            rows.append({"signal": name, "power": q, "kind": kind, "knots": knots, "points": p or "",
                         "steps": "/".join(map(str, steps)),
                         "skill": "/".join(f"{v:.2f}" for v in skill), "cover1sigma": "/".join(f"{v:.3f}" for v in one),
                         "cover2sigma": "/".join(f"{v:.3f}" for v in two), "largest_miss": round(miss, 2)})
            print(rows[-1], file=sys.stderr, flush=True)
    csv = a.csv or a.md.rsplit(".", 1)[0] + ".csv"
    write_rows(csv, rows, prov)
    table = markdown_table(
        ["calibrated spread", "points", "knots", "skill at the steps (rank corr. with the error)", "±1σ [%]",
         "±2σ [%]", "largest miss [tolerances]"],
        [[_label(r), r["points"] or "own", r["knots"], r["skill"],
          " / ".join(f"{100 * float(v):.1f}" for v in r["cover1sigma"].split("/")),
          " / ".join(f"{100 * float(v):.1f}" for v in r["cover2sigma"].split("/")), r["largest_miss"]] for r in rows])
    members = f", {pred.settings.members} friction member{'s' * (pred.settings.members > 1)}" if pred.physics else ""
    members += f", {a.substeps} physics steps per sample after the first second" if a.substeps else ""
    text = (f"# Which spread tells the windows that will miss ({a.ckpt}, physics mode {pred.settings.mode}{members})\n\n"
            f"Calibrated (`power`) on {len(cal_w.u)} windows of {a.cal}, scored on {len(test_w.u)} of {a.test}, "
            f"windows from offset `{a.offset}`, joints at steps {', '.join(map(str, steps))}. Skill: the rank "
            "correlation across the test windows between the signal and the joints' absolute error (median over the "
            "joints) of the spread as combined. Largest miss: of 68.3 % at ±1σ and 95.4 % at ±2σ, in units of "
            "5 and 3 points (1 or less: both goal bands met at every step).\n\n" + table)
    write_markdown(a.md, text, prov)
    print(table)


if __name__ == "__main__":
    sys.exit(run_command(main))
