"""``python -m gtsweep.reproduction.command``: the reproduction's command, kept where earlier versions had it (the
reproduction is its own package now, :mod:`gtsweep.reproduction`)."""
import sys

import gtsweep.experiments  # noqa: F401 - the experiment kinds, whose rows the reproduction's tables read
from gtsweep.reproduction.command import main

if __name__ == "__main__":
    sys.exit(main())
