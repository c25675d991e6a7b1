"""``python -m robomorph.fit`` (or ``robomorph fit``): train a meta-model (LightningCLI).

The door only; the machinery is :mod:`robomorph.training.fitting` (its options: ``--help``).
"""

from __future__ import annotations

import sys

from robomorph.core.errors import SIGTERM_EXIT, StoppedBySignal, run_command
from robomorph.core.recipes import locate_config_args
from robomorph.training.fitting import final_line, fit


def run(argv: list[str] | None) -> int:
    try:
        # LightningCLI parses argv and exits 2 itself on a bad flag; --config may name a shipped recipe.
        result = fit(locate_config_args(sys.argv[1:] if argv is None else argv))
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
