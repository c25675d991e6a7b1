"""Cheaper physics for a planner's candidates: what coarser steps and a tangent-linear model cost in accuracy.

A model-predictive controller asks for the horizons of many candidate torque sequences on one
robot from one state (the issue's figure: 256 of 60 steps in 50 ms on 2 cores). Exactly, at the
recipe's physics step, that is 123,000 MuJoCo steps (~0.4 s here). This script measures the two
cheaper ways there are, against that exact answer, on held-out robots given their *true*
parameters (so identification is out of the picture), in the command formulation:

- **exact at a coarser step**: the same rollouts at 4, 2 or 1 physics steps per sample;
- **tangent-linear**: the candidates' mean simulated exactly, the one-frame map linearized about
  it by forward differences (all frames' perturbed one-frame rollouts in one threaded call, at 2
  physics steps per frame), every candidate the mean plus the linear response to its deviation
  (``dx[t+1] = A[t] dx[t] + B[t] du[t]``); once with the robot as it is, once with its joints'
  friction losses set to zero (against the exact frictionless candidates): dry friction is the
  one non-smooth term of the Panda's dynamics;
- **tangent-linear, dry friction corrected** (:mod:`robomorph.identification.tangent`, what
  ``Predictor.configure(candidates="tangent")`` simulates): the same, with the friction torque each
  candidate's linear response implies held inside the friction losses, and sliding joints whose
  velocity would cross zero stopped.

Candidates: the recorded query torques plus white noise of ``--sigma`` N m (a sampling
planner's perturbations). Printed and written: the joint RMS difference to the exact candidates
[mrad] at steps 1, 15 and 60, the candidates' own spread about their mean at step 60 (what a
planner ranks them by), and the milliseconds per call (256 candidates, this machine).

    python benchmarks/candidates.py --test data/demo/ms_heldout.zarr --n 4 \\
        --csv results/benchmarks/candidates.csv --md results/benchmarks/candidates.md
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import check_outputs, print_provenance

from robomorph.core.errors import UsageError, run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.data.store import open_store
from robomorph.identification.backbone import PhysicsBackbone, parameter_layout
from robomorph.identification.tangent import candidate_joints, one_frame_maps

STEPS = (1, 15, 60)


def tangent_joints(bb: PhysicsBackbone, params: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray,
                   torque: np.ndarray) -> np.ndarray:
    """(K, F + 1, n) joint positions of K candidates (K, F, n) on one robot, linearized about their mean
    (the maps of :func:`robomorph.identification.tangent.one_frame_maps` at every frame, no friction correction)."""
    k, frames, nj = torque.shape
    nx, ref = 2 * nj, torque.mean(axis=0)
    states = bb.frame_states(params[None], qpos0[None], qvel0[None], ref[None])[0]  # (F + 1, S): time, qpos, qvel
    (_, diff), = one_frame_maps(bb, [params], states, ref)  # (F, nx, nx + nj): [A | B]
    du, dx = torque - ref, np.zeros((k, nx))
    out = np.empty((k, frames + 1, nj))
    out[:, 0] = states[0, 1:1 + nj]
    for t in range(frames):
        dx = dx @ diff[t, :, :nx].T + du[:, t] @ diff[t, :, nx:].T
        out[:, t + 1] = states[t + 1, 1:1 + nj] + dx[:, :nj]
    return out


def exact(bb: PhysicsBackbone, params, qpos0, qvel0, torque, substeps: int | None) -> np.ndarray:
    k = len(torque)
    fine, coarse = bb.FINE_STEPS, bb.coarse
    if substeps is not None:
        bb.FINE_STEPS, bb.coarse = 0, substeps
    try:
        return bb.frame_states(np.repeat(params[None], k, 0), np.repeat(qpos0[None], k, 0),
                               np.repeat(qvel0[None], k, 0), torque)[..., 1:1 + qpos0.size]
    finally:
        bb.FINE_STEPS, bb.coarse = fine, coarse


def timed(fn) -> tuple[np.ndarray, float]:
    fn()  # warm-up
    t0 = time.perf_counter()
    out = fn()
    return out, 1e3 * (time.perf_counter() - t0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--test", required=True, help="held-out store (simulated, with params)")
    p.add_argument("--n", type=int, default=4, help="robots (one context each, from the start)")
    p.add_argument("--candidates", type=int, default=256)
    p.add_argument("--sigma", default="0.2,1.0", help="comma-separated noise levels [N m]")
    p.add_argument("--context", type=int, default=200)
    p.add_argument("--csv", default=None, help="every robot's row")
    p.add_argument("--md", default=None, help="the printed table, with its provenance")
    args = p.parse_args(argv)
    check_outputs(csv=args.csv, md=args.md)
    prov = provenance()  # of the code that runs: taken before this run rewrites its own (tracked) result files
    print_provenance()
    ds = open_store(args.test)
    c, h = args.context, 60
    u, y = ds.read_inputs("command")[:args.n].astype(np.float64), ds.read("y")[:args.n].astype(np.float64)
    params = ds.read("params")[:args.n].astype(np.float64)
    if y.shape[1] < c + h:
        raise UsageError(f"{args.test} holds {y.shape[1]} steps per trajectory, fewer than --context + 60")
    rows = []
    with PhysicsBackbone(parameter_layout(dict(ds.attrs)), "command") as bb:
        friction = [i for i, name in enumerate(bb.ident.randomizer.names) if name.startswith("frictionloss")]
        qvel_end = bb.context_velocity(params, y[:, :c, 7:], u[:, :c], np.zeros((len(u), 7)))
        for sigma in (float(s) for s in args.sigma.split(",")):
            for b in range(len(u)):
                rng = np.random.default_rng(b)
                torque = u[b, c - 1:c + h - 1][None] + rng.normal(0.0, sigma, (args.candidates, h, 7))
                start = (y[b, c - 1, 7:], qvel_end[b])
                frictionless = params[b].copy()
                frictionless[friction] = 0.0
                truth = {False: timed(lambda: exact(bb, params[b], *start, torque, None)),
                         True: timed(lambda: exact(bb, frictionless, *start, torque, None))}
                runs = [(f"exact, {ss} physics steps per sample", False,
                         lambda ss=ss: exact(bb, params[b], *start, torque, ss)) for ss in (4, 2, 1)]
                runs += [("tangent-linear", False, lambda: tangent_joints(bb, params[b], *start, torque)),
                         ("tangent-linear, dry friction corrected", False,
                          lambda: candidate_joints(bb, params[b], *start, torque)),
                         ("tangent-linear, no friction loss", True,
                          lambda: tangent_joints(bb, frictionless, *start, torque))]
                for name, nofric, fn in [("exact (reference)", False, None)] + runs:
                    ref, ref_ms = truth[nofric]
                    q, ms = (ref, ref_ms) if fn is None else timed(fn)
                    spread = 1e3 * float(np.sqrt(np.mean((ref[:, 60] - ref[:, 60].mean(0)) ** 2)))
                    row = {"sigma": sigma, "robot": b, "method": name}
                    row.update({f"step{k}": 1e3 * float(np.sqrt(np.mean((q[:, k] - ref[:, k]) ** 2))) for k in STEPS})
                    row.update({"spread60": spread, "ms": ms})
                    rows.append(row)
    summary = []
    for sigma in sorted({r["sigma"] for r in rows}):
        for name in dict.fromkeys(r["method"] for r in rows):
            sel = [r for r in rows if r["sigma"] == sigma and r["method"] == name]
            summary.append([sigma, name] + [float(np.mean([r[f"step{k}"] for r in sel])) for k in STEPS]
                           + [float(np.mean([r["spread60"] for r in sel])), float(np.median([r["ms"] for r in sel]))])
    table = markdown_table(["sigma [N m]", "method"] + [f"step {k} [mrad]" for k in STEPS]
                           + ["spread at 60 [mrad]", "ms (median)"], summary, floatfmt=".3g")
    print(table)
    if args.md:
        write_markdown(args.md, f"# Cheaper physics for {args.candidates} candidates of 60 steps ({args.test}, "
                       f"{args.n} robots)\n\nJoint RMS difference to the exact candidates (the recipe's physics step) "
                       "[mrad], mean over the robots; the candidates' spread about their mean at step 60; the "
                       "milliseconds per call, median over the robots.\n\n" + table + "\n", prov)
        print(f"written: {args.md}")
    if args.csv:
        write_rows(args.csv, rows, prov)
        print(f"written: {args.csv}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_command(lambda: main()))
