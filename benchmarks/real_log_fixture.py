"""Logs that behave like a real arm's: the fixture of the README's "Your own robot" section.

A 6-joint arm (6 torques in, 6 joint angles out) logged at 10 Hz, one CSV file per
recording, recordings of unequal length, with measurement noise on every column. The arm
is simulated at 200 Hz and sampled every 100 ms: joint ``i`` is a damped pendulum with a
gravity load ``g_i sin(q_i)``, stiffness and damping that differ per joint, and coupling to
its neighbours; the torques are slowly varying random steps and sines around a holding
torque (joint 2 works around -6 N m, as a real shoulder does).

    python benchmarks/real_log_fixture.py --out data/arm6_logs [--lengths 1834,1207,953,1519,702] [--seed 0]

writes ``rec0.csv ...`` with columns ``t, tau1..tau6 [N m], q1..q6 [rad]``.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

N_JOINTS, DT, SUBSTEPS = 6, 0.1, 20
U_COLS = [f"tau{i + 1}" for i in range(N_JOINTS)]
Y_COLS = [f"q{i + 1}" for i in range(N_JOINTS)]
DEFAULT_LENGTHS = (1834, 1207, 953, 1519, 702)
# Per joint: inertia [kg m^2], damping [N m s/rad], stiffness [N m/rad], gravity load [N m].
_INERTIA = np.array([1.2, 1.5, 0.9, 0.5, 0.3, 0.2])
_DAMPING = np.array([2.0, 2.5, 1.5, 0.8, 0.5, 0.3])
_STIFFNESS = np.array([4.0, 3.0, 2.5, 1.5, 1.0, 0.8])
_GRAVITY = np.array([0.0, 6.0, 3.0, 1.0, 0.4, 0.0])
_HOLD = np.array([0.0, -6.0, -2.5, -0.8, 0.0, 0.0])  # holding torques [N m]
_COUPLING = 0.3  # N m/rad between neighbouring joints
_NOISE_U, _NOISE_Y = 0.05, 0.002  # measurement noise std: N m, rad


def _torques(rng: np.random.Generator, samples: int) -> np.ndarray:
    """(samples, 6) torques at 10 Hz: holding torque + random steps + two sines per joint."""
    t = np.arange(samples) * DT
    steps = np.repeat(rng.normal(0, 1.5, size=(samples // 30 + 1, N_JOINTS)), 30, axis=0)[:samples]
    freq, phase = rng.uniform(0.05, 0.6, (2, N_JOINTS)), rng.uniform(0, 2 * np.pi, (2, N_JOINTS))
    sines = sum(np.sin(2 * np.pi * freq[k] * t[:, None] + phase[k]) for k in range(2))
    return _HOLD + steps + 1.2 * sines


def simulate(tau: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Joint angles (samples, 6) at 10 Hz under zero-order-held torques (semi-implicit Euler)."""
    h = DT / SUBSTEPS
    q, qd = q0.astype(np.float64).copy(), np.zeros(N_JOINTS)
    out = np.empty_like(tau)
    for k, u in enumerate(tau):
        out[k] = q  # the sample at the start of the interval, before tau[k] acts
        for _ in range(SUBSTEPS):
            neighbours = np.zeros(N_JOINTS)
            neighbours[1:] += q[:-1] - q[1:]
            neighbours[:-1] += q[1:] - q[:-1]
            qdd = (u - _DAMPING * qd - _STIFFNESS * q - _GRAVITY * np.sin(q) + _COUPLING * neighbours) / _INERTIA
            qd += h * qdd
            q += h * qd
    return out


def write_logs(out: str, lengths=DEFAULT_LENGTHS, seed: int = 0, noise: bool = True) -> list[str]:
    """Writes one CSV per recording into ``out``; returns their paths (``noise=False``: the
    same recordings without measurement noise)."""
    os.makedirs(out, exist_ok=True)
    streams = np.random.SeedSequence(seed).spawn(len(lengths))
    paths = []
    for r, (length, stream) in enumerate(zip(lengths, streams)):
        rng = np.random.default_rng(stream)
        tau = _torques(rng, int(length))
        q = simulate(tau, rng.normal(0, 0.1, N_JOINTS))
        scale = 1.0 if noise else 0.0
        noisy_u = tau + scale * rng.normal(0, _NOISE_U, tau.shape)
        noisy_y = q + scale * rng.normal(0, _NOISE_Y, q.shape)
        t = np.arange(int(length)) * DT
        path = os.path.join(out, f"rec{r}.csv")
        header = ",".join(["t", *U_COLS, *Y_COLS])
        np.savetxt(path, np.column_stack([t, noisy_u, noisy_y]), delimiter=",", header=header, comments="",
                   fmt="%.6g")
        paths.append(path)
    return paths


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="folder for the CSV logs")
    p.add_argument("--lengths", default=",".join(map(str, DEFAULT_LENGTHS)), help="samples per recording")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    lengths = [int(v) for v in a.lengths.split(",")]
    for path, n in zip(write_logs(a.out, lengths, a.seed), lengths):
        print(f"{path}: {n} samples ({n * DT:g} s at {1 / DT:g} Hz)")


if __name__ == "__main__":
    main()
