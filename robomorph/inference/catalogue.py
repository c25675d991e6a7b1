"""A prediction with no training: the hybrid of a catalogue arm, with no network at all.

    from robomorph import Predictor
    pred = Predictor.from_arm("panda")                       # seconds; reads no checkpoint
    y_query, std = pred.simulate(u_ctx, y_ctx, u_query, return_std=True, at_rest=True)

In the command formulation the hybrid's default mode, ``regression``, identifies the robot
from the context by linear solves of its inverse dynamics, pulled toward the catalogue arm,
and simulates it over the horizon (:mod:`robomorph.inference.hybrid`): it never reads the network
of the checkpoint it comes from. So a Predictor built from the arm's catalogue model and a
generator recipe alone predicts exactly what a trained command-formulation hybrid predicts in
that mode, the same to the bit (a test checks it against a trained checkpoint).

What it cannot do, because there is no network: the modes that read one (``learned`` and
``fused``: a parameter head; ``blend`` and ``smoothed``: the decoder; ``none``: the decoder
alone) are refused with one line. Its standard deviation is the raw spread over robots
around the estimate, with no calibration (``robomorph calibrate`` fits one on a trained
checkpoint; :attr:`Predictor.calibration` is None here). There are no training statistics,
so the range check of :attr:`Predictor.max_input_std` is off: check the torques' units
yourself (N m, the command without gravity compensation).

Every registered arm has a catalogue physics backbone (:func:`robomorph.identification.backbone.parameter_layout`).
``inputs="total"`` takes the total joint torque a real arm's sensors log, gravity included (with the
recipe's ``gravity_compensation="none"``).
"""

from __future__ import annotations

import dataclasses

import torch

from robomorph.core.errors import RoboMorphError

# The modes that read no network.
NETWORK_FREE_MODES = ("regression", "refined")


class NoNetworkError(RoboMorphError, ValueError):
    """A prediction that needs a trained network, asked of a Predictor built from the arm alone."""


@dataclasses.dataclass(frozen=True)
class _Config:
    n_u: int
    n_y: int
    patch: int = 1
    n_params: int = 0
    channel_mask: bool = False


@dataclasses.dataclass(frozen=True)
class _Normalizer:
    normalization: str = "train_stats"


class NoNetwork:
    """What a :class:`robomorph.inference.predictor.Predictor` holds in place of a trained model when there is none:
    the channel counts, no calibrations and no blend; anything that would run a network says so instead."""

    gaussian = False
    blend = None
    network_free_modes = NETWORK_FREE_MODES  # the Predictor refuses the others (check_network_free)

    def __init__(self, n_u: int, n_y: int) -> None:
        self.config = _Config(n_u, n_y)
        self.normalizer = _Normalizer()
        self.calibrations: dict = {}

    def to(self, device) -> NoNetwork:
        return self

    def eval(self) -> NoNetwork:
        return self

    def forward_dist_raw(self, *args, **kwargs) -> tuple[torch.Tensor, torch.Tensor]:
        # Never reached through a Predictor (check_network_free refuses first): a direct call says why.
        raise NoNetworkError("this model was built from the arm alone (Predictor.from_arm), with no network: "
                             f"predict with physics_mode {' or '.join(map(repr, NETWORK_FREE_MODES))}")


def arm_record(arm: str = "panda", recipe: str | None = None, inputs: str = "command", **overrides) -> dict:
    """The data record a hybrid of ``arm`` would carry, from its catalogue and a recipe.

    Args:
        arm: a name of :data:`robomorph.sim.arms.ARMS`.
        recipe: a generator recipe (a shipped name such as ``multisine`` or a YAML path; default the
            generator's defaults), whose physics step, gravity compensation and randomization ranges
            the backbone uses, as a store generated with it records them.
        inputs: ``command`` (the torque the arm is sent; it compensates its own gravity as the
            recipe says) or ``total`` (the joint torque a torque sensor measures, gravity
            included: a real arm's log, with the recipe's ``gravity_compensation: none``).
        overrides: recipe fields changed (``dt=...``, ``substeps=...``).

    Raises:
        NoNetworkError: an arm that is not registered.
    """
    from robomorph.core.inputs import check_inputs  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.identification.backbone import parameter_layout  # noqa: PLC0415
    from robomorph.sim.randomize import param_names  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    if arm not in arms.ARMS:
        raise NoNetworkError(f"unknown arm {arm!r}: a prediction with no training needs a registered arm's catalogue "
                             f"model; choose one of {', '.join(arms.names())}")
    rec = load_recipe(recipe, {"robot": arm, **overrides})
    spec = rec.arm
    attrs = {"domain": spec.name, "config": rec.to_dict(), "param_names": param_names(spec.name)}
    # As a model trained today records it (robomorph.training.module): the observer, the springs and the debiasing on.
    physics = {**parameter_layout(attrs), "mode": "catalogue", "observer": True, "springs": True, "debias": True}
    return {"u_names": list(spec.u_names), "y_names": list(spec.y_names), "dt": float(rec.dt),
            "inputs": check_inputs(inputs),
            "stores": [], "physics": physics, "arm": spec.name}



def check_network_free(predictor) -> None:
    """Refuses, in one line, a physics mode that reads a network, asked of a Predictor that has none
    (called by :func:`robomorph.inference.predictor_checks.check_settings` before anything runs)."""
    free = getattr(predictor.model, "network_free_modes", None)
    if free is not None and predictor.physics_mode not in free:
        raise NoNetworkError(f"physics mode {predictor.physics_mode!r} reads a trained network, and this Predictor "
                             f"was built from the arm alone (Predictor.from_arm): use {' or '.join(map(repr, free))}, "
                             "or load a trained checkpoint (Predictor.from_checkpoint)")


def from_arm(cls, arm: str = "panda", recipe: str | None = None, device=None, inputs: str = "command", **overrides):
    """:meth:`robomorph.inference.predictor.Predictor.from_arm`: a ``cls`` (the Predictor) with no network.

    Args:
        arm: a name of :data:`robomorph.sim.arms.ARMS`.
        recipe: the generator recipe whose physics step, gravity compensation and randomization ranges the
            data follow (a shipped name such as ``multisine`` or a YAML path; default the generator's defaults).
        device: where tensors are returned (the simulation runs on the CPU).
        inputs: ``command`` or ``total`` (see :func:`arm_record`).
        overrides: recipe fields changed, e.g. ``dt=0.01``.

    Raises:
        NoNetworkError: an arm that is not registered.
    """
    info = arm_record(arm, recipe, inputs, **overrides)
    pred = cls(NoNetwork(len(info["u_names"]), len(info["y_names"])), device, info)
    # The record a trained command hybrid carries, set here: a model without a parameter head takes no
    # backbone from its record (Predictor.__init__), and this one has no model at all.
    pred.physics, pred.physics_mode, pred.has_std = info["physics"], "regression", True
    pred.physics_observer = pred.physics_springs = pred.physics_debias = True
    pred.max_input_std = None  # no training statistics to compare the inputs with
    return pred
