"""Does recalibrating the Gaussian head's std by horizon make its coverage right on new robots?

For each checkpoint: fit the calibration on the fit's validation robots with each method
(``robomorph.calibrate``, into temporary copies), then score the head's own std and each
calibrated one on a held-out store with :func:`robomorph.evaluation.scoring.score_windows`,
from the trajectory start and from random offsets (seed 0, ``--random-horizon`` steps):
joint-angle ±1σ / ±2σ coverage at steps 1, 15, 60, 300 and 800 (first step, 0.25 s, 1 s,
5 s, the end; step k is k dt after the last context sample), the mean absolute miss of
68.3 % / 95.4 % over all predicted steps (joints), and the mean Gaussian NLL per value (all
channels) relative to the uncalibrated head (negative: better; units cancel).

    python benchmarks/calibration.py \\
        --ckpt total-best=data/quality/confirm_runs_total/full/checkpoints/best.ckpt \\
        --ckpt total-last=data/quality/confirm_runs_total/full/checkpoints/last.ckpt \\
        --ckpt command-best=data/quality/confirm_runs_command/full_command/checkpoints/best.ckpt \\
        --ckpt command-last=data/quality/confirm_runs_command/full_command/checkpoints/last.ckpt \\
        --test data/quality/ms_heldout.zarr --csv results/benchmarks/calibration.csv

A hybrid's calibration wants more windows than a validation split holds: ``--cal-data`` fits
on another store of held-out robots (``--n`` of them), e.g. the hybrid's scale alone against
scale and power (``results/benchmarks/calibration_hybrid.csv``):

    python benchmarks/calibration.py --ckpt regression=data/hyb/regression_cal.ckpt \
        --cal-data data/demo/ms_cal256.zarr --n 256 --methods coverage,power --offsets start \
        --test data/demo/ms_test256.zarr --csv results/benchmarks/calibration_hybrid.csv
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

import torch
from common import check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, write_rows
from robomorph.evaluation.calibrating import calibrate
from robomorph.evaluation.requests import CalibrateConfig
from robomorph.evaluation.scoring import Predictions, score_windows
from robomorph.evaluation.windows import load_window
from robomorph.inference.calibration import METHODS, StdCalibration
from robomorph.model.files import read_model
from robomorph.inference.predictor import Predictor


def _windows(pred: Predictor, test: str, offset: str, random_horizon: int):
    """The training window from the start; from random offsets, a shorter horizon leaves them room."""
    info = pred.data_info
    horizon = info["horizon"] if offset == "start" else random_horizon
    return load_window(test, info["context_len"], horizon, None, info, pred.n_u, pred.n_y, offset, 0, pred.inputs)


def score_methods(pred: Predictor, w, cals: dict) -> dict:
    """Per method: coverage at the default steps and miss (joints), NLL relative to the head's own std."""
    with pred.raw_std():
        raw = score_windows(pred, w, ())
    mean, std = raw.preds["model"], raw.std
    out = {}
    for method, cal in cals.items():
        s = raw if cal is None else score_windows(Predictions(mean, cal.scaled(std)), w, ())
        h, c = s.result["horizons"], s.result["calibration"]
        out[method] = {"steps": h["steps"], "cover1": h["calibration"]["joints"]["1sigma"],
                       "cover2": h["calibration"]["joints"]["2sigma"],
                       "miss1": c["coverage_miss"]["joints"]["1sigma"], "miss2": c["coverage_miss"]["joints"]["2sigma"],
                       "dnll": c["nll"]["all"] - raw.result["calibration"]["nll"]["all"]}
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", action="append", required=True, metavar="NAME=CKPT")
    p.add_argument("--test", required=True, help="held-out store (robots neither trained nor calibrated on)")
    p.add_argument("--csv", default="results/benchmarks/calibration.csv")
    p.add_argument("--random-horizon", type=int, default=300, help="predicted steps from random offsets")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--cal-data", default=None, help="store to fit the calibrations on (default: the fit's validation split)")
    p.add_argument("--n", type=int, default=None, help="at most this many calibration windows")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated calibration methods")
    p.add_argument("--offsets", default="start,random", help="which test windows: start, random or both")
    a = p.parse_args(argv)
    check_outputs(csv=a.csv)
    print_provenance()
    torch.set_num_threads(a.threads)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for item in a.ckpt:
            name, ckpt = item.split("=", 1)
            pred = Predictor.from_checkpoint(ckpt, device="cpu")
            step = int(read_model(ckpt).get("global_step", 0))
            cals = {"none": None}
            for method in a.methods.split(","):
                report = calibrate(CalibrateConfig(ckpt=ckpt, data=a.cal_data, out=os.path.join(tmp, f"{name}-{method}.ckpt"),
                                                   n=a.n, method=method))
                cals[method] = StdCalibration.from_dict(report["calibration"])
                print(f"{name}: {method} fitted on {report['calibration']['source']['n']} windows",
                      file=sys.stderr)
            for offset in a.offsets.split(","):
                w = _windows(pred, a.test, offset, a.random_horizon)
                for method, s in score_methods(pred, w, cals).items():
                    rows.append({"model": name, "step": step, "offset": offset, "method": method, "windows": len(w.u),
                                 "steps": "/".join(map(str, s["steps"])),
                                 "cover1sigma": "/".join(f"{c:.3f}" for c in s["cover1"]),
                                 "cover2sigma": "/".join(f"{c:.3f}" for c in s["cover2"]),
                                 "miss1sigma": round(s["miss1"], 4), "miss2sigma": round(s["miss2"], 4),
                                 "dnll_vs_raw": round(s["dnll"], 4)})
                    print(rows[-1], file=sys.stderr)
    write_rows(a.csv, rows)
    head = ["offset", "model", "training step", "windows", "method", "steps", "±1σ coverage", "±2σ coverage",
            "mean miss ±1σ / ±2σ", "ΔNLL vs head"]
    print(markdown_table(head, [[r["offset"], r["model"], r["step"], r["windows"], r["method"], r["steps"],
                                 r["cover1sigma"], r["cover2sigma"],
                                 f"{100 * r['miss1sigma']:.1f} / {100 * r['miss2sigma']:.1f} pts",
                                 f"{r['dnll_vs_raw']:+.3f}"] for r in rows]))


if __name__ == "__main__":
    # A refused result file (another header) or a bad setting: one line, exit code 2.
    sys.exit(run_command(main))
