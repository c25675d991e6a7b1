"""Encoder noise: measured in a context, and what the identification and the start state do about it.

A real arm's joint angles carry its encoders' noise (1e-5 to 1e-4 rad: docs/guide/realism.md). The
regression (:mod:`robomorph.identification.regressor`) reads accelerations as second differences of the
joints, which multiply that noise by ``sqrt(6) / dt^2`` (1e-4 rad at 60 Hz: 0.9 rad/s^2, more than
most of the motion's), and the horizon starts from the last sample, which carries the noise whole.

- :func:`encoder_noise`: the noise's std, from the context alone. A fourth difference of a smooth
  motion sampled at 60 Hz is tiny (clean contexts: below 0.5e-6 rad), while white noise's is
  ``sqrt(70)`` times its std; the median absolute value is robust to the motion's few sharp bends.
- :func:`smooth_pair`: a Savitzky-Golay filter (cubic, :func:`window`) over the joints *and* the
  torques alike, so that the differences of the smoothed joints still match the (smoothed) torques
  (parallel filtering, as in the identification literature); the ends, where the filter extrapolates,
  are dropped. The window is the noise's (:func:`window`): measured on 8 held-out robots at 1e-4 rad,
  11 / 15 / 25 samples gave 5.1 / 4.3 / 4.6 mrad at 1 s. Weighting the solve's data by the noise as well
  (the smoothed accelerations' torque added to its error unit) moved no figure in the fourth digit: at
  these windows that torque is below the solve's own unit, 0.05 N m.
- :func:`denoised_context`: the context's last :data:`END_WINDOW` samples replaced by the identified
  robot's simulation of them (from a smoothed state) plus a quadratic fitted to what it misses
  (recorded less simulated, :func:`denoised_end`): the simulation carries the dynamics, the fit only
  a slow drift, so the start of the horizon has a fraction of the noise.

Below :data:`NOISE_FLOOR` none of this runs, so clean contexts predict exactly what they did.
"""

from __future__ import annotations

import numpy as np

# Below this measured std [rad] a context counts as noise-free (clean simulated contexts measure 0.02e-6 to
# 0.41e-6 rad; 1e-5 rad of noise measures 0.95e-5 to 1.1e-5, 32 windows of the sensitivity stores).
NOISE_FLOOR = 2e-6
# The most samples of the quadratic fitted to the simulated context's miss at its end (a third of a second): the
# identified robot's simulation misses the recorded motion by more than a quadratic over longer tails. Measured on 8
# held-out robots, the last context sample's joint RMS error against the true motion with the hybrid's own estimate
# (raw: 0.0101 mrad at 1e-5 rad of noise, 0.101 at 1e-4): tails of 8 / 12 / 20 / 30 / 60 samples gave 0.0095 /
# 0.0096 / 0.019 / 0.036 / 0.119 at 1e-5 and 0.090 / 0.080 / 0.078 / 0.114 / 0.261 at 1e-4 (:func:`end_window`).
END_WINDOW = 20


def encoder_noise(q: np.ndarray) -> float:
    """The joint angles' noise std [rad] measured in a context ``q`` (T, nj) (T >= 5; 0 when shorter)."""
    q = np.asarray(q, dtype=np.float64)
    if len(q) < 5:
        return 0.0
    d4 = np.diff(q, 4, axis=0)  # white noise: std sqrt(70) sigma; a smooth motion: next to nothing
    return float(np.median(np.abs(d4)) / 0.6745 / np.sqrt(70.0))


def window(noise: float) -> int:
    """The smoothing window [samples] for a noise std: odd, 9 at 1e-5 rad, growing as noise^(2/9) (a cubic's
    bias in the acceleration grows as window^4, the noise's variance there falls as window^-5), at most 41."""
    w = 9.0 * (max(noise, NOISE_FLOOR) / 1e-5) ** (2 / 9)
    return int(min(41, max(5, 2 * round(w / 2) + 1)))


def smooth_pair(q: np.ndarray, torque: np.ndarray, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Joints (T, nj) and torques (T, nj) smoothed by the same cubic Savitzky-Golay filter, less the
    half-windows at both ends (where the filter extrapolates); unchanged when the context is too short."""
    from scipy.signal import savgol_filter  # noqa: PLC0415

    w = window(noise)
    h = w // 2
    if len(q) < 2 * w + 3:
        return np.asarray(q, dtype=np.float64), np.asarray(torque, dtype=np.float64)
    qs = savgol_filter(np.asarray(q, dtype=np.float64), w, 3, axis=0)[h:-h]
    ts = savgol_filter(np.asarray(torque, dtype=np.float64), w, 3, axis=0)[h:-h]
    return qs, ts


def end_window(noise: float) -> int:
    """Samples of the end's quadratic for a noise std: more the noisier (the noise's share falls as 1 / samples),
    :data:`END_WINDOW` at 1e-4 rad and above (the simulation's miss grows with them), 8 at 1e-5."""
    return int(min(END_WINDOW, max(8, round(END_WINDOW * (noise / 1e-4) ** 0.4))))


def denoised_end(residual: np.ndarray, simulated: np.ndarray, window_: int = END_WINDOW) -> np.ndarray:
    """(W, nj) the last ``W`` joint positions: ``simulated`` (T, nj) plus a quadratic least-squares fit of
    ``residual`` (T, nj), recorded less simulated, over them (W = min(window_, T))."""
    w = min(window_, len(residual))
    t = np.arange(w, dtype=np.float64) - (w - 1)
    basis = np.stack([np.ones(w), t, t * t], axis=1)[:, :min(3, w)]
    coef, *_ = np.linalg.lstsq(basis, residual[-w:], rcond=None)
    return simulated[-w:] + basis @ coef


def denoised_context(backbone, params: np.ndarray, q_ctx: np.ndarray, torque_ctx: np.ndarray,
                     qvel_start: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """(B, T, nj) the contexts with their last :data:`END_WINDOW` joint samples denoised
    (:func:`denoised_end`) where their measured ``noise`` (B,) is above :data:`NOISE_FLOOR`: each robot
    ``params`` (B, P) simulated over the context's last :func:`end_window` samples in the formulation's own
    way (:class:`robomorph.identification.identify.ContextProblem`), from the joints and velocity a cubic
    Savitzky-Golay fit (:func:`window`) gives at the tail's first sample. Simulated from there, the miss is a
    slow drift of that start's small error, which the quadratic takes up; from the context's first sample it
    also held the identification's error over seconds (measured: the last sample's error 12 times larger at
    1e-5 rad over 60 samples). ``qvel_start`` is not read (the tail starts mid-context)."""
    from scipy.signal import savgol_filter  # noqa: PLC0415

    from robomorph.identification.identify import ContextProblem  # noqa: PLC0415

    out = np.array(q_ctx, dtype=np.float64, copy=True)
    space, t_all = backbone.ident.space, out.shape[1]
    for b in np.flatnonzero(np.asarray(noise) > NOISE_FLOOR):
        w, tail_len = window(float(noise[b])), end_window(float(noise[b]))
        s = t_all - 1 - tail_len
        if s < w:
            continue  # a context too short to start the tail from a smoothed state
        q0 = savgol_filter(out[b], w, 3, axis=0)[s]
        v0 = savgol_filter(out[b], w, 3, deriv=1, delta=backbone.dt, axis=0)[s]
        tail = out[b, s:].copy()
        tail[0] = q0
        problem = ContextProblem(backbone.ident, params[b], tail, np.asarray(torque_ctx[b, s:], dtype=np.float64), v0)
        z = space.to_unit(params[b][space.index])
        simulated = tail[1:] + problem.joint_error(z[None]).reshape(-1, out.shape[2])  # rows 1.. of the tail
        if not np.all(np.isfinite(simulated)) or np.abs(simulated - tail[1:]).max() > 0.1:
            continue  # a simulation that left the context far behind says nothing of its end
        out[b, s + 1:] = denoised_end(tail[1:] - simulated, simulated, tail_len)
    return out
