"""Validation R^2 and FIT against wall-clock minutes of training, default CPU config.

Generates in-distribution multi-sine data (training robots, and a held-out store from
another seed), trains the default CPU model with ``robomorph.fit`` for ``--minutes`` of
wall-clock time (cosine schedule sized to that budget), records val R^2 / FIT (approach 1
mean, fixed validation subset) at every validation, and finally tests on the held-out
robots. Prints one line per validation and writes ``<out>/quality_vs_time.csv`` and
``<out>/quality_vs_time.png``.

Then it scores the best checkpoint on the held-out robots with ``robomorph.evaluate``'s
functions: the approach-1 R² over the 800 predicted steps and the RMS errors by horizon in
physical units (joints [mrad], end-effector position [mm] and orientation [mrad] at the
first step, 0.25 s, 1 s, 5 s and the end) for the model and ``hold``, once with windows
from the trajectory start (the paper's) and once from random offsets (seeded, with a
shorter horizon so the windows have room to move). It prints both tables and appends one
row to ``<out>/quality_horizons_start.csv`` and ``<out>/quality_horizons_random.csv`` (the
ablation table's columns: name, minutes, steps, R², per-quantity errors of model and hold).

    python benchmarks/quality_vs_time.py --minutes 60
    python benchmarks/quality_vs_time.py --eval-ckpt data/quality/runs/x/checkpoints/best.ckpt --name x

Goal: mean R^2 >= 0.8 (approach 1) within 60 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import csv
import os
import time

import lightning.pytorch as L
import torch

from robomorph.data.generation import generate
from robomorph.sim.recipe import load_recipe
from robomorph.training.fitting import fit


class QualityLog(L.Callback):
    """Appends (minutes, step, val/r2, val/fit, val/loss) at every validation."""

    def __init__(self, path: str):
        self.path, self.t0 = path, None

    def on_train_start(self, trainer, pl_module):
        self.t0 = time.perf_counter()
        with open(self.path, "w", newline="") as f:
            csv.writer(f).writerow(["minutes", "step", "val_r2", "val_fit", "val_loss"])

    def on_validation_end(self, trainer, pl_module):
        if self.t0 is None or trainer.sanity_checking:
            return
        m = trainer.callback_metrics
        row = [(time.perf_counter() - self.t0) / 60, trainer.global_step,
               float(m["val/r2"]), float(m["val/fit"]), float(m["val/loss"])]
        with open(self.path, "a", newline="") as f:
            csv.writer(f).writerow(row)
        print(f"{row[0]:6.1f} min  step {row[1]:6d}  val/r2 {row[2]:.4f}  val/fit {row[3]:6.2f}  "
              f"val/loss {row[4]:.4f}", flush=True)


def _data(out: str, robots: int, held_out: int, train_too: bool = True) -> tuple[str, str]:
    train, test = os.path.join(out, "ms_train.zarr"), os.path.join(out, "ms_heldout.zarr")
    if train_too:
        generate(load_recipe("datamodules/multisine.yaml", {"robots": robots, "seed": 0}), train, progress=True)
    generate(load_recipe("datamodules/multisine.yaml", {"robots": held_out, "seed": 1}), test, progress=True)
    return train, test


def _plot(csv_path: str, png: str) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
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
                  offset: str, horizon: int, seed: int = 0) -> dict:
    """Evaluates ``ckpt`` beside ``hold`` (context 200), prints the per-horizon table and
    appends a row to ``<out>/quality_horizons_<offset>.csv``."""
    from robomorph.evaluation.evaluator import evaluate  # noqa: PLC0415
    from robomorph.evaluation.horizons import horizon_markdown  # noqa: PLC0415

    res = evaluate(ckpt, test, os.path.join(out, "eval", f"{name}-{offset}"), context_len=200, horizon=horizon,
                   baselines=("hold",), samples=0, offset=offset, seed=seed)
    h, r2 = res["horizons"], res["approach1"]["mean"]["r2"]["mean"]
    r2_hold = res["baselines"]["hold"]["approach1"]["mean"]["r2"]["mean"]
    where = "the trajectory start" if offset == "start" else f"random offsets (seed {seed})"
    print(f"\n{name}: held-out robots, windows from {where} (context 200, horizon {horizon}): "
          f"approach-1 R² model {r2:.4f}, hold {r2_hold:.4f}")
    print(horizon_markdown(h, ("model", "hold")))
    row = {"name": name, "minutes": minutes, "global_step": step, "offset": offset, "horizon": horizon,
           "r2_model": r2, "r2_hold": r2_hold}
    for q, info in h["quantities"].items():
        for src in ("model", "hold"):
            row.update({f"{q}_{src}_step{k}_{info['unit']}": v for k, v in zip(h["steps"], h["rms"][src][q])})
        row[f"{q}_below_hold_fraction"] = h["below_hold"][q]["fraction"]
    path = os.path.join(out, f"quality_horizons_{offset}.csv")  # one file per window kind: same columns
    new = not os.path.exists(path)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(row))
        if new:
            w.writeheader()
        w.writerow(row)
    return res


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=60)
    p.add_argument("--robots", type=int, default=4000, help="training robots")
    p.add_argument("--held-out", type=int, default=256)
    p.add_argument("--out", default="data/quality")
    p.add_argument("--sec-per-step", type=float, default=0.17,
                   help="expected seconds per step, sizes the cosine schedule (measured: benchmarks/train.py)")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--patch", type=int, default=10, help="steps per token (1 = token reduction off)")
    p.add_argument("--anchor", action="store_true", help="predict the deviation from the last context output")
    p.add_argument("--name", default="quality_vs_time", help="run name and output file stem")
    p.add_argument("--offset-horizon", type=int, default=300,
                   help="predicted steps of the random-offset evaluation (1000-step trajectories: 200 + 800 "
                        "leave no room to move)")
    p.add_argument("--eval-ckpt", help="skip training: only score this checkpoint on the held-out robots")
    args = p.parse_args()
    torch.set_num_threads(os.cpu_count() or 2)
    os.makedirs(args.out, exist_ok=True)
    train, test = _data(args.out, args.robots, args.held_out, train_too=not args.eval_ckpt)
    if args.eval_ckpt:
        ckpt, minutes, step = args.eval_ckpt, None, None
    else:
        ckpt, minutes, step = _train(args, train, test)
    score_heldout(ckpt, test, args.out, args.name, minutes, step, "start", 800)
    score_heldout(ckpt, test, args.out, args.name, minutes, step, "random", args.offset_horizon)


def _train(args, train: str, test: str) -> tuple[str, float, int]:
    log = os.path.join(args.out, f"{args.name}.csv")
    steps = int(args.minutes * 60 / args.sec_per_step)
    result = fit({
        "data": {"stores": train, "test_store": test, "split": [0.95, 0.05, 0.0], "context_len": 200,
                 "horizon": 800, "batch_size": args.batch, "val_subset": 200, "recenter": True},
        "model": {"decay_steps": steps, "warmup_steps": min(500, steps // 10), "patch": args.patch, "anchor": args.anchor},
        "trainer": {"max_steps": 10 * steps, "max_time": {"seconds": int(args.minutes * 60)},
                    "val_check_interval": max(20, min(500, steps // 12)),
                    "enable_progress_bar": False},
        "run": args.name, "runs_dir": os.path.join(args.out, "runs"), "wandb": "disabled",
    }, callbacks=[QualityLog(log)])
    print(f"run: {result.run_dir}  steps: {result.global_step}")
    _plot(log, os.path.join(args.out, f"{args.name}.png"))
    trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False)
    from robomorph.data.datamodule import RoboMorphDataModule  # noqa: PLC0415
    from robomorph.training.module import MetaModule  # noqa: PLC0415

    dm = RoboMorphDataModule(stores=train, test_store=test, split=(0.95, 0.05, 0.0), context_len=200, horizon=800,
                             batch_size=64, recenter=True)
    module = MetaModule.load_from_checkpoint(result.best_ckpt, map_location="cpu", init_ckpt=None)
    out = trainer.test(module, datamodule=dm, verbose=False)[0]
    print(f"held-out robots (seed 1, {args.held_out}): test/r2 {out['test/r2']:.4f}  test/fit {out['test/fit']:.2f}")
    return result.best_ckpt, args.minutes, result.global_step


if __name__ == "__main__":
    main()
