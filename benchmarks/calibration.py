"""Does recalibrating the Gaussian head's std by horizon make its coverage right on new robots?

For each checkpoint: fit the calibration on the fit's validation robots with each method
(``robomorph.calibrate``, into temporary copies), then score the head's own std and each
calibrated one on a held-out store, from the trajectory start and from random offsets
(seed 0, 300 predicted steps): joint-angle ±1σ / ±2σ coverage at the README's five horizons, the mean absolute
miss of 68.3 % / 95.4 % over all predicted steps, and the mean Gaussian NLL per value
relative to the uncalibrated head (negative: better; units cancel).

    python benchmarks/calibration.py \\
        --ckpt total-best=data/quality/confirm_runs_total/full/checkpoints/best.ckpt \\
        --ckpt total-last=data/quality/confirm_runs_total/full/checkpoints/last.ckpt \\
        --ckpt command-best=data/quality/confirm_runs_command/full_command/checkpoints/best.ckpt \\
        --ckpt command-last=data/quality/confirm_runs_command/full_command/checkpoints/last.ckpt \\
        --test data/quality/ms_heldout.zarr --csv results/benchmarks/calibration.csv
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from robomorph.evaluation.calibrating import calibrate  # noqa: E402
from robomorph.evaluation.evaluator import predict  # noqa: E402
from robomorph.evaluation.horizons import coverage  # noqa: E402
from robomorph.evaluation.windows import load_window  # noqa: E402
from robomorph.model.calibration import StdCalibration  # noqa: E402
from robomorph.model.checkpoint import load_checkpoint_file  # noqa: E402
from robomorph.model.predictor import Predictor  # noqa: E402

STEPS = (0, 15, 60, 300, 799)  # first step, 0.25 s, 1 s, 5 s, 13.3 s at 60 Hz (0-based)
TARGET = {1: 0.6827, 2: 0.9545}
RANDOM_HORIZON = 300  # as benchmarks/horizon_ablation.py: context 200 + 300 steps from a random offset


def _windows(pred: Predictor, test: str, offset: str):
    """The training window from the start; from random offsets, a shorter horizon leaves them room."""
    info = pred.data_info
    horizon = info["horizon"] if offset == "start" else RANDOM_HORIZON
    return load_window(test, info["context_len"], horizon, None, info, pred.n_u, pred.n_y, offset, 0, pred.inputs)


def score(y: np.ndarray, mean: np.ndarray, std: np.ndarray, factors: np.ndarray, joints: list[int]) -> dict:
    """Coverage at STEPS, mean miss over all steps (joints) and NLL relative to factors = 1 (all channels)."""
    z_raw = np.abs(y - mean) / std
    z = z_raw / factors[None]
    cover = coverage(y, mean, std * factors[None], list(range(1, y.shape[1] + 1)), tuple(joints))
    out = {}
    for k in (1, 2):
        per_step = np.asarray(cover[f"{k}sigma"])
        out[f"cover{k}"] = [float(per_step[t]) for t in STEPS if t < len(per_step)]
        out[f"miss{k}"] = float(np.abs(per_step - TARGET[k]).mean())
    out["dnll"] = float(np.mean(np.log(factors)[None] + 0.5 * z ** 2 - 0.5 * z_raw ** 2))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", action="append", required=True, metavar="NAME=CKPT")
    p.add_argument("--test", required=True, help="held-out store (robots neither trained nor calibrated on)")
    p.add_argument("--csv", default="results/benchmarks/calibration.csv")
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for item in a.ckpt:
            name, ckpt = item.split("=", 1)
            pred = Predictor.from_checkpoint(ckpt, device="cpu")
            step = int(load_checkpoint_file(ckpt)["global_step"])
            cals = {"none": None}
            for method in ("nll", "quantile"):
                out = os.path.join(tmp, f"{name}-{method}.ckpt")
                report = calibrate(ckpt, out=out, method=method)
                cals[method] = StdCalibration.from_dict(report["calibration"])
                print(f"{name}: {method} fitted on {report['calibration']['source']['n']} validation windows",
                      file=sys.stderr)
            for offset in ("start", "random"):
                w = _windows(pred, a.test, offset)
                u_ctx, y_ctx, u_q, y_q = w.split()
                y_q = y_q.astype(np.float64)
                joints = [i for i, n in enumerate(w.y_names) if n.startswith("q")]
                with pred.raw_std():
                    mean, std = predict(pred, u_ctx, y_ctx, u_q, 64, with_std=True)
                for method, cal in cals.items():
                    f = np.ones(std.shape[1:]) if cal is None else cal.factors(std.shape[1])
                    s = score(y_q, mean, std, f, joints)
                    rows.append({"model": name, "step": step, "offset": offset, "method": method, "windows": len(u_ctx),
                                 "cover1sigma": "/".join(f"{c:.2f}" for c in s["cover1"]),
                                 "cover2sigma": "/".join(f"{c:.2f}" for c in s["cover2"]),
                                 "miss1sigma": round(s["miss1"], 4), "miss2sigma": round(s["miss2"], 4),
                                 "dnll_vs_raw": round(s["dnll"], 4)})
                    print(rows[-1], file=sys.stderr)
    os.makedirs(os.path.dirname(a.csv) or ".", exist_ok=True)
    with open(a.csv, "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    head = ["model", "training step", "windows", "method", "±1σ coverage (5 horizons)", "±2σ coverage", "mean miss ±1σ / ±2σ",
            "ΔNLL vs head"]
    print("| offset | " + " | ".join(head) + " |")
    print("|" + "---|" * (len(head) + 1))
    for r in rows:
        print(f"| {r['offset']} | {r['model']} | {r['step']} | {r['windows']} | {r['method']} | {r['cover1sigma']} | "
              f"{r['cover2sigma']} | {100 * r['miss1sigma']:.1f} / {100 * r['miss2sigma']:.1f} pts | "
              f"{r['dnll_vs_raw']:+.3f} |")


if __name__ == "__main__":
    main()
