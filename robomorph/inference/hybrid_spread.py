"""The spread behind a hybrid's std: horizons of robots (and start velocities) around its estimate.

:func:`draw_spread` moves the identified parameters (the ``columns`` of the estimate's covariance, or random
``draws``); :func:`observed_spread` moves the start velocity by the observer's correction (the ``observed`` points,
:mod:`robomorph.inference.hybrid_std`). Both take the :meth:`robomorph.inference.hybrid.Hybrid.predict`'s ``horizon``.
"""

from __future__ import annotations

import numpy as np

# The start velocity's uncertainty per joint, in units of what the observer corrected there (``observed`` points;
# measured on the debiased fast setting from random offsets, 765 calibration and 255 test windows: 0.25 / 0.5 / 1 /
# 2 gave the coverage's largest miss 1.07 / 0.89 / 0.97 / 1.15 tolerances, 1.11 without the term).
OBSERVED_SIZE = 0.5


def default_points(observed: bool) -> str:
    """The points of a std no calibration was fitted on yet: ``observed`` where the horizon starts from the
    observer's velocity, else ``columns`` (what ``observed`` would be there)."""
    return "observed" if observed else "columns"


def draw_spread(space: tuple, params: np.ndarray, z_std: np.ndarray, covs, mean: np.ndarray, horizon, samples: int,
                 seed: int, points: str = "draws") -> np.ndarray:
    """(B, H, n_y) spread of the horizons of robots around ``params``, from the head's Gaussian (``covs``
    None: std ``z_std``) or the regression's covariances, in unit coordinates, about ``mean`` (the
    horizon of ``params`` itself). ``space``: the moved entries' indices in ``params`` and their bounds.

    ``points``: ``draws``, the RMS of ``samples`` random robots; ``columns``, one robot per column of the
    covariance's Cholesky factor, their squared distances summed (the linearized propagation, exact
    for a horizon linear in the parameters: no sampling noise, one horizon per parameter); ``observed``, the
    columns and :func:`observed_spread` in quadrature."""
    if points == "observed":  # the columns, and beside them the start velocity's spread
        return np.hypot(draw_spread(space, params, z_std, covs, mean, horizon, samples, seed, "columns"),
                        observed_spread(horizon, params, mean))
    index, low, high = space
    center = (params[:, index] - (low + high) / 2) / ((high - low) / 2)
    if covs is None:
        chol = z_std[:, :, None] * np.eye(center.shape[1])[None]
    else:
        chol = np.stack([np.linalg.cholesky(c + 1e-12 * np.eye(len(c))) for c in covs])
    if points == "columns":
        steps = [chol[:, :, i] for i in range(center.shape[1])]
    else:
        rng = np.random.default_rng(seed)
        steps = [np.einsum("bij,bj->bi", chol, rng.standard_normal(center.shape)) for _ in range(samples)]
    total = np.zeros_like(mean)
    for step in steps:
        pk = params.copy()
        pk[:, index] = (low + high) / 2 + np.clip(center + step, -1, 1) * (high - low) / 2
        total += (horizon(pk) - mean) ** 2
    return np.sqrt(total if points == "columns" else total / len(steps))


def observed_spread(horizon, params: np.ndarray, mean: np.ndarray, size: float = None) -> np.ndarray:
    """(B, H, n_y) the spread of the horizons of ``params`` whose start velocity is moved joint by joint by ``size``
    (default :data:`OBSERVED_SIZE`) times the observer's correction there, about ``mean`` (their own horizon):
    ``horizon(params, (joint, size))`` gives one (:meth:`robomorph.inference.hybrid.Hybrid.predict`)."""
    size = OBSERVED_SIZE if size is None else size
    total = np.zeros_like(mean)
    for joint in range(mean.shape[-1] - 7):  # y: the EE pose (7 channels), then one angle per joint
        total += (horizon(params, (joint, size)) - mean) ** 2
    return np.sqrt(total)
