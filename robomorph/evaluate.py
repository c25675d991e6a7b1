"""``python -m robomorph.evaluate`` (or ``robomorph evaluate``): a trained meta-model on a store, beside the baselines.

The door only; the machinery is :mod:`robomorph.evaluation.evaluator`.
"""

import sys

from robomorph.evaluation.evaluator import main

if __name__ == "__main__":
    sys.exit(main())
