"""``python -m robomorph.export`` (or ``robomorph export``): the inference-only model folder of a checkpoint.

    robomorph export --ckpt results/runs/ms/checkpoints/best.ckpt --out models/ms

writes ``models/ms/model.safetensors`` (the network and its normalization, without the
optimizer state) and ``models/ms/config.json`` (hyper-parameters, channel names, dt,
training window, std calibration). ``Predictor.from_pretrained("models/ms")``,
``robomorph evaluate --ckpt models/ms`` and ``robomorph calibrate --ckpt models/ms`` read
it. The door only; the machinery is :mod:`robomorph.model.files`.
"""

from __future__ import annotations

import argparse
import sys

from robomorph.core.errors import run_command


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m robomorph.export", description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True, help="checkpoint written by robomorph fit (or a model folder)")
    p.add_argument("--out", required=True, help="the model folder to write (created; an older export there "
                                                "is replaced, any other folder is refused)")
    return p


def _mib(n: int) -> str:
    return f"{n / 2**20:.2f} MiB"


def run(a: argparse.Namespace) -> int:
    from robomorph.model.files import export  # noqa: PLC0415  (torch only once the flags are read)

    done = export(a.ckpt, a.out)
    sizes = done["bytes"]
    print(f"wrote {done['weights']} ({_mib(sizes['weights'])}) and {done['config']} ({sizes['config']} bytes); "
          f"the checkpoint was {_mib(sizes['source'])}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
