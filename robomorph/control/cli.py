"""``robomorph control`` (or ``python -m robomorph.control``): closed-loop MPC of unseen robots.

The door only; the machinery is :mod:`robomorph.control.runner`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import signal
import sys
import threading

from robomorph.control.dynamics import ControlError
from robomorph.control.mppi import MPPIConfig
from robomorph.control.references import TASKS
from robomorph.control.runner import CONTROLLERS, DEFAULT_CONTROLLERS, UNCERTAINTY, ControlConfig
from robomorph.sim import arms
from robomorph.core.errors import run_command
from robomorph.core.locks import output_folder
from robomorph.core.names import PHYSICS_MODES
from robomorph.core.options import DeprecatedAlias, Parser, add_alias, integer, number

_WORKER: dict = {}
# Bounds of the options: far beyond any useful run, and short of what would exhaust memory or
# run for days (each episode holds every frame; a planner steps the physics this often per frame).
MAX_ROBOTS, MAX_SECONDS, MAX_SUBSTEPS = 10_000, 3600.0, 64


def build_parser() -> argparse.ArgumentParser:
    d, m = ControlConfig(), MPPIConfig()
    p = Parser(
        prog="robomorph control",
        description="Closed-loop control of randomized robots of a registered arm, never trained on: a warm-up "
                    "under the catalogue OSC records the first context, then each controller tracks the reference. "
                    "Writes OUT/metrics.json, OUT/table.md, OUT/errors.png and OUT/paths.png.")
    p.add_argument("--ckpt", help="model for mpc:model: a checkpoint or exported folder trained in the command "
                                  "formulation (a hybrid plans on its identified robot, a black-box model on its "
                                  "decoder)")
    p.add_argument("--task", default=d.task, choices=TASKS,
                   help="circle or spiral (the generator's paths), reach (10-20 cm point to point, then hold)")
    p.add_argument("--robot", choices=arms.names(),
                   help=f"the arm controlled (default: the arm --ckpt was trained on, else {arms.DEFAULT_ROBOT})")
    p.add_argument("--robots", type=integer(1, MAX_ROBOTS), default=d.robots,
                   help="held-out robots; every controller runs on each")
    p.add_argument("--controllers", default=",".join(DEFAULT_CONTROLLERS),
                   help=f"comma-separated, from {', '.join(CONTROLLERS)} (mpc:true_physics reads the hidden "
                        "parameters: a ceiling)")
    p.add_argument("--seed", type=integer(0, 2**63 - 1), default=d.seed, help="seeds robots, references and planner noise")
    p.add_argument("--out", default="results/control", help="output folder")
    p.add_argument("--uncertainty", default=d.uncertainty, choices=list(UNCERTAINTY),
                   help="wide: masses ±30 %%, damping 3-13, friction ×0.3-1.8 (outside training); training: the "
                        "training ranges")
    # Both are counted in frames (d.dt): under one frame the episode has no warm-up or no tracking.
    p.add_argument("--warmup", type=number(d.dt, MAX_SECONDS), default=d.warmup,
                   help="seconds under the catalogue OSC first (≥ the model's context)")
    p.add_argument("--duration", type=number(d.dt, MAX_SECONDS), default=d.duration,
                   help="seconds of tracking after the warm-up")
    p.add_argument("--candidates", type=integer(1, 100_000), default=m.samples,
                   help="MPPI candidate command sequences scored per re-plan")
    p.add_argument("--horizon", type=integer(1, 10_000), default=m.horizon, help="frames planned ahead (60 Hz)")
    p.add_argument("--replan", type=integer(1, 10_000), default=m.replan, help="frames applied from each plan")
    p.add_argument("--noise", type=number(0, 1, low_open=True), default=m.noise,
                   help="exploration std, fraction of each torque limit")
    p.add_argument("--temperature", type=number(0, 1e6, low_open=True), default=m.temperature,
                   help="MPPI lambda relative to the costs' spread")
    p.add_argument("--plan-substeps", type=integer(1, MAX_SUBSTEPS), default=d.plan_substeps,
                   help="physics steps per frame in planners")
    p.add_argument("--context-len", type=integer(1, 100_000), default=d.context,
                   help="context frames of the in-context model")
    p.add_argument("--reidentify", type=integer(0, 1_000_000), default=d.reidentify,
                   help="frames between a hybrid model's identifications from the rolling context (0: once)")
    p.add_argument("--physics", dest="physics_mode", choices=(*PHYSICS_MODES, "none"),
                   help="a hybrid model's physics mode (regression, fused, refined, learned, blend, smoothed, or "
                        "none for its black-box decoder; default: the model's), as evaluate's --physics")
    # The name before evaluate and calibrate agreed on --physics: kept one release.
    p.add_argument("--physics-mode", dest="physics_mode", choices=(*PHYSICS_MODES, "none"), action=DeprecatedAlias,
                   new="--physics", help=argparse.SUPPRESS)
    p.add_argument("--workers", type=integer(1, 1024), default=os.cpu_count() or 1, help="episodes run in parallel")
    # Their names before every command agreed on one name per meaning (core.options.VOCABULARY): one release.
    add_alias(p, "--context", "--context-len")
    add_alias(p, "--samples", "--candidates")
    return p


def load_model(ckpt: str, physics_mode: str | None):
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    predictor = Predictor.from_checkpoint(ckpt, device="cpu")
    predictor.use_physics(physics_mode, "--physics")
    return predictor


def check_model(predictor, cfg: ControlConfig, ckpt: str) -> None:
    """Refuses a model the controller cannot plan with, in one line."""
    if predictor.inputs != "command":
        raise ControlError(f"{ckpt} was trained on {predictor.inputs} torques; the controller sends commands to an "
                           "arm that compensates its own gravity: use a model trained with --data.inputs command")
    from robomorph.control.runner import check_model_arm  # noqa: PLC0415

    try:
        check_model_arm(predictor, cfg.robot)
    except ControlError as exc:
        raise ControlError(f"{ckpt}: {exc}") from None
    cfg_m = predictor.model.config
    if cfg.mpc.horizon + 1 > cfg_m.max_horizon:
        raise ControlError(f"--horizon {cfg.mpc.horizon} is beyond the model's trained maximum "
                           f"({cfg_m.max_horizon - 1} frames planned ahead)")
    if cfg.context > cfg_m.max_context or cfg.context < max(cfg_m.patch, cfg_m.n_init):
        raise ControlError(f"--context-len {cfg.context}: the model takes {max(cfg_m.patch, cfg_m.n_init)} to "
                           f"{cfg_m.max_context} frames")
    decoder = not (predictor.physics and predictor.settings.mode != "none")
    if decoder and cfg.context % cfg_m.patch:
        # The decoder reads whole patches: a context between two would be cut without a word.
        raise ControlError(f"--context-len {cfg.context}: the model reads contexts in patches of {cfg_m.patch} frames; "
                           f"give a multiple of {cfg_m.patch} (e.g. {cfg.context // cfg_m.patch * cfg_m.patch})")
    if cfg.warmup_frames < cfg.context:
        raise ControlError(f"--warmup {cfg.warmup:g} s is {cfg.warmup_frames} frames, shorter than the context "
                           f"({cfg.context}): lengthen the warm-up or shorten --context-len")


def _init_pool_worker(ckpt: str | None, physics_mode: str | None) -> None:
    import signal  # noqa: PLC0415

    # A Ctrl-C reaches every process of the terminal: the parent stops the run, workers say nothing.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _init_worker(ckpt, physics_mode)


def _init_worker(ckpt: str | None, physics_mode: str | None) -> None:
    import torch  # noqa: PLC0415

    torch.set_num_threads(1)
    _WORKER["predictor"] = load_model(ckpt, physics_mode) if ckpt else None


def _job(cfg: ControlConfig, robot: int, controller: str):
    from robomorph.control.runner import run_job  # noqa: PLC0415

    return run_job(cfg, robot, controller, _WORKER.get("predictor"))


def run(args: argparse.Namespace) -> int:
    from robomorph.control import outputs  # noqa: PLC0415
    from robomorph.core.results import provenance  # noqa: PLC0415

    try:
        mpc = MPPIConfig(samples=args.candidates, horizon=args.horizon, replan=args.replan, noise=args.noise,
                         temperature=args.temperature)
    except ValueError as exc:
        raise ControlError(str(exc).replace("mpc.samples", "--candidates").replace("mpc.", "--")) from None
    controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    cfg = ControlConfig(task=args.task, robot=args.robot or arms.DEFAULT_ROBOT, robots=args.robots,
                        controllers=controllers, seed=args.seed, warmup=args.warmup, duration=args.duration,
                        uncertainty=args.uncertainty, plan_substeps=args.plan_substeps, context=args.context_len,
                        reidentify=args.reidentify, mpc=mpc)
    uses_model = "mpc:model" in controllers
    if uses_model and not args.ckpt:
        raise ControlError("mpc:model needs --ckpt (a model trained in the command formulation), or drop it "
                           "from --controllers")
    if uses_model:
        from robomorph.control.runner import model_arm  # noqa: PLC0415

        predictor = load_model(args.ckpt, args.physics_mode)
        if args.robot is None:  # the arm the model knows, so a model of the UR5e needs no --robot
            cfg = dataclasses.replace(cfg, robot=model_arm(predictor) or arms.DEFAULT_ROBOT)
        check_model(predictor, cfg, args.ckpt)
    # The folder is checked and locked before any episode runs, and written whole at the end.
    with output_folder(args.out, "control") as tmp:
        results = _episodes(cfg, controllers, args.ckpt if uses_model else None, args.physics_mode, args.workers)
        config = {**dataclasses.asdict(cfg), "ckpt": args.ckpt, "physics_mode": args.physics_mode}
        metrics = outputs.write(tmp, results, list(controllers), config, provenance(), cfg.dt)
    print(outputs.table(metrics))
    print(f"wrote {os.path.join(args.out, 'metrics.json')}, table.md, errors.png and paths.png")
    return 0


@contextlib.contextmanager
def _interrupts_ignored():
    """Ctrl-C ignored while the workers are started (in the main thread; elsewhere signals cannot be set).

    A spawned interpreter that starts with SIGINT ignored keeps it ignored (Python installs its
    KeyboardInterrupt handler only over the default one), so a Ctrl-C that arrives while a worker
    is still importing, before its initializer runs, no longer prints that worker's traceback. The
    parent's own handler is back as soon as the processes exist (milliseconds) and stops the run.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _episodes(cfg: ControlConfig, controllers: tuple[str, ...], ckpt: str | None, physics_mode: str | None,
              workers: int) -> list:
    """Every (robot, controller) episode, in ``workers`` processes, with a progress report."""
    from robomorph.core.progress import Phase  # noqa: PLC0415

    jobs = [(r, c) for r in range(cfg.robots) for c in controllers]
    results = []
    with Phase(f"control {cfg.task}", total=len(jobs), unit="episode") as bar:
        if workers == 1:
            _init_worker(ckpt, physics_mode)
            for r, c in jobs:
                results.append(_job(cfg, r, c))
                bar.update()
        else:
            import multiprocessing as mp  # noqa: PLC0415
            from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: PLC0415

            pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_pool_worker,
                                       initargs=(ckpt, physics_mode))
            try:
                with _interrupts_ignored():  # the submissions start the workers
                    futures = [pool.submit(_job, cfg, r, c) for r, c in jobs]
                for fut in as_completed(futures):
                    results.append(fut.result())
                    bar.update()
            except BaseException:  # a Ctrl-C or a failed episode: no episode is kept, so none is waited for
                _stop_workers(pool)
                raise
            finally:  # the queued episodes are not run
                pool.shutdown(wait=True, cancel_futures=True)
    return results


def _stop_workers(pool) -> None:
    """Ends the pool's worker processes now. They ignore Ctrl-C (the parent stops the run), and a shutdown
    waits for the episodes they run: with ``--workers 2`` a Ctrl-C used to stop ``control`` only once those
    had finished, minutes later. ``ProcessPoolExecutor`` has no public way to end its workers before Python
    3.14 (``terminate_workers``): its process table is read before the shutdown clears it."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for proc in processes:
        proc.terminate()
    for proc in processes:
        proc.join(timeout=10)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args), kept=f"no episode is kept and nothing was written to {args.out} "
                                               "(its results are written whole, once every episode has run)")


if __name__ == "__main__":
    sys.exit(main())
