"""``python -m robomorph.generate`` (or ``robomorph generate``): randomized robot trajectories into a Zarr store.

The door only; the machinery is :mod:`robomorph.sim.generation`.
"""

import sys

from robomorph.sim.generation import main

if __name__ == "__main__":
    sys.exit(main())
