"""The hybrid's physics step: what a coarser step after the first second costs in accuracy.

Held-out robots are simulated by :class:`robomorph.identification.backbone.PhysicsBackbone` with their
*true* parameters (so the identification's error is out of the picture) over the context and
the horizon, in the command formulation, from the trajectory start; the generator recorded them
at the recipe's step, so any difference is the step's. Settings: the recipe's step throughout,
a coarser one throughout (the context's simulation included), and the default schedule (the
context and the first second at the recipe's step, then ``coarse_substeps``). Printed and
written: joint RMS error [mrad] against the recorded robot at steps 1, 15, 60, 300, 800, and
the wall time per window (threaded rollouts over all windows at once, this machine).

    python benchmarks/horizon_step.py --test data/demo/ms_heldout.zarr --n 32 \\
        --csv results/benchmarks/horizon_step.csv
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from common import check_outputs, print_provenance

from robomorph.core.errors import UsageError, run_command
from robomorph.core.results import markdown_table, provenance, write_rows
from robomorph.data.store import open_store
from robomorph.identification.backbone import PhysicsBackbone, parameter_layout

STEPS = (1, 15, 60, 300, 800)


def settings(recipe_substeps: int, coarse: int) -> list[tuple[str, int, int | None, int]]:
    """(name, the backbone's recipe substeps, its coarse substeps, its FINE_STEPS) per setting."""
    return [(f"{recipe_substeps} throughout (the generator's)", recipe_substeps, recipe_substeps, 0),
            (f"{coarse} throughout", coarse, coarse, 0),
            (f"{recipe_substeps} for the context and the first second, then {coarse} (default)",
             recipe_substeps, None, PhysicsBackbone.FINE_STEPS),
            (f"{coarse // 2} throughout", coarse // 2, coarse // 2, 0)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--test", required=True, help="held-out store (simulated, with params)")
    p.add_argument("--n", type=int, default=32, help="robots (one window each, from the start)")
    p.add_argument("--context", type=int, default=200)
    p.add_argument("--horizon", type=int, default=800)
    p.add_argument("--csv", default=None)
    args = p.parse_args(argv)
    check_outputs(csv=args.csv)
    print_provenance()
    ds = open_store(args.test)
    c, h = args.context, args.horizon
    u, y = ds.read_inputs("command")[:args.n].astype(np.float64), ds.read("y")[:args.n].astype(np.float64)
    params = ds.read("params")[:args.n].astype(np.float64)
    if y.shape[1] < c + h:
        raise UsageError(f"{args.test} holds {y.shape[1]} steps per trajectory, fewer than --context + --horizon")
    layout = parameter_layout(dict(ds.attrs))
    with PhysicsBackbone(layout, "command") as probe:
        coarse = probe.coarse
    rows = []
    for name, recipe_substeps, setting, fine in settings(int(layout["recipe"]["substeps"]), coarse):
        lay = copy.deepcopy(layout)
        lay["recipe"]["substeps"] = recipe_substeps
        with PhysicsBackbone(lay, "command", substeps=setting) as bb:
            bb.FINE_STEPS = fine
            t0 = time.perf_counter()
            pred = bb.simulate(params, y[:, :c, 7:], u[:, :c], u[:, c:c + h], np.zeros((len(u), 7)), y[:, c - 1, 3:7])
            seconds = (time.perf_counter() - t0) / len(u)
        err = pred[..., 7:] - y[:, c:c + h, 7:]
        row = {"setting": name, "physics_steps": c * recipe_substeps + fine * recipe_substeps
               + (h - fine) * (bb.coarse if fine else recipe_substeps)}
        row.update({f"step{k}": 1e3 * float(np.sqrt(np.mean(err[:, k - 1] ** 2))) for k in STEPS if k <= h})
        row["ms_per_window"] = 1e3 * seconds
        rows.append(row)
    headers = list(rows[0])
    print(markdown_table(headers, [[r[k] for k in headers] for r in rows], floatfmt=".4g"))
    if args.csv:
        write_rows(args.csv, rows, provenance())
        print(f"written: {args.csv}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_command(lambda: main()))
