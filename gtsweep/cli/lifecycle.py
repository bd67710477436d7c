"""How a run ends on the command line: bad input in one line (exit 2), a failure or an interrupt in one line with
what is kept and the command that resumes (exit 1, or 128 + the signal)."""
from __future__ import annotations

import shlex
import sys
from typing import NoReturn

from gtsweep.core.errors import GtsweepError, failure_cause, failure_line
from gtsweep.core.interrupts import Interrupted, interruption

COMMAND: list[str] = []  # the command line of this process's gtsweep.cli.main
#: Exit code of a run that stopped on a failure of its environment (disk, store, cluster) or a bug: not bad input (2).
EXIT_FAILED = 1


def resume_command() -> str:
    """The command that continues this run: the user's command as typed (``sys.orig_argv``) with
    ``resume=true``."""
    typed = list(getattr(sys, "orig_argv", []))
    args = typed[3:] if typed[1:3] == ["-m", "gtsweep"] else list(COMMAND)  # else called from Python: main()'s
    return shlex.join(["python", "-m", "gtsweep", *[a for a in args if not a.startswith("resume=")], "resume=true"])


def fail(error: Exception) -> NoReturn:
    """Bad input: one line, exit code 2."""
    print(f"gtsweep: error: {error}", file=sys.stderr)
    sys.exit(2)


def stop(error: BaseException, kept, abort=None) -> NoReturn:
    """End a job that stopped on ``error`` once its workers are stopped: bad input in one line (exit 2), else the
    cause or the interrupt with what is kept (``kept()``) and how to continue; ``abort(cause[, status])`` marks
    its MLflow run and says what became of it."""
    from gtsweep.orchestration.cluster import stop_workers

    signal = interruption(error)
    stop_workers()
    if isinstance(error, GtsweepError):
        if abort is not None:
            abort(str(error))
        fail(error)
    cause = str(signal) if signal else failure_cause(error)
    marked = abort(cause, "KILLED" if signal else "FAILED") if abort is not None else ""
    if signal is None:
        print(failure_line(cause, kept(), marked, resume_command()), file=sys.stderr)
        sys.exit(EXIT_FAILED)
    exit_interrupted(signal, kept())


def exit_interrupted(error: Interrupted, kept: str) -> NoReturn:
    """One line on stderr (what is kept, how to continue), exit code 128 + the signal (130 SIGINT, 143 SIGTERM)."""
    print(f"gtsweep: interrupted by {error.name}; {kept}; to continue: {resume_command()}", file=sys.stderr)
    sys.exit(128 + error.signum)
