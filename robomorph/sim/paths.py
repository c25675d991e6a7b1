"""The OSC tasks' reference paths: circles (YZ plane) and spirals (XY circles that climb).

Paths start at the EE position with zero velocity and acceleration: the time ``s(t)``
they are parameterized by ramps its rate from 0 to 1 with a quintic smoothstep, so
the controller sees no initial jump.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robomorph.core.config import check_range

TASKS = ("circle", "spiral")


def positive(where: str, **values: float | None) -> None:
    """Raises ``ValueError`` naming ``where.name`` for any value that is not > 0 (None passes)."""
    for name, value in values.items():
        if value is not None and not value > 0:
            raise ValueError(f"{where}.{name} must be > 0, got {value}")


@dataclass(frozen=True)
class CircleConfig:
    """Circle task: YZ plane, radius drawn per trajectory, one period for all robots.

    Attributes:
        radius: radius range [m].
        period: time for one revolution [s] (the paper: the same frequency for all).
        ramp: time over which the path speeds up from rest [s].
    """

    radius: tuple[float, float] = (0.05, 0.15)
    period: float = 6.0
    ramp: float = 1.0

    def __post_init__(self):
        check_range("circle.radius", self.radius)
        positive("circle", radius_low=self.radius[0], period=self.period)
        if not self.ramp >= 0:
            raise ValueError(f"circle.ramp must be >= 0, got {self.ramp}")


@dataclass(frozen=True)
class SpiralConfig:
    """Spiral task: circles in the XY plane while climbing or descending.

    The paper's code drew periods of U(20, 100) samples (0.3-1.7 s at 60 Hz); a 0.12 m
    circle in 0.33 s needs 43 m/s^2, beyond the Panda's torques. Periods are in seconds
    here, drawn so that the largest radius needs at most about 1.2 m/s^2 and every
    revolution spans 120 or more samples.

    Attributes:
        radius: radius range [m].
        period: period range of one revolution [s].
        climb: range of the total height change over the trajectory [m]; the sign
            (up or down) is drawn with probability 1/2. The paper's 0.1-0.4 m failed
            half the time from near the home pose (descents past 0.2 m fold the elbow
            into its limit, climbs past 0.3 m stretch the arm until it saturates or
            collides); with 0.1-0.2 m about 98% pass.
        ramp: time over which the path speeds up from rest [s].
    """

    radius: tuple[float, float] = (0.01, 0.12)
    period: tuple[float, float] = (2.0, 8.0)
    climb: tuple[float, float] = (0.1, 0.2)
    ramp: float = 1.0

    def __post_init__(self):
        for name in ("radius", "period", "climb"):
            check_range(f"spiral.{name}", getattr(self, name))
        positive("spiral", radius_low=self.radius[0], period_low=self.period[0])
        if not self.ramp >= 0:
            raise ValueError(f"spiral.ramp must be >= 0, got {self.ramp}")


def _time_warp(steps: int, dt: float, ramp: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s(t) at the frame times, with s' = h(t / ramp) (quintic smoothstep), and s', s''.

    s, s' and s'' are zero at t = 0 and s' = 1 from ``ramp`` on, so any path x(s) starts
    at rest and then runs at its nominal speed.
    """
    if steps < 1 or not dt > 0:
        raise ValueError(f"steps must be >= 1 and dt > 0, got {steps}, {dt}")
    t = np.arange(steps) * dt
    if ramp <= 0:
        return t.copy(), np.ones_like(t), np.zeros_like(t)
    tau = np.minimum(t / ramp, 1.0)
    # Integral of h over [0, 1] is 1/2: past the ramp s lags t by ramp / 2.
    s = np.where(t < ramp, ramp * tau**4 * (2.5 - 3 * tau + tau**2), t - ramp / 2)
    sd = tau**3 * (10 - 15 * tau + 6 * tau**2)
    sdd = np.where(t < ramp, 30 * tau**2 * (1 - tau) ** 2 / ramp, 0.0)
    return s, sd, sdd


def _ring(radius: float, phase0: float, omega: float, s, sd, sdd):
    """A circle of ``radius`` through the origin at s = 0, in 2-D: (pos, vel, acc) (T, 2)."""
    th = phase0 + omega * s
    thd, thdd = omega * sd, omega * sdd
    cos, sin = np.cos(th), np.sin(th)
    pos = radius * np.stack([cos - np.cos(phase0), sin - np.sin(phase0)], axis=-1)
    tangent = radius * np.stack([-sin, cos], axis=-1)
    normal = radius * np.stack([-cos, -sin], axis=-1)
    return pos, tangent * thd[:, None], normal * (thd**2)[:, None] + tangent * thdd[:, None]


def circle_path(rng: np.random.Generator, start_pos: np.ndarray, steps: int, dt: float,
                cfg: CircleConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draws a circle in the YZ plane through the EE start (random radius, phase, sense).

    Args:
        rng: the trajectory's random stream.
        start_pos: (3,) EE position at t = 0.
        steps: frames T; frame k is at time k dt.
        dt: frame period [s].
        cfg: circle ranges.

    Returns:
        pos, vel, acc: (T, 3) desired EE position [m], velocity and acceleration.
    """
    radius = rng.uniform(*cfg.radius)
    phase0 = rng.uniform(0.0, 2 * np.pi)
    omega = rng.choice([-1.0, 1.0]) * 2 * np.pi / cfg.period
    s, sd, sdd = _time_warp(steps, dt, cfg.ramp)
    pos, vel, acc = (np.zeros((steps, 3)) for _ in range(3))
    for out, part in zip((pos, vel, acc), _ring(radius, phase0, omega, s, sd, sdd)):
        out[:, 1:] = part
    return pos + start_pos, vel, acc


def spiral_path(rng: np.random.Generator, start_pos: np.ndarray, steps: int, dt: float,
                cfg: SpiralConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draws a spiral: an XY circle through the EE start with a steady climb or descent.

    The height changes by the drawn ``climb`` (with a random sign) between the first and
    the last frame, at a rate that follows the same ramp as the revolutions.

    Args and returns as :func:`circle_path`.
    """
    radius = rng.uniform(*cfg.radius)
    period = rng.uniform(*cfg.period)
    climb = rng.choice([-1.0, 1.0]) * rng.uniform(*cfg.climb)
    phase0 = rng.uniform(0.0, 2 * np.pi)
    omega = rng.choice([-1.0, 1.0]) * 2 * np.pi / period
    s, sd, sdd = _time_warp(steps, dt, cfg.ramp)
    rate = climb / s[-1] if steps > 1 else 0.0
    pos, vel, acc = (np.zeros((steps, 3)) for _ in range(3))
    for out, part, z in zip((pos, vel, acc), _ring(radius, phase0, omega, s, sd, sdd), (s, sd, sdd)):
        out[:, :2] = part
        out[:, 2] = rate * z
    return pos + start_pos, vel, acc


PATHS = {"circle": circle_path, "spiral": spiral_path}
