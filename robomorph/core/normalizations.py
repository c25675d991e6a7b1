"""The normalization protocols, by name: which exist, which leak the query outputs.

``train_stats`` is what a deployed model can use; ``paper_window`` reproduces the paper's
protocol (every window z-scored with its own mean and std over context and query together),
labelled wherever it is used because its predictions use statistics of the outputs they
predict. Torch-free: the data, the model, evaluation and reproduction all read these names.
"""

from __future__ import annotations

import numpy as np

from robomorph.core.errors import RoboMorphError

# ``train_stats``: training-split statistics (and optional context-only recentring), what a
# deployed model can use. ``paper_window``: each window z-scored with the mean and std of its
# context *and query*, as the paper's training script did (README, section 9).
NORMALIZATIONS = ("train_stats", "paper_window")
_LEAKY = frozenset({"paper_window"})


class NormalizationError(RoboMorphError, ValueError):
    """An unknown normalization, or one used where its statistics cannot exist."""


def check_normalization(normalization: str, recenter: bool = False) -> str:
    """Returns ``normalization`` when it is known and compatible with ``recenter``.

    Raises:
        NormalizationError: an unknown name, or ``paper_window`` with ``recenter`` (the window
            z-score already centres each window; the paper did nothing more).
    """
    if normalization not in NORMALIZATIONS:
        raise NormalizationError(f"normalization must be one of {list(NORMALIZATIONS)}, got {normalization!r}")
    if normalization == "paper_window" and recenter:
        raise NormalizationError("normalization 'paper_window' already centres each window on its own mean; "
                                 "set recenter: false with it (the paper's protocol has no recentring)")
    return normalization


def leaks_query_statistics(normalization: str | None) -> bool:
    """True when predictions under ``normalization`` use statistics of the outputs they predict."""
    return normalization in _LEAKY


def normalization_label(normalization: str | None) -> str:
    """The sentence a table header carries about the normalization (plain text, no markup).

    ``None`` (a result written before the option existed) reads as ``train_stats``.
    """
    if leaks_query_statistics(normalization):
        return (f"Normalization {normalization} (the paper's protocol): each window is z-scored with the mean "
                "and std of its own context and query, so every prediction uses statistics of the outputs it "
                "predicts; these are not the scores of a model that could be deployed.")
    return ("Normalization train_stats: training-split statistics (and context-only recentring); nothing of "
            "the query outputs reaches a prediction.")


def query_output_stats(y_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-trajectory mean and (population) std over time of the query outputs.

    What ``paper_window`` needs besides the context: ``y_query (..., Th, n_y)`` ->
    ``(mean (..., n_y), std (..., n_y))``. Only an evaluation that holds the true outputs
    can compute it, which is the leak.
    """
    y = np.asarray(y_query, dtype=np.float64)
    return y.mean(axis=-2), y.std(axis=-2)
