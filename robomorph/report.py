"""``python -m robomorph.report`` (or ``robomorph report``): the static HTML dashboard over runs and evaluations.

The door only; the machinery is :mod:`robomorph.reporting.dashboard`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.reporting import dashboard


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m robomorph.report", description=dashboard.__doc__.splitlines()[0])
    parser.add_argument("runs_dir", nargs="?", default="results/runs", help="folder of run directories (default: %(default)s)")
    parser.add_argument("--out", help="HTML file to write (default: <runs_dir>/../report.html)")
    parser.add_argument("--title", default="RoboMorph training report", help="page title")
    parser.add_argument("--control", help="a robomorph control output folder to show (default: <runs_dir>/../control "
                                          "when it holds a metrics.json)")
    return parser


def run(args: argparse.Namespace) -> int:
    import os  # noqa: PLC0415

    control = args.control or os.path.join(os.path.dirname(os.path.abspath(args.runs_dir)), "control")
    if args.control and not os.path.isfile(os.path.join(args.control, "metrics.json")):
        from robomorph.reporting.dashboard import ReportError  # noqa: PLC0415

        raise ReportError(f"--control {args.control} holds no metrics.json: run robomorph control --out {args.control}")
    print(dashboard.build_report(args.runs_dir, args.out or dashboard.default_out(args.runs_dir), args.title, control))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
