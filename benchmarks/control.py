"""Closed-loop control of held-out robots: every controller on the same robots, with the issue's goals.

Runs ``robomorph control`` once per task (same seed, robots and references for every
controller) and writes one table per task with the goal checks of issue 22:

- MPC on the in-context model at least 30 % better (EE RMS) than MPC on the catalogue model,
  and within 25 % of MPC on the true model;
- MPC on the in-context model better than the catalogue OSC;
- re-planning within 50 ms per step (median) on 2 cores;
- no failed episode (contact, joint limit) of the model's that the true-model MPC avoids.

    python benchmarks/control.py --ckpt results/runs/demo/checkpoints/best.ckpt \
        [--robots 16] [--tasks circle,spiral] [--out results/benchmarks/control]
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from common import check_outputs, print_provenance

from robomorph.control.cli import main as control_main
from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows

CONTROLLERS = "osc,mpc:model,mpc:nominal_physics,mpc:identified_physics,mpc:true_physics"


def goals(m: dict) -> list[tuple[str, str, bool]]:
    """(goal, measured, met) of one task's metrics."""
    model, nominal, true, osc = (m.get(k, {}) for k in ("mpc:model", "mpc:nominal_physics", "mpc:true_physics", "osc"))
    rms = {k: v.get("ee_rms_mm") for k, v in (("model", model), ("nominal", nominal), ("true", true), ("osc", osc))}
    out = []
    if None not in (rms["model"], rms["nominal"]):
        gain = 1 - rms["model"] / rms["nominal"]
        out.append(("≥ 30 % below MPC on the catalogue model", f"{100 * gain:.0f} % below", gain >= 0.30))
    if None not in (rms["model"], rms["true"]):
        gap = rms["model"] / rms["true"] - 1
        out.append(("within 25 % of MPC on the true model", f"{100 * gap:+.0f} %", gap <= 0.25))
    if None not in (rms["model"], rms["osc"]):
        out.append(("below the catalogue OSC", f"{rms['model']:.2f} vs {rms['osc']:.2f} mm", rms["model"] < rms["osc"]))
    if model.get("replan_ms_median") is not None:
        ms = model["replan_ms_median"]
        out.append(("re-plan ≤ 50 ms (median)", f"{ms:.1f} ms (p95 {model['replan_ms_p95']:.1f})", ms <= 50))
    if model and true:
        extra = {f["robot"] for f in model["failures"]} - {f["robot"] for f in true["failures"]}
        out.append(("no failure the true-model MPC avoids", f"{len(extra)} such episodes", not extra))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True)
    p.add_argument("--robots", type=int, default=16)
    p.add_argument("--tasks", default="circle,spiral")
    p.add_argument("--controllers", default=CONTROLLERS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--out", default="results/benchmarks/control", help="prefix of the .md and .csv result files")
    p.add_argument("--work", default="results/control_bench", help="folder of each task's full control outputs")
    args, extra = p.parse_known_args()
    check_outputs(out__md=args.out + ".md", out__csv=args.out + ".csv", work=args.work)
    prov = provenance()
    print_provenance()
    rows, sections = [], []
    for task in args.tasks.split(","):
        out = os.path.join(args.work, task)
        code = control_main(["--ckpt", args.ckpt, "--task", task, "--robots", str(args.robots), "--controllers",
                             args.controllers, "--seed", str(args.seed), "--workers", str(args.workers), "--out", out,
                             *extra])
        if code:
            sys.exit(code)
        with open(os.path.join(out, "metrics.json")) as f:
            metrics = json.load(f)
        for name, m in metrics.items():
            if name.startswith("_"):
                continue
            rows.append({"task": task, "controller": name, "ee_rms_mm": m["ee_rms_mm"],
                         "ee_rms_mm_median_robot": m["ee_rms_mm_median_robot"], "ee_max_mm": m["ee_max_mm"],
                         "torque_rms_nm": m["torque_rms_nm"], "saturation_events": m["saturation_events"],
                         "failed_episodes": m["failed_episodes"], "episodes": m["episodes"],
                         "replan_ms_median": m["replan_ms_median"], "replan_ms_p95": m["replan_ms_p95"]})
        with open(os.path.join(out, "table.md")) as f:
            # Without the provenance line and the page title: this page has its own.
            table = "\n".join(line for line in f.read().split("\n", 2)[2].splitlines() if not line.startswith("# "))
        checks = markdown_table(["goal", "measured", "met"], [(g, v, "yes" if ok else "**no**") for g, v, ok in goals(metrics)])
        sections.append(f"## {task}\n\n{table.strip()}\n\nGoals (issue 22):\n\n{checks}\n")
    write_rows(args.out + ".csv", rows, prov)
    cfg = metrics["_config"]
    head = (f"# Closed-loop control of held-out robots\n\n{args.robots} robots per task, {cfg['uncertainty']} "
            f"uncertainty, warm-up {cfg['warmup']:.2f} s under the catalogue OSC, then {cfg['duration']:g} s of "
            f"tracking; MPPI with {cfg['mpc']['samples']} samples over {cfg['mpc']['horizon']} frames, re-planned "
            f"every {cfg['mpc']['replan']} frame(s); model `{args.ckpt}` "
            f"(physics mode {cfg['physics_mode'] or 'its default'}).\n")
    write_markdown(args.out + ".md", head + "\n" + "\n".join(sections), prov)
    print(f"wrote {args.out}.md and {args.out}.csv")


if __name__ == "__main__":
    sys.exit(run_command(main))
