"""``python -m robomorph.calibrate`` (or ``robomorph calibrate``): a Gaussian head's std, rescaled by horizon.

The door only: it builds one :class:`robomorph.evaluation.requests.CalibrateConfig` (or, with ``--blend``,
a :class:`~robomorph.evaluation.requests.BlendConfig`) from the options and calls
:mod:`robomorph.evaluation.calibrating`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command
from robomorph.core.names import RECORDED_SWITCHES
from robomorph.evaluation import calibrating
from robomorph.evaluation.requests import PHYSICS_CHOICES, BlendConfig, CalibrateConfig
from robomorph.inference.blending import PHYSICS_MODES as BLEND_PHYSICS
from robomorph.inference.calibration import METHODS, POINTS, CalibrationError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.calibrate", description=calibrating.__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True, help="checkpoint of a model with a Gaussian head (written by robomorph.fit)")
    p.add_argument("--data", help="a store of held-out robots (default: the fit's validation split, read back "
                                  "from its stores)")
    p.add_argument("--out", help="write the calibrated checkpoint here (default: the checkpoint, in place)")
    p.add_argument("--method", choices=METHODS, default="power",
                   help="power: a scale and a power of the spread per step, ±1σ and ±2σ together nearest to 68.3 %% "
                        "and 95.4 %% (default; the power needs 128 windows, else coverage's); coverage: the same with "
                        "the scale alone; nll: the scale minimising the Gaussian NLL; quantile: exactly 68.3 %% inside ±1σ")
    p.add_argument("--n", type=int, help="use at most N windows")
    p.add_argument("--context-len", type=int, help="context steps (default: the checkpoint's)")
    p.add_argument("--horizon", type=int, help="predicted steps (default: the checkpoint's)")
    p.add_argument("--offset", default="start", help="where each window starts: start, random (seeded) or a step")
    p.add_argument("--seed", type=int, default=0, help="seeds --offset random")
    p.add_argument("--horizons", help="steps shown in the report, as evaluate's --horizons")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--device", help="cpu, cuda, ... (default: cuda when available)")
    p.add_argument("--physics", choices=PHYSICS_CHOICES,
                   help="a hybrid model's physics mode to calibrate (default: its default mode); each mode keeps its "
                        "own calibration (with --remove: drop that mode's only)")
    p.add_argument("--observer", choices=("on", "off"),
                   help="a command-formulation hybrid: start its horizons from the observer's velocity (the simulated "
                        "context's end velocity corrected by its position residual; on by default for models trained "
                        "since 2026-11-26) or not, recorded in the checkpoint; each setting keeps its own calibrations")
    p.add_argument("--springs", choices=("on", "off"),
                   help="a command-formulation hybrid: its regression fits the joints' springs too (on by default "
                        "for models trained since 2026-11-27; the std then carries their uncertainty) or not, "
                        "recorded in the checkpoint; each setting keeps its own calibrations")
    p.add_argument("--debias", choices=("on", "off"),
                   help="a command-formulation hybrid: its regression's bias, measured on the estimate's simulated "
                        "context, taken off (on by default for models trained since 2026-11-27) or not, recorded in "
                        "the checkpoint; each setting keeps its own calibrations")
    for name, what in (("payload", "its regression's flange may carry an unknown payload (and, where gravity is in "
                                    "the problem, the links' centres of mass are fitted)"),
                       ("coulomb", "its regression's friction losses and damping may leave the randomization box"),
                       ("denoise", "a command-formulation hybrid: the encoder noise measured in each context smooths "
                                   "the regression and the horizon's start")):
        p.add_argument(f"--{name}", choices=("on", "off"),
                       help=f"a hybrid: {what} (on by default for models trained since 2026-11-28) or not, recorded "
                            "in the checkpoint; each setting keeps its own calibrations")
    p.add_argument("--points", choices=POINTS,
                   help="a hybrid whose std is a spread of robots around its estimate: one per column of the "
                        "estimate's covariance (deterministic), those and the start velocity moved joint by joint "
                        "by the observer's correction (observed: the default for a command model not calibrated "
                        "before), or random draws (what calibrations before 2026-11-27 were fitted on); default: "
                        "as stored")
    p.add_argument("--remove", action="store_true", help="drop the stored calibrations instead")
    p.add_argument("--blend", action="store_true",
                   help="fit the per-step weights of the model's physics prediction against its decoder's instead "
                        "(physics early, decoder late: the total-torque formulation's default once fitted)")
    p.add_argument("--blend-physics", choices=BLEND_PHYSICS,
                   help="with --blend: the physics prediction blended: the identified robot smoothed against the "
                        "decoder over the whole horizon (the default for a model with a Gaussian head), or "
                        "simulated forward (the default otherwise)")
    return p


def run(a: argparse.Namespace) -> int:
    for name in (*RECORDED_SWITCHES, "points"):
        if getattr(a, name) and (a.remove or a.blend):
            raise CalibrationError(f"--{name} sets what a calibration is fitted on: drop --remove and --blend with it")
    if a.remove:
        had = calibrating.remove(a.ckpt, a.out, a.physics)
        what = "std calibration" + (f" of physics mode {a.physics}" if a.physics else "")
        print(f"{'removed the ' + what + ' from' if had else 'no ' + what + ' in'} {a.ckpt}"
              + (f" (written: {a.out})" if a.out else ""))
        return 0
    window = {"ckpt": a.ckpt, "data": a.data, "out": a.out, "n": a.n, "context_len": a.context_len,
              "horizon": a.horizon, "offset": a.offset, "seed": a.seed, "device": a.device, "horizons_spec": a.horizons}
    if a.blend:
        # Each window of a blend runs a simulation as well as the network: smaller batches.
        report = calibrating.blend(BlendConfig(**window, batch_size=min(a.batch_size, 16), physics=a.blend_physics))
        print(calibrating.blend_text(report))
        return 0
    switches = {name: None if getattr(a, name) is None else getattr(a, name) == "on"
                for name in RECORDED_SWITCHES}
    report = calibrating.calibrate(CalibrateConfig(**window, method=a.method, batch_size=a.batch_size,
                                                   physics=a.physics, points=a.points, **switches))
    print(calibrating.report_text(report))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
