"""Checks a fit before anything is written or trained: each failure is one clear line.

Everything here runs after the command line is parsed and before the run directory, its
``config.yaml`` or a training step exist, so a refused fit changes nothing on disk (a
resumed run keeps its configuration and checkpoints as they were).
"""

from __future__ import annotations

import os

from robomorph.core.errors import RoboMorphError
from robomorph.inference.checkpoint import CheckpointError, load_checkpoint_file
from robomorph.model.files import read_model
from robomorph.training.module import check_context

# Hyper-parameters that fix the network's tensors: a resume must agree on all of them.
ARCHITECTURE = ("n_u", "n_y", "d_model", "n_head", "n_layer", "n_layer_dec", "bias", "patch",
                "max_context", "max_horizon", "n_params")


class FitError(RoboMorphError, ValueError):
    """A fit that cannot train as configured; the message names the flag to change."""


def check_budget(trainer) -> None:
    """Refuses a step budget that trains nothing (``max_steps 0``) or is meaningless."""
    steps = trainer.max_steps
    if steps == 0 or steps < -1:
        raise FitError(f"--trainer.max_steps {steps} trains nothing: give a positive number of optimizer steps "
                       "(or -1 with --trainer.max_epochs)")
    if trainer.max_epochs == 0:
        raise FitError("--trainer.max_epochs 0 trains nothing: give a positive number or leave it unset")


def check_windows(module, dm) -> None:
    """The network for the data's channels exists and the windows fit it (after ``dm.setup``).

    The context is checked by the module's own :func:`check_context` (also run by its
    constructor when ``context_len`` is linked from the data); here again for a context
    the datamodule only knows after ``setup`` (``context_frac``).
    """
    cfg = module.config_for(dm.n_u, dm.n_y)
    check_context(dm.context_len, cfg.patch, cfg.max_context)
    if dm.horizon > cfg.max_horizon:
        raise FitError(f"--data.horizon {dm.horizon} exceeds --model.max_horizon {cfg.max_horizon} (the positional "
                       f"table's length): raise --model.max_horizon to at least {dm.horizon}")


def check_resume(module, dm, ckpt_path: str) -> int:
    """The step of the checkpoint a run resumes from, refusing an unreadable or incompatible one.

    Raises:
        CheckpointError: the file is corrupt, or its architecture differs from this run's.
    """
    try:
        ckpt = load_checkpoint_file(ckpt_path)
    except CheckpointError as exc:
        fix = ("Remove that file to start the run afresh, or pass --ckpt_path with another checkpoint "
               "(e.g. the run's checkpoints/best.ckpt)") if os.path.isfile(ckpt_path) else "Check --ckpt_path"
        raise CheckpointError(f"cannot resume: {exc}. {fix}") from exc
    # Checkpoints from before the parameter head have no n_params: none (0).
    saved = {**ckpt["hyper_parameters"], "n_params": ckpt["hyper_parameters"].get("n_params") or 0}
    ours = {**{k: module.hparams.get(k) for k in ARCHITECTURE}, "n_u": dm.n_u, "n_y": dm.n_y,
            "n_params": module.hparams.get("n_params") or 0}
    differ = {k: (saved.get(k), ours[k]) for k in ARCHITECTURE if saved.get(k) != ours[k]}
    if differ:
        shown = ", ".join(f"{k} {a} -> {b}" for k, (a, b) in differ.items())
        raise CheckpointError(f"cannot resume from {ckpt_path}: its architecture differs ({shown}). Give the run "
                              "another --run name, or drop the changed --model flags to continue it")
    return int(ckpt.get("global_step", 0))


def check_init(module) -> None:
    """A transfer's ``init_ckpt`` is a readable checkpoint or model folder (its fit is checked when it loads)."""
    if module.hparams.get("init_ckpt"):
        read_model(module.hparams.init_ckpt)
