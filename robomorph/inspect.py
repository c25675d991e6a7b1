"""``python -m robomorph.inspect`` (or ``robomorph inspect``): what a store holds: counts, channels, ranges, plots.

The door only; the machinery is :mod:`robomorph.data.summary`.
"""

import sys

from robomorph.data.summary import main

if __name__ == "__main__":
    sys.exit(main())
