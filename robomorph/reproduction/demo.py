"""``make demo``: the main job end to end on a small built-in default.

1. Generates a small dataset of every task (multi-sine, chirp, OSC circle and spiral) with
   the recipes in ``datamodules/``, writes each summary and a plot of its trajectories beside it,
   and prints one line for each.
2. Trains the CPU-sized meta-model briefly on a multi-sine training set, in the command
   formulation by default: the hybrid model (``physics: auto`` in ``train_cpu.yaml``),
   whose predictions simulate the robot identified from the context
   (:mod:`robomorph.inference.hybrid`); ``--inputs total`` trains on the paper's total torque.
3. Recalibrates the model's predicted standard deviation (a hybrid's: the spread over robots
   around the identified one, for windows from the start and for windows of a moving robot) by horizon
   on the training run's validation robots (``robomorph.calibrate``), then evaluates the model on held-out robots it never saw
   (context alone), beside the baselines, with the horizon and context sweeps, and prints
   the per-channel table.
4. Writes the HTML report of all runs (``results/report.html``) and prints its path.
5. Ends with the RMS errors by horizon in physical units (joint angles [mrad], end-effector
   position [mm] and orientation [mrad]) of the model, ``hold``, ``nominal_physics`` and
   ``identified_physics`` (with its fitting cost per window).

Re-running skips datasets that are complete and resumes the training run.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

from robomorph.core.errors import UsageError
from robomorph.core.names import TASKS
from robomorph.core.recipes import locate
from robomorph.core.rundir import RunDir
from robomorph.data.store import open_store
from robomorph.data.summary import plot, summarize
from robomorph.model.files import CheckpointError
from robomorph.reproduction.skip import ensure_store
from robomorph.sim.recipe import load_recipe


def make_data(out_dir: str, robots: int, steps: int, workers: int | None = None) -> list[str]:
    """Generates, summarizes and plots one small dataset per task; returns the store paths.

    Each store's full summary (channels, parameter ranges, attributes) goes to ``<task>.txt`` beside it
    (what ``robomorph inspect`` prints); the terminal gets its first line and the files' paths."""
    from robomorph.core.atomic import write_text  # noqa: PLC0415

    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for task in TASKS:
        t0 = time.time()
        path = _generate(task, os.path.join(out_dir, f"{task}.zarr"), {"robots": robots, "steps": steps}, workers)
        ds, base = open_store(path), os.path.join(out_dir, task)
        write_text(f"{base}.txt", summarize(ds) + "\n")
        plot(ds, f"{base}.png", n_traj=3)
        print(f"{path}: {ds.n} robots x {ds.steps} steps in {time.time() - t0:.0f} s "
              f"(summary: {base}.txt, plots: {base}.png)")
        paths.append(path)
    return paths


def _generate(task: str, path: str, overrides: dict, workers: int | None) -> str:
    recipe = load_recipe(f"datamodules/{task}.yaml", overrides)
    # A demo store from another recipe (e.g. an older version) is replaced, not refused.
    ensure_store(recipe, path, workers=workers)
    return path


def train(out_dir: str, robots: int, minutes: float, runs_dir: str, inputs: str = "command") -> tuple[str, str, str]:
    """Trains on ``robots`` multi-sine robots; returns (run dir, best checkpoint, held-out store)."""
    from robomorph.training.fitting import fit  # noqa: PLC0415  (torch/lightning only when training)

    t0 = time.time()
    train = _generate("multisine", os.path.join(out_dir, "ms_train.zarr"), {"robots": robots, "seed": 0}, None)
    test = _generate("multisine", os.path.join(out_dir, "ms_heldout.zarr"), {"robots": 64, "seed": 1}, None)
    print(f"training robots: {train} ({robots}), held-out robots: {test} (64), in {time.time() - t0:.0f} s")
    run = "demo" if inputs == "command" else "demo-total"
    args = ["--config", locate("datamodules/train_cpu.yaml"), "--data.stores", train, "--data.test_store", test,
            "--data.split", "[0.95, 0.05, 0.0]", "--trainer.max_time", _ddhhmmss(minutes * 60),
            "--trainer.val_check_interval", "200", "--data.inputs", inputs, "--run", run, "--runs_dir", runs_dir]
    try:
        result = fit(args)
    except CheckpointError as exc:
        # A demo run left by an older version (another model) cannot be resumed: keep it aside, start afresh.
        kept = _set_aside(os.path.join(runs_dir, run))
        print(f"note: {exc}\nnote: the earlier demo run is kept at {kept}; training a new one")
        result = fit(args)
    ckpt = result.best_ckpt or result.last_ckpt
    if ckpt is None:  # a budget too short to reach the first validation
        raise UsageError(f"training stopped after {result.global_step} steps without a checkpoint (the first "
                         "is written at the first validation, step 200): give it more --minutes")
    return result.run_dir, ckpt, test


def evaluate_and_report(ckpt: str, test: str, runs_dir: str, identified: bool = False) -> tuple[str, str, dict]:
    """Scores held-out robots (model and baselines, both sweeps) and builds the HTML report.

    ``identified`` adds the opt-in ``identified_physics`` baseline: a per-window fit of the
    robot's parameters that costs seconds per window (minutes over the demo's 64 robots).
    """
    from robomorph.evaluation.baselines import BASELINES, OPT_IN  # noqa: PLC0415
    from robomorph.evaluation.evaluator import evaluate, summary_text  # noqa: PLC0415
    from robomorph.reporting.dashboard import build_report, default_out  # noqa: PLC0415

    calibrate_std(ckpt)
    out = RunDir.of_checkpoint(ckpt).eval_dir(test)
    # Four horizons and five contexts (the paper's sweeps have 8 and 10): the same trends at half the passes.
    res = evaluate(ckpt, test, out, baselines=BASELINES + (OPT_IN if identified else ()), sweep_horizon_spec="200:800:200",
                   sweep_context_spec="40:200:40")
    with open(os.path.join(out, "table.md")) as f:
        print("\n" + f.read())
    print(summary_text(res, out, horizons=False))  # the demo closes with the horizon table
    report = build_report(runs_dir, default_out(runs_dir))
    return out, report, res


def calibrate_std(ckpt: str) -> bool:
    """Recalibrates a Gaussian head's std by horizon on the fit's validation robots (in place);
    False for a model without one. A total-torque model first gets its physics/decoder blend; a
    hybrid also gets the calibration of windows that do not open their trajectory."""
    from robomorph.evaluation.calibrating import blend, blend_text, calibrate  # noqa: PLC0415
    from robomorph.inference.calibration import CalibrationError  # noqa: PLC0415
    from robomorph.inference.checkpoint import load_trained  # noqa: PLC0415

    model, info = load_trained(ckpt)
    if (info or {}).get("inputs") == "total" and model.blend is None:
        # Total torques: the identified robot's simulation for the first second, the decoder after
        # (robomorph calibrate --blend); the std below is then the blend's.
        print("\n" + blend_text(blend(ckpt, n=64)))
    hybrid = bool(model.config.n_params and (info or {}).get("physics"))
    if not model.gaussian and not hybrid:
        return False
    # One line each: the table by step, and its advice, are `robomorph calibrate`'s (a newcomer cannot act on it here).
    print("\n" + brief_text(calibrate(ckpt)))
    if hybrid:
        # What a controller sends: contexts of a robot already moving, whose own calibration this is
        # (windows at random offsets, with room for them: three quarters of the training horizon).
        try:
            print(brief_text(calibrate(ckpt, horizon=max(1, 3 * int(info["horizon"]) // 4), offset="random")))
        except CalibrationError as exc:
            print(f"\n(no calibration for windows of a moving robot: {exc}; the start windows' serves them)")
    return True


def brief_text(report: dict) -> str:
    """One line of :func:`robomorph.evaluation.calibrating.report_text`: where the std was calibrated, the coverage before and after."""
    src, b, a = report["calibration"]["source"], report["before"], report["after"]
    span = lambda v: f"{min(v):.0%}" if f"{min(v):.0%}" == f"{max(v):.0%}" else f"{min(v):.0%}-{max(v):.0%}"  # noqa: E731
    where = ("validation" if src["split"] == "val" else "held-out") + " windows from " + \
        ("the start" if src.get("offset", "start") == "start" else "random offsets")
    return (f"std calibrated ({report['calibration']['method']}) on {src['n']} {where}: ±1σ covers "
            f"{span(b['1sigma'])} -> {span(a['1sigma'])}, ±2σ {span(b['2sigma'])} -> {span(a['2sigma'])} of them "
            "over the horizon (ideal 68 % / 95 %)")


def _set_aside(path: str) -> str:
    """Renames a run folder to the first free ``<path>.previous-<k>``; returns the new name."""
    k = 1
    while os.path.exists(f"{path}.previous-{k}"):
        k += 1
    os.replace(path, f"{path}.previous-{k}")
    return f"{path}.previous-{k}"


def _ddhhmmss(seconds: float) -> str:
    """Lightning's max_time string (DD:HH:MM:SS)."""
    s = int(seconds)
    return f"{s // 86400:02d}:{s % 86400 // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


@dataclass
class DemoResult:
    """Where the demo left its outputs."""

    stores: list[str]
    run_dir: str
    eval_dir: str
    report: str
    result: dict  # the evaluation's metrics.json content


def run_demo(out_dir: str = "data/demo", robots: int = 32, steps: int = 1000, train_robots: int = 1024,
             minutes: float = 6.0, runs_dir: str = "results/runs", workers: int | None = None,
             identified: bool = False, inputs: str = "command") -> DemoResult:
    """The three steps of the module docstring, in order."""
    paths = make_data(out_dir, robots, steps, workers)
    run_dir, ckpt, test = train(out_dir, train_robots, minutes, runs_dir, inputs)
    eval_dir, report, res = evaluate_and_report(ckpt, test, runs_dir, identified)
    return DemoResult(paths, run_dir, eval_dir, report, res)


def horizon_summary(res: dict) -> str:
    """The closing table: RMS error by horizon of the model, hold, nominal and identified physics."""
    from robomorph.evaluation.horizons import horizon_markdown  # noqa: PLC0415
    from robomorph.evaluation.tables import cost_note  # noqa: PLC0415

    meta = res["meta"]
    cost = cost_note(meta.get("baseline_notes", {}).get("identified_physics", {}))
    return (f"\nRMS error by horizon on {meta['n']} held-out robots (context {meta['context_len']} steps; "
            "step k is k dt after the last context sample):\n"
            + horizon_markdown(res["horizons"], ("model", "hold", "nominal_physics", "identified_physics"))
            + (f"\nidentified_physics: {cost}.\n" if cost else ""))
