"""Open-loop torque signals of the paper: multi-sine and chirp (t = k dt).

multi-sine:  u = A0 cos(w0 t) + A1 sin(1.5 w0 t) + A2 cos(2 w0 t) + A3 sin(3 w0 t),
             w0 = 2 pi f0, f0 ~ U(fm/1.5, 1.5 fm), Ai ~ U(-15 fm, 15 fm), divided per joint.
chirp:       u = A cos(w1 (1 + cos(w2 t) / 4) t + phi) + offset,
             A ~ U(-4, 4), phi ~ U(-pi, pi), f1 ~ U(fm, 1.5 fm), f2 ~ U(fm/1.5, 2 fm),
             offset ~ U(-0.5, 0.5).
Each joint draws its own coefficients. These torques ride on top of the gravity
compensation (see :mod:`robomorph.sim.panda`). The values are the Panda's; another arm
passes ``gain`` (how much larger its joints are than the Panda's: :attr:`Arm.joint_gain`),
which also sets its joint count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robomorph.core.config import check_range
from robomorph.sim.panda import N_JOINT


@dataclass(frozen=True)
class SignalConfig:
    """Parameters of the torque signals.

    Attributes:
        fm: main frequency [Hz]; a list means one value drawn uniformly per trajectory.
        amplitude_per_hz: multi-sine amplitudes are U(-a fm, a fm) (paper: 15).
        multisine_divisor: per-joint divisor of the multi-sine (paper's code: 1.3 for
            the first joint, 1.6 for the others). An arm with fewer joints uses the
            first values.
        chirp_amplitude: chirp amplitude A ~ U(-a, a) [N m] (paper: 4).
        chirp_offset: constant offset ~ U(-o, o) [N m] (paper: 0.5).
        scale: per-joint multiplier on the whole signal (1 keeps the paper's torques);
            an arm with fewer joints uses the first values.
    """

    fm: tuple[float, ...] = (0.1, 0.15, 0.2, 0.25)
    amplitude_per_hz: float = 15.0
    multisine_divisor: tuple[float, ...] = (1.3, 1.6, 1.6, 1.6, 1.6, 1.6, 1.6)
    chirp_amplitude: float = 4.0
    chirp_offset: float = 0.5
    scale: tuple[float, ...] = (1.0,) * N_JOINT

    def __post_init__(self):
        if not self.fm or min(self.fm) <= 0:
            raise ValueError(f"signal.fm must be one or more positive frequencies, got {self.fm}")
        for name in ("multisine_divisor", "scale"):
            value = getattr(self, name)
            if len(value) != N_JOINT:
                raise ValueError(f"signal.{name} needs {N_JOINT} values, got {len(value)}")
        if min(self.multisine_divisor) <= 0:
            raise ValueError("signal.multisine_divisor must be positive")
        for name in ("amplitude_per_hz", "chirp_amplitude", "chirp_offset"):
            check_range(f"signal.{name}", (0.0, getattr(self, name)))


def _gain(gain: np.ndarray | None) -> tuple[int, np.ndarray | float]:
    """(joints, per-joint multiplier): the Panda's 7 and 1.0 when no gain is given."""
    return (N_JOINT, 1.0) if gain is None else (len(gain), np.asarray(gain, dtype=np.float64))


def multisine(rng: np.random.Generator, steps: int, dt: float, cfg: SignalConfig,
              gain: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Draws one multi-sine torque signal; returns (steps, n) torques and the fm used."""
    n, gain = _gain(gain)
    fm = float(rng.choice(cfg.fm))
    f0 = rng.uniform(fm / 1.5, 1.5 * fm, n)
    amp = rng.uniform(-cfg.amplitude_per_hz * fm, cfg.amplitude_per_hz * fm, (4, n))
    w0t = 2 * np.pi * f0 * (np.arange(steps) * dt)[:, None]  # (T, 7)
    u = (amp[0] * np.cos(w0t) + amp[1] * np.sin(1.5 * w0t)
         + amp[2] * np.cos(2 * w0t) + amp[3] * np.sin(3 * w0t))
    u = u * (np.asarray(cfg.scale[:n]) / np.asarray(cfg.multisine_divisor[:n]))
    return u * gain, fm


def chirp(rng: np.random.Generator, steps: int, dt: float, cfg: SignalConfig,
          gain: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Draws one chirp torque signal; returns (steps, n) torques and the fm used."""
    n, gain = _gain(gain)
    fm = float(rng.choice(cfg.fm))
    amp = rng.uniform(-cfg.chirp_amplitude, cfg.chirp_amplitude, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    w1 = 2 * np.pi * rng.uniform(fm, 1.5 * fm, n)
    w2 = 2 * np.pi * rng.uniform(fm / 1.5, 2 * fm, n)
    offset = rng.uniform(-cfg.chirp_offset, cfg.chirp_offset, n)
    t = (np.arange(steps) * dt)[:, None]
    u = amp * np.cos(w1 * (1 + 0.25 * np.cos(w2 * t)) * t + phi) + offset
    return u * np.asarray(cfg.scale[:n]) * gain, fm


SIGNALS = {"multisine": multisine, "chirp": chirp}
