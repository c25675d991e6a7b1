"""Accuracy of the physics step: the same robots and torques at several substep counts.

Each setting simulates the same randomized robots (same seed, same torques held per 60 Hz
frame) and is compared with a fine reference (``--ref`` substeps). Prints, per setting,
the RMS and max error of EE position [mm] and joint angles [mrad] over the trajectory,
the fraction of robots whose validity verdict differs from the reference, and the speed.

    python benchmarks/substeps.py [--task multisine] [--robots 16] [--ref 64]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import print_provenance

from robomorph.sim import episode, filters, panda
from robomorph.sim.open_loop import OpenLoopEngine
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import load_recipe, replace


def simulate(recipe, robots: int) -> tuple[np.ndarray, list, float]:
    """Frame-rate sensor data (robots, T, nsens), verdicts and seconds for one setting."""
    model = episode.build_model(recipe)
    rnd = Randomizer(model, recipe.randomization)
    draws = [episode.draw(recipe, rnd, i) for i in range(robots)]
    with OpenLoopEngine(model, 2, recipe.substeps) as eng:
        t0 = time.perf_counter()
        sens, ranges = eng.run(lambda m, i: rnd.apply(m, draws[i].params),
                               np.stack([d.qpos0 for d in draws]), np.stack([d.ctrl for d in draws]))
        elapsed = time.perf_counter() - t0
        verdicts = [filters.check(s, jr[:7], recipe.filters) for s, jr in zip(sens, ranges)]
        frames = sens[:, :: recipe.substeps].copy()
    return frames, verdicts, elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="multisine")
    p.add_argument("--robots", type=int, default=16)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--ref", type=int, default=64)
    p.add_argument("--substeps", default="2,4,8,16")
    args = p.parse_args()
    print_provenance()
    base = load_recipe(f"datamodules/{args.task}.yaml", {"steps": args.steps})
    ref, ref_verdicts, _ = simulate(replace(base, substeps=args.ref), args.robots)
    print(f"task={args.task} robots={args.robots} steps={args.steps} reference substeps={args.ref}")
    print("substeps  dt_phys_ms  ee_rms_mm  ee_max_mm  q_rms_mrad  q_max_mrad  verdict_changed  traj/s")
    for n in (int(x) for x in args.substeps.split(",")):
        frames, verdicts, elapsed = simulate(replace(base, substeps=n), args.robots)
        ee = np.linalg.norm(frames[..., panda.SENS_EE_POS] - ref[..., panda.SENS_EE_POS], axis=-1) * 1e3
        dq = np.abs(frames[..., panda.SENS_QPOS] - ref[..., panda.SENS_QPOS]) * 1e3
        changed = np.mean([a != b for a, b in zip(verdicts, ref_verdicts)])
        print(f"{n:8d}  {base.dt / n * 1e3:10.3f}  {np.sqrt(np.mean(ee**2)):9.3f}  {ee.max():9.3f}  "
              f"{np.sqrt(np.mean(dq**2)):10.3f}  {dq.max():10.3f}  {changed:15.2f}  {args.robots / elapsed:6.1f}")


if __name__ == "__main__":
    main()
