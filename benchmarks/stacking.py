"""The context backtest's stack against the kinematic bars on every real arm's test windows (issue 62's goals).

For each public source (:mod:`robomorph.data.public_logs`, cloned under ``--data``), the same test windows as
``benchmarks/real_robots.py``: joint RMS error [mrad] of hold, constant velocity, constant acceleration and the stacked
prediction (:class:`robomorph.inference.stacking.StackedPredictor`, kinematic candidates: nothing fitted on the arm)
at step 1, 0.25 s, 1 s and 5 s where the horizon reaches them, the stack's ratio to the best kinematic bar at each
step, and the coverage of its std (the share of joint errors within one and two stds). Each goal of the issue gets a
verdict: zero-shot at most 1.05x the best kinematic at every reported step.

    python benchmarks/stacking.py --data DIR [--md results/benchmarks/stacking.md] [--robots ur5 ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

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


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="the folder holding the sources' clones")
    p.add_argument("--robots", nargs="+", default=list(public_logs.SOURCES), choices=list(public_logs.SOURCES))
    p.add_argument("--md", help="write the tables to this Markdown result file")
    p.add_argument("--work", help="where the test stores are written (default: a temporary folder)")
    return p.parse_args(argv)


def score(source, data: str, work: str) -> dict:
    stores = public_logs.write_stores(source, data, os.path.join(work, source.name), overwrite=True)
    test = open_store(stores["test"])
    w = load_window(stores["test"], source.context, source.horizon, None, None, len(test.u_names), len(test.y_names))
    c = w.context_len
    u, y = w.u.astype(np.float64), w.y.astype(np.float64)
    uc, yc, uq, yq = u[:, :c], y[:, :c], u[:, c:], y[:, c:]
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
    steps = [(1 if t is None else int(round(t / w.dt)), label) for t, label in TIMES]
    steps = [(k, label) for k, label in steps if k <= yq.shape[1]]
    preds = {name: fn(uc, yc, uq) for name, fn in KINEMATIC.items()}
    stack = StackedPredictor(None, w.dt, StackConfig())
    preds["stacked (kinematic)"], std = stack.simulate(uc, yc, uq, return_std=True)

    def rms(p, k):
        return 1000 * float(np.sqrt(np.mean((p[:, k - 1, joints] - yq[:, k - 1, joints]) ** 2)))

    rows = [[name] + [rms(p, k) for k, _ in steps] for name, p in preds.items()]
    best = [min(rms(preds[n], k) for n in KINEMATIC) for k, _ in steps]
    ratio = [rms(preds["stacked (kinematic)"], k) / b for (k, _), b in zip(steps, best)]
    rows.append(["stacked / best kinematic"] + ratio)
    z = np.abs(preds["stacked (kinematic)"][..., joints] - yq[..., joints]) / np.maximum(std[..., joints], 1e-300)
    rows.append(["stacked: share within 1 std"] + [float((z[:, k - 1] <= 1).mean()) for k, _ in steps])
    rows.append(["stacked: share within 2 std"] + [float((z[:, k - 1] <= 2).mean()) for k, _ in steps])
    return {"source": source, "steps": steps, "rows": rows, "windows": len(u), "dt": w.dt,
            "reach": stack.last_check.reach, "met": all(r <= 1.05 for r in ratio)}


def render(res: dict) -> str:
    s = res["source"]
    head = (f"## {s.robot}\n\n{res['windows']} test windows of {s.context} + {s.horizon} samples at "
            f"{1 / res['dt']:.6g} Hz; the backtest reaches {res['reach']} steps ({res['reach'] * res['dt']:.3g} s). "
            f"Goal (zero-shot, at most 1.05x the best kinematic at every step): "
            f"**{'met' if res['met'] else 'missed'}**.\n\n")
    return head + markdown_table(["joint RMS [mrad]"] + [label for _, label in res["steps"]], res["rows"],
                                 floatfmt=".3g")


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
            text = render(score(public_logs.get(name), args.data, args.work or tmp))
            print("\n" + text, flush=True)
            parts.append(text)
    if args.md:
        write_markdown(args.md, "# The context backtest's stack on real arms\n\n" + "\n\n".join(parts), provenance())
        print(f"\nwrote {args.md}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
