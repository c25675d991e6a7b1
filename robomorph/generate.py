"""``python -m robomorph.generate`` (or ``robomorph generate``): randomized robot trajectories into a Zarr store.

The door only; the machinery is :mod:`robomorph.data.generation`.
"""

import sys

from robomorph.data.generation import main

if __name__ == "__main__":
    sys.exit(main())
