"""Generation throughput: the full pipeline against a bare ``mujoco.rollout`` of the same physics.

Runs in one process, on the same randomized models, initial states and torques:
  1. ``robomorph.data.generation.generate`` (draw, randomize, roll out, filter, write Zarr);
  2. bare ``mujoco.rollout`` (threaded, as the pipeline calls it) over exactly the attempts the pipeline simulated;
then the OSC (closed-loop, worker processes) pipeline, and peak memory.

    python benchmarks/generate.py [--robots 256] [--osc-robots 32] [--workers N]

The last line is ``ratio_vs_raw_rollout=<float>`` (pipeline / raw, open-loop; goal >= 0.8).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import tempfile
import time

import numpy as np
from common import print_provenance

from robomorph.data.generation import generate
from robomorph.sim import episode
from robomorph.sim.open_loop import OpenLoopEngine, ThreadedRollout
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import load_recipe


def _raw_rollout(recipe, n_attempts: int, workers: int) -> float:
    """Seconds for mujoco.rollout alone on the pipeline's attempts (setup not timed)."""
    model = episode.build_model(recipe)
    rnd = Randomizer(model, recipe.randomization)
    elapsed = 0.0
    # The bare rollout gets one model per trajectory of a chunk (its natural use), and
    # only the rollout call is timed: no drawing, randomizing, filtering or writing.
    with OpenLoopEngine(model, workers, recipe.substeps, group=recipe.chunk) as eng:
        threaded = ThreadedRollout(model, workers)
        for start in range(0, n_attempts, recipe.chunk):
            draws = [episode.draw(recipe, rnd, i) for i in range(start, min(start + recipe.chunk, n_attempts))]
            models = eng.models[: len(draws)]
            for m, d in zip(models, draws):
                rnd.apply(m, d.params)
            x0 = np.stack([eng.initial_state(m, d.qpos0) for m, d in zip(models, draws)])
            ctrl = np.repeat(np.stack([d.ctrl for d in draws]), recipe.substeps, axis=1)
            t0 = time.perf_counter()
            threaded(models, x0, ctrl)
            elapsed += time.perf_counter() - t0
        threaded.close()
    return elapsed


def _pipeline(task: str, robots: int, workers: int, steps: int) -> tuple[float, int, dict]:
    recipe = load_recipe(f"datamodules/{task}.yaml", {"robots": robots, "steps": steps})
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        attrs = generate(recipe, os.path.join(tmp, f"{task}.zarr"), workers=workers, progress=False)
        elapsed = time.perf_counter() - t0
    simulated = math.ceil(attrs["attempted"] / recipe.chunk) * recipe.chunk  # whole batches run
    return elapsed, simulated, attrs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", type=int, default=256)
    p.add_argument("--osc-robots", type=int, default=32)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--workers", type=int, default=os.cpu_count())
    args = p.parse_args()
    print_provenance()
    print(f"cores={os.cpu_count()} workers={args.workers} steps={args.steps}")

    elapsed, simulated, attrs = _pipeline("multisine", args.robots, args.workers, args.steps)
    pipe_rate = simulated / elapsed
    print(f"pipeline multisine: {simulated} attempts in {elapsed:.2f} s = {pipe_rate:.2f} traj/s "
          f"(kept {attrs['kept']}/{attrs['attempted']})")
    # High-water mark of the pipeline alone, before the baseline allocates its own models.
    print(f"peak_rss_pipeline_mb={resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}")
    recipe = load_recipe("datamodules/multisine.yaml", {"robots": args.robots, "steps": args.steps})
    raw = _raw_rollout(recipe, simulated, args.workers)
    raw_rate = simulated / raw
    print(f"raw mujoco.rollout: {simulated} attempts in {raw:.2f} s = {raw_rate:.2f} traj/s")

    for task in ("circle", "spiral"):
        elapsed, simulated, attrs = _pipeline(task, args.osc_robots, args.workers, args.steps)
        print(f"pipeline {task} (OSC, {args.workers} processes): {simulated / elapsed:.2f} traj/s "
              f"(kept {attrs['kept']}/{attrs['attempted']})")

    print(f"ratio_vs_raw_rollout={pipe_rate / raw_rate:.3f}")


if __name__ == "__main__":
    sys.exit(main())
