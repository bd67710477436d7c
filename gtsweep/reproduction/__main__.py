"""``python -m gtsweep.reproduction``: see :mod:`gtsweep.reproduction.cli`."""
import sys

import gtsweep.experiments  # noqa: F401 - the experiment kinds, whose rows the state's cells and tables read
from gtsweep.reproduction.cli import main

if __name__ == "__main__":
    sys.exit(main())
