"""``python -m gtsweep.reproduction``: see :mod:`gtsweep.reproduction.cli`."""
import sys

from gtsweep.reproduction.cli import main

if __name__ == "__main__":
    sys.exit(main())
