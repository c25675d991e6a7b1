"""The paper's FIT colour bands."""

import pytest

from robomorph.evaluation.fit_bands import FIT_BANDS, fit_band


@pytest.mark.parametrize("fit, band", [(95, 0), (90, 0), (89.99, 1), (80, 1), (60, 2), (59.9, 3), (30, 3),
                                       (29.99, 4), (-250, 4), (float("nan"), 4)])
def test_fit_bands_follow_the_paper(fit, band):
    assert fit_band(fit) == band


def test_bands_descend_and_each_has_a_latex_colour():
    lows = [b.low for b in FIT_BANDS]
    assert lows == sorted(lows, reverse=True)
    assert [b.latex for b in FIT_BANDS[:2]] == ["lightgreen!80", "lightgreen!50"]
