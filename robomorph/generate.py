"""``python -m robomorph.generate`` (or ``robomorph generate``): randomized robot trajectories into a Zarr store.

The door only; the machinery is :mod:`robomorph.data.generation`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.core.names import GRAVITY_MODES
from robomorph.data import generation
from robomorph.sim import arms
from robomorph.sim.recipe import load_recipe


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.generate", description=generation.__doc__.split("\n")[0])
    p.add_argument("--config", help="recipe: a shipped name (multisine, chirp, circle, spiral, mixture) or a YAML "
                   "path; flags override its fields")
    p.add_argument("--robot", choices=arms.names(), help="the simulated arm (default: the recipe's, panda)")
    p.add_argument("--task", help="multisine | chirp | circle | spiral")
    p.add_argument("--robots", type=int, help="valid trajectories to keep")
    p.add_argument("--steps", type=int, help="samples per trajectory")
    p.add_argument("--seed", type=int, help="root seed")
    p.add_argument("--substeps", type=int, help="physics steps per sample")
    p.add_argument("--gravity-compensation", choices=list(GRAVITY_MODES))
    p.add_argument("--out", required=True, help="output store directory (e.g. data/ms.zarr)")
    p.add_argument("--workers", type=int, default=None, help="threads/processes (default: all cores)")
    p.add_argument("--shard", default="0/1", help="generate part i of n (e.g. 0/4); see README")
    p.add_argument("--overwrite", action="store_true", help="replace an existing RoboMorph store")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def run(args: argparse.Namespace) -> int:
    recipe = load_recipe(args.config, {
        "robot": args.robot, "task": args.task, "robots": args.robots, "steps": args.steps, "seed": args.seed,
        "substeps": args.substeps, "gravity_compensation": args.gravity_compensation,
    })
    shard = generation.Shard.parse(args.shard)
    attrs = generation.generate(recipe, args.out, args.workers, shard, args.overwrite, not args.quiet)
    rate = attrs["kept"] / max(attrs["attempted"], 1)
    rejected = {k: v for k, v in attrs["rejected"].items() if v}
    print(f"{args.out}: {attrs['n']} trajectories x {recipe.steps} steps ({attrs['task']}), "
          f"on the {attrs['domain']}, kept {attrs['kept']} of {attrs['attempted']} attempts ({rate:.1%}), rejected {rejected}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args), kept=f"{args.out} keeps every trajectory written before it (the store "
                                               "records where it stopped): run the same command again to resume")


if __name__ == "__main__":
    sys.exit(main())
