"""Channel sets by role name: one model for stores of different joint counts.

A store names its channels by role (``tau0..tau{n-1}``; ``ee_x .. ee_qw, q0..q{n-1}``), so a
6-joint arm's channels are a subset of a 7-joint arm's. A model trained on several arms
carries the union of their channels; a store with fewer joints fills only its own columns
and the model is told which are absent (:mod:`robomorph.model.transformer`, ``channel_mask``).
Torch-free: the DataModule, the model, the Predictor and evaluation share these rules.
"""

from __future__ import annotations

from collections.abc import Sequence

from robomorph.core.errors import RoboMorphError


class ChannelError(RoboMorphError, ValueError):
    """Channel names a model (or a run's channel set) cannot map onto its own."""


def union(name_lists: Sequence[Sequence[str]]) -> list[str]:
    """The channels of all lists, by name: the longest list's order, then the names the
    others add in their own order (so a 6-joint arm's names add nothing to a 7-joint arm's,
    and the union of two such arms is the 7-joint layout, column for column)."""
    if not name_lists:
        return []
    longest = max(range(len(name_lists)), key=lambda k: (len(name_lists[k]), -k))
    out = list(name_lists[longest])
    seen = set(out)
    for names in name_lists:
        for name in names:
            if name not in seen:
                out.append(name)
                seen.add(name)
    return out


def columns(names: Sequence[str], model_names: Sequence[str], what: str, source: str = "the arrays") -> list[int]:
    """The column of each of ``names`` in ``model_names``.

    Raises:
        ChannelError: a name the model does not carry, or one given twice (one line,
            naming them and the model's channels).
    """
    index = {n: i for i, n in enumerate(model_names)}
    unknown = [n for n in names if n not in index]
    if unknown:
        raise ChannelError(f"{source} have {what} {list(unknown)} that the model cannot map: it carries "
                           f"{list(model_names)}; train a model on these channels (or transfer one with "
                           "--model.init_ckpt and --model.reinit_io true)")
    if len(set(names)) != len(names):
        raise ChannelError(f"{source} name a {what} channel twice: {list(names)}")
    return [index[n] for n in names]


def is_identity(cols: Sequence[int], width: int) -> bool:
    """True when ``cols`` are all ``width`` columns in order (nothing to pad)."""
    return list(cols) == list(range(width))


def pad_columns(x, cols: Sequence[int], width: int):
    """``x (..., len(cols))`` spread over ``width`` columns: column ``cols[j]`` holds ``x[..., j]``,
    the others are NaN, the mark of an absent channel that the model reads
    (:class:`robomorph.model.transformer.MetaModel` with ``channel_mask``) and the loss skips."""
    import numpy as np  # noqa: PLC0415  (core stays import-light)

    out = np.full(x.shape[:-1] + (width,), np.nan, dtype=x.dtype)
    out[..., list(cols)] = x
    return out


# Role names whose numbered channels hold one kind of quantity (the simulator's and ingest's layouts).
KIND_STEMS = ("tau", "cmd", "q")


def channel_kind(name: str) -> str:
    """The kind of quantity a channel holds, by its role name: channels of one kind share units and a
    typical spread (``tau0..tau6`` torques, ``cmd0..`` commands, ``q0..q6`` joint angles,
    ``ee_x ee_y ee_z`` the EE position, ``ee_qx .. ee_qw`` its quaternion). Any other name (a log's own
    column names, ``u0``, ``y1``) is a kind of its own: nothing says two such columns share units."""
    if name.startswith("ee_q"):
        return "ee_quaternion"
    if name in ("ee_x", "ee_y", "ee_z"):
        return "ee_position"
    stem = name.rstrip("0123456789")
    return stem if stem in KIND_STEMS and stem != name else name
