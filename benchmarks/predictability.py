"""How far can the arm be followed? Replays of stored robots in both input formulations.

For each gravity mode, a store of multi-sine robots is generated (or reused) under
``--data``; each robot is re-simulated with its own parameters (redrawn exactly from its
attempt index, so nothing but the stored inputs is rounded) in each input formulation:

* ``total``: the recorded total joint torque ``u`` (signal + g(q) of the recorded state),
  held over each frame, as the paper's model input has it;
* ``command``: the recorded command ``u_cmd``, on an arm that adds its gravity compensation
  at its current state (how the data were made, and how a torque-controlled arm behaves).

Each replay starts from the exact initial state, and again from that state perturbed by
``--delta`` rad on every joint (seeded random signs). Printed per mode and formulation:
the max joint error against the stored trajectory at 50, 200, 400 and 800 steps (median
and max over robots) for both starts, and the e-folding time of the perturbation: the
perturbed replay against the exact-start one, log of the median error fitted linearly
over the steps before it reaches 1e-2 rad; fewer than one e-fold over that span is
reported as "no growth". The last two lines give, per formulation, the shortest
e-folding time over the gravity modes (``inf`` when nothing grows).

    python benchmarks/predictability.py [--robots 8] [--modes true_model,nominal_model,none]

The ``none`` mode (no gravity compensation at all) keeps no robot at the default recipe:
the arm falls onto the floor; it is reported as skipped (there ``u_cmd`` equals ``u``).
"""

from __future__ import annotations

import argparse
import math
import os

import numpy as np
from common import print_provenance

from robomorph.core.config import from_dict
from robomorph.data.generation import GenerationError
from robomorph.data.store import open_store
from robomorph.evaluation.physics import NominalPhysics
from robomorph.reproduction.skip import ensure_store
from robomorph.sim import episode
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import Recipe, load_recipe

HORIZONS = (50, 200, 400, 800)
SATURATION = 1e-2  # rad: beyond this the error stops growing exponentially (joint limits, wrap)


def make_store(mode: str, args) -> str | None:
    """The store of ``mode`` (generated once), or None when the recipe keeps no robot."""
    recipe = load_recipe("datamodules/multisine.yaml", {
        "robots": args.robots, "steps": args.steps, "seed": args.seed, "gravity_compensation": mode,
        "chunk": min(64, args.robots)})
    path = os.path.join(args.data, f"{mode}.zarr")
    try:
        ensure_store(recipe, path, workers=args.workers, progress=False, need_command=True)
    except GenerationError as exc:
        print(f"mode={mode}: skipped, no store: {str(exc).split(';')[0]}")
        return None
    return path


def replays(path: str, inputs: str, delta: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint trajectories (N, T, 7): stored, replayed from the exact start, from the perturbed start."""
    ds = open_store(path)
    recipe = from_dict(Recipe, ds.attrs["config"], "store config")
    sim = NominalPhysics(ds.attrs, inputs=inputs)
    rnd = Randomizer(episode.build_model(recipe), recipe.randomization)
    torque, y, attempts = ds.read_inputs(inputs), ds.read("y"), ds.read("attempt")
    rng = np.random.default_rng(seed)
    exact, perturbed = [], []
    for i, attempt in enumerate(attempts):
        draw = episode.draw(recipe, rnd, int(attempt))  # float64 parameters and start, as generated
        offset = delta * rng.choice([-1.0, 1.0], size=draw.qpos0.shape)
        exact.append(sim.rollout(torque[i], draw.qpos0, params=draw.params)[:, 7:])
        perturbed.append(sim.rollout(torque[i], draw.qpos0 + offset, params=draw.params)[:, 7:])
    return y[..., 7:].astype(np.float64), np.array(exact, np.float64), np.array(perturbed, np.float64)


def efolding_steps(err: np.ndarray, floor: float) -> float:
    """Steps per e-fold of a median error curve (T,), ``inf`` when it grows less than e-fold."""
    t = np.arange(len(err))
    ok = (t >= 1) & (err < SATURATION) & (err > 0)
    if np.any(err >= SATURATION):  # fit only up to the first saturation
        ok &= t < np.argmax(err >= SATURATION)
    if ok.sum() < 10:
        return math.nan
    slope = np.polyfit(t[ok], np.log(err[ok]), 1)[0]
    grown = np.log(max(err[t >= 1].max(), floor) / floor)
    return float(1.0 / slope) if slope > 0 and grown > 1.0 else math.inf


def report(mode: str, inputs: str, stored, exact, perturbed, delta: float) -> float:
    """Prints one block; returns the e-folding time in steps."""
    def at(e: np.ndarray, h: int) -> str:
        col = e[:, h]
        return f"{np.median(col):9.2e} / {col.max():8.2e}"

    e_exact = np.abs(exact - stored).max(axis=-1)  # (N, T) max joint error
    e_pert = np.abs(perturbed - stored).max(axis=-1)
    growth = np.median(np.abs(perturbed - exact).max(axis=-1), axis=0)
    efold = efolding_steps(growth, delta)
    steps = [h for h in HORIZONS if h < stored.shape[1]]
    print(f"mode={mode} inputs={inputs} robots={len(stored)}: max joint error [rad], median / max over robots")
    print("  start      " + "".join(f"{'step ' + str(h):>22s}" for h in steps))
    for name, e in (("exact", e_exact), (f"+{delta:g} rad", e_pert)):
        print(f"  {name:10s} " + "".join(f"{at(e, h):>22s}" for h in steps))
    text = "no growth" if math.isinf(efold) else f"{efold:.1f} steps ({efold / 60:.2f} s at 60 Hz)"
    print(f"  e-folding time of the {delta:g} rad perturbation: {text}")
    return efold


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", type=int, default=8)
    p.add_argument("--steps", type=int, default=1000, help="samples per trajectory (> 800)")
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--modes", default="true_model,nominal_model,none")
    p.add_argument("--delta", type=float, default=1e-6, help="initial perturbation [rad]")
    p.add_argument("--data", default="data/predictability", help="where the stores go (gitignored)")
    p.add_argument("--workers", type=int, default=None)
    args = p.parse_args()
    print_provenance()
    worst = {"total": math.inf, "command": math.inf}
    for mode in args.modes.split(","):
        path = make_store(mode, args)
        if path is None:
            continue
        for inputs in ("total", "command"):
            stored, exact, perturbed = replays(path, inputs, args.delta, args.seed)
            efold = report(mode, inputs, stored, exact, perturbed, args.delta)
            worst[inputs] = min(worst[inputs], efold)
    print(f"efold_steps_total={worst['total']:.1f}" if math.isfinite(worst["total"]) else "efold_steps_total=inf")
    print(f"efold_steps_command={worst['command']:.1f}" if math.isfinite(worst["command"]) else "efold_steps_command=inf")


if __name__ == "__main__":
    main()
