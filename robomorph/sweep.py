"""``python -m robomorph.sweep`` (or ``robomorph sweep``): Optuna studies over fit().

The door only; the machinery is :mod:`robomorph.tuning.runner`.
"""

import sys

from robomorph.tuning.runner import main

if __name__ == "__main__":
    sys.exit(main())
