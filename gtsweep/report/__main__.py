import sys

from gtsweep.report.output import main

sys.exit(main())
