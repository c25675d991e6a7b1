"""Zero-shot morphology: a model trained on a mixture of arms predicts an arm it never saw.

Generates multi-sine stores of the training arms (default: the 7-joint Panda, iiwa, xArm7,
Sawyer and Jaco) and of held-out robots of the held-out arms (default: Kinova3, also
7-joint), trains the CPU-sized black-box model on the mixture for ``--minutes`` (the
command formulation; the hybrid's parameter head is the Panda's), then scores each held-out
arm with :func:`robomorph.evaluation.scoring.score_windows` beside ``hold`` and the arm's own
catalogue physics (``nominal_physics``) on the same windows. Printed and written: joint RMS
error [mrad] at steps 1, 15, 60, 300 and 800, and the issue-23 checks over all 800 steps:
below hold at every step, and below the catalogue wherever the catalogue is below hold.

    python benchmarks/arms_zero_shot.py --minutes 20 --out results/benchmarks/arms_zero_shot.md
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from common import print_provenance

from robomorph.core.results import markdown_table, provenance, write_markdown
from robomorph.core.rundir import RunDir

STEPS = (1, 15, 60, 300, 800)


def _store(robot: str, path: str, robots: int, seed: int) -> str:
    from robomorph.reproduction.skip import ensure_store  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    ensure_store(load_recipe("datamodules/multisine.yaml", {"robot": robot, "robots": robots, "seed": seed}), path)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--train", default="panda,iiwa,xarm7,sawyer,jaco")
    p.add_argument("--heldout", default="kinova3")
    p.add_argument("--robots", type=int, default=192, help="training robots per arm")
    p.add_argument("--test-robots", type=int, default=16)
    p.add_argument("--minutes", type=float, default=20.0)
    p.add_argument("--data", default="data/arms_zero_shot")
    p.add_argument("--runs-dir", default="results/runs")
    p.add_argument("--out", default=None, help="Markdown result file")
    args = p.parse_args()
    prov = provenance()
    print_provenance()
    from robomorph.core.recipes import locate  # noqa: PLC0415
    from robomorph.evaluation.scoring import MODEL, score_windows  # noqa: PLC0415
    from robomorph.evaluation.windows import load_window  # noqa: PLC0415
    from robomorph.model.predictor import Predictor  # noqa: PLC0415
    from robomorph.training.fitting import fit  # noqa: PLC0415

    train = [_store(r, os.path.join(args.data, f"{r}.zarr"), args.robots, 0) for r in args.train.split(",")]
    tests = {r: _store(r, os.path.join(args.data, f"{r}_heldout.zarr"), args.test_robots, 1)
             for r in args.heldout.split(",")}
    hh, mm = divmod(int(args.minutes * 60), 3600)
    result = fit(["--config", locate("datamodules/train_cpu.yaml"), "--data.stores", "[" + ", ".join(train) + "]",
                  "--data.split", "[0.95, 0.05, 0.0]", "--data.inputs", "command", "--model.physics", "none",
                  "--trainer.max_time", f"00:{hh:02d}:{mm // 60:02d}:{mm % 60:02d}",
                  "--trainer.val_check_interval", "200", "--run", "arms-zero-shot", "--runs_dir", args.runs_dir])
    ckpt = result.best_ckpt or result.last_ckpt
    pred = Predictor.from_checkpoint(ckpt)
    info = pred.data_info
    rows, checks = [], []
    for robot, path in tests.items():
        w = load_window(path, info["context_len"], info["horizon"], args.test_robots, info, pred.n_u, pred.n_y,
                        "start", 0, pred.inputs)
        base = score_windows(None, w, ("hold", "nominal_physics"))
        model = score_windows(pred, w, ())
        curves = {"model": model.curve(MODEL, "joints"), "hold": base.curve("hold", "joints"),
                  "catalogue": base.curve("nominal_physics", "joints")}
        for name, c in curves.items():
            rows.append([robot, name, *(float(c[k - 1]) for k in STEPS)])
        below_hold = curves["model"] < curves["hold"]
        cat_wins = curves["catalogue"] < curves["hold"]
        below_cat = curves["model"][cat_wins] < curves["catalogue"][cat_wins]
        checks.append([robot, f"{below_hold.mean():.0%} of 800 steps", f"{below_cat.mean():.0%} of "
                       f"{int(cat_wins.sum())} steps" if cat_wins.any() else "catalogue never below hold"])
    table = markdown_table(["arm", "predictor"] + [f"step {k}" for k in STEPS], rows, floatfmt=".4g")
    goals = markdown_table(["held-out arm", "model below hold", "model below catalogue where it beats hold"], checks)
    print(table + "\n\n" + goals)
    if args.out:
        run = RunDir.of_checkpoint(ckpt)
        write_markdown(args.out, f"# Zero-shot morphology: {args.heldout} predicted by a model of {args.train}\n\n"
                       f"Multi-sine, command formulation, {args.robots} robots per training arm, {args.minutes:g} "
                       f"minutes of 2-core training (`train_cpu.yaml`, black-box model; run `{run.path}`, "
                       f"{result.global_step} steps), {args.test_robots} held-out robots per arm, context 200, "
                       "horizon 800. Joint RMS error [mrad] at step k (k dt after the last context sample).\n\n"
                       f"{table}\n\nIssue 23's zero-shot checks over the 800 steps:\n\n{goals}\n", prov)
    return 0


if __name__ == "__main__":
    sys.exit(main())
