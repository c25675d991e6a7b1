"""What each kind of physical parameter costs a prediction when it is held at the catalogue's value.

Each held-out robot is simulated with its *true* parameters (``true_physics``, the ceiling), then
again with one kind of parameter set back to the catalogue's (the middle of its randomization
range; the springs still anchored where the robot started), from the same estimated state and
under the same torques. The joint RMS error over the windows at the reported steps says how much
of a prediction's error a kind can account for if the identification leaves it at the catalogue,
and so which kinds an identification must fit (or its std cover). In the command formulation the
springs (0.01-0.05 N m/rad), which no fit identified, cost more at 13.3 s than the link masses, the
centres of mass or the armature: why the regression fits them (:data:`robomorph.identification.identify.SPRING_KINDS`).

    python benchmarks/nuisance.py --data data/demo/ms_test256.zarr --n 64 --md results/benchmarks/nuisance.md
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from common import check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.data.store import open_store
from robomorph.evaluation.physics import NominalPhysics
from robomorph.evaluation.sources import _batched
from robomorph.evaluation.windows import load_window, start_joints
from robomorph.sim.randomize import param_names

STEPS = (1, 15, 60, 300, 800)
KINDS = ("mass_", "com_", "damping_", "stiffness_", "armature_", "frictionloss_")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, help="held-out store (windows from the start)")
    p.add_argument("--n", type=int, default=64)
    p.add_argument("--inputs", default="command", choices=("command", "total"))
    p.add_argument("--context-len", type=int, default=200)
    p.add_argument("--horizon", type=int, default=800)
    p.add_argument("--md", default="results/benchmarks/nuisance.md")
    a = p.parse_args(argv)
    check_outputs(md=a.md)
    prov = provenance()
    print_provenance()
    ds = open_store(a.data)
    w = load_window(a.data, a.context_len, a.horizon, a.n, None, len(ds.input_names(a.inputs)), len(ds.y_names),
                    "start", 0, a.inputs)
    sim = NominalPhysics(w.attrs, inputs=a.inputs)
    u_ctx, y_ctx, u_q, y_q = w.split()
    joints = [i for i, name in enumerate(w.y_names) if name.startswith("q")]
    true = np.asarray(w.params, dtype=np.float64)
    start = start_joints(w, sim.n_joint)  # None: each window opens its trajectory
    catalogue = np.stack([sim.params(q0) for q0 in (y_ctx[:, 0, joints] if start is None else start)])
    names = param_names()
    steps = [s for s in STEPS if s <= w.horizon]
    rows = []
    for kind in ("none", *KINDS):
        params = true.copy()
        cols = [i for i, name in enumerate(names) if name.startswith(kind)]
        params[:, cols] = catalogue[:, cols]
        err = (_batched(sim, u_ctx, y_ctx, u_q, kind, params=params) - y_q)[..., joints] * 1e3
        rms = [float(np.sqrt(np.mean(err[:, s - 1] ** 2))) for s in steps]
        rows.append({"at_catalogue": kind.rstrip("_"), **{f"step_{s}": round(v, 4) for s, v in zip(steps, rms)}})
        print(rows[-1], file=sys.stderr, flush=True)
    csv = a.md.rsplit(".", 1)[0] + ".csv"
    write_rows(csv, rows, prov)
    table = markdown_table(["the true robot but", *(f"step {s} ({s * w.dt:.3g} s)" for s in steps)],
                           [["nothing (true physics)" if r["at_catalogue"] == "none" else f"`{r['at_catalogue']}` at "
                             "the catalogue's", *(r[f"step_{s}"] for s in steps)] for r in rows])
    text = (f"# What each parameter kind costs when held at the catalogue's ({a.data}, {len(w.u)} robots, "
            f"{a.inputs} formulation)\n\nJoint RMS error [mrad] over windows from the start (context {w.context_len}), "
            "each robot simulated with its true parameters but one kind set to the catalogue's value, from the "
            "same estimated state and under the same torques.\n\n" + table)
    write_markdown(a.md, text, prov)
    print(table)


if __name__ == "__main__":
    sys.exit(run_command(main))
