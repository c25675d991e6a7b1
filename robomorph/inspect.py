"""``python -m robomorph.inspect`` (or ``robomorph inspect``): what a store holds: counts, channels, ranges, plots.

The door only; the machinery is :mod:`robomorph.data.summary`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.core.options import add_alias
from robomorph.data import summary
from robomorph.data.store import StoreDamagedError, open_store


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.inspect", description=summary.__doc__.split("\n")[0])
    p.add_argument("store", help="dataset directory (e.g. data/ms.zarr)")
    p.add_argument("--plot", metavar="OUT.png", help="write trajectories to OUT.png, parameters to OUT_params.png")
    p.add_argument("--plot-trajectories", type=int, default=3, help="trajectories to plot (default: 3)")
    p.add_argument("--allow-incomplete", action="store_true", help="inspect the valid rows of an unfinished store")
    add_alias(p, "--n-traj", "--plot-trajectories")  # its name before core.options.VOCABULARY: one release
    return p


def run(args: argparse.Namespace) -> int:
    ds = open_store(args.store, allow_incomplete=args.allow_incomplete)
    print(summary.summarize(ds))
    damage = ds.describe_damage(decode=True)
    if damage:
        raise StoreDamagedError(damage)
    if args.plot:
        for path in summary.plot(ds, args.plot, args.plot_trajectories):
            print(f"wrote {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
