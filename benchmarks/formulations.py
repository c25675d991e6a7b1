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
import os
import sys
import time

import torch
from common import MULTISINE, TRAIN_CPU, check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, write_rows
from robomorph.data.generation import generate
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.windows import load_window
from robomorph.predictor import Predictor
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit

STEPS = (60, 300, 800)  # 1 s, 5 s, 13.3 s at 60 Hz (step k: k dt after the last context sample)


def _steps(horizon: int) -> list[int]:
    """STEPS within the horizon, and its end."""
    return sorted({k for k in STEPS if k <= horizon} | {horizon})


def _data(out: str, robots: int, held_out: int, steps: int) -> tuple[str, str]:
    train, test = os.path.join(out, "ms_train.zarr"), os.path.join(out, "ms_heldout.zarr")
    generate(load_recipe(MULTISINE, {"robots": robots, "seed": 0, "steps": steps}), train, progress=False)
    generate(load_recipe(MULTISINE, {"robots": held_out, "seed": 1, "steps": steps}), test, progress=False)
    return train, test


def _given(flags: dict) -> list[str]:
    """The fit arguments of the flags the user gave; the others keep train_cpu.yaml's values."""
    return [part for key, value in flags.items() if value is not None for part in (key, str(value))]


def _train(inputs: str, train: str, test: str, args) -> tuple[str, int, float]:
    """Trains one formulation; returns (best checkpoint, steps, minutes)."""
    t0 = time.perf_counter()
    result = fit([
        "--config", TRAIN_CPU, "--data.stores", train, "--data.test_store", test,
        "--data.split", "[0.95, 0.05, 0.0]", "--data.inputs", inputs, "--data.val_subset", str(args.val_subset),
        "--model.decay_steps", str(args.steps), "--model.warmup_steps", str(min(500, args.steps // 10)),
        *_given({"--model.d_model": args.d_model, "--model.n_layer": args.n_layer, "--model.patch": args.patch,
                 "--data.batch_size": args.batch}),
        "--trainer.max_steps", str(args.steps), "--trainer.max_time", f"00:00:{int(args.max_minutes):02d}:00",
        "--trainer.val_check_interval", str(max(2, args.steps // 6)), "--trainer.enable_progress_bar", "false",
        "--data.context_len", str(args.context), "--data.horizon", str(args.horizon),
        "--run", f"formulation_{inputs}", "--runs_dir", os.path.join(args.out, "runs"), "--wandb", "disabled",
        *(part for item in args.set or [] for part in ("--" + item.partition("=")[0], item.partition("=")[2])),
    ])
    return result.best_ckpt or result.last_ckpt, result.global_step, (time.perf_counter() - t0) / 60


def _rows(inputs: str, s, steps: int, minutes: float) -> list[dict]:
    """One row per scored source: joint RMS [mrad] at STEPS (1-based), approach-1 R² and FIT."""
    rows = []
    for source in s.preds:
        summary = s.summary(source)
        row = {"inputs": inputs, "predictor": source, "steps": steps if source == "model" else 0,
               "minutes": round(minutes, 1) if source == "model" else 0.0}
        row |= {f"joint_rms_mrad_step{k}": s.at(source, "joints", k) for k in _steps(s.y.shape[1])}
        row |= {"r2_a1": summary["r2"], "fit_a1": summary["fit"]}
        rows.append(row)
    return rows


def _score(inputs: str, ckpt: str, test: str, steps: int, minutes: float) -> list[dict]:
    predictor = Predictor.from_checkpoint(ckpt, device="cpu")
    info = predictor.data_info
    w = load_window(test, info["context_len"], info["horizon"], None, info, predictor.n_u, predictor.n_y, inputs=inputs)
    s = score_windows(predictor, w, ("hold", "nominal_physics", "true_physics"), _steps(w.horizon))
    if s.result["skipped_baselines"]:
        raise RuntimeError(f"baselines skipped: {s.result['skipped_baselines']}")
    return _rows(inputs, s, steps, minutes)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=1500, help="optimizer steps per formulation")
    p.add_argument("--max-minutes", type=float, default=12.0, help="wall-clock cap per formulation")
    p.add_argument("--robots", type=int, default=1500, help="training robots")
    p.add_argument("--held-out", type=int, default=128)
    p.add_argument("--val-subset", type=int, default=75, help="validation trajectories (fixed subset)")
    p.add_argument("--d-model", type=int, default=None, help="the model's width (default: train_cpu.yaml's)")
    p.add_argument("--n-layer", type=int, default=None, help="encoder and decoder depth (default: train_cpu.yaml's)")
    p.add_argument("--patch", type=int, default=None, help="steps per token (default: train_cpu.yaml's)")
    p.add_argument("--batch", type=int, default=None, help="trajectories per batch (default: train_cpu.yaml's)")
    p.add_argument("--context", type=int, default=200)
    p.add_argument("--horizon", type=int, default=800)
    p.add_argument("--trajectory-steps", type=int, default=1000, help="steps per generated trajectory")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="further fit settings, e.g. data.context_min=null (recorded in config.yaml)")
    p.add_argument("--out", default="data/formulations")
    p.add_argument("--csv", default="results/benchmarks/formulations.csv")
    args = p.parse_args(argv)
    check_outputs(out=args.out, csv=args.csv)
    print_provenance()
    torch.set_num_threads(os.cpu_count() or 2)
    os.makedirs(args.out, exist_ok=True)
    train, test = _data(args.out, args.robots, args.held_out, args.trajectory_steps)
    rows = []
    for inputs in ("total", "command"):
        ckpt, steps, minutes = _train(inputs, train, test, args)
        print(f"{inputs}: {steps} steps in {minutes:.1f} min -> {ckpt}", flush=True)
        rows += _score(inputs, ckpt, test, steps, minutes)
    write_rows(args.csv, rows)
    print(markdown_table(list(rows[0]), [list(r.values()) for r in rows]))

if __name__ == "__main__":
    # A refused result file (another header) or a bad setting: one line, exit code 2.
    sys.exit(run_command(main))
