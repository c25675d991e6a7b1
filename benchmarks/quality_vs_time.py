"""Validation R^2 and FIT against wall-clock minutes of training, default CPU config.

Generates in-distribution multi-sine data (training robots, and a held-out store from
another seed), trains the default CPU model with ``robomorph.fit`` for ``--minutes`` of
wall-clock time (cosine schedule sized to that budget), records val R^2 / FIT (approach 1
mean, fixed validation subset) at every validation, and finally tests on the held-out
robots. Prints one line per validation and writes ``<out>/quality_vs_time.csv`` and
``<out>/quality_vs_time.png``.

    python benchmarks/quality_vs_time.py --minutes 60

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


def _data(out: str, robots: int, held_out: int) -> tuple[str, str]:
    train, test = os.path.join(out, "ms_train.zarr"), os.path.join(out, "ms_heldout.zarr")
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
    args = p.parse_args()
    torch.set_num_threads(os.cpu_count() or 2)
    os.makedirs(args.out, exist_ok=True)
    train, test = _data(args.out, args.robots, args.held_out)
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


if __name__ == "__main__":
    main()
