"""``python -m robomorph.evaluate`` (or ``robomorph evaluate``): a trained or catalogue model on a store, beside the baselines.

The door only: it builds one :class:`robomorph.evaluation.requests.EvaluateConfig` from the options
and calls :func:`robomorph.evaluation.evaluator.evaluate`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import UsageError, run_command
from robomorph.core.names import INPUTS, NORMALIZATIONS
from robomorph.core.options import add_alias
from robomorph.evaluation import evaluator
from robomorph.evaluation.baselines import BASELINES, CEILINGS, OPT_IN
from robomorph.evaluation.requests import PHYSICS_CHOICES, STACKED_CHOICES, EvaluateConfig


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.evaluate", description=evaluator.__doc__.split("\n")[0])
    p.add_argument("--ckpt", help="checkpoint written by robomorph.fit (or a folder written by robomorph export)")
    p.add_argument("--robot", help="instead of --ckpt: a registered arm whose catalogue hybrid, untrained, is "
                                   "evaluated with the recipe the store records (needs --context-len and --horizon)")
    p.add_argument("--data", required=True, help="store to evaluate on (.zarr)")
    p.add_argument("--out", help="output folder (default: <run>/eval/<store name>; with --robot "
                                 "results/catalogue/<arm>/eval/<store name>)")
    p.add_argument("--context-len", type=int, help="context steps (default: the checkpoint's)")
    p.add_argument("--horizon", type=int, help="predicted steps (default: the checkpoint's)")
    p.add_argument("--n", type=int, help="evaluate only the first N trajectories")
    p.add_argument("--baselines", default=",".join(BASELINES),
                   help=f"comma list from {BASELINES + OPT_IN + CEILINGS}, or 'none' (identified_physics fits "
                        "each window's parameters: seconds per window; identified_physics_springs its joints' "
                        "springs too; true_physics reads the hidden "
                        "parameters: a predictability ceiling, not a competitor)")
    p.add_argument("--sweep-horizon", help="horizons to sweep, e.g. 200:800:50 or 100,400,800")
    p.add_argument("--sweep-context", help="context lengths to sweep, e.g. 20:200:20")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--device", help="cpu, cuda, ... (default: cuda when available)")
    p.add_argument("--plot-trajectories", type=int, default=3, help="sample trajectories to plot")
    p.add_argument("--arx-orders", default="2,2", help="ARX output and input lags na,nb")
    p.add_argument("--horizons", help="steps of the per-horizon errors: steps (15), seconds (0.25s) or 'end', "
                   "comma-separated (default: 1,0.25s,1s,5s,end)")
    p.add_argument("--offset", default="start", help="where each window starts: 'start' (the paper's), 'random' "
                   "(seeded by --seed, within the data) or a step number")
    p.add_argument("--seed", type=int, default=0, help="picks the plotted sample trajectories and the random offsets")
    p.add_argument("--normalization", choices=NORMALIZATIONS,
                   help="require the checkpoint to have been trained with this normalization (default: its own)")
    p.add_argument("--inputs", choices=INPUTS,
                   help="input formulation of the data (default: the checkpoint's; a different one is refused; "
                        "with --robot the formulation its hybrid takes, default command)")
    p.add_argument("--compare", action="append", default=[], metavar="NAME=CKPT",
                   help="another checkpoint scored beside the baselines (repeatable), e.g. scratch=runs/a/checkpoints/best.ckpt")
    p.add_argument("--physics", choices=PHYSICS_CHOICES,
                   help="how a model with a physics backbone predicts: its robot identified by linear solves "
                        "(regression, the default for commands), read by the network (learned), both (fused), "
                        "fused then a few Gauss-Newton steps (refined), the regression's simulation and the decoder "
                        "weighted by step (blend: fitted by calibrate --blend, the default for total torques "
                        "once fitted), or its black-box decoder (none)")
    p.add_argument("--stacked", choices=STACKED_CHOICES, default="auto",
                   help="stack the model with hold, constant velocity and constant acceleration by the backtest on "
                        "each window's own context: auto (on for recordings of a real robot, an ingested store, off "
                        "on simulated stores), on or off")
    p.add_argument("--arx-train-data", help="comma list of stores to fit arx_train on, whole (default: the "
                                            "checkpoint's training split, read back from its stores)")
    # The names before every command agreed on one name per meaning (core.options.VOCABULARY): kept one release.
    add_alias(p, "--arm", "--robot")
    add_alias(p, "--samples", "--plot-trajectories")
    return p


def _orders(text: str) -> tuple[int, int]:
    try:
        na, nb = (int(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"--arx-orders takes two integers na,nb, got {text!r}") from None
    return na, nb


def _compare(items: list[str]) -> dict[str, str]:
    compare = dict(c.split("=", 1) for c in items if "=" in c)
    if len(compare) != len(items):
        raise UsageError(f"--compare takes NAME=CKPT, got {items}")
    return compare


def config(a: argparse.Namespace) -> EvaluateConfig:
    """The request the options make (validated as it is built)."""
    baselines = () if a.baselines.strip() in ("", "none") else tuple(s.strip() for s in a.baselines.split(","))
    return EvaluateConfig(
        data=a.data, ckpt=a.ckpt, arm=a.robot, out=a.out, context_len=a.context_len, horizon=a.horizon, n=a.n,
        baselines=baselines, sweep_horizon_spec=a.sweep_horizon, sweep_context_spec=a.sweep_context,
        batch_size=a.batch_size, device=a.device, samples=a.plot_trajectories, arx_orders=_orders(a.arx_orders), seed=a.seed,
        normalization=a.normalization, horizons_spec=a.horizons, offset=a.offset, inputs=a.inputs,
        arx_train_data=tuple(s.strip() for s in (a.arx_train_data or "").split(",") if s.strip()),
        compare=tuple(_compare(a.compare).items()), physics=a.physics, stacked=a.stacked)


def run(a: argparse.Namespace) -> int:
    cfg = config(a)
    res = evaluator.evaluate(cfg)
    print(evaluator.summary_text(res, cfg.out_dir))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
