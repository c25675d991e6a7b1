"""``python -m robomorph.priors`` (or ``robomorph priors``): the hybrid's predictions over windows of a
store, written as a prior store that a residual model trains on.

The door only; the machinery is :mod:`robomorph.evaluation.priors`, the store's layout
:mod:`robomorph.data.priors`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.config import yaml_value
from robomorph.core.errors import run_command
from robomorph.core.options import add_alias
from robomorph.data.priors import PriorError
from robomorph.evaluation import priors


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.priors", description=priors.__doc__.split("\n")[0])
    p.add_argument("store", help="source store (simulated, with commands u_cmd and its recipe)")
    p.add_argument("--out", required=True, help="the prior store to write (resumed when left in progress)")
    p.add_argument("--context-len", type=int, default=200, help="context steps of each window")
    p.add_argument("--horizon", type=int, default=300, help="query steps the prior predicts")
    p.add_argument("--offsets", default="0",
                   help="comma list of each trajectory's window starts (e.g. 0,300: two windows per trajectory)")
    p.add_argument("--n", type=int, help="at most this many source trajectories (default: all)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a hybrid setting (HybridSettings field, value read as YAML) over Predictor.from_arm's, "
                        "which has payload, coulomb and denoise on (repeatable; e.g. --set workers=16)")
    p.add_argument("--batch-size", type=int, default=16, help="windows per batch (written together)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store at --out")
    # Their names before every command agreed on one name per meaning (core.options.VOCABULARY): one release.
    add_alias(p, "--context", "--context-len")
    add_alias(p, "--batch", "--batch-size")
    return p


def parse_settings(items: list[str]) -> dict:
    """``NAME=VALUE`` items: changes of ``Predictor.from_arm``'s hybrid settings."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise PriorError(f"--set takes NAME=VALUE (a HybridSettings field), got {item!r}")
        out[name.strip()] = yaml_value(value, f"--set {name.strip()}")
    return out


def parse_offsets(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise PriorError(f"--offsets takes a comma list of steps, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    req = priors.PriorRequest(args.store, args.out, args.context_len, args.horizon, parse_offsets(args.offsets), args.n,
                              tuple(parse_settings(args.set).items()), args.batch_size, args.overwrite)
    record = priors.write_priors(req)
    print(f"{args.out}: priors of {record['settings']} over {record['source_n']} trajectories x "
          f"{len(record['offsets'])} windows (context {record['context']}, horizon {record['horizon']})")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
