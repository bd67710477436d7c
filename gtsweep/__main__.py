from gtsweep.core.interrupts import quiet_until_handled

quiet_until_handled()  # Ctrl-C while Python imports gtsweep: one line, no traceback

from gtsweep.cli import main  # noqa: E402

main()
