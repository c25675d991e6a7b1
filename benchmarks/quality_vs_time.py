"""Validation R^2 and FIT against wall-clock minutes of training, the default CPU recipe.

Measures ``datamodules/train_cpu.yaml`` as it is: generates in-distribution multi-sine data
(training robots, and a held-out store from another seed), trains with ``robomorph.fit
--config datamodules/train_cpu.yaml`` (its model, data windows and learning-rate schedule;
only the stores, the split and ``--set`` overrides are added, and all of it is recorded in
the run's ``config.yaml``) until ``trainer.max_steps`` or ``--minutes`` of wall clock,
records val R^2 / FIT (approach 1 mean, fixed validation subset) at every validation, and
writes ``<out>/<name>.csv`` and ``<out>/<name>.png``.

Then it scores the best checkpoint on the held-out robots with ``robomorph.evaluate`` (one
scoring path: :func:`robomorph.evaluation.scoring.score_windows`): approach-1 R² over the
predicted steps and the RMS errors by horizon in physical units (joints [mrad], end-effector
position [mm] and orientation [mrad] at steps 1, 15, 60, 300 and the end: first step,
0.25 s, 1 s, 5 s; step k is k dt after the last context sample) for the model and ``hold``,
once with windows from the trajectory start (the paper's) and once from random offsets
(seeded, with a shorter horizon so the windows have room to move). It prints both tables and
appends one row to ``<out>/quality_horizons_start.csv`` and ``<out>/quality_horizons_random.csv``.

    python benchmarks/quality_vs_time.py --minutes 60
    python benchmarks/quality_vs_time.py --eval-ckpt data/quality/runs/x/checkpoints/best.ckpt --name x

Goal: mean R^2 >= 0.8 (approach 1) within 60 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import lightning.pytorch as L
import torch
from common import MULTISINE, parse_sets, print_provenance, train_cpu_config

from robomorph.core.errors import run_command
from robomorph.core.results import ResultsCsv, read_rows
from robomorph.data.generation import generate
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit


class QualityLog(L.Callback):
    """Appends (minutes, step, val/r2, val/fit, val/loss) at every validation."""

    def __init__(self, path: str):
        self.path, self.t0, self.rows = path, None, None

    def on_train_start(self, trainer, pl_module):
        self.t0, self.rows = time.perf_counter(), ResultsCsv(self.path, overwrite=True)

    def on_validation_end(self, trainer, pl_module):
        if self.t0 is None or trainer.sanity_checking:
            return
        m = trainer.callback_metrics
        row = {"minutes": (time.perf_counter() - self.t0) / 60, "step": trainer.global_step,
               "val_r2": float(m["val/r2"]), "val_fit": float(m["val/fit"]), "val_loss": float(m["val/loss"])}
        self.rows.append(row)
        print(f"{row['minutes']:6.1f} min  step {row['step']:6d}  val/r2 {row['val_r2']:.4f}  "
              f"val/fit {row['val_fit']:6.2f}  val/loss {row['val_loss']:.4f}", flush=True)


def _data(out: str, robots: int, held_out: int, steps: int, train_too: bool = True) -> tuple[str, str]:
    train, test = os.path.join(out, "ms_train.zarr"), os.path.join(out, "ms_heldout.zarr")
    if train_too:
        generate(load_recipe(MULTISINE, {"robots": robots, "seed": 0, "steps": steps}), train, progress=True)
    generate(load_recipe(MULTISINE, {"robots": held_out, "seed": 1, "steps": steps}), test, progress=True)
    return train, test


def _plot(csv_path: str, png: str) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    rows = read_rows(csv_path)
    t = [float(r["minutes"]) for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.5))
    ax[0].plot(t, [float(r["val_r2"]) for r in rows], marker="o")
    ax[0].axhline(0.8, ls="--", c="gray", label="goal 0.8")
    ax[0].axhline(0.793, ls=":", c="r", label="paper, 12 layers (0.793)")
    ax[0].set(xlabel="wall-clock minutes (2 CPU cores)", ylabel="val R² (approach 1)")
    ax[0].legend()
    ax[1].plot(t, [float(r["val_fit"]) for r in rows], marker="o")
    ax[1].set(xlabel="wall-clock minutes (2 CPU cores)", ylabel="val FIT [%]")
    fig.tight_layout()
    fig.savefig(png, dpi=120)


def score_heldout(ckpt: str, test: str, out: str, name: str, minutes: float | None, step: int | None,
                  offset: str, horizon: int, context: int = 200, seed: int = 0) -> dict:
    """Evaluates ``ckpt`` beside ``hold``, prints the per-horizon table and appends a row to
    ``<out>/quality_horizons_<offset>.csv``."""
    from robomorph.evaluation.evaluator import evaluate  # noqa: PLC0415
    from robomorph.evaluation.horizons import horizon_markdown  # noqa: PLC0415
    from robomorph.evaluation.requests import EvaluateConfig  # noqa: PLC0415

    res = evaluate(EvaluateConfig(data=test, ckpt=ckpt, out=os.path.join(out, "eval", f"{name}-{offset}"),
                                  context_len=context, horizon=horizon, baselines=("hold",), samples=0, offset=offset,
                                  seed=seed))
    h, r2 = res["horizons"], res["approach1"]["mean"]["r2"]["mean"]
    r2_hold = res["baselines"]["hold"]["approach1"]["mean"]["r2"]["mean"]
    where = "the trajectory start" if offset == "start" else f"random offsets (seed {seed})"
    print(f"\n{name}: held-out robots, windows from {where} (context {context}, horizon {horizon}): "
          f"approach-1 R² model {r2:.4f}, hold {r2_hold:.4f}")
    print(horizon_markdown(h, ("model", "hold")))
    row = {"name": name, "minutes": minutes, "global_step": step, "offset": offset, "horizon": horizon,
           "r2_model": r2, "r2_hold": r2_hold}
    for q, info in h["quantities"].items():
        for src in ("model", "hold"):
            row.update({f"{q}_{src}_step{k}_{info['unit']}": v for k, v in zip(h["steps"], h["rms"][src][q])})
        row[f"{q}_below_hold_fraction"] = h["below"]["hold"][q]["fraction"]
    ResultsCsv(os.path.join(out, f"quality_horizons_{offset}.csv")).append(row)  # one file per window kind
    return res


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=60, help="wall-clock cap (trainer.max_time)")
    p.add_argument("--robots", type=int, default=4000, help="training robots")
    p.add_argument("--held-out", type=int, default=256)
    p.add_argument("--trajectory-steps", type=int, default=1000, help="steps per generated trajectory")
    p.add_argument("--out", default="data/quality")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="overrides of train_cpu.yaml, e.g. trainer.max_steps=5000 (recorded in config.yaml)")
    p.add_argument("--name", default="quality_vs_time", help="run name and output file stem")
    p.add_argument("--offset-horizon", type=int, default=300,
                   help="predicted steps of the random-offset evaluation (1000-step trajectories: 200 + 800 "
                        "leave no room to move)")
    p.add_argument("--eval-ckpt", help="skip training: only score this checkpoint on the held-out robots")
    args = p.parse_args(argv)
    print_provenance()
    torch.set_num_threads(os.cpu_count() or 2)
    os.makedirs(args.out, exist_ok=True)
    train, test = _data(args.out, args.robots, args.held_out, args.trajectory_steps, train_too=not args.eval_ckpt)
    cfg = _config(args, train, test)
    if args.eval_ckpt:
        ckpt, minutes, step = args.eval_ckpt, None, None
    else:
        ckpt, minutes, step = _train(args, cfg)
    context, horizon = cfg["data"]["context_len"], cfg["data"]["horizon"]
    score_heldout(ckpt, test, args.out, args.name, minutes, step, "start", horizon, context)
    score_heldout(ckpt, test, args.out, args.name, minutes, step, "random", args.offset_horizon, context)


def _config(args, train: str, test: str) -> dict:
    """train_cpu.yaml with this benchmark's stores, split, time cap and ``--set`` overrides."""
    s = int(args.minutes * 60)
    cfg = train_cpu_config({"data": {"stores": train, "test_store": test, "split": [0.95, 0.05, 0.0]},
                            "trainer": {"max_time": f"{s // 86400:02d}:{s % 86400 // 3600:02d}:{s % 3600 // 60:02d}:"
                                                    f"{s % 60:02d}", "enable_progress_bar": False}},
                           parse_sets(args.set))
    return {**cfg, "run": args.name, "runs_dir": os.path.join(args.out, "runs"), "wandb": "disabled"}


def _train(args, cfg: dict) -> tuple[str, float, int]:
    log = os.path.join(args.out, f"{args.name}.csv")
    t0 = time.perf_counter()
    result = fit(cfg, callbacks=[QualityLog(log)])
    print(f"run: {result.run_dir}  steps: {result.global_step}")
    _plot(log, os.path.join(args.out, f"{args.name}.png"))
    return result.best_ckpt or result.last_ckpt, round((time.perf_counter() - t0) / 60, 1), result.global_step


if __name__ == "__main__":
    # A refused result file (another header) or a bad setting: one line, exit code 2.
    sys.exit(run_command(main))
