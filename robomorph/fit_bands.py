"""The paper's fit-index colour convention (its Table 3), defined once for tables and pages.

Standard library only, so the HTML report can use it without importing torch.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Band(NamedTuple):
    low: float  # lower bound of FIT [%] (inclusive)
    rgb: tuple[int, int, int]  # the paper's colour
    strength: int  # percent of the colour mixed with white (LaTeX ``colour!strength``)
    mark: str  # the markdown tables' symbol
    label: str


FIT_BANDS: tuple[Band, ...] = (
    Band(90.0, (144, 238, 144), 80, "🟩", "FIT ≥ 90"),
    Band(80.0, (144, 238, 144), 50, "🟢", "80 ≤ FIT < 90"),
    Band(60.0, (255, 255, 0), 50, "🟨", "60 ≤ FIT < 80"),
    Band(30.0, (255, 165, 0), 50, "🟧", "30 ≤ FIT < 60"),
    Band(-math.inf, (255, 0, 0), 30, "🟥", "FIT < 30"),
)


def fit_band(fit: float) -> int:
    """Index into :data:`FIT_BANDS` of a FIT value (NaN falls in the lowest band)."""
    for i, band in enumerate(FIT_BANDS):
        if fit >= band.low:
            return i
    return len(FIT_BANDS) - 1
