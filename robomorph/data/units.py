"""Channel units recorded in a store's attributes, and the labels plots show with them."""

from __future__ import annotations

from typing import Any


def channel_units(attrs: dict[str, Any], kind: str) -> list[str]:
    """Units of the ``u`` or ``y`` channels (``attrs['u_units']``, written by ``ingest
    --u-units``); empty strings where the store does not say."""
    names = attrs.get(f"{kind}_names") or []
    units = list(attrs.get(f"{kind}_units") or [])
    return units if len(units) == len(names) else [""] * len(names)


def channel_label(name: str, unit: str) -> str:
    """``"q1 [rad]"``, or the bare name when the unit is unknown (a plot's axis label)."""
    return f"{name} [{unit}]" if unit else name


def literal(text) -> str:
    """``text`` as matplotlib draws it verbatim: every ``$`` escaped.

    Channel names, units, domains and ``--compare`` names are the user's: matplotlib would
    read a pair of ``$`` in them as TeX and fail on whatever lies between. Escaping the
    user's text (rather than switching mathtext off) keeps matplotlib's own TeX, such as the
    ``10^4`` tick labels of log axes.
    """
    return str(text).replace("$", r"\$")
