"""Where a smoothed horizon's late error comes from, out of distribution (total torques).

On spiral-OSC robots the blend of ``smoothed`` tracks the joints within a few mrad for the
first 5 s and then leaves them (about 16 mrad at step 300, 170 at 700, 340 at 800 against
hold's 294), while in distribution it ends at 34 mrad. Two explanations were open: the
robot identified from an OSC context (whose motions excite the parameters differently), or
the smoother's structure, where the directions the torques to come do not fix (a neutral or
slowly unstable mode) follow the decoder, here out of its training distribution.

This script smooths the same windows (:func:`robomorph.identification.smoother.smooth_windows`, the
smoothed physics alone, no blend) in variants side by side:

- ``identified``: the regression's robot, as the model predicts;
- ``true parameters``: the stored robot, nothing else changed;
- ``true, alphas ...`` / ``true, v_std ...``: the decoder's pull weakened, the model error per
  sample lowered (``SmootherConfig``);
- ``true, decoder = truth``: the recorded horizon as the decoder, std 0.05 rad (the frames
  re-enact the trajectory: near zero);
- ``true, decoder = truth + 0.1 rad``: the same, every joint offset by 0.1 rad: the share of a
  decoder's bias that passes into the smoothed path at each step (in distribution the torques
  to come would hold it out of all but the last steps).

Printed and written: joint RMS error [mrad] over the windows at the chosen steps, with hold and
the decoder beside.

    python benchmarks/smoother_ood.py --ckpt data/quality/blend/best.ckpt --data data/demo/spiral.zarr --n 16 \\
        --md results/benchmarks/smoother_ood_spiral.md
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np
import torch
from common import check_outputs, print_provenance

from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.windows import load_window
from robomorph.inference.predictor import Predictor
from robomorph.identification.smoother import SmootherConfig, smooth_windows

STEPS = (60, 300, 600, 700, 750, 800)
BIAS = 0.1  # rad: the synthetic decoder's offset on every joint
TRUTH_STD = 0.05  # rad: the synthetic decoders' std


def _variants(config) -> list[tuple[str, bool, object, float | None]]:
    """(label, true parameters?, smoother config, synthetic decoder offset or None)."""
    return [("identified", False, config, None),
            ("true parameters", True, config, None),
            ("true, alphas 1/3/8/20", True, dataclasses.replace(config, alphas=(1.0, 3.0, 8.0, 20.0)), None),
            ("true, v_std 3e-5", True, dataclasses.replace(config, v_std=3e-5), None),
            ("true, decoder = truth", True, config, 0.0),
            (f"true, decoder = truth + {BIAS} rad", True, config, BIAS)]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True, help="a total-torque model with a Gaussian head and a physics backbone")
    p.add_argument("--data", required=True, help="a store of simulated Panda robots (with their parameters)")
    p.add_argument("--n", type=int, default=16)
    p.add_argument("--md", default="results/benchmarks/smoother_ood.md")
    p.add_argument("--csv", default=None, help="default: --md with .csv")
    a = p.parse_args(argv)
    check_outputs(md=a.md, csv=a.csv)
    prov = provenance()
    print_provenance()
    pred = Predictor.from_checkpoint(a.ckpt, device="cpu")
    if pred.inputs != "total" or not pred.physics:
        raise SystemExit("error: the smoother is for total-torque models with a physics backbone; pass such a --ckpt")
    info = pred.data_info
    w = load_window(a.data, info["context_len"], info["horizon"], a.n, info, pred.n_u, pred.n_y, "start", 0,
                    pred.inputs)
    if w.params.shape[1] == 0:
        raise SystemExit(f"error: {a.data} holds no robot parameters; pass a simulated store")
    raw = w.split()
    u_ctx, y_ctx, u_q, y_q = (np.asarray(x, dtype=np.float64) for x in raw)
    steps = [s for s in STEPS if s <= w.horizon]
    joints = slice(7, 14)
    hybrid = pred.hybrid()
    tensors = [torch.as_tensor(x) for x in raw[:3]]  # the network's dtype
    with torch.no_grad():
        mean, std = pred.model.forward_dist_raw(*tensors)
    decoder, decoder_std = mean.double().numpy(), std.double().numpy()
    identified = hybrid.identify(tensors[0], tensors[1], "regression", at_rest=bool(w.starts.all()))
    smoothed = {"decoder": decoder}
    for label, true, config, offset in _variants(pred.settings.smoother or SmootherConfig()):
        dec, dec_std = decoder, decoder_std
        if offset is not None:
            dec, dec_std = y_q.copy(), np.full_like(decoder_std, TRUTH_STD)
            dec[..., joints] += offset
        params = np.asarray(w.params, dtype=np.float64) if true else identified
        smoothed[label] = smooth_windows(hybrid.backbone, params, y_ctx[..., joints], u_ctx, u_q, y_ctx[:, -1, 3:7],
                                         dec, dec_std, config, with_std=False)[0]
        print(f"smoothed: {label}", file=sys.stderr, flush=True)
    # Scored as evaluate scores: hold beside the decoder and the variants, on the same windows.
    scores = score_windows(None, w, ("hold",), steps, others=smoothed)
    rows = [{"variant": name, **{str(k): scores.at(name, "joints", k) for k in steps}}
            for name in ("hold", *smoothed)]
    csv = a.csv or a.md.rsplit(".", 1)[0] + ".csv"
    write_rows(csv, rows, prov)
    table = markdown_table(["source", *(f"step {s}" for s in steps)],
                           [[r["variant"], *(f"{r[str(s)]:.3g}" for s in steps)] for r in rows])
    text = (f"# The smoothed physics alone, variants side by side ({a.ckpt} on {len(y_q)} windows of {a.data})\n\n"
            "Joint RMS error [mrad] over the windows from the trajectory start (step k is k dt after the last "
            f"context sample). Synthetic decoders: std {TRUTH_STD} rad.\n\n" + table)
    write_markdown(a.md, text, prov)
    print(table)


if __name__ == "__main__":
    sys.exit(run_command(main))
