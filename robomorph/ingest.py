"""``python -m robomorph.ingest`` (or ``robomorph ingest``): a real robot's logs (NPZ, CSV, MAT) into a store.

The door only; the machinery is :mod:`robomorph.data.ingest`.
"""

import sys

from robomorph.data.ingest import main

if __name__ == "__main__":
    sys.exit(main())
