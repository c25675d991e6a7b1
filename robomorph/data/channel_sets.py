"""The channel set of a training run over stores of different arms (joint counts).

Stores name their channels by role, so an arm with fewer joints has a subset of another
arm's channels. The run's channel set is the widest training store's (or the set given
as ``channels``); every store must map into it by name. A store with fewer channels gets
a layout (:attr:`robomorph.data.sources.Source.layout`): its windows are padded to the
set's width with NaN in the absent columns, which the model reads as a mask and the loss
skips. Statistics are per channel role: each column's come from the stores that have it.
"""

from __future__ import annotations

import math

from robomorph.core.channels import columns, is_identity
from robomorph.data.sources import DataError, Source
from robomorph.data.statistics import StatsAccumulator


def channel_set(sources: list[Source], n_train: int, channels: dict | None = None) -> tuple[list[str], list[str]]:
    """The run's ``(u_names, y_names)``; sets each source's layout when it has fewer channels.

    Args:
        sources: training stores first (``n_train`` of them), then held-out stores.
        channels: ``{"u": [...], "y": [...]}``, the set to use (e.g. a multi-arm model's, to
            fine-tune it on one arm); default the widest training store's.

    Raises:
        DataError: stores with another dt, or whose channels are not all in the set (one line).
    """
    ref = sources[0]
    for src in sources[1:]:
        if not math.isclose(ref.dt, src.dt, rel_tol=1e-9):
            raise DataError(f"stores disagree on dt: {ref.path} has {ref.dt}, {src.path} has {src.dt}")
    if channels is not None:
        u_set, y_set = _given(channels)
    else:
        widest = max(sources[:n_train], key=lambda s: len(s.u_names) + len(s.y_names))
        u_set, y_set = list(widest.u_names), list(widest.y_names)
    for src in sources:
        for what, names, full in (("u_names", src.u_names, u_set), ("y_names", src.y_names, y_set)):
            if not set(names) <= set(full) or len(set(names)) != len(names):
                other = "the channel set given" if channels is not None else widest.path
                raise DataError(f"stores disagree on {what}: {other} has {full}, {src.path} has {list(names)}; "
                                "the stores of one run must share u_names, y_names and dt, or have channels "
                                "(by name) that the widest store has as well (arms with fewer joints)")
        u_cols, y_cols = columns(src.u_names, u_set, "u"), columns(src.y_names, y_set, "y")
        if not (is_identity(u_cols, len(u_set)) and is_identity(y_cols, len(y_set))):
            src.layout = (u_cols, y_cols, len(u_set), len(y_set))
    return u_set, y_set


def _given(channels: dict) -> tuple[list[str], list[str]]:
    if not isinstance(channels, dict) or set(channels) != {"u", "y"} or not all(
            isinstance(v, (list, tuple)) and v and all(isinstance(n, str) for n in v) for v in channels.values()):
        raise DataError(f"channels must be {{'u': [names...], 'y': [names...]}}, got {channels!r}")
    u, y = list(channels["u"]), list(channels["y"])
    for what, names in (("u", u), ("y", y)):
        if len(set(names)) != len(names):
            raise DataError(f"channels: {what} names a channel twice: {names}")
    return u, y


class ColumnAccumulator:
    """Feeds one store's blocks to a :class:`StatsAccumulator` of the run's channel set, in
    the columns its channels have there (what :func:`robomorph.data.sources.scan` calls)."""

    def __init__(self, acc: StatsAccumulator, layout: tuple[list[int], list[int], int, int] | None):
        self.acc, self.layout = acc, layout

    def update(self, u, y) -> None:
        if self.layout is None:
            self.acc.update(u, y)
        else:
            self.acc.update(u, y, self.layout[0], self.layout[1])


def last_joint(u_names: list[str], y_names: list[str]) -> tuple[list[int], list[int]]:
    """The columns ``([u column], [y column])`` of the highest joint the channel set names
    (``tau{k}`` or ``cmd{k}``, and ``q{k}``): what ``joint_dropout`` hides.

    Raises:
        DataError: the set has no joint named by role in both u and y (imported logs with
            other names: rename the channels at ingest, or train without joint_dropout).
    """
    joints = {int(n[3:]): i for i, n in enumerate(u_names)
              if n[:3] in ("tau", "cmd") and n[3:].isdigit() and f"q{n[3:]}" in y_names}
    if not joints:
        raise DataError(f"joint_dropout needs joints named by role (tau<k> or cmd<k> in u, q<k> in y); these "
                        f"stores have u {list(u_names)}, y {list(y_names)}: train without joint_dropout")
    k = max(joints)
    return [joints[k]], [list(y_names).index(f"q{k}")]


def pads_any(sources: list[Source]) -> bool:
    """True when a store leaves some of the run's channels absent (a reordering pads nothing)."""
    return any(s.layout is not None and (len(s.layout[0]) < s.layout[2] or len(s.layout[1]) < s.layout[3])
               for s in sources)


def layouts(sources: list[Source]) -> list[dict[str, list[str]]]:
    """The distinct ``{"u_names", "y_names"}`` of ``sources``, in order."""
    out: list[dict[str, list[str]]] = []
    for src in sources:
        layout = {"u_names": list(src.u_names), "y_names": list(src.y_names)}
        if layout not in out:
            out.append(layout)
    return out
