"""The hybrid within one frame (issue 65): its latency before and after, in one run, on the same machine.

Times ``Predictor.from_arm(ARM, RECIPE)`` (default: the Panda, the realistic recipe: the demo's held-out robots)
on windows of a store (context 200 from each trajectory's start):

- one trajectory, 60 steps (1 s), default settings and ``members=1``: the median of ``--repeats`` calls per
  robot (after one untimed call), its range over the robots;
- a batch of ``--batch`` windows x 800 steps, default settings and ``members=1``: seconds per window;
- a rolling context (after only): :class:`robomorph.inference.rolling.RollingHybrid`, identified every
  ``--reidentify`` calls, one call per frame over ``--frames`` frames from frame 200: median and p95 per call, and
  the joint RMS at 1 s against the recorded motion beside a fresh identification at the same frames;
- a model-predictive controller's re-plan (``robomorph control``'s MPPI: the planner's rollout of 128 candidates x
  20 frames at 2 physics steps, one robot) and the hybrid planner's identification it runs every ``--reidentify``
  frames;
- where the time goes: cProfile's largest own times over the single-trajectory calls of the code after.

"Before" and "after" are two commits of this repository (``--before``, default the landed main the issue was
measured on; ``--after``, default HEAD), each unpacked with ``git archive`` into a temporary folder and timed in its
own process, in alternating rounds (``--rounds``) so that the machine's load falls on both alike; the figures are
the medians over rounds, the ratio is before / after, and the load average is printed with each round.

    python benchmarks/realtime.py --data /tmp/heldout.zarr [--robots 8] [--repeats 3] [--batch 8] [--rounds 2]
        [--before e9f8f46] [--after HEAD] [--out results/benchmarks/realtime.md]

``--after .`` times the working tree as it is.

The store: ``robomorph generate --config realistic --robots 16 --seed 1 --out heldout.zarr`` (the demo's held-out
robots). Bad arguments: one line, exit code 2, nothing written.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

CONTEXT, SHORT, LONG = 200, 60, 800
BEFORE = "e9f8f46"  # the landed main of issue 65's measurements


def _arrays(path: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    from robomorph.data.store import open_store  # noqa: PLC0415

    ds = open_store(path)
    n = min(n, ds.n)
    u = np.asarray(ds.group["u_cmd"][:n], dtype=np.float32)
    y = np.asarray(ds.group["y"][:n], dtype=np.float32)
    return u, y


def _single(pred, u, y, repeats: int) -> list[list[float]]:
    """Per robot, the median wall and CPU seconds (all threads) of one window's prediction (1 s horizon)."""
    out = []
    for i in range(len(u)):
        args = (u[i, :CONTEXT], y[i, :CONTEXT], u[i, CONTEXT:CONTEXT + SHORT])
        pred.simulate(*args, at_rest=True)
        times = []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            pred.simulate(*args, at_rest=True)
            times.append((time.perf_counter() - t0, time.process_time() - c0))
        out.append(np.median(times, axis=0).tolist())
    return out


def _batch(pred, u, y, n: int) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds per window of one batch of ``n`` windows x 800 steps, and its joint RMS [mrad] at 1 and
    13.3 s."""
    pred.simulate(u[:2, :CONTEXT], y[:2, :CONTEXT], u[:2, CONTEXT:CONTEXT + 5], at_rest=True)
    t0, c0 = time.perf_counter(), time.process_time()
    got = pred.simulate(u[:n, :CONTEXT], y[:n, :CONTEXT], u[:n, CONTEXT:CONTEXT + LONG], at_rest=True)
    seconds = [(time.perf_counter() - t0) / n, (time.process_time() - c0) / n]
    # The last query step's output lies past a 1000-step trajectory's end: scored at steps 60 and 799 (13.3 s).
    truth = y[:n, CONTEXT + 1:CONTEXT + LONG + 1, 7:]
    err = np.asarray(got, dtype=np.float64)[:, :truth.shape[1], 7:] - truth
    return seconds, [1e3 * float(np.sqrt(np.mean(err[:, k - 1] ** 2))) for k in (SHORT, truth.shape[1])]


def _rolling(pred, u, y, frames: int, reidentify: int) -> dict:
    """Per-call seconds of a rolling context, and the joint RMS [mrad] at 1 s of it and of fresh identifications."""
    from robomorph.inference.rolling import RollingHybrid  # noqa: PLC0415

    times, cpu, errs, fresh = [], [], [], []
    for i in range(len(u)):
        roll = RollingHybrid(pred, reidentify=reidentify)
        for f in range(CONTEXT, CONTEXT + frames):
            args = (u[i, f - CONTEXT:f], y[i, f - CONTEXT:f], u[i, f:f + SHORT])
            t0, c0 = time.perf_counter(), time.process_time()
            got = roll.predict(*args)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            if (f - CONTEXT) % reidentify == reidentify // 2:  # half-way between identifications
                truth = y[i, f + SHORT, 7:]
                errs.append(1e3 * float(np.sqrt(np.mean((got[-1, 7:] - truth) ** 2))))
                ref = np.asarray(pred.simulate(*args), dtype=np.float64)
                fresh.append(1e3 * float(np.sqrt(np.mean((ref[-1, 7:] - truth) ** 2))))
    return {"median": float(np.median(times)), "p95": float(np.percentile(times, 95)),
            "cpu_median": float(np.median(cpu)), "cpu_p95": float(np.percentile(cpu, 95)),
            "rms_rolling": float(np.sqrt(np.mean(np.square(errs)))),
            "rms_fresh": float(np.sqrt(np.mean(np.square(fresh)))), "probes": len(errs)}


def _planner(pred, u, y, arm: str, repeats: int = 20) -> dict:
    """A model-predictive controller's work (``robomorph control``'s MPPI: 128 candidates x 20 frames at 2 physics
    steps each, on one robot): the planner's rollout of the candidates per re-plan (wall, CPU: median and p95), and
    the hybrid planner's identification from a 200-frame context, which it runs every ``--reidentify`` frames."""
    import torch  # noqa: PLC0415

    from robomorph.control import dynamics as dyn  # noqa: PLC0415
    from robomorph.sim.recipe import Recipe  # noqa: PLC0415

    recipe = Recipe(robot=arm)
    planner = dyn.CataloguePlanner("mpc", recipe.randomization, recipe.dt, 2, robot=arm)
    nj = u.shape[2]
    m = dyn.Measured(CONTEXT + 1, nj, y[0, 0, 7:])
    m.frame, m.qpos[:] = CONTEXT, y[0, CONTEXT, 7:]
    planner.observe(m, True)
    plans = np.random.default_rng(0).normal(0.0, 0.5, (128, 20, nj))
    times = []
    for _ in range(repeats + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        planner.predict(plans)
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    times = np.asarray(times[1:])
    planner.close()
    ident = []
    for i in range(len(u)):
        args = [torch.as_tensor(a[None, :CONTEXT]) for a in (u[i], y[i])]
        t0, c0 = time.perf_counter(), time.process_time()
        pred.hybrid().identify(*args, pred.settings.mode, at_rest=True)
        ident.append((time.perf_counter() - t0, time.process_time() - c0))
    return {"replan": np.median(times, axis=0).tolist(), "replan_p95": np.percentile(times, 95, axis=0).tolist(),
            "identify": np.median(ident, axis=0).tolist()}


def _profile(pred, u, y) -> str:
    """cProfile's largest own times over the single-trajectory calls (what a flame graph's widest frames show)."""
    import cProfile  # noqa: PLC0415
    import io  # noqa: PLC0415
    import pstats  # noqa: PLC0415

    prof = cProfile.Profile()
    prof.enable()
    for i in range(len(u)):
        pred.simulate(u[i, :CONTEXT], y[i, :CONTEXT], u[i, CONTEXT:CONTEXT + SHORT], at_rest=True)
    prof.disable()
    text = io.StringIO()
    pstats.Stats(prof, stream=text).sort_stats("tottime").print_stats(14)
    lines = [ln for ln in text.getvalue().splitlines() if ln.strip()]
    total = next(ln.strip() for ln in lines if "function calls" in ln)
    start = next(k for k, ln in enumerate(lines) if ln.lstrip().startswith("ncalls"))
    return "\n".join([total] + lines[start:])


def measure(args) -> dict:
    """Every figure of one commit's code (the package on ``sys.path``), as a JSON-able dict."""
    import torch  # noqa: PLC0415

    from robomorph.predictor import Predictor  # noqa: PLC0415

    torch.set_num_threads(2)
    u, y = _arrays(args.data, max(args.robots, args.batch))
    pred = Predictor.from_arm(args.arm, args.recipe)
    out = {"load": os.getloadavg()[0]}
    ur, yr = u[:args.robots], y[:args.robots]
    out["single"] = _single(pred, ur, yr, args.repeats)
    out["batch"] = _batch(pred, u, y, args.batch)
    pred.configure(members=1)
    out["single_m1"] = _single(pred, ur, yr, args.repeats)
    out["batch_m1"] = _batch(pred, u, y, args.batch)
    pred.configure(members=Predictor.from_arm(args.arm, args.recipe).settings.members)
    out["planner"] = _planner(pred, ur, yr, args.arm)
    try:
        import robomorph.inference.rolling  # noqa: F401, PLC0415
    except ImportError:
        out["rolling"] = None
    else:
        out["rolling"] = _rolling(pred, u[:args.roll_robots], y[:args.roll_robots], args.frames, args.reidentify)
        out["profile"] = _profile(pred, ur, yr)
    out["load_end"] = os.getloadavg()[0]
    return out


def _tree(ref: str, root: str, into: str) -> str:
    """The package and recipes of commit ``ref`` unpacked into ``into`` (returns it); ``.``: the working tree."""
    if ref == ".":
        return root
    archive = subprocess.run(["git", "-C", root, "archive", ref, "robomorph", "datamodules"], capture_output=True)
    if archive.returncode:  # checked in main: a commit that exists archives
        raise RuntimeError(f"git archive {ref}: {archive.stderr.decode().strip()}")
    subprocess.run(["tar", "-x", "-C", into], input=archive.stdout, check=True)
    return into


def _run(tree: str, argv: list[str]) -> dict:
    with tempfile.NamedTemporaryFile(suffix=".json") as f:
        env = dict(os.environ, PYTHONPATH=tree)
        subprocess.run([sys.executable, os.path.abspath(__file__), *argv, "--measure", f.name], cwd=tree, env=env,
                       check=True)
        with open(f.name) as g:
            return json.load(g)


def _ms(x: float) -> str:
    return f"{1e3 * x:.1f} ms"


def table(before: list[dict], after: list[dict], args) -> str:
    """The issue's table: before, after, ratio (medians over rounds); wall time, and CPU time of all threads (less
    moved by other processes on a shared machine)."""
    def med(runs, key):
        return np.median(np.asarray([r[key] for r in runs], dtype=np.float64), axis=0)

    rows = []
    for key, what in (("single", "one trajectory, context 200, 60 steps, default settings"),
                      ("single_m1", "the same, `members=1`")):
        b, a = med(before, key), med(after, key)  # (robots, wall / cpu)
        for col, kind in ((0, "wall"), (1, "CPU")):
            r = b[:, col] / a[:, col]
            rows.append([f"{what}: {kind}", f"{_ms(b[:, col].min())} to {_ms(b[:, col].max())}",
                         f"{_ms(a[:, col].min())} to {_ms(a[:, col].max())}",
                         f"{np.median(r):.2f}x (robots {r.min():.2f} to {r.max():.2f})"])
    for key, what in (("batch", f"batch of {args.batch} windows x 800 steps, default"),
                      ("batch_m1", "the same, `members=1`")):
        b = np.median([r[key][0] for r in before], axis=0)
        a = np.median([r[key][0] for r in after], axis=0)
        rows.append([f"{what}: wall / CPU per window", f"{b[0]:.3f} / {b[1]:.3f} s", f"{a[0]:.3f} / {a[1]:.3f} s",
                     f"{b[0] / a[0]:.2f}x / {b[1] / a[1]:.2f}x"])
        eb, ea = before[-1][key][1], after[-1][key][1]
        rows.append(["its joint RMS at 1 / 13.3 s [mrad] (steps 60 / 799)", f"{eb[0]:.3f} / {eb[1]:.3f}",
                     f"{ea[0]:.3f} / {ea[1]:.3f}", ""])
    if all("planner" in r for r in before + after):
        for key, what in (("replan", "MPC re-plan's rollout: 128 candidates x 20 frames x 2 steps, median"),
                          ("replan_p95", "the same, p95"),
                          ("identify", "the hybrid planner's identification (every `--reidentify` frames), median")):
            b = np.median([r["planner"][key] for r in before], axis=0)
            a = np.median([r["planner"][key] for r in after], axis=0)
            rows.append([f"{what}: wall / CPU", f"{_ms(b[0])} / {_ms(b[1])}", f"{_ms(a[0])} / {_ms(a[1])}",
                         f"{b[0] / a[0]:.2f}x / {b[1] / a[1]:.2f}x"])
    roll = [r["rolling"] for r in after if r.get("rolling")]
    if roll:
        get = lambda k: float(np.median([r[k] for r in roll]))  # noqa: E731
        rows.append([f"rolling context, identified every {args.reidentify} calls (`RollingHybrid`): per call",
                     "(every call identifies)", f"wall median {_ms(get('median'))}, p95 {_ms(get('p95'))}; CPU median "
                     f"{_ms(get('cpu_median'))}, p95 {_ms(get('cpu_p95'))}", ""])
        rows.append(["its joint RMS at 1 s, half-way between identifications", "",
                     f"{roll[-1]['rms_rolling']:.2f} mrad (a fresh identification {roll[-1]['rms_fresh']:.2f}; "
                     f"{roll[-1]['probes']} windows)", ""])
    head = "| what | before | after | before / after |\n|---|---|---|---|\n"
    loads = ", ".join(f"{r['load']:.1f}-{r['load_end']:.1f}" for pair in zip(before, after) for r in pair)
    text = head + "\n".join("| " + " | ".join(r) + " |" for r in rows)
    text += (f"\n\nBefore: commit `{args.before}`; after: `{args.after}`; {args.robots} robots of `{args.data}` "
             f"(median of {args.repeats} calls each), {args.rounds} rounds, 1-minute load average per process "
             f"(before, after alternately; start-end): {loads}.\n")
    prof = next((r.get("profile") for r in reversed(after) if r.get("profile")), None)
    if prof:
        text += "\nWhere the time goes after (cProfile over the single-trajectory calls, largest own times):\n\n```\n" \
                + prof + "\n```\n"
    return text


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, help="a store of the recipe's robots (commands u_cmd and outputs y)")
    p.add_argument("--arm", default="panda")
    p.add_argument("--recipe", default="realistic")
    p.add_argument("--robots", type=int, default=8)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--frames", type=int, default=60, help="rolling calls per robot")
    p.add_argument("--reidentify", type=int, default=30)
    p.add_argument("--roll-robots", type=int, default=4)
    p.add_argument("--before", default=BEFORE)
    p.add_argument("--after", default="HEAD")
    p.add_argument("--out", default=None, help="markdown file for the table (default: printed only)")
    p.add_argument("--measure", default=None, help=argparse.SUPPRESS)  # a worker: this commit's figures to JSON
    args = p.parse_args()
    for name in ("robots", "repeats", "batch", "rounds", "frames", "reidentify", "roll_robots"):
        if getattr(args, name) < 1:
            p.exit(2, f"error: --{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}\n")
    if not os.path.isdir(args.data):
        p.exit(2, f"error: --data {args.data}: no such store; make one with robomorph generate --config realistic "
                  "--robots 16 --seed 1 --out heldout.zarr\n")
    args.data = os.path.abspath(args.data)
    if args.measure:
        with open(args.measure, "w") as f:
            json.dump(measure(args), f)
        return

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import REPO, print_provenance  # noqa: PLC0415

    from robomorph.core.results import provenance, write_markdown  # noqa: PLC0415

    from robomorph.core.atomic import check_replaceable  # noqa: PLC0415

    from robomorph.core.errors import RoboMorphError  # noqa: PLC0415

    for ref in (args.before, args.after):
        known = subprocess.run(["git", "-C", REPO, "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
                               capture_output=True)
        if ref != "." and known.returncode:
            p.exit(2, f"error: {ref!r} is not a commit of this repository (--before / --after take a commit, or '.' "
                      "for the working tree)\n")
    if args.out:
        try:
            check_replaceable(args.out, "markdown", "--out")
        except RoboMorphError as exc:
            p.exit(2, f"error: {exc}\n")
    prov = provenance()
    print_provenance()
    argv = [a for a in sys.argv[1:]]
    before, after = [], []
    with tempfile.TemporaryDirectory() as tb, tempfile.TemporaryDirectory() as ta:
        trees = _tree(args.before, REPO, tb), _tree(args.after, REPO, ta)
        for r in range(args.rounds):
            before.append(_run(trees[0], argv))
            after.append(_run(trees[1], argv))
            print(f"round {r + 1}/{args.rounds}: load {before[-1]['load']:.1f} / {after[-1]['load']:.1f}", flush=True)
    text = table(before, after, args)
    print(text)
    if args.out:
        write_markdown(args.out, "# The hybrid within one frame (issue 65)\n\n" + text, prov)


if __name__ == "__main__":
    main()
