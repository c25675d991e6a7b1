"""A hybrid's standard deviation: which robots it is the spread of, and which stored calibration scales which rows.

A hybrid's std is the spread of the horizons of robots around its estimate (the regression's covariance, or the
parameter head's Gaussian). :data:`POINTS` names how those robots are chosen:

- ``columns`` (the default without the observer): one robot per column of the covariance's Cholesky factor, the
  squared distances from the estimate's horizon summed: the linearized propagation, deterministic, the same
  whatever else is in the batch, one horizon per identified parameter (29 on the Panda);
- ``draws``: the RMS over ``settings.samples`` random robots (8), what every calibration written
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
from robomorph.inference.calibration import CalibrationError


def observing(predictor) -> bool:
    """True when the predictions start the horizon from the observer's velocity (commands' simulated contexts)."""
    return bool(predictor.physics) and predictor.settings_in_effect.observer


def kind_calibrations(predictor) -> tuple:
    """(for windows that open their trajectory, for the others): the mode's calibrations, each
    standing in for the other where only one was fitted; (None, None) without any."""
    mode = predictor.settings_in_effect.calibration_key if predictor.physics else "none"
    start, moving = predictor.model.calibrations.get(mode), predictor.model.calibrations.get(f"{mode}/moving")
    return start or moving, moving or start


def spread_points(predictor, strict: bool = True) -> str:
    """The points (:data:`POINTS`) behind a hybrid's std: ``Predictor.settings.points`` where set, else
    those its mode's stored calibrations were fitted on, else :func:`robomorph.inference.hybrid_spread.default_points` (the observer's where it runs). ``strict`` False: the choice
    (or the default) instead of the errors below, for predictions that ask for no std.

    Raises: CalibrationError: an unknown name, a choice other than the stored calibrations', or calibrations of
    the two window kinds fitted on different points (the std would be scaled as another spread)."""
    if not strict:
        try:
            return spread_points(predictor)
        except CalibrationError:
            return predictor.settings.points or hybrid_spread.default_points(observing(predictor))
    chosen = predictor.settings.points  # (a name of POINTS: the settings check it)
    cals = {c.points or "draws": c for c in kind_calibrations(predictor) if c is not None}
    if len(cals) > 1:
        raise CalibrationError("this model's two std calibrations (windows from the start, and the others) were "
                               f"fitted on different spreads ({' and '.join(sorted(cals))}): calibrate both kinds "
                               "with one --points (robomorph calibrate --offset start, then --offset random)")
    fitted = next(iter(cals), None)
    if chosen is not None and fitted is not None and chosen != fitted:
        raise CalibrationError(f"the stored std calibration was fitted on the spread of {fitted!r}, not "
                               f"{chosen!r}: leave the points unset (configure(points=None)), or calibrate again with "
                               f"--points {chosen}")
    return chosen or fitted or hybrid_spread.default_points(observing(predictor))


def drawn_points(predictor) -> str | None:
    """What a calibration of ``predictor``'s current std records: its points where its mode draws robots
    (every hybrid mode but a smoothed horizon's), None for a decoder's std or the smoother's covariance."""
    from robomorph.inference.hybrid import solves_whole_horizon  # noqa: PLC0415  (torch only here)

    mode = predictor.settings.mode
    if not predictor.physics or mode == "none" or solves_whole_horizon(predictor.model, mode):
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
