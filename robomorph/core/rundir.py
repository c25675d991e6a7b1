"""The layout of one training run, known in one place.

``python -m robomorph.fit`` writes, and evaluate, report, sweep and reproduce read::

    <runs_dir>/<run>/
      config.yaml              the resolved configuration
      checkpoints/last.ckpt    the latest state (resume point)
      checkpoints/best.ckpt    the lowest validation loss
      logs/metrics.csv         the CSV log (one column per log key)
      eval/<store>/            one evaluation per store (metrics.json, metrics.csv, table.md, plots)
      wandb/, wandb_id.txt     the wandb run and its id (so a resumed run continues it)
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class RunDir:
    """One run directory: every path of its layout, derived from ``path``."""

    path: str

    # Any of these makes a folder a run (a run may have been stopped before writing them all).
    MARKERS = ("config.yaml", "logs", "checkpoints", "eval")

    @classmethod
    def named(cls, runs_dir: str | os.PathLike, run: str) -> RunDir:
        """The run ``run`` under ``runs_dir``."""
        return cls(os.path.join(os.fspath(runs_dir), run))

    @classmethod
    def of_checkpoint(cls, ckpt: str | os.PathLike) -> RunDir:
        """The run a checkpoint belongs to: ``<run>/checkpoints/<name>.ckpt`` -> ``<run>``."""
        return cls(os.path.dirname(os.path.dirname(os.path.abspath(os.fspath(ckpt)))))

    @property
    def name(self) -> str:
        return os.path.basename(os.path.normpath(self.path))

    @property
    def config(self) -> str:
        return os.path.join(self.path, "config.yaml")

    @property
    def checkpoints(self) -> str:
        return os.path.join(self.path, "checkpoints")

    @property
    def last_ckpt(self) -> str:
        return os.path.join(self.checkpoints, "last.ckpt")

    @property
    def best_ckpt(self) -> str:
        return os.path.join(self.checkpoints, "best.ckpt")

    @property
    def logs(self) -> str:
        return os.path.join(self.path, "logs")

    @property
    def metrics_csv(self) -> str:
        return os.path.join(self.logs, "metrics.csv")

    @property
    def evals(self) -> str:
        return os.path.join(self.path, "eval")

    def eval_dir(self, store: str | os.PathLike) -> str:
        """``eval/<name>``, where a store path ``data/x.zarr`` gives the name ``x``."""
        name = os.path.basename(os.path.normpath(os.fspath(store))).removesuffix(".zarr")
        return os.path.join(self.evals, name)

    @property
    def wandb(self) -> str:
        return os.path.join(self.path, "wandb")

    @property
    def wandb_id(self) -> str:
        return os.path.join(self.path, "wandb_id.txt")

    def file(self, name: str) -> str:
        """Another file at the top of the run (e.g. a caller's marker)."""
        return os.path.join(self.path, name)

    def looks_like_run(self) -> bool:
        """True when the folder holds any part of the layout."""
        return any(os.path.exists(os.path.join(self.path, m)) for m in self.MARKERS)
