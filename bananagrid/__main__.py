"""``python -m bananagrid``: the command line of :mod:`bananagrid.cli`."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
