"""``make demo``: the main job end to end on a small built-in default.

1. Generates a small dataset of every task (multi-sine, chirp, OSC circle and spiral) with
   the recipes in ``datamodules/``, prints each summary and draws its trajectories.
2. Trains the CPU-sized meta-model briefly on a multi-sine training set.
3. Evaluates it on held-out robots it never saw (context alone), beside the baselines,
   with the horizon and context sweeps, and prints the per-channel table.
4. Writes the HTML report of all runs (``results/report.html``) and prints its path.
5. Ends with the RMS errors by horizon in physical units (joint angles [mrad], end-effector
   position [mm] and orientation [mrad]) of the model, ``hold`` and ``nominal_physics``.

Re-running skips datasets that are complete and resumes the training run.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from robomorph.data.store import open_store
from robomorph.data.summary import plot, summarize
from robomorph.reproduction.skip import ensure_store
from robomorph.sim.recipe import load_recipe

TASKS = ("multisine", "chirp", "circle", "spiral")


def make_data(out_dir: str, robots: int, steps: int, workers: int | None = None) -> list[str]:
    """Generates, summarizes and plots one small dataset per task; returns the store paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for task in TASKS:
        path = _generate(task, os.path.join(out_dir, f"{task}.zarr"), {"robots": robots, "steps": steps}, workers)
        ds = open_store(path)
        print(summarize(ds))
        png = os.path.join(out_dir, f"{task}.png")
        plot(ds, png, n_traj=3)
        print(f"plots: {png}\n")
        paths.append(path)
    return paths


def _generate(task: str, path: str, overrides: dict, workers: int | None) -> str:
    recipe = load_recipe(f"datamodules/{task}.yaml", overrides)
    t0 = time.time()
    # A demo store from another recipe (e.g. an older version) is replaced, not refused.
    ensure_store(recipe, path, workers=workers)
    print(f"=== {path}: {time.time() - t0:.1f} s ===")
    return path


def train(out_dir: str, robots: int, minutes: float, runs_dir: str) -> tuple[str, str, str]:
    """Trains on ``robots`` multi-sine robots; returns (run dir, best checkpoint, held-out store)."""
    from robomorph.training.fitting import fit  # noqa: PLC0415  (torch/lightning only when training)

    train = _generate("multisine", os.path.join(out_dir, "ms_train.zarr"), {"robots": robots, "seed": 0}, None)
    test = _generate("multisine", os.path.join(out_dir, "ms_heldout.zarr"), {"robots": 64, "seed": 1}, None)
    result = fit(["--config", "datamodules/train_cpu.yaml", "--data.stores", train, "--data.test_store", test,
                  "--data.split", "[0.95, 0.05, 0.0]", "--trainer.max_time", _ddhhmmss(minutes * 60),
                  "--trainer.val_check_interval", "200", "--run", "demo", "--runs_dir", runs_dir])
    return result.run_dir, result.best_ckpt, test


def evaluate_and_report(ckpt: str, test: str, runs_dir: str) -> tuple[str, str, dict]:
    """Scores held-out robots (model and baselines, both sweeps) and builds the HTML report."""
    from robomorph.evaluation.evaluator import default_out, evaluate, summary_text  # noqa: PLC0415
    from robomorph.reporting.dashboard import build_report  # noqa: PLC0415

    out = default_out(ckpt, test)
    res = evaluate(ckpt, test, out, sweep_horizon_spec="100:800:100", sweep_context_spec="20:200:20")
    with open(os.path.join(out, "table.md")) as f:
        print("\n" + f.read())
    print(summary_text(res, out, horizons=False))  # the demo closes with the horizon table
    report = build_report(runs_dir, os.path.join(os.path.dirname(os.path.abspath(runs_dir)), "report.html"))
    return out, report, res


def _ddhhmmss(seconds: float) -> str:
    """Lightning's max_time string (DD:HH:MM:SS)."""
    s = int(seconds)
    return f"{s // 86400:02d}:{s % 86400 // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m robomorph.demo", description=__doc__.split("\n")[0])
    p.add_argument("--out-dir", default="data/demo")
    p.add_argument("--robots", type=int, default=32, help="robots per task in the showcase datasets")
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--train-robots", type=int, default=1024)
    p.add_argument("--minutes", type=float, default=6.0, help="training budget (wall clock)")
    p.add_argument("--runs-dir", default="results/runs")
    p.add_argument("--workers", type=int, default=None)
    args = p.parse_args(argv)
    paths = make_data(args.out_dir, args.robots, args.steps, args.workers)
    run_dir, ckpt, test = train(args.out_dir, args.train_robots, args.minutes, args.runs_dir)
    eval_dir, report, res = evaluate_and_report(ckpt, test, args.runs_dir)
    print(f"\ndatasets: {', '.join(paths)}")
    print(f"training run: {run_dir} (config.yaml, checkpoints/best.ckpt, logs/metrics.csv, wandb/)")
    print(f"evaluation: {eval_dir} (metrics.json, metrics.csv, table.md, plots)")
    print(f"report: {report}  (open it in a browser; it works offline)")
    print(horizon_summary(res))
    return 0


def horizon_summary(res: dict) -> str:
    """The closing table: RMS error by horizon of the model, hold and nominal physics."""
    from robomorph.evaluation.horizons import horizon_markdown  # noqa: PLC0415

    meta = res["meta"]
    return (f"\nRMS error by horizon on {meta['n']} held-out robots (context {meta['context_len']} steps; "
            "step k is k dt after the last context sample):\n"
            + horizon_markdown(res["horizons"], ("model", "hold", "nominal_physics")))


if __name__ == "__main__":
    sys.exit(main())
