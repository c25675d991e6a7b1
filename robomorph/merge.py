"""``python -m robomorph.merge`` (or ``robomorph merge``): shards of one generation into one store.

The door only; the machinery is :mod:`robomorph.data.merging`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.data import merging


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.merge", description=merging.__doc__.split("\n")[0])
    p.add_argument("parts", nargs="+", help="shard stores (complete)")
    p.add_argument("--out", required=True)
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--allow-partial", action="store_true",
                   help="merge a subset of the shards into a store marked partial (default: every shard is required)")
    return p


def run(args: argparse.Namespace) -> int:
    attrs = merging.merge(args.parts, args.out, args.overwrite, allow_partial=args.allow_partial)
    print(f"{args.out}: {attrs['n']} trajectories from {len(args.parts)} shards"
          + (f" (partial: shards {attrs['missing_shards']} missing)" if attrs.get("partial") else ""))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
