"""``python -m robomorph.fit`` (or ``robomorph fit``): train a meta-model (LightningCLI).

The door only; the machinery is :mod:`robomorph.training.fitting`.
"""

import sys

from robomorph.training.fitting import main

if __name__ == "__main__":
    sys.exit(main())
