"""``python -m robomorph.merge`` (or ``robomorph merge``): shards of one generation into one store.

The door only; the machinery is :mod:`robomorph.data.merging`.
"""

import sys

from robomorph.data.merging import main

if __name__ == "__main__":
    sys.exit(main())
