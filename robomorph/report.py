"""``python -m robomorph.report`` (or ``robomorph report``): the static HTML dashboard over runs and evaluations.

The door only; the machinery is :mod:`robomorph.reporting.dashboard`.
"""

import sys

from robomorph.reporting.dashboard import main

if __name__ == "__main__":
    sys.exit(main())
