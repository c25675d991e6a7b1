"""``python -m robomorph.fit`` (or ``robomorph fit``): train a meta-model (LightningCLI).

The door only; the machinery is :mod:`robomorph.training.fitting` (its options: ``--help``).
"""

from __future__ import annotations

import sys

from robomorph.core.errors import SIGTERM_EXIT, StoppedBySignal, run_command
from robomorph.training.fitting import final_line, fit


def run(argv: list[str] | None) -> int:
    try:
        result = fit(argv)  # LightningCLI parses argv (sys.argv when None) and exits 2 itself on a bad flag
    except StoppedBySignal as stop:
        print(stop, file=sys.stderr)
        return SIGTERM_EXIT
    print(f"best checkpoint: {result.best_ckpt}\nrun directory: {result.run_dir}")
    print(final_line(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(lambda: run(argv))


if __name__ == "__main__":
    sys.exit(main())
