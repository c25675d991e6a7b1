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
from robomorph.evaluation.evaluator import load_window, run_baselines
from robomorph.evaluation.metrics import approach1_mean
from robomorph.data.generation import generate
from robomorph.data.store import open_store
from robomorph.model.checkpoint import TrainedModel
from robomorph.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

STEPS = (0, 15, 60, 300, 799)  # first step, 0.25 s, 1 s, 5 s, end of the horizon at 60 Hz
CONTEXT, HORIZON = 200, 800
# Windows at random offsets (what a controller meets mid-motion) need room in the 1000-step
# trajectories: context 200 + horizon 300, each start drawn uniformly from 0..500 (seed 0).
RANDOM_HORIZON, RANDOM_STEPS = 300, (0, 15, 60, 299)
PHYSICS_FROM = 30  # "below catalogue physics from 0.5 s on" (issue 12's goal)
HORIZON_AWARE = {"data": {"context_min": 60, "horizon_min": 100, "window": "random"},
                 "model": {"horizon_weight": 4.0, "horizon_tau": 60.0}}
# The model before issue 11 (explicit, so that the baseline stays put whatever
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
    # The same recipe in the command formulation (issue 12): inputs without the arm's gravity compensation.
    "full_command": {"data": {**HORIZON_AWARE["data"], "inputs": "command"},
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
        # The last point is the final scoring's (after fit returns), not scored twice here.
        if self.every and self.next < self.seconds and self.spent() >= self.next:
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


def _config(name: str, train: str, test: str, runs_dir: str, val_share: float = 0.05) -> dict:
    with open("datamodules/train_cpu.yaml") as f:
        cfg = yaml.safe_load(f)
    for overrides in (BEFORE, VARIANTS[name]):
        for section, values in overrides.items():
            cfg[section] = {**cfg.get(section, {}), **values}
    cfg["data"].update({"stores": train, "test_store": test, "split": [1.0 - val_share, val_share, 0.0],
                        "context_len": CONTEXT, "horizon": HORIZON, "seed": 0})
    # The CPU-budget callback drives the rate and the stop; the step schedule stays flat at lr.
    cfg["model"].update({"warmup_steps": 0, "decay_steps": 10**9, "min_lr_ratio": 1.0})
    cfg["trainer"].update({"max_steps": 10**7, "val_check_interval": 250, "enable_progress_bar": False})
    return {**cfg, "run": name, "runs_dir": runs_dir, "wandb": "disabled", "seed_everything": 0}


def _in_memory(module) -> TrainedModel:
    """The weights being trained as the :class:`TrainedModel` a checkpoint would load into
    (sharing the module's network and normalization): scoring mid-run without a checkpoint."""
    h = module.hparams
    model = TrainedModel(module.model_config, recenter=h.recenter, anchor=h.anchor, normalization=h.normalization,
                         integrate=h.integrate)
    model.net, model.normalizer = module.net, module.normalizer
    return model


def _inputs(name: str) -> str:
    return VARIANTS[name].get("data", {}).get("inputs", "total")


def _curve(yhat: np.ndarray, y_q: np.ndarray, joints: list[int]) -> np.ndarray:
    """Joint-angle RMS over robots and joints per query step [mrad]."""
    return 1e3 * np.sqrt(((yhat[..., joints] - y_q[..., joints]) ** 2).mean(axis=(0, 2)))


def _predict(pred: Predictor, w) -> tuple[np.ndarray, np.ndarray | None]:
    u_ctx, y_ctx, u_q, _ = w.split()
    means, stds = [], []
    for b in range(0, len(u_ctx), 16):
        if pred.has_std:
            m, s = pred.simulate(u_ctx[b:b + 16], y_ctx[b:b + 16], u_q[b:b + 16], return_std=True)
            stds.append(s)
        else:
            m = pred.simulate(u_ctx[b:b + 16], y_ctx[b:b + 16], u_q[b:b + 16])
        means.append(m)
    return np.concatenate(means).astype(np.float64), (np.concatenate(stds) if stds else None)


def physics(test: str, inputs: str) -> dict:
    """Catalogue physics (nominal parameters) from the true state: its per-step joint RMS,
    R^2 and FIT on the evaluation window of ``inputs`` (issue 12's anchor)."""
    ds = open_store(test)
    w = load_window(test, CONTEXT, HORIZON, None, None, len(ds.u_names), len(ds.y_names), inputs=inputs)
    y_q = w.split()[3].astype(np.float64)
    preds, skipped, _ = run_baselines(w, ("hold", "nominal_physics"), (2, 2))
    if skipped:
        raise RuntimeError(f"baselines skipped: {skipped}")
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
    p = preds["nominal_physics"]
    return {"curve_model": _curve(p, y_q, joints), "curve_hold": _curve(preds["hold"], y_q, joints),
            "r2": float(r2(y_q, p).mean()), "fit": float(approach1_mean(y_q, p, "fit"))}


def score(pred: Predictor, test: str, inputs: str = "total", nominal: np.ndarray | None = None) -> dict:
    """Per-horizon joint RMS [mrad] of model and hold, R^2, FIT and sigma coverage on ``test``
    from the trajectory start; the same against hold at random offsets; and, given the
    catalogue physics' curve ``nominal``, whether the model stays below it from 0.5 s on."""
    w = load_window(test, CONTEXT, HORIZON, None, None, pred.n_u, pred.n_y, inputs=inputs)
    y_q = w.split()[3].astype(np.float64)
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
    yhat, std = _predict(pred, w)
    hold = np.repeat(w.split()[1][:, -1:], HORIZON, axis=1).astype(np.float64)
    curve = {"model": _curve(yhat, y_q, joints), "hold": _curve(hold, y_q, joints)}
    above = curve["model"] >= curve["hold"]
    out = {"curve_model": curve["model"], "curve_hold": curve["hold"],
           "r2": float(r2(y_q, yhat).mean()), "fit": float(approach1_mean(y_q, yhat, "fit")),
           "below_hold_everywhere": not above.any(),
           "first_step_above_hold": int(np.argmax(above)) if above.any() else -1}
    if nominal is not None:
        out["below_physics_from_0.5s"] = bool((curve["model"][PHYSICS_FROM:] < nominal[PHYSICS_FROM:]).all())
    if std is not None:
        z = np.abs(yhat - y_q)[..., joints] / std[..., joints]
        for k in (1, 2):
            out[f"cover{k}"] = [float((z[:, t] <= k).mean()) for t in STEPS]
    wr = load_window(test, CONTEXT, RANDOM_HORIZON, None, None, pred.n_u, pred.n_y, offset="random", inputs=inputs)
    yr_q = wr.split()[3].astype(np.float64)
    model_r = _curve(_predict(pred, wr)[0], yr_q, joints)
    hold_r = _curve(np.repeat(wr.split()[1][:, -1:], RANDOM_HORIZON, axis=1).astype(np.float64), yr_q, joints)
    out |= {"random_model": model_r, "random_hold": hold_r, "random_below_hold_everywhere": bool((model_r < hold_r).all())}
    return out


def _row(name: str, budget: float, cpu: float, wall: float, steps: int, s: dict, train_robots: int | str = "") -> dict:
    row = {"variant": name, "inputs": _inputs(name) if name in VARIANTS else name.split("[")[-1].rstrip("]"),
           "budget_2core_min": budget, "cpu_min": cpu, "wall_min": wall, "steps": steps}
    row |= {f"model_mrad_{t}": round(float(s["curve_model"][t]), 2) for t in STEPS}
    row |= {f"hold_mrad_{t}": round(float(s["curve_hold"][t]), 2) for t in STEPS}
    row |= {"below_hold_everywhere": s.get("below_hold_everywhere", ""),
            "first_step_above_hold": s.get("first_step_above_hold", ""),
            "below_physics_from_0.5s": s.get("below_physics_from_0.5s", ""),
            "r2_800": round(s["r2"], 4), "fit_800": round(s["fit"], 2)}
    for k in (1, 2):
        row[f"cover{k}sigma"] = "/".join(f"{c:.2f}" for c in s[f"cover{k}"]) if f"cover{k}" in s else ""
    for key in ("random_model", "random_hold"):
        row |= {f"{key}_mrad_{t}": round(float(s[key][t]), 2) if key in s else "" for t in RANDOM_STEPS}
    row["random_below_hold_everywhere"] = s.get("random_below_hold_everywhere", "")
    row["train_robots"] = train_robots  # "" for the catalogue robot, which is not trained
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
    p.add_argument("--val-share", type=float, default=0.05,
                   help="share of the training robots held out for validation (0.05: 51 of 1024; give "
                        "0.0125 on 4096 robots for the same 51, so validation costs the same)")
    p.add_argument("--threads", type=int, default=os.cpu_count() or 2,
                   help="torch threads (1: two runs side by side, each on a core of its own)")
    args = p.parse_args()
    names = args.variants.split(",")
    if unknown := [n for n in names if n not in VARIANTS]:
        p.error(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    torch.set_num_threads(args.threads)
    _data(args.train, args.test)
    n_train = open_store(args.train).n
    curves_path = args.curves or args.csv.replace(".csv", "_curves.csv")
    curves, nominal = {}, {}
    for name in names:
        inputs = _inputs(name)
        if inputs not in nominal:  # before the budget starts: catalogue physics, once per formulation
            nominal[inputs] = physics(args.test, inputs)
            row = _row(f"nominal_physics[{inputs}]", 0, 0, 0, 0, nominal[inputs])
            _append(args.csv, row)
            print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
            curves[f"nominal_physics[{inputs}]"] = nominal[inputs]["curve_model"]
        t0 = time.perf_counter()

        def report(module, cpu, step, name=name, t0=t0, inputs=inputs):
            s = score(Predictor(_in_memory(module), device="cpu"), args.test, inputs, nominal[inputs]["curve_model"])
            row = _row(name, round(cpu / 120, 1), round(cpu / 60, 1), round((time.perf_counter() - t0) / 60, 1), step, s,
                       n_train)
            _append(args.csv, row)
            print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)

        budget = CpuBudget(args.minutes * 60 * 2, every=args.score_every and args.score_every * 120, report=report)
        result = fit(_config(name, args.train, args.test, args.runs_dir, args.val_share), callbacks=[budget])
        cpu, wall = budget.spent() / 60, (time.perf_counter() - t0) / 60
        s = score(Predictor.from_checkpoint(result.last_ckpt, device="cpu"), args.test, inputs, nominal[inputs]["curve_model"])
        row = _row(name, args.minutes, round(cpu, 1), round(wall, 1), result.global_step, s, n_train)
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
