"""Checkpoints and training logs that are never half-written (:mod:`robomorph.core.atomic`)."""

from __future__ import annotations

import csv
import os
from typing import Any

from lightning.pytorch.loggers import CSVLogger
from lightning.pytorch.plugins.io import TorchCheckpointIO

from robomorph.core.atomic import atomic_open, write_bytes
from robomorph.model.files import load_checkpoint_file, save_torch


class AtomicCheckpointIO(TorchCheckpointIO):
    """``torch.save`` through the atomic writer: a crash mid-save leaves the previous
    checkpoint intact instead of a truncated file. Reading (a resume's ``ckpt_path``) goes
    through the package's one reader, which runs nothing stored in the file."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: str, storage_options: Any | None = None) -> None:
        save_torch(checkpoint, path)

    def load_checkpoint(self, path, map_location: Any = None, weights_only: bool | None = None) -> dict[str, Any]:
        # Whatever Lightning or the environment (TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD) asks for,
        # a resume reads tensors and plain values only.
        return load_checkpoint_file(str(path))


class ResumableCSVLogger(CSVLogger):
    """A CSV log that a resumed run extends instead of rewriting.

    Lightning's writer deletes an existing ``metrics.csv`` when it starts and rebuilds the
    header from the keys logged since; a resumed run would lose its history. This keeps
    the rows and the header, and the writer appends after them.
    """

    @property
    def experiment(self):
        if self._experiment is not None:
            return self._experiment
        path = os.path.join(self.log_dir, "metrics.csv")
        kept = open(path, "rb").read() if os.path.isfile(path) else b""
        exp = super().experiment
        if kept:
            write_bytes(exp.metrics_file_path, kept)
            with open(exp.metrics_file_path, newline="") as f:
                exp.metrics_keys = sorted(next(csv.reader(f), []))
        return exp


def prune_log(path: str, from_step: int) -> None:
    """Drops rows logged at ``step >= from_step`` (a killed run may have logged past its
    last checkpoint; the resumed run logs those steps again)."""
    if not os.path.isfile(path):
        return
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames or [], list(reader)
    kept = [r for r in rows if not r.get("step") or int(float(r["step"])) < from_step]
    if len(kept) == len(rows):
        return
    with atomic_open(path) as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(kept)
