import sys

from gtsweep.report.localization import is_localization
from gtsweep.report.localization import main as localization_main
from gtsweep.report.output import main

sys.exit(localization_main(sys.argv[1:]) if is_localization(sys.argv[1:]) else main())
