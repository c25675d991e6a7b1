"""Why the hybrid loses to constant velocity at the first step on a real arm: its start velocity or its acceleration?

On each real arm with an MJCF (:mod:`robomorph.data.public_logs`, cloned under ``--data``), the hybrid with no
training (``Predictor.from_arm``, on the commands of an arm compensating its gravity with its catalogue model, as
``benchmarks/real_robots.py`` scores it) predicts the first steps of every test window. Its implied velocity and
acceleration at the context's end (second-order differences of the last context sample and its first two predicted
steps) are compared with the recorded ones (the same differences of the recorded samples), joint by joint: the RMS
velocity error, the acceleration error, and the step-1 error each alone would cause. Also the hybrid with its start
velocity replaced by the measured one (the last backward difference, constant velocity's), over the whole horizon.

    python benchmarks/hybrid_first_steps.py --data DIR [--robots kinova_gen3 ur5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile

import numpy as np
from common import print_provenance
from stacking import TIMES, commands

from robomorph.core.errors import run_command
from robomorph.data import public_logs
from robomorph.data.store import open_store
from robomorph.evaluation.windows import load_window


def parse_args(argv=None) -> argparse.Namespace:
    arms = [name for name, s in public_logs.SOURCES.items() if s.arm]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="the folder holding the sources' clones")
    p.add_argument("--robots", nargs="+", default=arms, choices=arms)
    return p.parse_args(argv)


def measure(source, data: str, work: str) -> str:
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    stores = public_logs.write_stores(source, data, f"{work}/{source.name}", overwrite=True)
    test = open_store(stores["test"])
    w = load_window(stores["test"], source.context, source.horizon, None, None, len(test.u_names), len(test.y_names))
    c, dt = w.context_len, w.dt
    y = w.y.astype(np.float64)
    joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
    cmd = commands(source.arm, w.u.astype(np.float64), y, dt)
    nominal = Predictor.from_arm(source.arm, "multisine", dt=dt, gravity_compensation="nominal_model")
    h = np.asarray(nominal.simulate(cmd[:, :c], y[:, :c], cmd[:, c:]), dtype=np.float64)[..., joints]
    q = y[..., joints]
    q0, qm1, yq = q[:, c - 1], q[:, c - 2], q[:, c:]
    v_h, a_h = (-3 * q0 + 4 * h[:, 0] - h[:, 1]) / (2 * dt), (q0 - 2 * h[:, 0] + h[:, 1]) / dt ** 2
    v_t, a_t = (-3 * q0 + 4 * yq[:, 0] - yq[:, 1]) / (2 * dt), (q0 - 2 * yq[:, 0] + yq[:, 1]) / dt ** 2

    def rms(x, axis=None):
        return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))

    k = np.arange(1, yq.shape[1] + 1)[None, :, None]
    cv = q0[:, None] + k * (q0 - qm1)[:, None]
    anchored = h + k * ((q0 - qm1) - v_h * dt)[:, None]  # the hybrid from the measured start velocity
    steps = [(1 if t is None else int(round(t / dt)), label) for t, label in TIMES]
    steps = [(s, label) for s, label in steps if s <= yq.shape[1]]
    lines = [f"## {source.robot}: {len(y)} test windows at {1 / dt:.6g} Hz",
             f"step-1 joint RMS: hybrid {1000 * rms(h[:, 0] - yq[:, 0]):.3g} mrad, constant velocity "
             f"{1000 * rms(cv[:, 0] - yq[:, 0]):.3g}",
             f"start velocity off by {rms(v_h - v_t):.3g} rad/s (recorded speeds {rms(v_t):.3g} RMS): "
             f"{1000 * rms(v_h - v_t) * dt:.3g} mrad at step 1 alone; per joint {np.round(rms(v_h - v_t, 0), 3)}",
             f"acceleration off by {rms(a_h - a_t):.3g} rad/s^2 (recorded {rms(a_t):.3g} RMS): "
             f"{1000 * 0.5 * rms(a_h - a_t) * dt ** 2:.3g} mrad at step 1 alone; per joint {np.round(rms(a_h - a_t, 0), 1)}",
             "joint RMS [mrad] at " + ", ".join(label for _, label in steps) + ":"]
    for name, p in (("constant velocity", cv), ("hybrid", h), ("hybrid from the measured start velocity", anchored)):
        lines.append(f"  {name:40s}" + "".join(f"{1000 * rms(p[:, s - 1] - yq[:, s - 1]):10.3g}" for s, _ in steps))
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse_args(argv)
    print_provenance()
    with tempfile.TemporaryDirectory(prefix="first_steps_") as tmp:
        for name in args.robots:
            print(measure(public_logs.get(name), args.data, tmp) + "\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
