"""``python -m robomorph.reproduce`` (or ``robomorph reproduce``): the paper's tables and figures.

The door only; the machinery is :mod:`robomorph.reproduction.pipeline`.
"""

import sys

from robomorph.reproduction.pipeline import main

if __name__ == "__main__":
    sys.exit(main())
