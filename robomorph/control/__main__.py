import sys

from robomorph.control.cli import main

sys.exit(main())
