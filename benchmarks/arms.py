"""Kept rates per arm and task, and generation throughput per arm against the Panda, in one run.

For every registered arm (``robomorph.sim.arms``) and every task, generates a tiny store
with the shipped defaults (``--robots`` kept trajectories of ``--steps`` samples) and
records kept / attempted and the rejection reasons. The time per attempt of each arm's
open-loop (multi-sine) and OSC (circle) runs, divided by the Panda's measured in the same
process, is the throughput ratio (goal: within 20 % of the Panda, ratio >= 0.8).

    python benchmarks/arms.py [--robots 16] [--steps 1000] [--workers 2] [--out results/benchmarks/arms.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

from common import check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.names import TASKS
from robomorph.core.results import markdown_table, provenance, write_markdown
from robomorph.data.generation import GenerationError, generate
from robomorph.sim import arms
from robomorph.sim.recipe import load_recipe


def _run(robot: str, task: str, robots: int, steps: int, workers: int, tmp: str) -> dict:
    recipe = load_recipe(None, {"robot": robot, "task": task, "robots": robots, "steps": steps, "seed": 0})
    t0 = time.perf_counter()
    try:
        a = generate(recipe, os.path.join(tmp, f"{robot}_{task}.zarr"), workers=workers, overwrite=True, progress=False)
    except GenerationError as exc:
        return {"kept": 0, "attempted": 0, "rejected": {}, "seconds": time.perf_counter() - t0, "error": str(exc)}
    return {"kept": a["kept"], "attempted": a["attempted"], "rejected": {k: v for k, v in a["rejected"].items() if v},
            "seconds": time.perf_counter() - t0}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", type=int, default=16)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--robot", nargs="*", default=arms.names(), help="arms to run (the Panda is always run)")
    p.add_argument("--out", default=None, help="Markdown result file (default: print only)")
    args = p.parse_args()
    check_outputs(out__md=args.out)
    robots = ["panda"] + [r for r in args.robot if r != "panda"]
    prov = provenance()
    print_provenance()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        # Warm the compiled-model caches so the first arm does not pay for the imports.
        _run("panda", "multisine", 1, 10, args.workers, tmp)
        for robot in robots:
            for task in TASKS:
                r = results[robot, task] = _run(robot, task, args.robots, args.steps, args.workers, tmp)
                rate = r["kept"] / max(r["attempted"], 1)
                print(f"{robot:8s} {task:9s} kept {r['kept']}/{r['attempted']} ({rate:.0%}) {r['rejected']} "
                      f"{r['seconds']:.1f}s{' ' + r['error'][:80] if 'error' in r else ''}", flush=True)
    rows, ratios = [], {}
    for robot in robots:
        per = [results[robot, t] for t in TASKS]
        cells = [f"{r['kept'] / max(r['attempted'], 1):.0%} ({r['kept']}/{r['attempted']})" for r in per]
        speed = []
        for task in ("multisine", "circle"):
            mine, ref = results[robot, task], results["panda", task]
            ratio = (ref["seconds"] / max(ref["attempted"], 1)) / (mine["seconds"] / max(mine["attempted"], 1))
            ratios[robot, task] = ratio
            speed.append(round(ratio, 2))
        reasons = {}
        for r in per:
            for k, v in r["rejected"].items():
                reasons[k] = reasons.get(k, 0) + v
        arm = arms.get(robot)
        rows.append([robot, arm.n_joint, *cells, *speed, ", ".join(f"{k} {v}" for k, v in sorted(reasons.items()))])
    headers = ["robot", "joints", *[f"kept {t}" for t in TASKS], "throughput vs Panda (multisine)",
               "throughput vs Panda (circle)", "rejected (all tasks)"]
    table = markdown_table(headers, rows)
    print(table)
    if args.out:
        text = (f"# Arms: kept rates and generation throughput\n\n"
                f"{args.robots} kept robots of {args.steps} steps per arm and task, shipped defaults "
                f"(`true_model` gravity compensation, seed 0, {args.workers} workers). Kept: kept / attempted. "
                "Throughput: the Panda's seconds per attempt over the arm's, both measured in this run "
                "(> 1: faster than the Panda).\n\n" + table + "\n")
        write_markdown(args.out, text, prov)
        print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(run_command(main))
