"""``python -m gtsweep`` and the ``gtsweep`` console script: Ctrl-C is quiet from the first line on."""
from gtsweep.core.interrupts import quiet_until_handled


def run() -> None:
    quiet_until_handled()  # Ctrl-C while Python imports gtsweep: one line, no traceback
    from gtsweep.cli import main
    from gtsweep.orchestration.cluster import leave

    try:
        main()
    except SystemExit as end:  # after Ray was stopped on an interrupt or a failure: no crash in Ray's exit code
        leave(end.code)


if __name__ == "__main__":
    run()
