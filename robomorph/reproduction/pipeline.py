"""``python -m robomorph.reproduce``: the paper's tables and context figure, end to end.

    python -m robomorph.reproduce table1 --scale ci
    python -m robomorph.reproduce all --scale small --out results/paper/small
    python -m robomorph.reproduce table2 --scale paper --steps-factor 0.1
    python -m robomorph.reproduce table1 --scale small --inputs command
    python -m robomorph.reproduce table1 --scale small --normalization paper_window
    python -m robomorph.reproduce compare --scale small

Targets:

- ``table1``: Table 1, three depths trained on in-distribution multi-sine robots, each
  scored on three in-distribution test stores (test0..test2): R², σ(R²), RMSE, σ(RMSE).
- ``table2``: Table 2, the spiral task: a model pre-trained on a multi-sine + chirp mixture
  scored zero-shot, fine-tuned for B steps, and a model trained from scratch for
  ``scratch_ratio * B`` steps; per-channel R² and FIT in the paper's colour convention.
- ``context``: R² and FIT against the predicted horizon and the context length, for
  Table 1's middle model.
- ``improved``: only Table 1's extra row (the improved model: the project's default options on
  the middle depth, same store and budget), added to an existing ``<out>/table1.*``;
  ``table1`` trains and adds it itself (leak-free runs only).
- ``all``: table1, table2 and context in order, sharing data and models.
- ``collect``: the tables and the figure from the evaluations already in ``--work``, training and scoring nothing
  (for a command cut short, or runs fetched back from another machine without their
  checkpoints; :mod:`robomorph.reproduction.collect`).
- ``compare``: Table 1 under both normalizations side by side with the paper's figures,
  from the ``table1.json`` of a ``train_stats`` and a ``paper_window`` output folder
  (:mod:`robomorph.reproduction.protocols`); trains nothing.

``--normalization paper_window`` trains and scores every model with the paper's protocol
(each window z-scored over context and query, so predictions use the query outputs'
statistics); its runs are named ``...-paper_window`` beside the leak-free ones on the same
stores, its tables go to ``results/paper/<scale>_paper_window`` by default, and every table
header says which protocol produced it.

Generated stores and training runs (each with its evaluations in ``<run>/eval/``) go to
``--work`` (default ``data/reproduce/<scale>``, not committed), with a dashboard of them all
in ``<work>/report.html``; the tables and the figure go to ``--out`` (default
``results/paper/<scale>``). Every step whose output exists is skipped (complete
stores, runs that reached their budget, evaluations newer than their checkpoint), and an
interrupted run resumes from its last checkpoint: re-run the same command.

``--inputs command`` trains and scores every model on the command formulation (``u_cmd``,
the torque without the gravity compensation the arm adds) instead of the total joint
torque: its runs are named ``...-command``, its tables go to ``results/paper/<scale>-command``
by default and name the formulation in their header.

Run times of each scale: docs/guide/reproducing.md. Sizes and budgets:
:mod:`robomorph.reproduction.scales`.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import platform
import shutil
import time
from dataclasses import dataclass

from robomorph.core.atomic import check_outside_stores
from robomorph.core.errors import MissingInputError, UsageError
from robomorph.core.names import INPUTS, NORMALIZATIONS
from robomorph.core.normalizations import leaks_query_statistics
from robomorph.core.overrides import merge
from robomorph.core.recipes import locate
from robomorph.core.rundir import RunDir
from robomorph.reproduction import skip
from robomorph.reproduction.improved import IMPROVED, improved_overrides
from robomorph.reproduction.runs import (SPIRAL_EVAL, SWEEPS_EVAL, improved_run, pretrain_run, table1_run,
                                         table2_budgets, table2_run, table2_titles)
from robomorph.reproduction.scales import Scale
from robomorph.sim.recipe import load_recipe
from robomorph.training.transfer import regime_overrides

TARGETS = ("table1", "improved", "table2", "context", "all", "compare", "collect")
# (recipe, robots field of the scale, seed): disjoint seeds, so no test robot is a training robot.
STORES = {
    "ms_train": ("multisine", "train_robots", 0),
    **{f"ms_test{i}": ("multisine", "test_robots", 101 + i) for i in range(3)},
    "mixture_train": ("mixture", "mixture_robots", 200),
    "spiral_train": ("spiral", "spiral_robots", 300),
    "spiral_test": ("spiral", "test_robots", 301),
}
TESTS = ("test0", "test1", "test2")


@dataclass(frozen=True)
class Plan:
    """Where a reproduction reads and writes, and how it runs."""

    scale: Scale
    work: str
    out: str
    command: str
    workers: int | None = None
    device: str | None = None
    wandb: str = "offline"
    normalization: str = "train_stats"
    inputs: str = "total"  # the input formulation of every model: total torque or command
    started: float = dataclasses.field(default_factory=time.time)  # for the tables' elapsed time

    def path(self, *parts: str) -> str:
        """A path inside the work folder."""
        return os.path.join(self.work, *parts)

    def run_name(self, name: str) -> str:
        """``name``, suffixed with the normalization unless it is the default and with the input
        formulation unless it is ``total``: runs of every protocol and formulation share the
        work folder's stores without sharing a run directory."""
        name = name if self.normalization == "train_stats" else f"{name}-{self.normalization}"
        return name if self.inputs == "total" else f"{name}-{self.inputs}"


def say(target: str, message: str) -> None:
    """A progress line (stdout, flushed: long steps follow)."""
    print(f"[{target}] {message}", flush=True)


def prepared_store(plan: Plan, key: str, target: str) -> str:
    """The path of store ``key``, generated or resumed first when it is not complete."""
    task, robots_field, seed = STORES[key]
    s = plan.scale
    recipe = load_recipe(recipe_path(task), {"robots": getattr(s, robots_field), "steps": s.steps, "seed": seed})
    path = plan.path("data", f"{key}.zarr")
    need = plan.inputs == "command"
    state = skip.store_state(path, recipe, need)
    if state == "complete":
        say(target, f"data {key}: complete ({recipe.robots} robots x {s.steps} steps), kept")
    else:
        say(target, f"data {key}: generating {recipe.robots} {recipe.task_label} robots x {s.steps} steps ({state}) ...")
        # progress on: generate draws a bar on a terminal and writes a line every few seconds in a log.
        skip.ensure_store(recipe, path, workers=plan.workers, progress=True, need_command=need)
    return path


def recipe_path(name: str) -> str:
    """``datamodules/<name>.yaml`` of the working directory, else the shipped recipe ``name``."""
    return locate(f"datamodules/{name}.yaml", "datamodules")


def base_args(plan: Plan, depth: int, stores: list[str], run: str, steps: int) -> dict:
    """The :func:`robomorph.training.fitting.fit` arguments of a run at this scale."""
    s, paper = plan.scale, plan.normalization == "paper_window"
    return {
        # The paper's protocol z-scores each window itself: no recentring on top (refused otherwise).
        "data": {"stores": stores, "context_len": s.context_len, "horizon": s.horizon, "batch_size": s.batch_size,
                 "split": [1 - s.val_fraction, s.val_fraction, 0.0], "val_subset": s.val_subset, "recenter": not paper,
                 "normalization": plan.normalization, "seed": 0, "inputs": plan.inputs},
        "model": {"d_model": s.d_model, "n_head": s.n_head, "n_layer": depth, "patch": s.patch, "lr": s.lr,
                  "warmup_steps": s.warmup_steps, "max_context": s.context_len, "max_horizon": s.horizon,
                  "loss": "huber", "compile": s.compile},
        "trainer": {"max_steps": steps, "val_check_interval": min(s.val_every, steps), "accelerator": s.accelerator,
                    "devices": 1, "max_time": s.max_time,
                    # fit's step bar on a terminal, and in a log a line every few seconds (minutes between
                    # validations would be silent otherwise).
                    "enable_progress_bar": True,
                    "enable_model_summary": False},
        "run": plan.run_name(run), "runs_dir": plan.path("runs"), "wandb": plan.wandb,
    }


def trained_ckpt(plan: Plan, target: str, args: dict, what: str) -> str:
    """Trains (or resumes, or skips) one run; returns the checkpoint that stands for it."""
    from robomorph.training import fitting  # noqa: PLC0415  (torch and Lightning only when training)

    run_dir = RunDir.named(args["runs_dir"], args["run"]).path
    budget = {"max_steps": args["trainer"]["max_steps"], "max_time": args["trainer"]["max_time"]}
    if skip.run_finished(run_dir, budget):
        say(target, f"{what}: finished run {run_dir}, kept")
        return skip.finished_ckpt(run_dir)
    say(target, f"training {what} ({budget['max_steps']} steps) -> {run_dir} ...")
    result = fitting.fit(args)
    ckpt = result.best_ckpt or result.last_ckpt
    if ckpt is None:
        raise RuntimeError(f"{run_dir}: training wrote no checkpoint")
    # A wall-clock cap may end a run early by design; anything else short of the budget was interrupted.
    if result.global_step < budget["max_steps"] and budget["max_time"] is None:
        raise RuntimeError(f"{run_dir} stopped at step {result.global_step} of {budget['max_steps']}: "
                           "re-run the same command to resume it")
    skip.mark_finished(run_dir, budget, ckpt, result.global_step)
    return ckpt


def scored(plan: Plan, target: str, ckpt: str, data: str, name: str, sweeps: bool = False) -> dict:
    """Evaluates ``ckpt`` on ``data`` into ``<run>/eval/<name>`` unless a fresh result is there.

    That is where ``python -m robomorph.evaluate`` puts an evaluation by default, so the
    reproduction's dashboard (:func:`write_report`) shows every score beside its training run.
    """
    from robomorph.evaluation.evaluator import evaluate  # noqa: PLC0415
    from robomorph.evaluation.requests import EvaluateConfig  # noqa: PLC0415

    layout = RunDir.of_checkpoint(ckpt)
    run, out = layout.name, layout.eval_dir(name)
    if skip.eval_fresh(out, ckpt):
        say(target, f"evaluation {run} on {name}: up to date, kept")
        return skip.read_json(os.path.join(out, "metrics.json"))
    say(target, f"evaluating {run} on {name} ...")
    if skip.stale_evaluation(out):
        shutil.rmtree(out)  # evaluate writes its folder whole and refuses one it cannot recognise
    s = plan.scale
    return evaluate(EvaluateConfig(data=data, ckpt=ckpt, out=out, n=s.eval_n, baselines=("hold",), batch_size=64,
                                   device=plan.device, samples=s.samples,
                                   sweep_horizon_spec=s.sweep_horizon if sweeps else None,
                                   sweep_context_spec=s.sweep_context if sweeps else None,
                                   normalization=plan.normalization))


def table1_ckpt(plan: Plan, depth: int, train_store: str, target: str = "table1") -> str:
    """Trains Table 1's model of ``depth`` layers on the multi-sine training store."""
    s = plan.scale
    args = base_args(plan, depth, [train_store], table1_run(s, depth), s.train_steps)
    return trained_ckpt(plan, target, args, f"{depth}-layer model")


def improved_results(plan: Plan, train_store: str, tests: dict[str, str], target: str = "table1") -> dict[str, dict]:
    """Trains (or keeps) Table 1's improved model at the middle depth and scores it on every test store."""
    s, depth = plan.scale, plan.scale.transfer_depth
    over = improved_overrides(recipe_path("train_cpu"), s.context_len, s.horizon, s.patch)
    args = merge(base_args(plan, depth, [train_store], improved_run(s), s.train_steps), over)
    ckpt = trained_ckpt(plan, target, args, f"improved {depth}-layer model")
    return {t: scored(plan, target, ckpt, path, t) for t, path in tests.items()}


def table1_stores(plan: Plan, target: str = "table1") -> tuple[str, dict[str, str]]:
    """Table 1's training store and its test stores by name."""
    return (prepared_store(plan, "ms_train", target),
            {t: prepared_store(plan, f"ms_test{i}", target) for i, t in enumerate(TESTS)})


def make_table1(plan: Plan) -> dict:
    """Table 1: three depths x three in-distribution test stores, and (leak-free runs) the
    improved model's extra rows; writes table1.md/.tex/.json."""
    from robomorph.reproduction.tables import table1_rows, write_table1  # noqa: PLC0415

    train_store, tests = table1_stores(plan)
    results = {}
    for depth in plan.scale.depths:
        ckpt = table1_ckpt(plan, depth, train_store)
        results[depth] = {t: scored(plan, "table1", ckpt, path, t) for t, path in tests.items()}
    rows = table1_rows(results)
    if plan.normalization == "train_stats":  # the paper's protocol is measured on its own architecture only
        # Written before the improved row trains, so that a command stopped there keeps the paper's rows.
        write_table1(plan.out, rows, {**run_info(plan), "pending": IMPROVED})
        rows += table1_rows({plan.scale.transfer_depth: improved_results(plan, train_store, tests)}, IMPROVED)
    doc = write_table1(plan.out, rows, run_info(plan))
    say("table1", f"written {os.path.join(plan.out, 'table1.md')} (.tex, .json)")
    return doc


def make_improved(plan: Plan) -> dict:
    """Adds (or refreshes) the improved model's rows in an existing ``<out>/table1.*``,
    keeping its other rows and header, and naming this command beside it."""
    from robomorph.reproduction.tables import table1_rows, write_table1  # noqa: PLC0415

    path = os.path.join(plan.out, "table1.json")
    if plan.normalization != "train_stats":
        raise UsageError("the improved row is measured leak-free only: drop --normalization paper_window")
    if not os.path.isfile(path):
        raise MissingInputError(f"{path} not found: run `python -m robomorph.reproduce table1 --scale "
                                f"{plan.scale.name} --out {plan.out}` (it adds the improved row itself)")
    doc = skip.read_json(path)
    info = {k: v for k, v in doc["info"].items() if k != "pending"}  # this command adds what was pending
    if (info.get("scale"), info.get("inputs", "total"), info.get("normalization") or "train_stats") != (
            plan.scale.name, plan.inputs, plan.normalization):
        raise UsageError(f"{path} was written at scale {info.get('scale')!r} with inputs {info.get('inputs', 'total')!r}: "
                         f"pass the same --scale and --inputs (asked: {plan.scale.name!r}, {plan.inputs!r})")
    train_store, tests = table1_stores(plan, IMPROVED)
    rows = [r for r in doc["rows"] if r.get("model", "paper") != IMPROVED]
    rows += table1_rows({plan.scale.transfer_depth: improved_results(plan, train_store, tests, IMPROVED)}, IMPROVED)
    now = run_info(plan)
    info = {**info, IMPROVED: {k: now[k] for k in ("command", "date", "machine")}}
    doc = write_table1(plan.out, rows, info)
    say(IMPROVED, f"added the improved rows to {os.path.join(plan.out, 'table1.md')} (.tex, .json)")
    return doc


def make_table2(plan: Plan) -> dict:
    """Table 2: zero-shot, fine-tuned and from-scratch models on the spiral; writes table2.md/.tex/.json."""
    from robomorph.reproduction.tables import table2_data, write_table2  # noqa: PLC0415

    s, depth = plan.scale, plan.scale.transfer_depth
    mixture, spiral = prepared_store(plan, "mixture_train", "table2"), prepared_store(plan, "spiral_train", "table2")
    test = prepared_store(plan, "spiral_test", "table2")
    pre = base_args(plan, depth, [mixture], pretrain_run(s), s.pretrain_steps)
    pretrained = trained_ckpt(plan, "table2", pre, f"{depth}-layer model on the multi-sine + chirp mixture")
    results = {}
    for regime, steps in table2_budgets(s).items():
        ckpt = pretrained
        over = regime_overrides(regime, pretrained, steps, lr=s.finetune_lr if regime == "finetune" else None)
        if over is not None:
            args = merge(base_args(plan, depth, [spiral], table2_run(s, regime), steps), over)
            ckpt = trained_ckpt(plan, "table2", args, f"{regime} on the spiral")
        results[regime] = scored(plan, "table2", ckpt, test, SPIRAL_EVAL)
    doc = write_table2(plan.out, table2_data(results), table2_titles(s), run_info(plan))
    say("table2", f"written {os.path.join(plan.out, 'table2.md')} (.tex, .json)")
    return doc


def make_context_figure(plan: Plan) -> dict:
    """The context and horizon figure of Table 1's middle model on test0; writes context_horizon.*."""
    from robomorph.reproduction.figures import write_context_figure  # noqa: PLC0415

    ckpt = table1_ckpt(plan, plan.scale.transfer_depth, prepared_store(plan, "ms_train", "context"), "context")
    res = scored(plan, "context", ckpt, prepared_store(plan, "ms_test0", "context"), SWEEPS_EVAL, sweeps=True)
    doc = write_context_figure(plan.out, res["sweeps"], res["meta"], run_info(plan))
    say("context", f"written {os.path.join(plan.out, 'context_horizon.png')} (.json, .csv)")
    return doc


def run_info(plan: Plan) -> dict:
    """Provenance for the table headers: scale, command, date, minutes since the command
    started (steps skipped as done cost nothing), machine, budgets."""
    return {"scale": plan.scale.name, "command": plan.command, "normalization": plan.normalization,
            "leaks_query_statistics": leaks_query_statistics(plan.normalization),
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "elapsed_min": round((time.time() - plan.started) / 60, 1),
            "machine": machine_description(), "budgets": plan.scale.budgets(), "inputs": plan.inputs}


def machine_description() -> str:
    """Platform, CPU count and GPU name (if any)."""
    gpu = "no GPU"
    try:
        import torch  # noqa: PLC0415

        if torch.cuda.is_available():
            gpu = f"GPU {torch.cuda.get_device_name(0)}"
    except ImportError:
        pass
    return f"{platform.platform()}, {os.cpu_count()} CPUs, {gpu}"


def default_out(scale: Scale, normalization: str = "train_stats", inputs: str = "total") -> str:
    """``results/paper/<scale>``, or ``results/paper/<scale>_paper_window`` for the paper's protocol
    (so that it never overwrites the leak-free tables), with ``-command`` for the command formulation."""
    suffix = "" if normalization == "train_stats" else f"_{normalization}"
    suffix += "" if inputs == "total" else f"-{inputs}"
    return os.path.join("results", "paper", scale.name + suffix)


def reproduce(target: str, scale: Scale, out: str | None = None, work: str | None = None, command: str = "",
              workers: int | None = None, device: str | None = None, wandb: str = "offline",
              normalization: str = "train_stats", leak_free: str | None = None,
              inputs: str = "total") -> dict[str, dict]:
    """Runs ``target`` (``table1``, ``improved``, ``table2``, ``context``, ``all`` or ``compare``) at ``scale``.

    Args:
        normalization: ``train_stats`` (default, leak-free) or ``paper_window`` (the paper's protocol).
        leak_free: ``compare`` only: the ``train_stats`` output folder (default ``results/paper/<scale>``);
            ``out`` is then the ``paper_window`` one and receives the side-by-side table.
        inputs: the formulation every model trains on: ``total`` (the paper's) or ``command``.

    ``inputs`` is the formulation every model trains on: ``total`` (the paper's) or ``command``.

    Returns:
        ``{target: the JSON content written}`` for each target run.
    """
    if target not in TARGETS:
        raise UsageError(f"unknown target {target!r}; choose from {list(TARGETS)}")
    if normalization not in NORMALIZATIONS:
        raise UsageError(f"unknown normalization {normalization!r}; choose from {list(NORMALIZATIONS)}")
    if inputs not in INPUTS:
        raise UsageError(f"inputs must be one of {INPUTS}, got {inputs!r}")
    if target == "compare":
        from robomorph.reproduction.protocols import FILE, compare  # noqa: PLC0415

        out = out or default_out(scale, "paper_window", inputs)
        doc = compare(leak_free or default_out(scale, inputs=inputs), out, scale=scale.name)
        say("compare", f"written {os.path.join(out, FILE + '.md')} (.json)")
        return {"compare": doc}
    plan = Plan(scale, work or os.path.join("data", "reproduce", scale.name),
                out or default_out(scale, normalization, inputs), command, workers, device, wandb, normalization, inputs)
    for flag, folder in (("--out", plan.out), ("--work", plan.work)):  # before any folder is made
        check_outside_stores(folder, flag, may_be_store=False)
    os.makedirs(plan.out, exist_ok=True)
    if target == "collect":
        from robomorph.reproduction.collect import collect  # noqa: PLC0415

        done = collect(plan, TESTS)
        files = {"table1": "table1.md", "table2": "table2.md", "context": "context_horizon.png"}
        say("collect", "written " + ", ".join(os.path.join(plan.out, files[name]) for name in done))
        return done
    steps = {"table1": make_table1, IMPROVED: make_improved, "table2": make_table2, "context": make_context_figure}
    chosen = ["table1", "table2", "context"] if target == "all" else [target]
    done = {name: steps[name](plan) for name in chosen}
    write_report(plan)
    return done


def write_report(plan: Plan) -> str:
    """The dashboard of every run and evaluation so far: ``<work>/report.html`` (loss curves, tables, plots)."""
    from robomorph.reporting.dashboard import build_report  # noqa: PLC0415

    path = build_report(plan.path("runs"), plan.path("report.html"),
                        title=f"RoboMorph reproduction, scale {plan.scale.name}")
    say("report", f"written {path} (open it in a browser, offline)")
    return path

