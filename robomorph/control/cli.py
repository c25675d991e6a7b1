"""``robomorph control`` (or ``python -m robomorph.control``): closed-loop MPC of unseen robots.

The door only; the machinery is :mod:`robomorph.control.runner`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from robomorph.control.dynamics import ControlError
from robomorph.control.mppi import MPPIConfig
from robomorph.control.references import TASKS
from robomorph.control.runner import CONTROLLERS, DEFAULT_CONTROLLERS, UNCERTAINTY, ControlConfig
from robomorph.core.errors import run_command

_WORKER: dict = {}


def build_parser() -> argparse.ArgumentParser:
    d, m = ControlConfig(), MPPIConfig()
    p = argparse.ArgumentParser(
        prog="robomorph control",
        description="Closed-loop control of randomized Panda robots never trained on: a warm-up under the "
                    "catalogue OSC records the first context, then each controller tracks the reference. "
                    "Writes OUT/metrics.json, OUT/table.md, OUT/errors.png and OUT/paths.png.")
    p.add_argument("--ckpt", help="model for mpc:model: a checkpoint or exported folder trained in the command "
                                  "formulation (a hybrid plans on its identified robot, a black-box model on its "
                                  "decoder)")
    p.add_argument("--task", default=d.task, choices=TASKS,
                   help="circle or spiral (the generator's paths), reach (10-20 cm point to point, then hold)")
    p.add_argument("--robots", type=int, default=d.robots, help="held-out robots; every controller runs on each")
    p.add_argument("--controllers", default=",".join(DEFAULT_CONTROLLERS),
                   help=f"comma-separated, from {', '.join(CONTROLLERS)} (mpc:true_physics reads the hidden "
                        "parameters: a ceiling)")
    p.add_argument("--seed", type=int, default=d.seed, help="seeds robots, references and planner noise")
    p.add_argument("--out", default="results/control", help="output folder")
    p.add_argument("--uncertainty", default=d.uncertainty, choices=list(UNCERTAINTY),
                   help="wide: masses ±30 %%, damping 3-13, friction ×0.3-1.8 (outside training); training: the "
                        "training ranges")
    p.add_argument("--warmup", type=float, default=d.warmup, help="seconds under the catalogue OSC first (≥ the "
                                                                   "model's context)")
    p.add_argument("--duration", type=float, default=d.duration, help="seconds of tracking after the warm-up")
    p.add_argument("--samples", type=int, default=m.samples, help="MPPI candidates per re-plan")
    p.add_argument("--horizon", type=int, default=m.horizon, help="frames planned ahead (60 Hz)")
    p.add_argument("--replan", type=int, default=m.replan, help="frames applied from each plan")
    p.add_argument("--noise", type=float, default=m.noise, help="exploration std, fraction of each torque limit")
    p.add_argument("--temperature", type=float, default=m.temperature, help="MPPI lambda relative to the costs' spread")
    p.add_argument("--plan-substeps", type=int, default=d.plan_substeps, help="physics steps per frame in planners")
    p.add_argument("--context", type=int, default=d.context, help="context frames of the in-context model")
    p.add_argument("--reidentify", type=int, default=d.reidentify,
                   help="frames between a hybrid model's identifications from the rolling context (0: once)")
    p.add_argument("--physics-mode", help="a hybrid model's physics mode (regression, fused, refined, learned, blend, "
                                          "or none for its black-box decoder; default: the model's)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="episodes run in parallel")
    return p


def load_model(ckpt: str, physics_mode: str | None):
    from robomorph.model.predictor import Predictor  # noqa: PLC0415

    predictor = Predictor.from_checkpoint(ckpt, device="cpu")
    predictor.use_physics(physics_mode, "--physics-mode")
    return predictor


def check_model(predictor, cfg: ControlConfig, ckpt: str) -> None:
    """Refuses a model the controller cannot plan with, in one line."""
    if predictor.inputs != "command":
        raise ControlError(f"{ckpt} was trained on {predictor.inputs} torques; the controller sends commands to an "
                           "arm that compensates its own gravity: use a model trained with --data.inputs command")
    if (predictor.n_u, predictor.n_y) != (7, 14):
        raise ControlError(f"{ckpt} predicts {predictor.n_y} outputs from {predictor.n_u} inputs; the controlled "
                           "arm is the Panda (7 torques in; EE pose and 7 joints out)")
    cfg_m = predictor.model.config
    if cfg.mpc.horizon + 1 > cfg_m.max_horizon:
        raise ControlError(f"--horizon {cfg.mpc.horizon} is beyond the model's trained maximum "
                           f"({cfg_m.max_horizon - 1} frames planned ahead)")
    if cfg.context > cfg_m.max_context or cfg.context < max(cfg_m.patch, cfg_m.n_init):
        raise ControlError(f"--context {cfg.context}: the model takes {max(cfg_m.patch, cfg_m.n_init)} to "
                           f"{cfg_m.max_context} frames")
    if cfg.warmup_frames < cfg.context:
        raise ControlError(f"--warmup {cfg.warmup:g} s is {cfg.warmup_frames} frames, shorter than the context "
                           f"({cfg.context}): lengthen the warm-up or shorten --context")


def _init_worker(ckpt: str | None, physics_mode: str | None) -> None:
    import torch  # noqa: PLC0415

    torch.set_num_threads(1)
    _WORKER["predictor"] = load_model(ckpt, physics_mode) if ckpt else None


def _job(cfg: ControlConfig, robot: int, controller: str):
    from robomorph.control.runner import run_job  # noqa: PLC0415

    return run_job(cfg, robot, controller, _WORKER.get("predictor"))


def run(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm  # noqa: PLC0415

    from robomorph.control import outputs  # noqa: PLC0415
    from robomorph.core.results import provenance  # noqa: PLC0415

    try:
        mpc = MPPIConfig(samples=args.samples, horizon=args.horizon, replan=args.replan, noise=args.noise,
                         temperature=args.temperature)
    except ValueError as exc:
        raise ControlError(str(exc).replace("mpc.", "--")) from None
    controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    cfg = ControlConfig(task=args.task, robots=args.robots, controllers=controllers, seed=args.seed,
                        warmup=args.warmup, duration=args.duration, uncertainty=args.uncertainty,
                        plan_substeps=args.plan_substeps, context=args.context, reidentify=args.reidentify, mpc=mpc)
    if os.path.isfile(args.out):
        raise ControlError(f"--out {args.out} is a file; give a folder")
    if args.workers < 1:
        raise ControlError(f"--workers must be >= 1, got {args.workers}")
    uses_model = "mpc:model" in controllers
    if uses_model and not args.ckpt:
        raise ControlError("mpc:model needs --ckpt (a model trained in the command formulation), or drop it "
                           "from --controllers")
    if uses_model:
        check_model(load_model(args.ckpt, args.physics_mode), cfg, args.ckpt)
    ckpt = args.ckpt if uses_model else None
    jobs = [(r, c) for r in range(cfg.robots) for c in controllers]
    results = []
    bar = tqdm(total=len(jobs), desc=f"control {cfg.task}", unit="episode")
    if args.workers == 1:
        _init_worker(ckpt, args.physics_mode)
        for r, c in jobs:
            results.append(_job(cfg, r, c))
            bar.update()
    else:
        import multiprocessing as mp  # noqa: PLC0415
        from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: PLC0415

        with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                 initargs=(ckpt, args.physics_mode)) as pool:
            for fut in as_completed([pool.submit(_job, cfg, r, c) for r, c in jobs]):
                results.append(fut.result())
                bar.update()
    bar.close()
    config = {**dataclasses.asdict(cfg), "ckpt": args.ckpt, "physics_mode": args.physics_mode}
    metrics = outputs.write(args.out, results, list(controllers), config, provenance(), cfg.dt)
    print(outputs.table(metrics))
    print(f"wrote {os.path.join(args.out, 'metrics.json')}, table.md, errors.png and paths.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
