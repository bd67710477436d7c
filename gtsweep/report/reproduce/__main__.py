"""``python -m gtsweep.reproduction.command``: the reproduction's command, kept where earlier versions had it (the
reproduction is its own package now, :mod:`gtsweep.reproduction`)."""
import sys

from gtsweep.reproduction.command import main

if __name__ == "__main__":
    sys.exit(main())
