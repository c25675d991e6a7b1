"""The hybrid model's modes beside hold, the catalogue robot and identified physics, on the same windows.

Each mode of a checkpoint trained with ``--model.physics amortized`` (``learned``: the
parameter head's estimate; ``regression``: linear least-squares solves of the inverse
dynamics, ``regression@1`` a single one, ``regression~1`` without the friction mixture; ``refined``: a few Gauss-Newton iterations from the regression), optionally the
checkpoint's black-box decoder (``--black-box``) and other checkpoints (``--compare``), and
the baselines are scored on the same held-out windows with
:func:`robomorph.evaluation.scoring.score_windows`: from the trajectory start and from random
offsets (seed 0). Printed and written: joint RMS error [mrad] at steps 1, 15, 60, 300 and 800
(the first step, 0.25 s, 1 s, 5 s, 13.3 s; step k is k dt after the last context sample),
R^2 (approach 1, all channels), the joints' ±1σ/±2σ coverage at the reported steps (mean, lowest
and highest), and the cost per window (wall clock on this machine, all its cores). With
``identified_physics`` among the baselines (or the one ``--paired`` names), a second table compares
window by window: at each reported step, the share of windows where a source's joint error is below
its error and the median of the ratio of the two errors (an RMS over windows can be decided by a
few). ``identified_physics_springs`` (a baseline of evaluate): identified physics fitting the joints'
springs too, as the command hybrid's regression does (``MODE+springs``).

    python benchmarks/hybrid.py --ckpt data/hyb/runs/amort40/checkpoints/best.ckpt \\
        --test data/demo/ms_heldout.zarr --n 16 --csv results/benchmarks/hybrid.csv
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from common import check_outputs, print_provenance

from robomorph.core.errors import RoboMorphError, run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.evaluation.horizons import squared_error
from robomorph.evaluation.scoring import MODEL, score_windows
from robomorph.evaluation.windows import load_window
from robomorph.inference.predictor import Predictor
from robomorph.inference.settings import HybridSettings

STEPS = (1, 15, 60, 300, 800)
# The baseline the window-by-window table compares against (default of --paired).
PAIRED = "identified_physics"

def _window_errors(scores, source: str) -> np.ndarray:
    """(N, len(STEPS)) each window's joint RMS error [mrad] at the reported steps (nan beyond the horizon)."""
    group = scores.group("joints")
    err = np.sqrt(squared_error(scores.y, scores.preds[source], group)) * group.scale
    return np.stack([err[:, k - 1] if k <= err.shape[1] else np.full(len(err), np.nan) for k in STEPS], axis=1)


def _paired(row: dict, mine: np.ndarray, ref: np.ndarray | None) -> dict:
    """``row`` with, per reported step, the share of windows below ``ref``'s error and the median ratio."""
    for i, k in enumerate(STEPS):
        ok = ref is not None and not np.isnan(ref[:, i]).all()
        row[f"below_ref{k}"] = float(np.mean(mine[:, i] < ref[:, i])) if ok else float("nan")
        row[f"ratio_ref{k}"] = float(np.median(mine[:, i] / np.maximum(ref[:, i], 1e-12))) if ok else float("nan")
    return row


def _row(name: str, offset: str, scores, source: str, seconds: float | None, std: bool) -> dict:
    h = scores.y.shape[1]
    row = {"source": name, "windows": offset}
    for k in STEPS:
        row[f"step{k}"] = scores.at(source, "joints", k) if k <= h else float("nan")
    row["r2"] = scores.summary(source)["r2"]
    # The joints' coverage at the reported steps (the goal is a band at every one): mean, min, max.
    cal = scores.result["horizons"].get("calibration", {}).get("joints", {}) if std and source == MODEL else {}
    for k in (1, 2):
        at = np.asarray(cal.get(f"{k}sigma", [np.nan]), dtype=np.float64)
        row[f"cover{k}"], row[f"cover{k}_min"], row[f"cover{k}_max"] = float(np.mean(at)), float(at.min()), float(at.max())
    row["s_per_window"] = seconds if seconds is not None else float("nan")
    return row


def configure(pred: Predictor, spec: str) -> str:
    """Sets ``pred`` up as the settings key ``spec`` says (:meth:`HybridSettings.from_key`:
    ``MODE[@K][~M][/S][+obs][+springs][+debias][+tangent]``); returns MODE."""
    try:
        pred.configure(HybridSettings.from_key(spec, pred.settings))
    except RoboMorphError as exc:
        raise SystemExit(f"error: {exc}") from None
    return pred.settings.mode


def latency(args, prov: dict) -> None:
    """Median wall time of Predictor.simulate per mode: one trajectory, and 256 candidates on one context."""
    from robomorph.data.store import open_store  # noqa: PLC0415

    pred = Predictor.from_checkpoint(args.ckpt)
    ds = open_store(args.test)
    u, y = ds.read_inputs(pred.inputs)[:1].astype(np.float32), ds.read("y")[:1].astype(np.float32)
    c, h = pred.data_info["context_len"], pred.data_info["horizon"]
    rng = np.random.default_rng(0)
    cands = u[0, c:c + 60][None] + rng.normal(0, 0.2, size=(256, 60, u.shape[2])).astype(np.float32)
    calls = [(spec, what, call) for spec in [m for m in args.modes.split(",") if m] + ["none"]
             for what, call in (("one trajectory (200 + 800)", lambda: pred.simulate(u[0, :c], y[0, :c], u[0, c:c + h])),
                                ("256 candidates x 60 steps, one context",
                                 lambda: pred.simulate(np.repeat(u[:, :c], 256, 0), np.repeat(y[:, :c], 256, 0), cands)))]
    for spec, _, call in calls:
        configure(pred, spec)
        call()  # warm-up (builds the simulators)
    # Round by round, every call once: a burst of load on a shared machine then slows one round of all of them
    # alike, which the median leaves out, rather than every repeat of one mode.
    times = {(spec, what): [] for spec, what, _ in calls}
    for _ in range(args.repeats):
        for spec, what, call in calls:
            configure(pred, spec)
            t0 = time.perf_counter()
            call()
            times[spec, what].append(time.perf_counter() - t0)
    rows = [{"mode": spec, "call": what, "ms_median": 1e3 * float(np.median(ts))} for (spec, what), ts in times.items()]
    print(markdown_table(["mode", "call", "ms (median)"], [[r["mode"], r["call"], r["ms_median"]] for r in rows]))
    if args.latency_csv:
        write_rows(args.latency_csv, rows, prov)
        print(f"written: {args.latency_csv}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ckpt", required=True, help="a checkpoint trained with --model.physics amortized")
    p.add_argument("--test", required=True, help="held-out store")
    p.add_argument("--n", type=int, default=16, help="held-out robots (one window each per offset)")
    p.add_argument("--modes", default="learned,regression,refined",
                   help="comma-separated physics modes; MODE@K solves the regression K times (default 3), "
                        "each linearized where the last landed; MODE~M predicts with M robots of the friction "
                        "mixture over the joints that held still (default 9; ~1: the estimate alone); MODE/S "
                        "simulates the horizon after its first second at S physics steps per sample (default: "
                        "a 240th of a second, 4 for the Panda recipe's 8; /8 re-enacts the generator throughout); "
                        "MODE+obs starts the horizon from the observer's velocity (Predictor.settings.observer); "
                        "MODE+springs fits the joints' springs too (Predictor.settings.springs); MODE+debias takes the "
                        "regression's bias off (Predictor.settings.debias); "
                        "MODE+tangent simulates the latency's candidates tangent-linear (Predictor.settings.candidates)")
    p.add_argument("--baselines", default="hold,nominal_physics,identified_physics",
                   help="comma-separated baselines of evaluate (identified_physics_springs: identified physics "
                        "fitting the joints' springs too)")
    p.add_argument("--paired", default=PAIRED, help="the baseline the window-by-window table compares against")
    p.add_argument("--offsets", default="start,random")
    p.add_argument("--black-box", action="store_true", help="also score the checkpoint's black-box decoder")
    p.add_argument("--compare", action="append", default=[], metavar="NAME=CKPT",
                   help="another checkpoint scored on the same windows (e.g. the black-box model)")
    p.add_argument("--random-horizon", type=int, default=600, help="horizon of the random-offset windows")
    p.add_argument("--std", action="store_true", help="also score the hybrid's std (parameter draws: slower)")
    p.add_argument("--csv", default=None)
    p.add_argument("--md", default=None, help="also write the printed table, with its command, as Markdown")
    p.add_argument("--latency", action="store_true",
                   help="also time one prediction (context 200, horizon 800) and a batch of 256 candidate "
                        "60-step torque sequences on one context, per mode (median of --repeats)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cost-repeats", type=int, default=3,
                   help="timed passes over the windows per model source; the cost per window is their median")
    p.add_argument("--latency-csv", default=None)
    args = p.parse_args(argv)
    check_outputs(csv=args.csv, md=args.md, latency_csv=args.latency_csv)
    prov = provenance()  # of the code that runs: taken before this run rewrites its own (tracked) result files
    print_provenance()
    if args.latency:
        latency(args, prov)
    base = Predictor.from_checkpoint(args.ckpt)
    info = base.data_info
    rows = []
    for offset in args.offsets.split(","):
        horizon = info["horizon"] if offset == "start" else args.random_horizon
        w = load_window(args.test, info["context_len"], horizon, args.n, info, base.n_u, base.n_y, offset, 0,
                        base.inputs)
        baselines = tuple(b for b in args.baselines.split(",") if b)
        scores = score_windows(None, w, baselines)
        notes = scores.result["meta"]["baseline_notes"]
        ref = _window_errors(scores, args.paired) if args.paired in scores.preds else None
        for b in baselines:
            if b in scores.preds:
                rows.append(_paired(_row(b, offset, scores, b, notes.get(b, {}).get("seconds_per_window"), False),
                                    _window_errors(scores, b), None if b == args.paired else ref))
        sources = [(m, args.ckpt, m) for m in args.modes.split(",") if m]  # "mode@k": k regression solves
        if args.black_box:
            sources.append(("black_box", args.ckpt, "none"))
        sources += [(spec.partition("=")[0], spec.partition("=")[2], None) for spec in args.compare]
        for name, ckpt, mode in sources:
            pred = Predictor.from_checkpoint(ckpt)
            if mode is not None:
                mode = configure(pred, mode)
            std = args.std and mode not in (None, "none")
            if not std and pred.physics:
                pred.has_std = False  # the mean alone: the cost of a prediction without draws
            score_windows(pred, w.rows(slice(0, 2)), ())  # warm-up: builds the simulators (once a run), which is not a window's cost
            # The cost per window: the predictions alone, as identified physics' is its fits and simulations alone; the
            # median of --cost-repeats passes (a pass takes seconds, where identified physics' mean spans minutes, so a
            # burst of load on this shared machine would weigh on one pass far more than on the baseline).
            s = score_windows(pred, w, ())
            seconds = [s.result["meta"]["seconds_per_window"]]
            seconds += [score_windows(pred, w, ()).result["meta"]["seconds_per_window"] for _ in range(args.cost_repeats - 1)]
            rows.append(_paired(_row(name, offset, s, MODEL, float(np.median(seconds)), std),
                                _window_errors(s, MODEL), ref))
            print(f"  scored {name} ({offset})", file=sys.stderr, flush=True)
    headers = ["source", "windows"] + [f"step{k}" for k in STEPS] + ["r2", "cover1", "cover2", "s_per_window"]
    table = markdown_table(["source", "windows"] + [f"step {k}" for k in STEPS] + ["R²", "±1σ [%]", "±2σ [%]", "s/window"],
                           [[_coverage(r, h) if h.startswith("cover") else r[h] for h in headers] for r in rows],
                           floatfmt=".4g")
    paired = [r for r in rows if not np.isnan(r["below_ref1"])]
    if paired:
        table += (f"\n\nWindow by window against {args.paired}, at steps " + ", ".join(map(str, STEPS))
                  + f": the share of windows where the source's joint error is below {args.paired}'s [%], "
                  "and the median ratio of the two errors.\n\n")
        table += markdown_table(["source", "windows"] + [f"below at {k} [%]" for k in STEPS] + [f"ratio at {k}" for k in STEPS],
                                [[r["source"], r["windows"]] + [100 * r[f"below_ref{k}"] for k in STEPS]
                                 + [r[f"ratio_ref{k}"] for k in STEPS] for r in paired], floatfmt=".3g")
    print(table)
    if args.md:
        write_markdown(args.md, f"# The hybrid model's modes beside the baselines ({args.test}, {args.n} robots)\n\n"
                       "Joint RMS error [mrad] at steps 1, 15, 60, 300, 800 (step k is k dt after the last "
                       "context sample; random-offset windows have a shorter horizon), R² (approach 1), the "
                       "joints' ±1σ/±2σ coverage at the reported steps (sources with a std: the mean, and the "
                       "lowest and highest step in brackets), and the wall time per window on this machine "
                       "(identified physics: the mean of its fits and simulations; the model's sources: the median of "
                       f"{args.cost_repeats} passes of their predictions over the windows).\n\n"
                       + table + "\n", prov)
        print(f"written: {args.md}")
    if args.csv:
        write_rows(args.csv, rows, prov)
        print(f"written: {args.csv}")
    return 0


def _coverage(row: dict, key: str) -> str:
    """``mean [min-max]`` in percent of a coverage column, or empty for a source without a std."""
    if np.isnan(row[key]):
        return ""
    return f"{100 * row[key]:.1f} [{100 * row[key + '_min']:.0f}-{100 * row[key + '_max']:.0f}]"


if __name__ == "__main__":
    raise SystemExit(run_command(lambda: main()))
