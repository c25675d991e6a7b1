"""Total torque against command: the same model, data and budget in both input formulations.

Generates multi-sine training robots and held-out robots of another seed (or reuses them
under ``--out``), trains the default CPU model (``datamodules/train_cpu.yaml``) once with
``data.inputs: total`` and once with ``data.inputs: command`` for the same number of
optimizer steps (each also capped at ``--max-minutes``), then scores both best
checkpoints on the held-out robots (context 200, horizon 800) beside ``hold``,
``nominal_physics`` and ``true_physics`` of the same formulation. Prints and writes
``<csv>`` with, per formulation and predictor: joint RMS error [mrad] at 1 s, 5 s and
13.3 s into the horizon (steps 60, 300, 800; RMS over joints and robots), approach-1 mean
R^2 and FIT over the 800 steps, and the steps and minutes trained.

    python benchmarks/formulations.py --steps 1500 --max-minutes 12
    python benchmarks/formulations.py --steps 400 --max-minutes 14 --d-model 64 --n-layer 2 --patch 20 --batch 16
"""

from __future__ import annotations

import argparse
import csv
import os
import time

import numpy as np
import torch

from robomorph.data.generation import generate
from robomorph.evaluation import metrics
from robomorph.evaluation.evaluator import load_window, predict, run_baselines
from robomorph.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

HORIZON_STEPS = (60, 300, 800)  # 1 s, 5 s, 13.3 s at 60 Hz
CONTEXT, HORIZON = 200, 800
Q = slice(7, 14)  # joint angles in y


def _data(out: str, robots: int, held_out: int) -> tuple[str, str]:
    train, test = os.path.join(out, "ms_train.zarr"), os.path.join(out, "ms_heldout.zarr")
    generate(load_recipe("datamodules/multisine.yaml", {"robots": robots, "seed": 0}), train, progress=False)
    generate(load_recipe("datamodules/multisine.yaml", {"robots": held_out, "seed": 1}), test, progress=False)
    return train, test


def _train(inputs: str, train: str, test: str, args) -> tuple[str, int, float]:
    """Trains one formulation; returns (best checkpoint, steps, minutes)."""
    t0 = time.perf_counter()
    result = fit([
        "--config", "datamodules/train_cpu.yaml", "--data.stores", train, "--data.test_store", test,
        "--data.split", "[0.95, 0.05, 0.0]", "--data.inputs", inputs, "--data.val_subset", str(args.val_subset),
        "--model.decay_steps", str(args.steps), "--model.warmup_steps", str(min(500, args.steps // 10)),
        "--model.d_model", str(args.d_model), "--model.n_layer", str(args.n_layer), "--model.patch", str(args.patch),
        "--data.batch_size", str(args.batch),
        "--trainer.max_steps", str(args.steps), "--trainer.max_time", f"00:00:{int(args.max_minutes):02d}:00",
        "--trainer.val_check_interval", str(max(2, args.steps // 6)), "--trainer.enable_progress_bar", "false",
        "--run", f"formulation_{inputs}", "--runs_dir", os.path.join(args.out, "runs"), "--wandb", "disabled",
    ])
    return result.best_ckpt or result.last_ckpt, result.global_step, (time.perf_counter() - t0) / 60


def _row(inputs: str, source: str, y_q: np.ndarray, pred: np.ndarray, steps: int, minutes: float) -> dict:
    err = pred[..., Q] - y_q[..., Q]  # (N, H, 7)
    row = {"inputs": inputs, "predictor": source, "steps": steps, "minutes": round(minutes, 1)}
    for h in HORIZON_STEPS:
        row[f"joint_rms_mrad_{h}"] = float(np.sqrt(np.mean(err[:, h - 1] ** 2)) * 1e3)
    row["r2_a1"] = float(metrics.approach1_mean(y_q, pred, "r2"))
    row["fit_a1"] = float(metrics.approach1_mean(y_q, pred, "fit"))
    return row


def _score(inputs: str, ckpt: str, test: str, steps: int, minutes: float) -> list[dict]:
    predictor = Predictor.from_checkpoint(ckpt, device="cpu")
    w = load_window(test, CONTEXT, HORIZON, None, predictor.data_info, predictor.n_u, predictor.n_y, inputs=inputs)
    u_ctx, y_ctx, u_q, y_q = w.split()
    y_q = y_q.astype(np.float64)
    rows = [_row(inputs, "model", y_q, predict(predictor, u_ctx, y_ctx, u_q, 64), steps, minutes)]
    base, skipped, _ = run_baselines(w, ("hold", "nominal_physics", "true_physics"), (2, 2))
    if skipped:
        raise RuntimeError(f"baselines skipped: {skipped}")
    rows += [_row(inputs, name, y_q, p, 0, 0.0) for name, p in base.items()]
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=1500, help="optimizer steps per formulation")
    p.add_argument("--max-minutes", type=float, default=12.0, help="wall-clock cap per formulation")
    p.add_argument("--robots", type=int, default=1500, help="training robots")
    p.add_argument("--held-out", type=int, default=128)
    p.add_argument("--val-subset", type=int, default=75, help="validation trajectories (fixed subset)")
    p.add_argument("--d-model", type=int, default=128, help="the CPU model's width (train_cpu.yaml: 128)")
    p.add_argument("--n-layer", type=int, default=4, help="encoder and decoder depth (train_cpu.yaml: 4)")
    p.add_argument("--patch", type=int, default=10, help="steps per token (train_cpu.yaml: 10)")
    p.add_argument("--batch", type=int, default=32, help="trajectories per batch (train_cpu.yaml: 32)")
    p.add_argument("--out", default="data/formulations")
    p.add_argument("--csv", default="results/benchmarks/formulations.csv")
    args = p.parse_args()
    torch.set_num_threads(os.cpu_count() or 2)
    os.makedirs(args.out, exist_ok=True)
    train, test = _data(args.out, args.robots, args.held_out)
    rows = []
    for inputs in ("total", "command"):
        ckpt, steps, minutes = _train(inputs, train, test, args)
        print(f"{inputs}: {steps} steps in {minutes:.1f} min -> {ckpt}", flush=True)
        rows += _score(inputs, ckpt, test, steps, minutes)
    keys = list(rows[0])
    with open(args.csv, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    print(" ".join(f"{k:>16s}" for k in keys))
    for r in rows:
        print(" ".join(f"{v:>16.4g}" if isinstance(v, float) else f"{v!s:>16s}" for v in r.values()))


if __name__ == "__main__":
    main()
