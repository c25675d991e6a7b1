"""Table 1's extra row: the improved model beside the paper's architecture.

The reproduction trains the paper's encoder-decoder for its tables (the paper's rows, at
the scale's depths). Beside them it trains one more model at the middle depth, on the same
store and budget, with the options that won the equal-budget ablation and are the default of
``datamodules/train_cpu.yaml`` (README, section 8): the last context steps as the decoder's
initial-condition tokens (``n_init``), outputs relative to the last context output
(``anchor``), a Gaussian head trained with its negative log-likelihood, horizon weights, and
random context and query lengths and offsets. Readers then see both: what the paper's model
scores here, and what the project's default does with the same data and steps.

The options are read from ``datamodules/train_cpu.yaml`` (so the row follows the default
recipe) and its window lengths scaled to the scale's window, in multiples of its patch.
"""

from __future__ import annotations

import yaml

from robomorph.core.errors import MissingInputError

IMPROVED = "improved"
# What makes the improved model: these keys of train_cpu.yaml, nothing else (width, depth,
# batch, learning rate and budget stay the scale's, as for the paper's rows).
OPTIONS = {"data": ("context_min", "horizon_min", "window"),
           "model": ("n_init", "anchor", "gaussian", "loss", "horizon_weight", "horizon_tau")}
DESCRIPTION = ("the project's default options (n_init initial-condition tokens, anchor, Gaussian NLL head, "
               "horizon weights, random context/query lengths and offsets) on the paper's encoder-decoder")


def _steps(n: int, full: int, ours: int, patch: int) -> int:
    """``n`` of a ``full``-step window scaled to an ``ours``-step one: a multiple of ``patch``
    in ``[patch, ours]``."""
    return max(patch, min(ours, round(n * ours / full / patch) * patch))


def improved_overrides(recipe_file: str, context_len: int, horizon: int, patch: int) -> dict:
    """The ``{"data": ..., "model": ...}`` overrides that turn a reproduction run into the
    improved model, for a window of ``context_len + horizon`` steps in tokens of ``patch``.

    Raises:
        MissingInputError: the recipe lacks one of the options (it is not the default recipe).
    """
    with open(recipe_file) as f:
        cfg = yaml.safe_load(f)
    try:
        data = {k: cfg["data"][k] for k in OPTIONS["data"]}
        model = {k: cfg["model"][k] for k in OPTIONS["model"]}
        c0, h0 = cfg["data"]["context_len"], cfg["data"]["horizon"]
    except KeyError as exc:
        raise MissingInputError(f"{recipe_file} has no {exc.args[0]!r}: the improved row reads the default recipe's "
                                f"options {OPTIONS}") from None
    data["context_min"] = _steps(data["context_min"], c0, context_len, patch)
    data["horizon_min"] = _steps(data["horizon_min"], h0, horizon, patch)
    model["n_init"] = min(_steps(model["n_init"], c0, context_len, patch), data["context_min"]) if model["n_init"] else 0
    return {"data": data, "model": model}
