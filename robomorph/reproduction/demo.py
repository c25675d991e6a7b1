"""``make demo``: the main job end to end on a small built-in default.

1. Generates a small dataset of every task (multi-sine, chirp, OSC circle and spiral) with
   the recipes in ``datamodules/``, writes each summary and a plot of its trajectories beside it,
   and prints one line for each.
2. Trains the CPU-sized meta-model briefly on robots of the ``realistic`` recipe (encoder noise, torque
   offsets, latency, payloads, real friction, feedback control: :mod:`robomorph.sim.realism`), and holds
   out others of the same recipe, in the command
   formulation by default: the hybrid model (``physics: auto`` in ``train_cpu.yaml``),
   whose predictions simulate the robot identified from the context
   (:mod:`robomorph.inference.hybrid`); ``--inputs total`` trains on the paper's total torque.
3. Gives the model's predicted standard deviation its calibration by horizon. A hybrid's default
   mode predicts what ``Predictor.from_arm("panda")`` predicts, to the bit, so the calibration
   shipped for that one (fitted on 256 other simulated robots, :mod:`robomorph.inference.catalogue`)
   is its own, and is copied into the checkpoint; otherwise (``--inputs total``, or a recipe the
   shipped one was not fitted on) ``robomorph calibrate`` fits one on the training run's validation
   robots (a total-torque model first gets its physics/decoder blend).
4. Evaluates the model on held-out robots it never saw (context alone), beside the baselines, with
   short horizon and context sweeps, and writes the HTML report of all runs (``results/report.html``).
5. Ends with one table, the RMS errors by horizon in physical units (joint angles [mrad],
   end-effector position [mm] and orientation [mrad]) of the model, ``hold``, ``nominal_physics``
   and ``identified_physics`` (when asked for), and the paths of what it wrote. The per-channel
   table and the calibration's are in the evaluation folder (``table.md``, ``metrics.json``) and the
   report, and printed with ``--verbose``.

Every long phase reports its progress on stderr. Re-running skips datasets that are complete and
resumes the training run.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

from robomorph.core.atomic import check_outside_stores
from robomorph.core.errors import UsageError
from robomorph.core.names import TASKS
from robomorph.core.progress import Phase
from robomorph.core.recipes import locate
from robomorph.core.rundir import RunDir
from robomorph.data.store import open_store
from robomorph.data.summary import plot, summarize
from robomorph.model.files import CheckpointError
from robomorph.reproduction.skip import ensure_store
from robomorph.sim.recipe import load_recipe

# The evaluation's sweeps: each setting re-runs the model on every held-out window, so the demo
# sweeps three settings of each (the paper's have 8 and 10): the trend, at a quarter of the passes.
SWEEP_HORIZONS = "200,400,800"
SWEEP_CONTEXTS = "40,120,200"
# 16: a hybrid on the realistic recipe's robots takes a second or more a window (the arm's compensation by its
# catalogue model is simulated step by step, over each robot of the friction mixture), and the evaluation runs
# every window seven times (the scores with their std, three horizons, three contexts).
HELD_OUT_ROBOTS = 16
# What the demo trains and evaluates on: robots as messy as real ones (robomorph.sim.realism), not the clean recipes
# of the paper's tables. Measured on the real UR5's logs, zero-shot, two equal black-box UR5e models (7 minutes each):
# trained on realistic data 67.2 / 103 / 358 / 1210 mrad at step 1 / 0.25 s / 1 s / 5 s, FIT 6.6 %, on clean data
# 68.1 / 110 / 371 / 1220, FIT 4.0 % (CHANGELOG, 2026-11-28).
TRAIN_RECIPE = "realistic"


def make_data(out_dir: str, robots: int, steps: int, workers: int | None = None) -> list[str]:
    """Generates, summarizes and plots one small dataset per task; returns the store paths.

    Each store's full summary (channels, parameter ranges, attributes) goes to ``<task>.txt`` beside it
    (what ``robomorph inspect`` prints), and a plot of three trajectories to ``<task>.png``; the terminal
    gets one line and the files' paths. Every task draws its robots from the same randomization, so the
    parameter histograms (seconds to draw) are drawn once, for the first store."""
    from robomorph.core.atomic import write_text  # noqa: PLC0415
    from robomorph.data.summary import params_plot_path  # noqa: PLC0415

    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for task in TASKS:
        t0 = time.time()
        path = _generate(task, os.path.join(out_dir, f"{task}.zarr"), {"robots": robots, "steps": steps}, workers)
        ds, base = open_store(path), os.path.join(out_dir, task)
        # Drawing takes seconds, a minute on a loaded machine: reported as any long phase.
        with Phase(f"{task}: summary and plots", total=1, unit="store") as phase:
            write_text(f"{base}.txt", summarize(ds) + "\n")
            written = plot(ds, f"{base}.png", n_traj=3, params=not paths)
            phase.update()
        extra = f", parameters: {params_plot_path(base + '.png')}" if len(written) > 1 else ""
        print(f"{path}: {ds.n} robots x {ds.steps} steps in {time.time() - t0:.0f} s "
              f"(summary: {base}.txt, plots: {base}.png{extra})", flush=True)
        paths.append(path)
    return paths


def _generate(task: str, path: str, overrides: dict, workers: int | None) -> str:
    recipe = load_recipe(f"datamodules/{task}.yaml", overrides)
    # A demo store from another recipe (e.g. an older version) is replaced, not refused.
    ensure_store(recipe, path, workers=workers)
    return path


def training_data(out_dir: str, robots: int) -> tuple[str, str]:
    """Generates (or finds) ``robots`` training robots and :data:`HELD_OUT_ROBOTS` held-out ones of
    :data:`TRAIN_RECIPE`; returns their stores' paths."""
    t0 = time.time()
    train = _generate(TRAIN_RECIPE, os.path.join(out_dir, "train.zarr"), {"robots": robots, "seed": 0}, None)
    test = _generate(TRAIN_RECIPE, os.path.join(out_dir, "heldout.zarr"), {"robots": HELD_OUT_ROBOTS, "seed": 1}, None)
    print(f"training robots: {train} ({robots}), held-out robots: {test} ({HELD_OUT_ROBOTS}), {TRAIN_RECIPE} recipe, "
          f"in {time.time() - t0:.0f} s", flush=True)
    return train, test


def train(train: str, test: str, minutes: float, runs_dir: str, inputs: str = "command") -> tuple[str, str]:
    """Trains on the ``train`` store (:func:`training_data`'s), ``test`` the held-out one the run records; returns
    (run dir, best checkpoint)."""
    from robomorph.core.atomic import set_aside  # noqa: PLC0415
    from robomorph.training.fitting import fit  # noqa: PLC0415  (torch/lightning only when training)

    run = "demo" if inputs == "command" else "demo-total"
    # A tenth of the robots validate: the curves of the report, and a total-torque model's blend and calibration.
    args = ["--config", locate("datamodules/train_cpu.yaml"), "--data.stores", train, "--data.test_store", test,
            "--data.split", "[0.9, 0.1, 0.0]", "--trainer.max_time", _ddhhmmss(minutes * 60),
            "--trainer.val_check_interval", "50", "--data.inputs", inputs, "--run", run, "--runs_dir", runs_dir]
    try:
        result = fit(args)
    except CheckpointError as exc:
        # A demo run left by an older version (another model) cannot be resumed: keep it aside, start afresh.
        kept = set_aside(os.path.join(runs_dir, run))
        print(f"note: {exc}\nnote: the earlier demo run is kept at {kept}; training a new one")
        result = fit(args)
    ckpt = result.best_ckpt or result.last_ckpt
    if ckpt is None:  # a budget too short to reach the first validation
        raise UsageError(f"training stopped after {result.global_step} steps without a checkpoint (the first "
                         "is written at the first validation, step 50): give it more --minutes")
    return result.run_dir, ckpt


def calibrate_std(ckpt: str, verbose: bool = False) -> bool:
    """Gives a Gaussian head's or a hybrid's std its calibration by horizon, in place; False for a model
    without one. A command hybrid takes the shipped calibration of the catalogue arm's (:func:`shipped_std`)
    where it applies; otherwise ``robomorph calibrate`` fits one on the fit's validation robots, and a
    total-torque model first gets its physics/decoder blend."""
    from robomorph.evaluation.calibrating import blend, blend_text, calibrate, report_text  # noqa: PLC0415
    from robomorph.evaluation.requests import BlendConfig, CalibrateConfig  # noqa: PLC0415
    from robomorph.inference.calibration import CalibrationError  # noqa: PLC0415
    from robomorph.inference.checkpoint import load_trained  # noqa: PLC0415

    model, info = load_trained(ckpt)
    if (info or {}).get("inputs") == "total" and model.blend is None:
        # Total torques: the identified robot's simulation for the first second, the decoder after
        # (robomorph calibrate --blend); the std below is then the blend's.
        text = blend_text(blend(BlendConfig(ckpt, n=64)))
        print("\n" + text if verbose else "physics/decoder blend fitted on the validation robots", flush=True)
    hybrid = bool(model.config.n_params and (info or {}).get("physics"))
    if not model.gaussian and not hybrid:
        return False
    if hybrid and (line := shipped_std(ckpt)):
        print(line, flush=True)
        return True
    show = report_text if verbose else brief_text
    print(show(calibrate(CalibrateConfig(ckpt))), flush=True)
    if hybrid:
        # What a controller sends: contexts of a robot already moving, whose own calibration this is
        # (windows at random offsets, with room for them: three quarters of the training horizon).
        try:
            moving = CalibrateConfig(ckpt, horizon=max(1, 3 * int(info["horizon"]) // 4), offset="random")
            print(show(calibrate(moving)), flush=True)
        except CalibrationError as exc:
            print(f"(no calibration for windows of a moving robot: {exc}; the start windows' serves them)")
    return True


def shipped_std(ckpt: str) -> str | None:
    """Copies the shipped calibrations of the catalogue arm's hybrid (:func:`robomorph.inference.catalogue.
    shipped_calibrations`) into a command hybrid's checkpoint, in place, when they apply to it: its default mode
    then predicts what ``Predictor.from_arm`` predicts, mean and spread, so their calibration is its own, fitted on
    more robots than its validation split holds and at no cost here. Returns the line to print, or None (none
    applies: another arm, recipe or physics step)."""
    from robomorph.inference.calibration import CALIBRATION_KEY, calibrations_entry, read_calibrations  # noqa: PLC0415
    from robomorph.inference.catalogue import shipped_calibrations  # noqa: PLC0415
    from robomorph.model.files import DATA_INFO_KEY, read_model, write_model  # noqa: PLC0415

    record = read_model(ckpt)
    shipped = shipped_calibrations(record.get(DATA_INFO_KEY) or {})
    if not shipped:
        return None
    record[CALIBRATION_KEY] = calibrations_entry({**read_calibrations(record.get(CALIBRATION_KEY)), **shipped})
    write_model(record, ckpt)
    src = next(c.source for key, c in shipped.items() if not key.endswith("/moving"))
    after = src["held_out"]["after"]
    span = lambda v: f"{min(v):.0%}-{max(v):.0%}"  # noqa: E731
    return (f"std: the {src['arm']}'s shipped calibration (fitted on {src['robots']} simulated robots; on "
            f"{src['held_out']['robots']} others ±1σ covers {span(after['1sigma'])}, ±2σ {span(after['2sigma'])} of "
            "the joints' errors over the horizon; ideal 68 % / 95 %)")


def brief_text(report: dict) -> str:
    """One line of :func:`robomorph.evaluation.calibrating.report_text`: where the std was calibrated, the coverage before and after."""
    src, b, a = report["calibration"]["source"], report["before"], report["after"]
    span = lambda v: f"{min(v):.0%}" if f"{min(v):.0%}" == f"{max(v):.0%}" else f"{min(v):.0%}-{max(v):.0%}"  # noqa: E731
    where = ("validation" if src["split"] == "val" else "held-out") + " windows from " + \
        ("the start" if src.get("offset", "start") == "start" else "random offsets")
    return (f"std calibrated ({report['calibration']['method']}) on {src['n']} {where}: ±1σ covers "
            f"{span(b['1sigma'])} -> {span(a['1sigma'])}, ±2σ {span(b['2sigma'])} -> {span(a['2sigma'])} of them "
            "over the horizon (ideal 68 % / 95 %)")


def evaluate_and_report(ckpt: str, test: str, runs_dir: str, identified: bool = False,
                        verbose: bool = False) -> tuple[str, str, dict]:
    """Scores held-out robots (model and baselines, both sweeps) and builds the HTML report.

    ``identified`` adds the opt-in ``identified_physics`` baseline: a per-window fit of the
    robot's parameters that costs seconds per window (minutes over the demo's held-out robots).
    """
    from robomorph.evaluation.baselines import BASELINES, OPT_IN  # noqa: PLC0415
    from robomorph.evaluation.evaluator import evaluate, summary_text  # noqa: PLC0415
    from robomorph.evaluation.requests import EvaluateConfig  # noqa: PLC0415
    from robomorph.reporting.dashboard import build_report, default_out  # noqa: PLC0415

    calibrate_std(ckpt, verbose)
    out = RunDir.of_checkpoint(ckpt).eval_dir(test)
    request = EvaluateConfig(test, ckpt=ckpt, out=out, baselines=BASELINES + (OPT_IN if identified else ()),
                             sweep_horizon_spec=SWEEP_HORIZONS, sweep_context_spec=SWEEP_CONTEXTS)
    # evaluate reports its model batches and sweeps; this outer line covers what it does between them
    # (the baselines, reading the training data for arx_train, the plots: tens of seconds on a loaded machine).
    with Phase("evaluation", total=1, unit="store") as phase:
        res = evaluate(request)
        phase.update()
    if verbose:
        with open(os.path.join(out, "table.md")) as f:
            print("\n" + f.read())
        print(summary_text(res, out, horizons=False))
    with Phase("report", total=1, unit="page") as phase:
        report = build_report(runs_dir, default_out(runs_dir))
        phase.update()
    return out, report, res


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
    seconds: dict = field(default_factory=dict)  # wall-clock seconds of each step


def run_demo(out_dir: str = "data/demo", robots: int = 16, steps: int = 1000, train_robots: int = 128,
             minutes: float = 1.5, runs_dir: str = "results/runs", workers: int | None = None,
             identified: bool = False, inputs: str = "command", verbose: bool = False) -> DemoResult:
    """The steps of the module docstring, in order."""
    for flag, folder in (("--out", out_dir), ("--runs-dir", runs_dir)):  # before any folder is made
        check_outside_stores(folder, flag, may_be_store=False)
    t0 = time.time()
    paths = make_data(out_dir, robots, steps, workers)
    train_store, test = training_data(out_dir, train_robots)
    t1 = time.time()
    run_dir, ckpt = train(train_store, test, minutes, runs_dir, inputs)
    t2 = time.time()
    eval_dir, report, res = evaluate_and_report(ckpt, test, runs_dir, identified, verbose)
    seconds = {"data": t1 - t0, "training": t2 - t1, "evaluation": time.time() - t2}
    return DemoResult(paths, run_dir, eval_dir, report, res, seconds)


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
