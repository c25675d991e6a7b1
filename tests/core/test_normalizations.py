"""The normalization protocols: known names, the recenter rule, labels, query statistics."""

import numpy as np
import pytest

from robomorph.core.normalizations import (
    NORMALIZATIONS,
    NormalizationError,
    check_normalization,
    leaks_query_statistics,
    normalization_label,
    query_output_stats,
)


def test_names_and_which_of_them_leak():
    assert NORMALIZATIONS == ("train_stats", "paper_window")
    assert [leaks_query_statistics(n) for n in (*NORMALIZATIONS, None)] == [False, True, False]
    assert "not the scores of a model that could be deployed" in normalization_label("paper_window")
    assert normalization_label(None) == normalization_label("train_stats")  # results from before the option


def test_unknown_names_and_paper_window_with_recenter_are_refused():
    assert check_normalization("train_stats", recenter=True) == "train_stats"
    with pytest.raises(NormalizationError, match="one of"):
        check_normalization("per_channel")
    with pytest.raises(NormalizationError, match="recenter: false"):
        check_normalization("paper_window", recenter=True)


def test_query_statistics_are_per_trajectory_over_time():
    y = np.random.default_rng(0).normal(size=(3, 20, 2))
    mean, std = query_output_stats(y)
    assert mean.shape == std.shape == (3, 2)
    np.testing.assert_allclose(mean[1], y[1].mean(0))
    np.testing.assert_allclose(std[2], y[2].std(0))
