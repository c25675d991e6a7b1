"""The context backtest's stacks against the kinematic bars on every real arm's test windows, with issue 62's goals.

For each public source (:mod:`robomorph.data.public_logs`, cloned under ``--data``), the same test windows as
``benchmarks/real_robots.py`` (which prints these rows too): joint RMS error [mrad] at step 1, 0.25 s, 1 s and 5 s
where the horizon reaches them, and FIT [%] over the horizon, of

- the kinematic bars (hold, constant velocity, constant acceleration), the per-context ``arx`` and ``accel_arx``, the
  hybrid with no training (``Predictor.from_arm``, on the commands of an arm compensating its gravity with its catalogue
  model, where the arm has an MJCF), and ``arx_train``/``accel_arx_train`` fitted on the arm's training recordings;
- three stacks (:class:`robomorph.inference.stacking.StackedPredictor`): ``stacked (kinematic)``, the kinematic
  candidates alone; ``stacked (zero-shot)``, with the per-context ARX models and the hybrid (nothing fitted on the
  arm's other recordings); ``stacked (training recordings)``, with the trained ARX models too and its prior weights
  learned on the training recordings' windows (:meth:`StackedPredictor.learn`);
- each stack's ratio to the best kinematic bar at each step, and its std's coverage (the share of joint errors
  within one and two stds).

Then each goal's verdict, met or missed, per arm.

    python benchmarks/stacking.py --data DIR [--md results/benchmarks/stacking.md] [--robots ur5 ...] [--no-hybrid]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np
from common import print_provenance

from robomorph.core.atomic import check_not_input, check_replaceable
from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown
from robomorph.data import public_logs
from robomorph.data.store import open_store
from robomorph.evaluation.windows import load_window
from robomorph.inference.kinematics import KINEMATIC
from robomorph.inference.stacking import StackConfig, StackedPredictor

TIMES = ((None, "step 1"), (0.25, "0.25 s"), (1.0, "1 s"), (5.0, "5 s"))
STACKS = ("stacked (kinematic)", "stacked (zero-shot)", "stacked (training recordings)")
# Training windows the learned prior reads (a few hundred pool plenty of evidence; more cost only time).
LEARN_WINDOWS = 256


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="the folder holding the sources' clones")
    p.add_argument("--robots", nargs="+", default=list(public_logs.SOURCES), choices=list(public_logs.SOURCES))
    p.add_argument("--md", help="write the tables to this Markdown result file")
    p.add_argument("--work", help="where the stores are written (default: a temporary folder)")
    p.add_argument("--no-hybrid", action="store_true", help="leave the hybrid out (it costs most of the time)")
    return p.parse_args(argv)


def commands(arm: str, u: np.ndarray, y: np.ndarray, dt: float) -> np.ndarray:
    """The command an arm compensating its gravity with its catalogue model is sent: the logged torque less g(q)."""
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.sim.episode import NominalGravity  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    n = arms.get(arm).n_joint
    gravity = NominalGravity(load_recipe("multisine", {"robot": arm, "dt": dt}))
    return u - np.stack([[gravity(q) for q in rows[:, 7:7 + n]] for rows in np.asarray(y, dtype=np.float64)])


def stacked_predictions(arm: str | None, w, train_store: str | None, hybrid: bool = True) -> tuple[dict, dict]:
    """The candidates' and the three stacks' predictions on the windows ``w`` (``{name: mean}``), and the stacks'
    stds (``{name: std}``). Where the arm has an MJCF (and ``hybrid``), every candidate reads the commands of an arm
    compensating its gravity with its catalogue model, as the hybrid does; else the logged torques."""
    from robomorph.evaluation.baselines import ARX, AccelARX  # noqa: PLC0415
    from robomorph.evaluation import references  # noqa: PLC0415
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    u, y = w.u.astype(np.float64), w.y.astype(np.float64)
    with_hybrid = bool(arm) and hybrid
    if with_hybrid:
        u = commands(arm, u, y, w.dt)
    c = w.context_len
    uc, yc, uq = u[:, :c], y[:, :c], u[:, c:]
    per_context = {"arx": (ARX(2, 2), 8), "accel_arx": (AccelARX(), 8)}
    zero_shot = dict(per_context)
    if with_hybrid:
        nominal = Predictor.from_arm(arm, "multisine", dt=w.dt, gravity_compensation="nominal_model")
        zero_shot["hybrid (nominal commands)"] = (nominal.simulate, 1)
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]  # what the weights are decided on
    stacks = {"stacked (kinematic)": StackedPredictor(None, w.dt, StackConfig(), decide_on=joints),
              "stacked (zero-shot)": StackedPredictor(zero_shot, w.dt, StackConfig(), decide_on=joints)}
    if train_store:
        train = open_store(train_store)
        tw = load_window(train_store, c, w.horizon, LEARN_WINDOWS, None, len(train.u_names), len(train.y_names))
        tu, ty = tw.u.astype(np.float64), tw.y.astype(np.float64)
        if with_hybrid:
            tu = commands(arm, tu, ty, w.dt)

        def blocks():
            for s in range(0, train.n, 256):
                rows = slice(s, s + 256)
                bu, by = train.read("u", rows), train.read("y", rows)
                yield (commands(arm, bu, by, w.dt) if with_hybrid else bu), by

        trained = {"arx_train": (references.fit_arx_train((2, 2), blocks), 8),
                   "accel_arx_train": (references.fit_accel_arx_train(blocks), 8)}
        learner = {**per_context, **trained}  # the hybrid is left out of the learned prior: its windows cost most
        stack = StackedPredictor({**zero_shot, **trained}, w.dt, StackConfig(), decide_on=joints)
        stack.learn(tu, ty, c) if not with_hybrid else stack.learn(tu, ty, c, models=learner)
        stacks["stacked (training recordings)"] = stack
    preds = {name: fn(uc, yc, uq) for name, fn in KINEMATIC.items()}
    for name, (fn, _) in {**zero_shot, **(trained if train_store else {})}.items():
        preds[name] = np.asarray(fn(uc, yc, uq), dtype=np.float64)
    stds = {}
    for name, stack in stacks.items():
        preds[name], stds[name] = stack.simulate(uc, yc, uq, return_std=True)
    return preds, stds


def _fit(pred: np.ndarray, truth: np.ndarray) -> float:
    """FIT [%] over the horizon: each joint over all windows, then the joints' mean."""
    err = np.sqrt(((pred - truth) ** 2).mean(axis=(0, 1)))
    spread = np.sqrt(((truth - truth.mean(axis=(0, 1))) ** 2).mean(axis=(0, 1)))
    return float(np.mean(100 * (1 - err / np.maximum(spread, 1e-12))))


def score(source, data: str, work: str, hybrid: bool = True) -> dict:
    stores = public_logs.write_stores(source, data, os.path.join(work, source.name), overwrite=True)
    test = open_store(stores["test"])
    w = load_window(stores["test"], source.context, source.horizon, None, None, len(test.u_names), len(test.y_names))
    start = time.perf_counter()
    preds, stds = stacked_predictions(source.arm, w, stores.get("train"), hybrid)
    seconds = time.perf_counter() - start
    return summarize(source, w, preds, stds) | {"seconds": seconds}


def summarize(source, w, preds: dict, stds: dict) -> dict:
    """The table's rows and each goal's verdict for one arm."""
    c = w.context_len
    yq = w.y[:, c:].astype(np.float64)
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
    steps = [(1 if t is None else int(round(t / w.dt)), label) for t, label in TIMES]
    steps = [(k, label) for k, label in steps if k <= yq.shape[1]]

    def rms(p, k):
        return 1000 * float(np.sqrt(np.mean((p[:, k - 1, joints] - yq[:, k - 1, joints]) ** 2)))

    fits = {name: _fit(p[..., joints], yq[..., joints]) for name, p in preds.items()}
    rows = [[name] + [rms(p, k) for k, _ in steps] + [fits[name]] for name, p in preds.items()]
    best = [min(rms(preds[n], k) for n in KINEMATIC) for k, _ in steps]
    best_fit = max(fits[n] for n in KINEMATIC)
    ratios, coverage = {}, {}
    for name in stds:
        ratios[name] = [rms(preds[name], k) / b for (k, _), b in zip(steps, best)]
        rows.append([f"{name} / best kinematic"] + ratios[name] + [None])
        z = np.abs(preds[name][..., joints] - yq[..., joints]) / np.maximum(stds[name][..., joints], 1e-300)
        coverage[name] = [(float((z[:, k - 1] <= 1).mean()), float((z[:, k - 1] <= 2).mean())) for k, _ in steps]
        rows.append([f"{name}: within 1 std / 2 std"] + [f"{a:.0%} / {b:.0%}" for a, b in coverage[name]] + [None])
    labels = [label for _, label in steps]
    verdicts = goal_verdicts(labels, ratios, coverage, fits, best_fit)
    return {"source": source, "steps": steps, "rows": rows, "windows": len(w.u), "dt": w.dt, "verdicts": verdicts,
            "ratios": ratios, "coverage": coverage}


def goal_verdicts(labels: list[str], ratios: dict, coverage: dict, fits: dict, best_fit: float) -> list[str]:
    """Issue 62's goals on one arm, each met or missed with its figures."""
    out = []

    def verdict(ok: bool) -> str:
        return "**met**" if ok else "**missed**"

    zs = ratios.get("stacked (zero-shot)")
    if zs:
        out.append(f"zero-shot at most 1.05x the best kinematic at every step: {verdict(max(zs) <= 1.05)} "
                   f"({', '.join(f'{lab} {r:.2f}' for lab, r in zip(labels, zs))})")
        if "0.25 s" in labels:
            r = zs[labels.index("0.25 s")]
            out.append(f"zero-shot at most 0.75x at 0.25 s (asked on three of four arms): {verdict(r <= 0.75)} ({r:.2f})")
    tr = ratios.get("stacked (training recordings)")
    if tr:
        picked = [(lab, tr[labels.index(lab)]) for lab in ("0.25 s", "1 s") if lab in labels]
        ok = all(r <= 0.5 for _, r in picked) and fits["stacked (training recordings)"] > best_fit
        out.append(f"with the training recordings at most 0.5x at 0.25 s and 1 s, FIT above the best kinematic's: "
                   f"{verdict(ok)} ({', '.join(f'{lab} {r:.2f}' for lab, r in picked)}; FIT "
                   f"{fits['stacked (training recordings)']:.1f} against {best_fit:.1f})")
    for name, cov in coverage.items():
        ok = all(0.58 <= a <= 0.78 and 0.90 <= b <= 1.0 for a, b in cov)
        out.append(f"{name} std: within 1 std 68 ± 10 %, within 2 std 95 ± 5 % at every step: {verdict(ok)}")
    return out


def render(res: dict) -> str:
    s = res["source"]
    head = (f"## {s.robot}\n\n{res['windows']} test windows of {s.context} + {s.horizon} samples at "
            f"{1 / res['dt']:.6g} Hz ({res.get('seconds', 0):.0f} s for every candidate and stack).\n\n")
    table = markdown_table(["joint RMS [mrad]"] + [label for _, label in res["steps"]] + ["FIT [%]"], res["rows"],
                           floatfmt=".3g")
    return head + table + "\n\nGoals:\n\n" + "\n".join(f"- {v}" for v in res["verdicts"])


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.md:  # refused before any store is written
        check_replaceable(args.md, "markdown", "--md")
        check_not_input(args.md, [args.data], "--md")
    print_provenance()
    parts = []
    with tempfile.TemporaryDirectory(prefix="stacking_") as tmp:
        for name in args.robots:
            print(f"{name}: ingesting and scoring ...", file=sys.stderr, flush=True)
            text = render(score(public_logs.get(name), args.data, args.work or tmp, not args.no_hybrid))
            print("\n" + text, flush=True)
            parts.append(text)
    if args.md:
        write_markdown(args.md, "# The context backtest's stacks on real arms\n\n" + "\n\n".join(parts), provenance())
        print(f"\nwrote {args.md}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
