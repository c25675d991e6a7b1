"""The inference API users import: ``from robomorph.predictor import Predictor`` (or ``from
robomorph import Predictor``). It lives in :mod:`robomorph.inference.predictor`, below the
evaluation that uses it too; a deployed model needs only ``robomorph.model`` and
``robomorph.core``.
"""

from robomorph.inference.predictor import MAX_INPUT_STDS, PredictionError, Predictor

__all__ = ["MAX_INPUT_STDS", "PredictionError", "Predictor"]
