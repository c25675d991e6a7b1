"""``python -m robomorph <command> ...``: the same as the ``robomorph`` console script."""

import sys

from robomorph.cli import main

if __name__ == "__main__":
    sys.exit(main())
