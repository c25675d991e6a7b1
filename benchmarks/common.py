"""What the benchmark scripts share: the repository's paths, the CPU training recipe with
``--set`` overrides, and the provenance line of printed results.

The scripts run as ``python benchmarks/<name>.py`` from anywhere (this folder is then on
``sys.path``); scoring is :func:`robomorph.evaluation.scoring.score_windows` and result
files are written by :mod:`robomorph.core.results`.
"""

from __future__ import annotations

import os

import yaml

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
