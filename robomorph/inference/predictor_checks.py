"""What :meth:`robomorph.inference.predictor.Predictor.simulate` checks before it predicts.

Every array it is given (shapes, lengths, batch sizes, finite values, and how far inputs and
context outputs lie from the training data), the range limit, and a mode that needs a network
asked of a Predictor without one (the hybrid's settings are checked whole where they are set,
:class:`robomorph.inference.settings.HybridSettings`). Anything else would predict from the wrong
thing without a word: a context output in millimetres instead of metres, a query of zero steps
answered with one, ``members = 0`` read as 1. Each refusal is a :class:`PredictionError` naming
the array or setting.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from robomorph.core.errors import RoboMorphError


class PredictionError(RoboMorphError, ValueError):
    """Inputs the model cannot predict from (wrong shape or length, non-finite, far outside
    the training range, or overflowing)."""


# How far (in training standard deviations of each channel) inputs and context outputs may
# lie from the training mean before simulate refuses them. Measured on a multi-sine model:
# its own data reach 5.2, a chirp store (another task, a legitimate transfer) 19, and torques
# in the wrong units (x1000, N m given as mN m) thousands. 100 lets every transfer through and
# stops unit errors, which otherwise return plausible-looking numbers.
MAX_INPUT_STDS = 100.0

_NAMES = ("u_ctx", "y_ctx", "u_query")

# The fewest context samples a hybrid identifies a robot from: its regression reads accelerations, second
# differences of the joint angles, so 2 samples leave it no equation at all (numpy's "zero-size array to
# reduction operation maximum" was all a user saw) and 1 no velocity.
MIN_HYBRID_CONTEXT = 3


def all_finite(t: torch.Tensor) -> bool:
    """Whether every value of ``t`` is finite. A finite sum says so at once (a NaN or inf
    anywhere makes the sum non-finite); only a non-finite sum (that, or an overflow of huge
    values) takes the elementwise test, which torch runs far slower on the CPU (measured:
    8.7 ms against 0.04 ms for 256 contexts of 200 x 14 values, on a busy 2-core machine)."""
    return bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())


def as_batch(arrays, widths: tuple[int, int, int], device: torch.device) -> tuple[list[torch.Tensor], bool]:
    """``(u_ctx, y_ctx, u_query)``, numpy or torch, as float32 tensors (B, T, C) on ``device``,
    and whether they came unbatched (T, C).

    Raises:
        PredictionError: arrays not all batched or all unbatched, channel counts other than
            ``widths``, batches of different sizes or none, an empty context or query,
            contexts of inputs and outputs of different lengths, or NaN / inf values (each named).
    """
    tensors = [torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x,
                               dtype=torch.float32, device=device) for x in arrays]
    single = tensors[0].dim() == 2
    if any(t.dim() != (2 if single else 3) for t in tensors):
        raise PredictionError("give all three arrays unbatched (T, C) or all batched (B, T, C)")
    if single:
        tensors = [t.unsqueeze(0) for t in tensors]
    sizes = [t.shape[0] for t in tensors]
    if len(set(sizes)) != 1 or sizes[0] == 0:
        raise PredictionError(f"u_ctx, y_ctx and u_query hold {sizes[0]}, {sizes[1]} and {sizes[2]} windows: give "
                              "each the same number of windows, at least one")
    for name, t, width in zip(_NAMES, tensors, widths):
        if t.shape[-1] != width:
            raise PredictionError(f"{name} has {t.shape[-1]} channels, the model expects {width}")
        if t.shape[1] == 0:
            raise PredictionError(f"{name} has no time steps: give at least one "
                                  f"({'context' if 'ctx' in name else 'query'} sample)")
        if not all_finite(t):
            raise PredictionError(f"{name} holds NaN or inf values")
    if tensors[0].shape[1] != tensors[1].shape[1]:
        raise PredictionError(f"u_ctx has {tensors[0].shape[1]} steps but y_ctx {tensors[1].shape[1]}: the context's "
                              "inputs and outputs are one record, of one length")
    return tensors, single


def check_hybrid_context(steps: int) -> None:
    """Refuses a context too short for the hybrid to identify a robot from (:data:`MIN_HYBRID_CONTEXT`)."""
    if steps < MIN_HYBRID_CONTEXT:
        raise PredictionError(f"u_ctx has {steps} step{'s' * (steps != 1)}: the hybrid identifies the robot from the "
                              f"context's accelerations, which take at least {MIN_HYBRID_CONTEXT} samples (it is "
                              "measured on contexts of hundreds); give a longer context")


def check_range(predictor, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor) -> None:
    """Refuses inputs or context outputs far outside the training range (wrong units, most often)."""
    limits = getattr(predictor, "limits", None)
    if limits is not None:  # a catalogue arm's limits (Predictor.from_arm, which has no training statistics)
        limits.check(u_ctx, y_ctx, u_query, predictor.data_info or {})
    if predictor.max_input_std is None:
        return
    stats = predictor.model.normalizer
    info = predictor.data_info or {}
    for arrays, mean, std, what, names in (
            ((u_ctx, u_query), stats.u_mean, stats.u_std, "inputs", info.get("u_names")),
            ((y_ctx,), stats.y_mean, stats.y_std, "context outputs", info.get("y_names"))):
        # The furthest sample per channel from each channel's extremes (a planner's batch is large: no array-wide ops).
        ends = [torch.aminmax(a.reshape(-1, a.shape[-1]), dim=0) for a in arrays]
        z = torch.stack([torch.maximum((hi - mean).abs(), (lo - mean).abs()) / std for lo, hi in ends])
        z = torch.nan_to_num(z, nan=0.0).amax(0)  # the furthest sample per channel (absent channels: NaN)
        worst = int(torch.argmax(z))
        if float(z[worst]) > predictor.max_input_std:
            label = names[worst] if names and worst < len(names) else f"{what[0]}{worst}"
            raise PredictionError(
                f"the {what} reach {float(z[worst]):.3g} training standard deviations (channel {label!r}), "
                f"far outside the training range (refused above {predictor.max_input_std:g}); check their units and "
                "scale (the checkpoint expects the training data's), or set Predictor.max_input_std")


def check_settings(predictor) -> None:
    """Refuses a setting of the Predictor that it cannot predict with (each named, with what it takes)."""
    from robomorph.inference.catalogue import check_network_free  # noqa: PLC0415

    # (the hybrid's settings are validated whole when set: robomorph.inference.settings.HybridSettings)
    check_network_free(predictor)  # a Predictor of a catalogue arm alone (Predictor.from_arm)
    limit = predictor.max_input_std
    if limit is not None and not (isinstance(limit, (int, float)) and math.isfinite(limit) and limit > 0):
        raise PredictionError(f"max_input_std must be None or a finite number > 0, got {limit!r}")
    limits = getattr(predictor, "limits", None)
    if limits is not None and not hasattr(limits, "check"):
        raise PredictionError(f"limits must be None or a catalogue arm's ArmLimits, got {type(limits).__name__}")


def model_arms(predictor) -> list[str]:
    """The arms a model was trained on (store ``domain`` names), or [] where it does not say
    (checkpoints written before it was recorded, real logs without a registered arm). A
    hybrid's backbone is the robot of its generator recipe (the Panda where it names none)."""
    arms = list((predictor.data_info or {}).get("arms") or [])
    if not arms and predictor.physics:
        arms = [str(((predictor.physics or {}).get("recipe") or {}).get("robot") or "panda")]
    return arms

