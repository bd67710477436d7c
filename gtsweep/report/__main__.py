"""``python -m gtsweep.report``: the report command, dispatched by the run's recorded experiment kind."""
import sys

from gtsweep.experiments.report_command import main

sys.exit(main())
