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

    @property
    def latex(self) -> str:
        """The paper's ``\\cellcolor`` argument, e.g. ``lightgreen!80`` (see :data:`LATEX_COLORS`)."""
        return f"{_LATEX_NAMES[self.rgb]}!{self.strength}"


# A property, not a sixth field: callers unpack the five fields of a Band.
_LATEX_NAMES = {(144, 238, 144): "lightgreen", (255, 255, 0): "yellow", (255, 165, 0): "orange", (255, 0, 0): "red"}
# The paper's preamble for these names (with ``\\usepackage{colortbl}``).
LATEX_COLORS = "\n".join(f"\\definecolor{{{name}}}{{RGB}}{{{r},{g},{b}}}" for (r, g, b), name in _LATEX_NAMES.items())

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
