import sys

from gtsweep.report.tables import main

sys.exit(main())
