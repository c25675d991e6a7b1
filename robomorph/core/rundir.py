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

from robomorph.core.errors import RoboMorphError
from robomorph.core.names import check_plain_name


class RunDirError(RoboMorphError, ValueError):
    """A run folder whose state cannot be used as it is (e.g. a damaged resume point)."""


@dataclass(frozen=True)
class RunDir:
    """One run directory: every path of its layout, derived from ``path``."""

    path: str

    # Any of these makes a folder a run (a run may have been stopped before writing them all).
    MARKERS = ("config.yaml", "logs", "checkpoints", "eval")

    @classmethod
    def named(cls, runs_dir: str | os.PathLike, run: str) -> RunDir:
        """The run ``run`` under ``runs_dir``; ``run`` must be a plain name (never a path)."""
        return cls(os.path.join(os.fspath(runs_dir), check_plain_name(run, "run name")))

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
        """``eval/<name>``, where a store path ``data/x.zarr`` gives the name ``x``.

        Always a folder directly inside ``eval/``: the name comes from the store's absolute
        path (so ``..`` or ``x/..`` name the folder they point to, not ``eval/..``), and a
        name that is empty or starts with a dot becomes ``store``.
        """
        name = os.path.basename(os.path.abspath(os.fspath(store))).removesuffix(".zarr")
        return os.path.join(self.evals, name if name and not name.startswith(".") else "store")

    def check_resume_point(self) -> None:
        """Raises when ``checkpoints/last.ckpt`` is there but is no readable file.

        Without this a folder (or a dangling link) in its place reads as "no checkpoint":
        the run restarts at step 0, appends duplicate rows to its log, then fails to save.
        Whether a readable file is a valid checkpoint is the checkpoint loader's to judge.
        """
        last = self.last_ckpt
        if not os.path.lexists(last):
            return
        fix = (f"delete it to start this run again from step 0, or pass a fresh --run (the resume point of "
               f"{self.path} is damaged)")
        if os.path.isdir(last):
            raise RunDirError(f"{last} is a folder, not a checkpoint: {fix}")
        try:
            with open(last, "rb") as f:
                f.read(1)
        except OSError as exc:
            raise RunDirError(f"{last} cannot be read ({exc.strerror or exc}): {fix}") from exc

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
