"""Prediction quality by horizon: model options against today's default, equal wall clock.

Trains each variant (the default CPU recipe ``datamodules/train_cpu.yaml`` plus the
variant's overrides) for ``--minutes`` of 2-core time on the same training robots, one
after the other in this process (seed 0 everywhere), and scores its final weights on the
same held-out robots from the trajectory start (context 200, horizon 800, the paper's
formulation).

The budget is this process's CPU time (``--minutes`` x 60 x 2 CPU-seconds, what
``--minutes`` of wall clock give on an idle 2-core machine): the machine these runs share
is loaded by other jobs, and wall-clock budgets would hand each variant whatever the others
left over. The learning rate follows the spent fraction of the budget (warmup over the first
5 %, cosine to lr/10 at the end), so a variant with slower steps is not left with an
undecayed schedule; the step count each variant reached is reported beside it.

Prints and appends to ``--csv`` one row per variant: joint-angle RMS over robots and joints
[mrad] at query steps 0/15/60/300/799 for the model and for holding the last context
output, whether the model is below hold at every step, approach-1 R^2 (mean over
channels and robots) over the 800 steps and, for a Gaussian head, the fraction of true
joint angles inside +-1 and +-2 sigma. Per-step curves go to ``--curves``.

    python benchmarks/horizon_ablation.py --minutes 8            # the screening, all variants
    python benchmarks/horizon_ablation.py --minutes 60 --variants full --score-every 10 \
        --csv results/benchmarks/confirm60.csv --runs-dir data/quality/confirm_runs

Data (gitignored): ``data/quality/ms_train.zarr`` (1024 robots, seed 0) and
``data/quality/ms_heldout.zarr`` (64 robots, seed 1), generated when missing.
"""

from __future__ import annotations

import os

# Idle OpenMP threads sleep instead of spinning, so CPU time measures work, not waiting.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import csv
import math
import time

import lightning.pytorch as L
import numpy as np
import torch
import yaml

from robomorph.core.metrics import r2
from robomorph.data.generation import generate
from robomorph.data.store import open_store
from robomorph.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

STEPS = (0, 15, 60, 300, 799)  # first step, 0.25 s, 1 s, 5 s, end of the horizon at 60 Hz
CONTEXT, HORIZON = 200, 800
HORIZON_AWARE = {"data": {"context_min": 60, "horizon_min": 100, "window": "random"},
                 "model": {"horizon_weight": 4.0, "horizon_tau": 60.0}}
# The model before issue 11 (explicit, so that the baseline stays put whatever
# datamodules/train_cpu.yaml makes the default).
BEFORE = {"data": {"context_min": None, "horizon_min": None, "window": "start"},
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
    "full_integrate": {"data": HORIZON_AWARE["data"],
                       "model": {"anchor": True, "integrate": True, "n_init": 20, "gaussian": True, "loss": "nll",
                                 **HORIZON_AWARE["model"]}},
}


class CpuBudget(L.Callback):
    """Sets the learning rate from the spent fraction of a CPU-time budget before each step
    and stops training when it is spent. With ``every`` (CPU seconds) it calls
    ``report(module, cpu_seconds, step)`` each time that much more is spent; the report's own
    CPU time is left out of the budget."""

    def __init__(self, cpu_seconds: float, warmup: float = 0.05, floor: float = 0.1,
                 every: float | None = None, report=None):
        self.seconds, self.warmup, self.floor, self.t0 = cpu_seconds, warmup, floor, None
        self.every, self.report, self.excluded, self.next = every, report, 0.0, every

    def spent(self) -> float:
        return time.process_time() - self.t0 - self.excluded

    def on_train_start(self, trainer, pl_module):
        self.t0 = time.process_time()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if self.every and self.spent() >= min(self.next, self.seconds):
            t = time.process_time()
            self.report(pl_module, self.spent(), trainer.global_step)
            pl_module.train()
            self.excluded += time.process_time() - t
            self.next += self.every
        if self.spent() >= self.seconds:
            trainer.should_stop = True

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        frac = min(1.0, self.spent() / self.seconds)
        if frac < self.warmup:
            factor = max(frac / self.warmup, 0.01)
        else:
            progress = (frac - self.warmup) / (1 - self.warmup)
            factor = self.floor + (1 - self.floor) * 0.5 * (1 + math.cos(math.pi * progress))
        for group in trainer.optimizers[0].param_groups:
            group["lr"] = pl_module.hparams.lr * factor


def _data(train: str, test: str) -> None:
    for path, robots, seed in ((train, 1024, 0), (test, 64, 1)):
        if not os.path.isdir(path):
            generate(load_recipe("datamodules/multisine.yaml", {"robots": robots, "seed": seed}), path, progress=True)


def _config(name: str, train: str, test: str, runs_dir: str) -> dict:
    with open("datamodules/train_cpu.yaml") as f:
        cfg = yaml.safe_load(f)
    for overrides in (BEFORE, VARIANTS[name]):
        for section, values in overrides.items():
            cfg[section] = {**cfg.get(section, {}), **values}
    cfg["data"].update({"stores": train, "test_store": test, "split": [0.95, 0.05, 0.0],
                        "context_len": CONTEXT, "horizon": HORIZON, "seed": 0})
    # The CPU-budget callback drives the rate and the stop; the step schedule stays flat at lr.
    cfg["model"].update({"warmup_steps": 0, "decay_steps": 10**9, "min_lr_ratio": 1.0})
    cfg["trainer"].update({"max_steps": 10**7, "val_check_interval": 250, "enable_progress_bar": False})
    return {**cfg, "run": name, "runs_dir": runs_dir, "wandb": "disabled", "seed_everything": 0}


def score(pred: Predictor, test: str) -> dict:
    """Per-horizon joint RMS [mrad] of model and hold, R^2 and sigma coverage on ``test``."""
    ds = open_store(test)
    u, y = ds.read("u"), ds.read("y")
    joints = [i for i, n in enumerate(ds.y_names) if n.startswith("q")]
    u_ctx, y_ctx, u_q, y_q = u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:CONTEXT + HORIZON], y[:, CONTEXT:CONTEXT + HORIZON]
    means, stds = [], []
    for b in range(0, len(u), 16):
        m, s = pred.simulate(u_ctx[b:b + 16], y_ctx[b:b + 16], u_q[b:b + 16], return_std=True) \
            if pred.has_std else (pred.simulate(u_ctx[b:b + 16], y_ctx[b:b + 16], u_q[b:b + 16]), None)
        means.append(m)
        stds.append(s)
    yhat = np.concatenate(means).astype(np.float64)
    hold = np.repeat(y_ctx[:, -1:], HORIZON, axis=1).astype(np.float64)
    curve = {k: 1e3 * np.sqrt(((v[..., joints] - y_q[..., joints]) ** 2).mean(axis=(0, 2)))
             for k, v in (("model", yhat), ("hold", hold))}
    out = {"curve_model": curve["model"], "curve_hold": curve["hold"],
           "r2": float(r2(y_q.astype(np.float64), yhat).mean()),
           "below_hold_everywhere": bool((curve["model"] < curve["hold"]).all()),
           "first_step_above_hold": int(np.argmax(curve["model"] >= curve["hold"]))
           if (curve["model"] >= curve["hold"]).any() else -1}
    if stds[0] is not None:
        z = np.abs(yhat - y_q)[..., joints] / np.concatenate(stds)[..., joints]
        for k in (1, 2):
            out[f"cover{k}"] = [float((z[:, t] <= k).mean()) for t in STEPS]
    return out


def _row(name: str, budget: float, cpu: float, wall: float, steps: int, s: dict) -> dict:
    row = {"variant": name, "budget_2core_min": budget, "cpu_min": cpu, "wall_min": wall, "steps": steps}
    row |= {f"model_mrad_{t}": round(float(s["curve_model"][t]), 2) for t in STEPS}
    row |= {f"hold_mrad_{t}": round(float(s["curve_hold"][t]), 2) for t in STEPS}
    row |= {"below_hold_everywhere": s["below_hold_everywhere"], "first_step_above_hold": s["first_step_above_hold"],
            "r2_800": round(s["r2"], 4)}
    for k in (1, 2):
        row[f"cover{k}sigma"] = "/".join(f"{c:.2f}" for c in s[f"cover{k}"]) if f"cover{k}" in s else ""
    return row


def _append(path: str, row: dict) -> None:
    new = not os.path.isfile(path)
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(row))
        if new:
            w.writeheader()
        w.writerow(row)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=8)
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {list(VARIANTS)}")
    p.add_argument("--train", default="data/quality/ms_train.zarr")
    p.add_argument("--test", default="data/quality/ms_heldout.zarr")
    p.add_argument("--runs-dir", default="data/quality/ablation_runs")
    p.add_argument("--csv", default="results/benchmarks/horizon_ablation.csv")
    p.add_argument("--curves", default=None, help="per-step curves CSV (default: <csv stem>_curves.csv)")
    p.add_argument("--score-every", type=float, default=None,
                   help="also score the held-out robots every this many 2-core minutes of training (a row each)")
    args = p.parse_args()
    names = args.variants.split(",")
    if unknown := [n for n in names if n not in VARIANTS]:
        p.error(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    torch.set_num_threads(os.cpu_count() or 2)
    _data(args.train, args.test)
    curves_path = args.curves or args.csv.replace(".csv", "_curves.csv")
    curves = {}
    for name in names:
        t0 = time.perf_counter()

        def report(module, cpu, step, name=name, t0=t0):
            s = score(Predictor(module, device="cpu"), args.test)
            row = _row(name, round(cpu / 120, 1), round(cpu / 60, 1), round((time.perf_counter() - t0) / 60, 1), step, s)
            _append(args.csv, row)
            print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)

        budget = CpuBudget(args.minutes * 60 * 2, every=args.score_every and args.score_every * 120, report=report)
        result = fit(_config(name, args.train, args.test, args.runs_dir), callbacks=[budget])
        cpu, wall = budget.spent() / 60, (time.perf_counter() - t0) / 60
        s = score(Predictor.from_checkpoint(result.last_ckpt, device="cpu"), args.test)
        row = _row(name, args.minutes, round(cpu, 1), round(wall, 1), result.global_step, s)
        _append(args.csv, row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
        curves[name] = s["curve_model"]
        curves["hold"] = s["curve_hold"]
        with open(curves_path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", *curves])
            w.writerows([t, *(round(float(c[t]), 3) for c in curves.values())] for t in range(HORIZON))


if __name__ == "__main__":
    main()
