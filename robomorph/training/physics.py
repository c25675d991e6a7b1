"""Training the hybrid model's parameter head: which runs get one, its targets and its loss.

``--model.physics amortized`` gives the meta-model a parameter head
(:meth:`robomorph.model.transformer.MetaModel.forward_params`) trained against each robot's
stored physical parameters, in the unit coordinates of the training stores' randomization
ranges (:func:`robomorph.identification.backbone.parameter_layout`, recorded in the checkpoint so the
Predictor can simulate the robot it identifies). ``auto`` decides from the data.
"""

from __future__ import annotations

import math

import torch

from robomorph.identification.backbone import BackboneError
from robomorph.training.losses import ModelOptionError

# The parameter head's outputs: the Panda's identifiable parameters (robomorph.identification.backbone).
N_PHYSICAL = 29
TRAIN_PARAM_RMSE = "train/param_rmse"
PHYSICS = ("none", "amortized", "auto")


def check_physics(physics: str, param_weight: float, decoder_loss: bool) -> None:
    """Refuses physics settings that cannot work, naming the ``--model.`` flag."""
    if physics not in PHYSICS:
        raise ModelOptionError(f"--model.physics must be one of {PHYSICS}, got {physics!r}")
    if not param_weight > 0 or not isinstance(decoder_loss, bool):
        raise ModelOptionError("--model.param_weight must be > 0 and --model.decoder_loss true or false")


def physics_layout(dm) -> dict:
    """The parameter layout of the DataModule's stores, which must agree (one line otherwise).

    Raises:
        BackboneError: a store is not a simulated Panda store with params, or the stores'
            randomization ranges differ (the unit coordinates would mean different things).
    """
    from robomorph.identification.backbone import parameter_layout, same_layout  # noqa: PLC0415

    sources = dm.open_sources()
    layouts = [parameter_layout(src.attrs) for src in sources]
    for src, lay in zip(sources[1:], layouts[1:]):
        if not same_layout(layouts[0], lay):
            raise BackboneError(f"{src.path} randomizes the parameters over other ranges than {sources[0].path}: "
                                "train the parameter head on stores of one recipe's ranges")
    return layouts[0]


def resolve_physics(physics: str, dm, stage: str) -> tuple[bool, dict | None]:
    """Whether the run trains a parameter head, and the stores' parameter layout.

    ``auto`` trains one in the command formulation on stores that can have it, and otherwise
    says (at fit) why it trains the black-box model alone; the windows then carry each robot's
    parameters (:meth:`robomorph.data.windows.WindowDataset.add_params`).
    """
    if physics == "none":
        return False, None
    try:
        if physics == "auto" and getattr(dm, "inputs", "total") != "command":
            # Total torques pay gravity at the recorded state: a simulation diverges within
            # seconds even with the true parameters (docs: the hybrid model).
            raise BackboneError("the hybrid predicts in the command formulation (--data.inputs command)")
        layout = physics_layout(dm)
    except BackboneError as exc:
        if physics != "auto":
            raise
        if stage == "fit":
            why = str(exc).split(";")[0].replace("--model.physics needs", "the hybrid needs")
            print(f"note: --model.physics auto: {why}; training the black-box model alone")
        return False, None
    for name in ("train_set", "val_set", "test_set"):
        if getattr(dm, name, None) is not None:
            getattr(dm, name).add_params()
    return True, layout


def param_loss(net, layout: dict, batch: dict, uc: torch.Tensor, yc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The parameter head's Gaussian NLL and RMS error, in unit coordinates (the context only).

    Raises:
        BackboneError: the batch carries no parameters.
    """
    if "params" not in batch or layout is None:
        raise BackboneError("--model.physics amortized needs the robots' parameters in every batch: train on "
                            "simulated Panda stores that record params, or use --model.physics none")
    index = torch.as_tensor(layout["index"], device=uc.device)
    low = torch.as_tensor(layout["low"], device=uc.device, dtype=torch.float64)
    high = torch.as_tensor(layout["high"], device=uc.device, dtype=torch.float64)
    half = (high - low) / 2
    # A collapsed range is known exactly: its target is the middle (0).
    target = torch.where(half > 0, (batch["params"][:, index] - (low + high) / 2) / half.clamp_min(1e-12), 0.0)
    mean, logvar = net.forward_params(uc, yc)
    target = target.to(mean.dtype)
    nll = 0.5 * (logvar + (target - mean) ** 2 * torch.exp(-logvar) + math.log(2 * math.pi))
    return nll.mean(), ((target - mean) ** 2).mean().sqrt()
