"""``python -m robomorph.sweep`` (or ``robomorph sweep``): Optuna studies over fit().

``python -m robomorph.sweep summary ...`` prints (and writes) a study's table.
The door only; the machinery is :mod:`robomorph.tuning.runner` and :mod:`robomorph.tuning.summary`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import UsageError, run_command
from robomorph.core.names import check_plain_name
from robomorph.tuning import runner, summary
from robomorph.tuning.space import load_space
from robomorph.tuning.storage import open_storage


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.sweep", description=runner.__doc__.split("\n")[0],
                                epilog="python -m robomorph.sweep summary --help: the study's table")
    p.add_argument("space", help="search space: a YAML path or a shipped space's name, e.g. architecture_cpu")
    p.add_argument("--n-trials", type=int, required=True, help="finished trials the study should hold")
    p.add_argument("--storage", help="SQLAlchemy URL (default: sqlite:///results/sweeps/optuna.db)")
    p.add_argument("--study-name", help="default: the space's name")
    p.add_argument("--runs-dir", default="results/runs")
    p.add_argument("--wandb", default="offline", choices=("offline", "online", "disabled"))
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a fit() argument of every trial (over the base and the budget), e.g. --set "
                        "data.stores=data/ms.zarr, or a transfer setting, e.g. --set transfer.init_ckpt=CKPT "
                        "(repeatable)")
    p.add_argument("--heartbeat", type=int, default=60, help="seconds between a running trial's heartbeats")
    p.add_argument("--grace", type=int, default=180, help="seconds without heartbeat before a trial counts as dead")
    return p


def build_summary_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.sweep summary", description=summary.__doc__.split("\n")[0])
    p.add_argument("--study-name", required=True)
    p.add_argument("--storage", help="SQLAlchemy URL (default: sqlite:///results/sweeps/optuna.db)")
    p.add_argument("--out", help="folder for summary.md and trials.csv (default: <runs-dir>/<study>-summary)")
    p.add_argument("--runs-dir", help="where the study's runs are (default: read from its trials)")
    return p


def run(a: argparse.Namespace) -> int:
    if a.study_name is not None:
        check_plain_name(a.study_name, "--study-name")  # it names folders under --runs-dir
    if a.n_trials < 1:
        raise UsageError("--n-trials must be >= 1")
    space = runner.with_overrides(load_space(a.space), a.set)
    storage = open_storage(a.storage, a.heartbeat, a.grace)
    out = summary.summary_dir(a.runs_dir, a.study_name or space.name)
    # Before any trial runs: a folder holding another study's summary is refused now.
    summary.claim_summary_dir(out, a.study_name or space.name, a.storage)
    study = runner.run_sweep(space, a.n_trials, storage, a.study_name, a.runs_dir, a.wandb)
    print(summary.summarize(study, out))
    return 0


def run_summary(a: argparse.Namespace) -> int:
    check_plain_name(a.study_name, "--study-name")
    study = summary.load_study(a.study_name, a.storage)
    out = a.out or summary.summary_dir(a.runs_dir or summary.runs_dir_of(study), a.study_name)
    summary.claim_summary_dir(out, a.study_name, a.storage)
    print(summary.summarize(study, out))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["summary"]:
        args = build_summary_parser().parse_args(argv[1:])
        return run_command(lambda: run_summary(args))
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
