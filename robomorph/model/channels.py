"""An arm's arrays in a multi-arm model's channel set: which columns they fill, padding, selection.

A model trained on stores of several arms (``ModelConfig.channel_mask``) carries the union
of their channels by role name (:mod:`robomorph.core.channels`). The :class:`Predictor`
takes an arm's own arrays (e.g. 6 torques and 13 outputs for a 7-joint model), pads them
with NaN, the absent mark the network reads, and returns the arm's outputs only.
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.core.channels import ChannelError, columns, is_identity

Columns = tuple[list[int], list[int]]


def arm_columns(masked: bool, info: dict | None, arrays, model_widths: tuple[int, int],
                names: tuple[list[str], list[str]] | None = None) -> Columns | None:
    """The model columns of the arrays' input and output channels, or None when the arrays
    carry the model's own channels (nothing to pad).

    Args:
        masked: the model reads absent channels (trained on several arms); without it the
            arrays must carry the model's channels and None is returned.
        info: the model's data record (its ``u_names``, ``y_names`` and training ``layouts``).
        arrays: ``(u_ctx, y_ctx, ...)`` as given (numpy, torch or nested lists).
        model_widths: the model's.
        names: the arrays' channel names; default the one training layout of their widths.

    Raises:
        ChannelError: names the model does not carry, or widths no training layout has and no
            names given (one line).
    """
    widths = _widths(arrays) if masked else None
    if widths is None:
        return None  # the Predictor's own shape checks name what is wrong
    info = info or {}
    model_u, model_y = info.get("u_names"), info.get("y_names")
    if names is None:
        if tuple(widths) == tuple(model_widths):
            return None
        found = [lay for lay in info.get("layouts", [])
                 if (len(lay["u_names"]), len(lay["y_names"])) == tuple(widths)]
        if len(found) != 1:
            raise ChannelError(
                f"the arrays have {widths[0]} input and {widths[1]} output channels, which "
                f"{'no' if not found else 'more than one'} layout this model was trained on has "
                f"({[(len(x['u_names']), len(x['y_names'])) for x in info.get('layouts', [])]}); name them: "
                "Predictor.channels = (u_names, y_names)")
        names = (found[0]["u_names"], found[0]["y_names"])
    if model_u is None or model_y is None:
        raise ChannelError("this model does not record its channel names, so it cannot map an arm's channels")
    cols = (columns(names[0], model_u, "inputs"), columns(names[1], model_y, "outputs"))
    if (len(cols[0]), len(cols[1])) != tuple(widths):
        raise ChannelError(f"Predictor.channels names {len(cols[0])} inputs and {len(cols[1])} outputs, "
                           f"the arrays have {widths[0]} and {widths[1]}")
    if is_identity(cols[0], model_widths[0]) and is_identity(cols[1], model_widths[1]):
        return None
    return cols


def _widths(arrays) -> tuple[int, int] | None:
    """Channel counts of ``(u_ctx, y_ctx, ...)``, or None for arrays without a channel axis."""
    try:
        return int(np.shape(arrays[0])[-1]), int(np.shape(arrays[1])[-1])
    except (IndexError, TypeError, ValueError):
        return None


def pad(tensors: list[torch.Tensor], cols: Columns, n_u: int, n_y: int) -> list[torch.Tensor]:
    """``[u_ctx, y_ctx, u_query]`` (B, T, arm channels) spread over the model's columns, NaN elsewhere."""
    out = []
    for t, c, width in zip(tensors, (cols[0], cols[1], cols[0]), (n_u, n_y, n_u)):
        full = torch.full(t.shape[:-1] + (width,), float("nan"), dtype=t.dtype, device=t.device)
        full[..., c] = t
        out.append(full)
    return out


def select(t: torch.Tensor | None, cols: Columns | None) -> torch.Tensor | None:
    """The arm's output columns of a prediction (B, Th, n_y); unchanged without ``cols``."""
    return t if t is None or cols is None else t[..., cols[1]]
