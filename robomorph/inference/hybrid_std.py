"""A hybrid's standard deviation: which robots it is the spread of, and which stored calibration scales which rows.

A hybrid's std is the spread of the horizons of robots around its estimate (the regression's covariance, or the
parameter head's Gaussian). :data:`POINTS` names how those robots are chosen:

- ``columns`` (the default without the observer): one robot per column of the covariance's Cholesky factor, the
  squared distances from the estimate's horizon summed: the linearized propagation, deterministic, the same
  whatever else is in the batch, one horizon per identified parameter (29 on the Panda);
- ``draws``: the RMS over :attr:`Predictor.physics_samples` random robots (8), what every calibration written
  before ``columns`` was fitted on. Eight draws leave a sampling noise of about a quarter of the std (sd 0.25 of
  the log ratio to 128 draws, 32 windows) and a window's draws depended on its row in the batch;
- ``observed`` (the default with the observer, since 2026-11-27): ``columns``, and beside the parameters the start's
  velocity: one horizon per joint whose start velocity is moved by
  :data:`robomorph.inference.hybrid_spread.OBSERVED_SIZE` times what the observer corrected there
  (:func:`robomorph.identification.backbone.observed_velocity`: how far the estimate's simulated context had drifted from the
  recorded joints), in quadrature (:func:`robomorph.inference.hybrid_spread.observed_spread`). The parameters' spread
  does not cover the state's error, which is most of the first steps' (the skill at step 1 fell to 0.45-0.48 once
  the regression's bias was taken off). Without the observer (total torques) it is ``columns``.

A calibration scales the spread it was fitted on, so it records its points (``StdCalibration.points``; None:
``draws``, fitted before the choice) and a prediction uses them.
"""

from __future__ import annotations

import numpy as np
import torch

from robomorph.inference import hybrid_spread
from robomorph.inference.calibration import POINTS, CalibrationError, mode_key


def observing(predictor) -> bool:
    """True when the predictions start the horizon from the observer's velocity (commands' simulated contexts)."""
    return bool(predictor.physics and predictor.physics_observer and predictor.inputs == "command")


def springing(predictor) -> bool:
    """True when the regression fits the joints' springs too (:attr:`Predictor.physics_springs`)."""
    return _regression_setting(predictor, predictor.physics_springs)


def debiasing(predictor) -> bool:
    """True when the regression's bias is taken off (:attr:`Predictor.physics_debias`, :mod:`robomorph.inference.debias`).

    Never on an arm that compensates its gravity with its catalogue model (``nominal_model``): measured worse
    there (simulated kinova3, 4 robots, joint RMS at steps 1 / 15 / 60 / 300: 0.15 / 8.2 / 54 / 256 mrad with it,
    0.055 / 2.1 / 10 / 57 without; identified physics 0.49 / 9.0 / 33 / 122).
    """
    recipe = (predictor.physics or {}).get("recipe") or {}
    if recipe.get("gravity_compensation") == "nominal_model":
        return False
    return _regression_setting(predictor, predictor.physics_debias)


def _regression_setting(predictor, on: bool) -> bool:
    """A setting of the regression in effect: asked for, commands, and a mode whose robot the regression identifies
    without the parameter head's prior."""
    return bool(predictor.physics and on and predictor.inputs == "command"
                and predictor.physics_mode not in ("learned", "fused", "none"))


def kind_calibrations(predictor) -> tuple:
    """(for windows that open their trajectory, for the others): the mode's calibrations, each
    standing in for the other where only one was fitted; (None, None) without any."""
    mode = mode_key(predictor.physics_mode if predictor.physics else "none", observing(predictor), springing(predictor),
                    debiasing(predictor))
    start, moving = predictor.model.calibrations.get(mode), predictor.model.calibrations.get(f"{mode}/moving")
    return start or moving, moving or start


def spread_points(predictor, strict: bool = True) -> str:
    """The points (:data:`POINTS`) behind a hybrid's std: :attr:`Predictor.physics_points` where set, else
    those its mode's stored calibrations were fitted on, else :func:`default_points`. ``strict`` False: the choice
    (or the default) instead of the errors below, for predictions that ask for no std.

    Raises: CalibrationError: an unknown name, a choice other than the stored calibrations', or calibrations of
    the two window kinds fitted on different points (the std would be scaled as another spread)."""
    if not strict:
        try:
            return spread_points(predictor)
        except CalibrationError:
            return predictor.physics_points if predictor.physics_points in POINTS else default_points(predictor)
    chosen = predictor.physics_points
    if chosen is not None and chosen not in POINTS:
        raise CalibrationError(f"physics_points {chosen!r}: choose one of {', '.join(POINTS)}")
    cals = {c.points or "draws": c for c in kind_calibrations(predictor) if c is not None}
    if len(cals) > 1:
        raise CalibrationError("this model's two std calibrations (windows from the start, and the others) were "
                               f"fitted on different spreads ({' and '.join(sorted(cals))}): calibrate both kinds "
                               "with one --points (robomorph calibrate --offset start, then --offset random)")
    fitted = next(iter(cals), None)
    if chosen is not None and fitted is not None and chosen != fitted:
        raise CalibrationError(f"the stored std calibration was fitted on the spread of {fitted!r}, not "
                               f"{chosen!r}: leave physics_points unset, or calibrate again with --points {chosen}")
    return chosen or fitted or default_points(predictor)


def default_points(predictor) -> str:
    """The points of a std no calibration was fitted on yet (:func:`robomorph.inference.hybrid_spread.default_points`)."""
    return hybrid_spread.default_points(observing(predictor))


def drawn_points(predictor) -> str | None:
    """What a calibration of ``predictor``'s current std records: its points where its mode draws robots
    (every hybrid mode but a smoothed horizon's), None for a decoder's std or the smoother's covariance."""
    from robomorph.inference.hybrid import solves_whole_horizon  # noqa: PLC0415  (torch only here)

    if not predictor.physics or predictor.physics_mode == "none" \
            or solves_whole_horizon(predictor.model, predictor.physics_mode):
        return None
    return spread_points(predictor)


def calibrated_rows(predictor, std: torch.Tensor, at_rest) -> torch.Tensor:
    """A hybrid's std (B, H, n_y) recalibrated row by row: rows whose window opens its trajectory
    (``at_rest``) by the calibration fitted on such windows, the others by the other kind's."""
    start, moving = kind_calibrations(predictor)
    if start is None:
        return std
    rest = np.broadcast_to(np.asarray(False if at_rest is None else at_rest, dtype=bool), (std.shape[0],))
    raw = std.detach().cpu().numpy()
    out = np.empty_like(raw)
    for rows, cal in ((rest, start), (~rest, moving)):  # each row by its own kind's, once
        if rows.any():
            out[rows] = cal.scaled(raw[rows])
    return torch.as_tensor(out, dtype=std.dtype, device=std.device)
