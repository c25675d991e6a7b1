"""Prediction quality by horizon: model options against the paper's formulation, same training budget.

Trains each variant (``datamodules/train_cpu.yaml``, the paper's formulation ``BEFORE``, then
the variant's overrides) on the same training robots, one after the other in this process
(seed 0 everywhere), and scores its last weights on the same held-out robots with
:func:`robomorph.evaluation.scoring.score_windows`: windows from the trajectory start
(context 200, horizon 800, the paper's) and from random offsets (seed 0, horizon 300).

The learning-rate schedule is the package's (warmup, then cosine over ``trainer.max_steps``),
configured, not driven from outside: ``--steps`` sets ``trainer.max_steps`` (default
train_cpu.yaml's), so each run's ``config.yaml`` records what ran. ``--minutes`` optionally
caps each variant's CPU time (``--minutes`` x 60 x 2 CPU-seconds: what ``--minutes`` of wall
clock give on an idle 2-core machine; the machine may be shared); a capped run stops before
its cosine ends, and its row gives the steps it reached.

Appends to ``--csv`` one row per variant (and per ``--score-every`` point): joint-angle RMS
over robots and joints [mrad] of the model and of ``hold`` at steps 1, 15, 60, 300 and 800
(first step, 0.25 s, 1 s, 5 s, the end; step k is k dt after the last context sample),
whether the model is below hold at every step (and the first step where it is not), whether
it is below the catalogue physics from 0.5 s on, approach-1 R² and FIT over the horizon,
for a Gaussian head the fraction of true joint angles inside ±1σ and ±2σ at those steps, and
the same errors from random offsets. Each formulation's catalogue physics (nominal
parameters) is a row of its own. Per-step curves go to ``--curves``.

    python benchmarks/horizon_ablation.py --steps 2800                     # the screening, all variants
    python benchmarks/horizon_ablation.py --variants full --score-every 2000 \\
        --csv results/benchmarks/confirm60_total.csv --runs-dir data/quality/confirm_runs

Data (gitignored): ``data/quality/ms_train.zarr`` (``--robots`` 1024, seed 0) and
``data/quality/ms_heldout.zarr`` (``--held-out`` 64, seed 1), generated when missing.
"""

from __future__ import annotations

import os

# Idle OpenMP threads sleep instead of spinning, so CPU time measures work, not waiting.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import sys
import time

import lightning.pytorch as L
import torch
from common import MULTISINE, check_outputs, parse_sets, print_provenance, train_cpu_config

from robomorph.core.errors import run_command
from robomorph.core.results import ResultsCsv, write_rows
from robomorph.data.generation import generate
from robomorph.data.store import open_store
from robomorph.evaluation.scoring import resolve_steps, score_windows
from robomorph.evaluation.windows import load_window
from robomorph.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

PHYSICS_FROM_S = 0.5  # "below catalogue physics from 0.5 s on"
HORIZON_AWARE = {"data": {"context_min": 60, "horizon_min": 100, "window": "random"},
                 "model": {"horizon_weight": 4.0, "horizon_tau": 60.0}}
# The paper's formulation (explicit, so that the reference stays put whatever
# datamodules/train_cpu.yaml makes the default).
BEFORE = {"data": {"context_min": None, "horizon_min": None, "window": "start", "inputs": "total"},
          "model": {"anchor": False, "integrate": False, "n_init": 0, "gaussian": False, "loss": "huber", "horizon_weight": 0.0}}
# name -> overrides of datamodules/train_cpu.yaml ({"data": ..., "model": ...}) on top of BEFORE.
VARIANTS: dict[str, dict] = {
    "default": {},
    "anchor": {"model": {"anchor": True}},
    "anchor_init": {"model": {"anchor": True, "n_init": 20}},
    "anchor_init_horizon": {"data": HORIZON_AWARE["data"],
                            "model": {"anchor": True, "n_init": 20, **HORIZON_AWARE["model"]}},
    "full": {"data": HORIZON_AWARE["data"],
             "model": {"anchor": True, "n_init": 20, "gaussian": True, "loss": "nll", **HORIZON_AWARE["model"]}},
    # The same recipe in the command formulation: inputs without the arm's gravity compensation.
    "full_command": {"data": {**HORIZON_AWARE["data"], "inputs": "command"},
                     "model": {"anchor": True, "n_init": 20, "gaussian": True, "loss": "nll", **HORIZON_AWARE["model"]}},
    "full_integrate": {"data": HORIZON_AWARE["data"],
                       "model": {"anchor": True, "integrate": True, "n_init": 20, "gaussian": True, "loss": "nll",
                                 **HORIZON_AWARE["model"]}},
}


class Budget(L.Callback):
    """Stops training once ``cpu_seconds`` of this process's CPU time are spent (the schedule
    is the configured one; this only ends the run). With ``every`` (optimizer steps) it calls
    ``report(module, cpu_seconds, step)`` each time that many more steps are done; the
    report's own CPU time is left out of the budget."""

    def __init__(self, cpu_seconds: float | None = None, every: int | None = None, report=None):
        self.seconds, self.every, self.report, self.t0, self.excluded = cpu_seconds, every, report, None, 0.0

    def spent(self) -> float:
        return time.process_time() - self.t0 - self.excluded

    def on_train_start(self, trainer, pl_module):
        self.t0 = time.process_time()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        step = trainer.global_step
        # The last point is the final scoring's (after fit returns), not scored twice here.
        if self.every and step % self.every == 0 and step < trainer.max_steps:
            t = time.process_time()
            self.report(pl_module, self.spent(), step)
            pl_module.train()
            self.excluded += time.process_time() - t
        if self.seconds is not None and self.spent() >= self.seconds:
            trainer.should_stop = True


def _data(train: str, test: str, robots: int, held_out: int, steps: int) -> None:
    for path, n, seed in ((train, robots, 0), (test, held_out, 1)):
        if not os.path.isdir(path):
            generate(load_recipe(MULTISINE, {"robots": n, "seed": seed, "steps": steps}), path, progress=True)


def config(name: str, args) -> dict:
    """The fit configuration of a variant: train_cpu.yaml, BEFORE, the variant, the data, ``--set``."""
    data = {"stores": args.train, "test_store": args.test, "split": [1.0 - args.val_share, args.val_share, 0.0],
            "context_len": args.context, "horizon": args.horizon, "seed": 0}
    trainer = {"enable_progress_bar": False, **({"max_steps": args.steps} if args.steps else {})}
    cfg = train_cpu_config(BEFORE, VARIANTS[name], {"data": data, "trainer": trainer}, parse_sets(args.set))
    return {**cfg, "run": name, "runs_dir": args.runs_dir, "wandb": "disabled", "seed_everything": 0}


def _inputs(name: str) -> str:
    return VARIANTS[name].get("data", {}).get("inputs", "total")


def physics(test: str, inputs: str, context: int, horizon: int, random_horizon: int) -> dict:
    """Catalogue physics (nominal parameters) from the true state, scored as a predictor (from
    the trajectory start only: its row leaves the random-offset columns empty)."""
    ds = open_store(test)
    w = load_window(test, context, horizon, None, None, len(ds.u_names), len(ds.y_names), inputs=inputs)
    s = score_windows(None, w, ("hold", "nominal_physics"), None)
    if s.result["skipped_baselines"]:
        raise RuntimeError(f"baselines skipped: {s.result['skipped_baselines']}")
    summary = s.summary("nominal_physics")
    return {"steps": s.result["horizons"]["steps"], "dt": w.dt, "curve_model": s.curve("nominal_physics", "joints"),
            "curve_hold": s.curve("hold", "joints"), "r2": summary["r2"], "fit": summary["fit"],
            "random_steps": resolve_steps(None, random_horizon, w.dt)}


def score(pred, test: str, inputs: str = "total", nominal=None, context: int = 200, horizon: int = 800,
          random_horizon: int = 300) -> dict:
    """The model beside hold on ``test``: from the trajectory start and from random offsets;
    given the catalogue physics' curve ``nominal``, whether the model stays below it from 0.5 s on."""
    w = load_window(test, context, horizon, None, None, pred.n_u, pred.n_y, inputs=inputs)
    s = score_windows(pred, w, ("hold",), None)
    h = s.result["horizons"]
    below = h["below"]["hold"]["joints"]
    out = {"steps": h["steps"], "dt": w.dt, "curve_model": s.curve("model", "joints"),
           "curve_hold": s.curve("hold", "joints"), "r2": s.summary()["r2"], "fit": s.summary()["fit"],
           "below_hold_everywhere": below["first_not_below"] is None,
           "first_step_not_below_hold": below["first_not_below"] or ""}
    if nominal is not None:
        k = resolve_steps([round(PHYSICS_FROM_S / w.dt)], horizon, w.dt)[0]
        out["below_physics_from_0.5s"] = bool((out["curve_model"][k - 1:] < nominal[k - 1:]).all())
    if "calibration" in h:
        out |= {f"cover{k}": h["calibration"]["joints"][f"{k}sigma"] for k in (1, 2)}
    wr = load_window(test, context, random_horizon, None, None, pred.n_u, pred.n_y, offset="random", inputs=inputs)
    r = score_windows(pred, wr, ("hold",), None)
    out |= {"random_steps": r.result["horizons"]["steps"], "random_model": r.curve("model", "joints"),
            "random_hold": r.curve("hold", "joints"),
            "random_below_hold_everywhere": r.result["horizons"]["below"]["hold"]["joints"]["first_not_below"] is None}
    return out


def row(name: str, inputs: str, budget: float | str, cpu: float, wall: float, steps: int, s: dict,
        train_robots: int | str = "") -> dict:
    """One CSV row; the step columns are 1-based (``model_mrad_step15``: 15 dt after the context)."""
    r = {"variant": name, "inputs": inputs, "budget_2core_min": budget, "cpu_min": cpu, "wall_min": wall,
         "steps": steps}
    r |= {f"model_mrad_step{k}": round(float(s["curve_model"][k - 1]), 2) for k in s["steps"]}
    r |= {f"hold_mrad_step{k}": round(float(s["curve_hold"][k - 1]), 2) for k in s["steps"]}
    r |= {"below_hold_everywhere": s.get("below_hold_everywhere", ""),
          "first_step_not_below_hold": s.get("first_step_not_below_hold", ""),
          "below_physics_from_0.5s": s.get("below_physics_from_0.5s", ""),
          "r2": round(s["r2"], 4), "fit": round(s["fit"], 2)}
    for k in (1, 2):
        r[f"cover{k}sigma"] = "/".join(f"{c:.2f}" for c in s[f"cover{k}"]) if f"cover{k}" in s else ""
    for key in ("random_model", "random_hold"):
        r |= {f"{key}_mrad_step{k}": round(float(s[key][k - 1]), 2) if key in s else ""
              for k in s.get("random_steps", ())}
    r["random_below_hold_everywhere"] = s.get("random_below_hold_everywhere", "")
    r["train_robots"] = train_robots  # "" for the catalogue robot, which is not trained
    return r


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=None, help="optimizer steps per variant (trainer.max_steps; the "
                   "cosine runs over them); default: train_cpu.yaml's")
    p.add_argument("--minutes", type=float, default=None, help="optional cap per variant, 2-core minutes of CPU time")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {list(VARIANTS)}")
    p.add_argument("--train", default="data/quality/ms_train.zarr")
    p.add_argument("--test", default="data/quality/ms_heldout.zarr")
    p.add_argument("--robots", type=int, default=1024, help="training robots when --train is generated")
    p.add_argument("--held-out", type=int, default=64, help="held-out robots when --test is generated")
    p.add_argument("--trajectory-steps", type=int, default=1000, help="steps per generated trajectory")
    p.add_argument("--context", type=int, default=200)
    p.add_argument("--horizon", type=int, default=800)
    p.add_argument("--random-horizon", type=int, default=300, help="predicted steps from random offsets")
    p.add_argument("--runs-dir", default="data/quality/ablation_runs")
    p.add_argument("--csv", default="results/benchmarks/horizon_ablation.csv")
    p.add_argument("--curves", default=None, help="per-step curves CSV (default: <csv stem>_curves.csv)")
    p.add_argument("--score-every", type=int, default=None, help="also score every this many optimizer steps")
    p.add_argument("--val-share", type=float, default=0.05,
                   help="share of the training robots held out for validation (0.05: 51 of 1024)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="further fit configuration, e.g. trainer.val_check_interval=250 (recorded in config.yaml)")
    p.add_argument("--threads", type=int, default=os.cpu_count() or 2)
    args = p.parse_args(argv)
    if unknown := [n for n in args.variants.split(",") if n not in VARIANTS]:
        p.error(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    check_outputs(csv=args.csv)
    print_provenance()
    torch.set_num_threads(args.threads)
    _data(args.train, args.test, args.robots, args.held_out, args.trajectory_steps)
    n_train = open_store(args.train).n
    results = ResultsCsv(args.csv)
    curves_path = args.curves or args.csv.replace(".csv", "_curves.csv")
    curves, nominal = {}, {}
    window = {"context": args.context, "horizon": args.horizon}

    def emit(r: dict) -> None:
        results.append(r)
        print(" ".join(f"{k}={v}" for k, v in r.items()), flush=True)

    for name in args.variants.split(","):
        inputs = _inputs(name)
        if inputs not in nominal:  # before the budget starts: catalogue physics, once per formulation
            nominal[inputs] = physics(args.test, inputs, random_horizon=args.random_horizon, **window)
            emit(row(f"nominal_physics[{inputs}]", inputs, 0, 0, 0, 0, nominal[inputs]))
            curves[f"nominal_physics[{inputs}]"] = nominal[inputs]["curve_model"]
        t0 = time.perf_counter()

        def report(module, cpu, step, name=name, t0=t0, inputs=inputs):
            pred = Predictor(module.trained_model, device=module.device, data_info=module.data_info)
            s = score(pred, args.test, inputs, nominal[inputs]["curve_model"], random_horizon=args.random_horizon,
                      **window)
            emit(row(name, inputs, args.minutes or "", round(cpu / 60, 1), round((time.perf_counter() - t0) / 60, 1),
                     step, s, n_train))

        budget = Budget(args.minutes and args.minutes * 60 * 2, every=args.score_every, report=report)
        result = fit(config(name, args), callbacks=[budget])
        cpu, wall = budget.spent() / 60, (time.perf_counter() - t0) / 60
        s = score(Predictor.from_checkpoint(result.last_ckpt, device="cpu"), args.test, inputs,
                  nominal[inputs]["curve_model"], random_horizon=args.random_horizon, **window)
        emit(row(name, inputs, args.minutes or "", round(cpu, 1), round(wall, 1), result.global_step, s, n_train))
        curves[name], curves["hold"] = s["curve_model"], s["curve_hold"]
        write_rows(curves_path, [{"step": k, **{c: round(float(v[k - 1]), 3) for c, v in curves.items()}}
                                 for k in range(1, args.horizon + 1)])


if __name__ == "__main__":
    # A refused result file (another header) or a bad setting: one line, exit code 2.
    sys.exit(run_command(main))
