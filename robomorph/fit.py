"""``python -m robomorph.fit`` (or ``robomorph fit``): train a meta-model (LightningCLI).

The door only; the machinery is :mod:`robomorph.training.fitting` (its options: ``--help``).
"""

from __future__ import annotations

import sys

from robomorph.core.errors import run_command
from robomorph.training.fitting import fit


def run(argv: list[str] | None) -> int:
    result = fit(argv)  # LightningCLI parses argv (sys.argv when None) and exits 2 itself on a bad flag
    if result.metrics:
        shown = ", ".join(f"{k}={v:.4g}" for k, v in sorted(result.metrics.items()) if k.startswith("val/"))
        print(f"{result.run_dir}: step {result.global_step}, {shown}")
    print(f"best checkpoint: {result.best_ckpt}\nrun directory: {result.run_dir}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(lambda: run(argv))


if __name__ == "__main__":
    sys.exit(main())
