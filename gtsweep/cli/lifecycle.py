"""A run's life outside the science: its own output directory, and a clean stop on Ctrl-C or SIGTERM.

- Every run gets a directory of its own: ``hydra.run.dir`` / ``hydra.sweep.dir`` default to
  ``${gtsweep.new_dir:outputs/<date>/<time>}``, which claims the folder with an exclusive ``mkdir`` (``<time>-2``,
  ``-3``... when a run started in the same second holds it); an explicit directory is locked for the run's life.
- SIGINT and SIGTERM raise :class:`~gtsweep.core.interrupts.Interrupted` in the main thread; the app then stops the
  workers, marks its MLflow run KILLED and prints one line with the command that resumes (:func:`exit_interrupted`).
"""
from __future__ import annotations

import atexit
import contextlib
import logging
import os
import shlex
import sys
import tempfile
import traceback
from pathlib import Path
from typing import NoReturn

from filelock import FileLock, Timeout
from omegaconf import OmegaConf

from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.interrupts import Interrupted, interruption

LOCK_FILE = ".gtsweep.lock"
COMMAND: list[str] = []  # the command line of this process's gtsweep.cli.main
_held: dict = {}  # output directory -> its lock file, held for this process's life


def new_dir(base: str) -> str:
    """``base``, or ``base-2``, ``base-3``... : the first that this process creates (an exclusive claim)."""
    try:
        Path(base).parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BadInput(f"cannot write the output directory {base}: {e.strerror or e}") from None
    for n in range(1, 1000):
        candidate = base if n == 1 else f"{base}-{n}"
        try:
            os.mkdir(candidate)
            return candidate
        except FileExistsError:
            continue
    raise BadInput(f"cannot find a free output directory beside {base}")


#: The settings ``${gtsweep.new_dir:...}`` may stand in; anywhere else (a planted file) it creates nothing.
RUN_DIR_KEYS = ("hydra.run.dir", "hydra.sweep.dir")
_claimed: dict = {}  # (setting, base) -> the folder claimed for it


def run_dir(base: str, _node_) -> str:
    """``${gtsweep.new_dir:...}``: the folder :func:`new_dir` claims for ``hydra.run.dir``/``hydra.sweep.dir``,
    once per setting (every read gives the same folder); refused in any other setting."""
    key = _node_._get_full_key(None)
    if key not in RUN_DIR_KEYS:
        raise BadInput(f"${{gtsweep.new_dir:...}} sets {' or '.join(RUN_DIR_KEYS)} only, not '{key}'")
    if (key, base) not in _claimed:
        _claimed[key, base] = new_dir(base)
    return _claimed[key, base]


def register_resolvers() -> None:
    """``${gtsweep.new_dir:...}`` for conf/config.yaml (:func:`run_dir`)."""
    if not OmegaConf.has_resolver("gtsweep.new_dir"):
        OmegaConf.register_new_resolver("gtsweep.new_dir", run_dir)


def check_writable(directory: str | os.PathLike) -> None:
    """A one-line BadInput unless ``directory`` can be created and written."""
    try:
        Path(directory).mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        raise BadInput(f"cannot write the output directory {directory}: {e.strerror or e}") from None


def claim(output_dir: Path) -> None:
    """Lock ``output_dir`` for this process's life: a second run writing there stops with one line."""
    key = str(output_dir.resolve())
    if key in _held:
        return
    lock = FileLock(output_dir / LOCK_FILE, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise BadInput(f"another gtsweep run is writing to {output_dir}; wait for it or choose another "
                       f"hydra.run.dir") from None
    _held[key] = lock


def leave(code: int | str | None) -> NoReturn:
    """End the process with a :class:`SystemExit`'s ``code``. After :func:`stop_workers` ended Ray, the process
    skips C's exit handlers: once its raylet and GCS are gone (a Ctrl-C to the whole process group reaches them
    too), Ray's core-worker exit handler (``CoreWorkerProcess::HandleAtExit``, Ray 2.60) waits for the dead GCS and
    then crashes the process (SIGSEGV: exit status -11 instead of 130). Python's own exit work (atexit functions,
    logging, the standard streams) is done first."""
    from gtsweep.orchestration.cluster import ray_stopped

    if not ray_stopped():
        sys.exit(code)
    if isinstance(code, str):  # sys.exit("message"): Python prints it
        print(code, file=sys.stderr)
    atexit._run_exitfuncs()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code if isinstance(code, int) else (0 if code is None else 1))
def resume_command() -> str:
    """The command that continues this run: the user's command as typed (``sys.orig_argv``) with
    ``resume=true``."""
    typed = list(getattr(sys, "orig_argv", []))
    if typed[1:3] == ["-m", "gtsweep"]:
        args = typed[3:]
    else:  # called from Python (tests, scripts): the command line gtsweep's main() got
        args = list(COMMAND)
    return shlex.join(["python", "-m", "gtsweep", *[a for a in args if not a.startswith("resume=")], "resume=true"])


#: Exit code of a run that stopped on a failure of its environment (disk, store, cluster) or a bug: not bad input (2).
EXIT_FAILED = 1
RAYLET_LOST = "the Ray cluster was lost (raylet died)"


def failure_cause(error: BaseException) -> str:
    """Why a run stopped, in one line: a file error with its file (``No space left on device: cells/x.csv``), a
    locked or broken MLflow store, a lost Ray cluster, else the exception's type, message and where it was raised."""
    if isinstance(error, OSError) and error.strerror:
        where = f": {error.filename}" if error.filename else ""
        return f"{error.strerror}{where}"
    message = " ".join((str(error).strip().splitlines() or [""])[0].split())
    kind = type(error).__name__
    module = type(error).__module__ or ""
    if "database is locked" in str(error):
        return "the MLflow store is locked by another process (database is locked)"
    if kind == "LocalRayletDiedError":
        return RAYLET_LOST
    if module.startswith("ray"):
        return f"the Ray cluster was lost ({kind}: {message})"
    if module.startswith(("mlflow", "sqlalchemy")):
        return f"the MLflow store failed ({kind}: {message})"
    frames = traceback.extract_tb(error.__traceback__)
    where = f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{kind}: {message}{where}"


def exit_failed(error: BaseException, kept: str, marked: str = "") -> None:
    """One line on stderr (the cause, what is kept, how to continue), exit code :data:`EXIT_FAILED`; ``marked``
    says what became of the MLflow run when it could not be marked FAILED."""
    print(failure_line(failure_cause(error), kept, marked), file=sys.stderr)
    sys.exit(EXIT_FAILED)


def failure_line(cause: str, kept: str, marked: str = "", resume: str | None = None) -> str:
    """The one line a failed run ends with (also printed by :mod:`gtsweep.cli.watchdog` for a vanished sweep)."""
    return f"gtsweep: error: {cause}; {kept}{marked}; to continue: {resume or resume_command()}"


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
    marked = abort(str(signal) if signal else failure_cause(error), "KILLED" if signal else "FAILED") \
        if abort is not None else ""
    if signal is None:
        exit_failed(error, kept(), marked)
    exit_interrupted(signal, kept())


def exit_interrupted(error: Interrupted, kept: str) -> None:
    """One line on stderr (what is kept, how to continue), exit code 128 + the signal (130 SIGINT, 143 SIGTERM)."""
    print(f"gtsweep: interrupted by {error.name}; {kept}; to continue: {resume_command()}", file=sys.stderr)
    sys.exit(128 + error.signum)
