"""``make demo``: the main job end to end on a small built-in default.

Generates a small dataset of every task (multi-sine, chirp, OSC circle, OSC spiral) with
the recipes in ``datamodules/``, prints each summary and draws its trajectories. Re-running
skips datasets that are already complete.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from robomorph.data.store import open_store
from robomorph.generate import generate
from robomorph.inspect import plot, summarize
from robomorph.recipe import load_recipe

TASKS = ("multisine", "chirp", "circle", "spiral")


def run(out_dir: str = "data/demo", robots: int = 32, steps: int = 1000, workers: int | None = None) -> list[str]:
    """Generates, summarizes and plots one small dataset per task; returns the store paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for task in TASKS:
        recipe = load_recipe(f"datamodules/{task}.yaml", {"robots": robots, "steps": steps})
        path = os.path.join(out_dir, f"{task}.zarr")
        t0 = time.time()
        generate(recipe, path, workers=workers, overwrite=_stale(path, recipe))
        ds = open_store(path)
        print(f"\n=== {task}: {time.time() - t0:.1f} s ===")
        print(summarize(ds))
        png = os.path.join(out_dir, f"{task}.png")
        plot(ds, png, n_traj=3)
        print(f"plots: {png}")
        paths.append(path)
    return paths


def _stale(path: str, recipe) -> bool:
    """A demo store from another recipe (e.g. an older version) is replaced, not refused."""
    try:
        return open_store(path, allow_incomplete=True).attrs.get("config") != recipe.to_dict()
    except Exception:  # noqa: BLE001  (missing or unreadable: nothing to keep)
        return False


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m robomorph.demo", description=__doc__.split("\n")[0])
    p.add_argument("--out-dir", default="data/demo")
    p.add_argument("--robots", type=int, default=32)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--workers", type=int, default=None)
    args = p.parse_args(argv)
    paths = run(args.out_dir, args.robots, args.steps, args.workers)
    print(f"\ndemo datasets: {', '.join(paths)}")
    print("next: training arrives with `python -m robomorph.fit` (see README)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
