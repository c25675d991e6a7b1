"""The learned residual: a meta-model that corrects the physics hybrid's prediction.

A residual model (``ModelConfig.residual``, trained by ``robomorph fit`` on prior stores,
:mod:`robomorph.data.priors`) reads a context of the robot, the query commands and the hybrid's
prediction of the query outputs, and predicts the correction; its prediction is ``prior +
correction``. The checkpoint records how its priors were made (``data_info["residual"]``: the
catalogue arm, its recipe, the hybrid's settings), and the :class:`~robomorph.inference.predictor.Predictor`
of a residual model makes the same prior itself: ``Predictor.from_arm`` with that recipe and those
settings (:func:`prior_predictor`), run on the very context and query it is given, before the
network adds its correction. ``simulate(..., prior=...)`` takes a prior computed already (the same
hybrid's, e.g. in a benchmark that scores the hybrid alone too) instead.
"""

from __future__ import annotations

import torch
import yaml

from robomorph.inference.predictor_checks import PredictionError


def hybrid_of(predictor_cls, recipe, settings: dict, arm: str | None = None):
    """``(predictor_cls.from_arm(arm, recipe) configured with settings, arm)``: the catalogue arm's hybrid for
    data of generator recipe ``recipe`` (a dict, or YAML text; its ``robot`` names the arm unless ``arm``
    does), with no std calibration. ``predictor_cls`` is :class:`~robomorph.inference.predictor.Predictor`
    (passed in: the Predictor imports this module)."""
    if isinstance(recipe, str):
        recipe = yaml.safe_load(recipe)
    if not isinstance(recipe, dict):
        raise PredictionError("no generator recipe to build the hybrid from: priors need a simulated store whose "
                              "attrs['config'] names the arm and its ranges")
    arm = arm or recipe.get("robot", "panda")
    # The whole recipe as fields over the generator's defaults: the recipe itself (as from_arm's overrides).
    pred = predictor_cls.from_arm(arm, calibrated=False, **{**recipe, "robot": arm})
    return pred.configure(**settings), arm


def prior_predictor(predictor_cls, record: dict):
    """The hybrid a residual model's priors came from, as its checkpoint records it (a ``predictor_cls``)."""
    if not record or "recipe" not in record:
        raise PredictionError("this residual model's checkpoint does not record how its priors were made "
                              "(data_info['residual']): pass prior= to simulate")
    return hybrid_of(predictor_cls, record["recipe"], dict(record.get("fields") or {}), record.get("arm"))[0]


def query_prior(predictor, tensors: list[torch.Tensor], prior, at_rest, anchor) -> torch.Tensor:
    """The prior (B, Th, n_y) a residual Predictor corrects: ``prior`` as given, else its hybrid's prediction
    on the context and query of ``tensors`` (``at_rest``, ``anchor``: as the hybrid takes them)."""
    u_ctx, y_ctx, u_query = tensors
    shape = (u_query.shape[0], u_query.shape[1], y_ctx.shape[-1])
    if prior is None:
        prior = predictor.prior_predictor.simulate(u_ctx, y_ctx, u_query, at_rest=at_rest, anchor=anchor)
    prior = torch.as_tensor(prior, dtype=u_query.dtype, device=u_query.device)
    if prior.dim() == 2:
        prior = prior.unsqueeze(0)
    if tuple(prior.shape) != shape:
        raise PredictionError(f"prior must have shape (B, Th, n_y) = {shape}, got {tuple(prior.shape)}")
    if not bool(torch.isfinite(prior).all()):
        raise PredictionError("the prior holds NaN or inf: the hybrid failed on these windows")
    return prior
