"""What the benchmark scripts share: the repository's paths, the CPU training recipe with
``--set`` overrides, the check of their outputs, and the provenance line of printed results.

The scripts run as ``python benchmarks/<name>.py`` from anywhere (this folder is then on
``sys.path``); scoring is :func:`robomorph.evaluation.scoring.score_windows` and result
files are written by :mod:`robomorph.core.results`.
"""

from __future__ import annotations

import os

import yaml

from robomorph.core.atomic import check_outside_stores, check_replaceable
from robomorph.core.config import yaml_value
from robomorph.core.overrides import merge, unflatten
from robomorph.core.results import provenance, provenance_markdown

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRAIN_CPU = os.path.join(REPO, "datamodules", "train_cpu.yaml")
MULTISINE = os.path.join(REPO, "datamodules", "multisine.yaml")


def parse_sets(items: list[str] | None) -> dict:
    """``["model.d_model=32", "trainer.val_check_interval=2"]`` (values read as YAML) as a nested dict."""
    flat = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"error: --set takes KEY=VALUE (e.g. model.d_model=64), got {item!r}")
        flat[key.strip()] = yaml_value(value, f"--set {key.strip()}")
    return unflatten(flat)


def train_cpu_config(*overrides: dict) -> dict:
    """``datamodules/train_cpu.yaml`` with ``overrides`` merged in, in order (later ones win)."""
    with open(TRAIN_CPU) as f:
        cfg = yaml.safe_load(f)
    for o in overrides:
        cfg = merge(cfg, o)
    return cfg


def print_provenance() -> None:
    """The provenance line (command, commit, date, machine) first in a benchmark's printed output."""
    print(provenance_markdown(provenance()), flush=True)


def check_outputs(**paths: str | None) -> None:
    """Refuses, before a script's work, an output that is not its own: a Markdown or CSV file (``md=``, ``csv=``,
    ``latency_csv=``) that is no earlier result file (a checkpoint, a page, notes) or lies inside a Zarr store, a
    folder (any other name: ``work=``, ``out=``) that is or lies inside a store. Each name is the option without
    its dashes, or ``<option>__md`` / ``<option>__csv`` where the option's name does not say; None is skipped. The writers check the files again when they write them."""
    for name, path in paths.items():
        if not path:
            continue
        # The kind comes from the option, never from the name given: --md victim.ckpt is a Markdown output.
        # ``out__md=``: the option --out, a Markdown file (a script whose --out names its table).
        option, _, kind = name.partition("__")
        flag, kind = "--" + option.replace("_", "-"), kind or option.rsplit("_", 1)[-1]
        if kind in ("md", "csv"):
            check_replaceable(path, "markdown" if kind == "md" else "csv", flag)
        else:
            check_outside_stores(path, flag, may_be_store=False)
