"""A run's life outside the science: its own output directory, and a clean stop on Ctrl-C or SIGTERM.

- Every run gets a directory of its own: ``hydra.run.dir`` / ``hydra.sweep.dir`` default to
  ``${gtsweep.new_dir:outputs/<date>/<time>}``, which claims the folder with an exclusive ``mkdir`` (``<time>-2``,
  ``-3``... when a run started in the same second holds it); an explicit directory is locked for the run's life.
- SIGINT and SIGTERM raise :class:`~gtsweep.core.interrupts.Interrupted` in the main thread; the app then stops the
  workers, marks its MLflow run KILLED and prints one line with the command that resumes (:func:`exit_interrupted`).
"""
from __future__ import annotations

import contextlib
import os
import shlex
import signal
import sys
import tempfile
import threading
import traceback
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout
from omegaconf import OmegaConf

from gtsweep.core import interrupts
from gtsweep.core.errors import BadInput
from gtsweep.core.interrupts import Interrupted

LOCK_FILE = ".gtsweep.lock"
_held: dict = {}  # output directory -> its lock file, held for this process's life


def new_dir(base: str) -> str:
    """``base``, or ``base-2``, ``base-3``... : the first that this process creates (an exclusive claim)."""
    Path(base).parent.mkdir(parents=True, exist_ok=True)
    for n in range(1, 1000):
        candidate = base if n == 1 else f"{base}-{n}"
        try:
            os.mkdir(candidate)
            return candidate
        except FileExistsError:
            continue
    raise BadInput(f"cannot find a free output directory beside {base}")


def register_resolvers() -> None:
    """``${gtsweep.new_dir:...}`` for conf/config.yaml; cached, so every read of the setting gives one folder."""
    if not OmegaConf.has_resolver("gtsweep.new_dir"):
        OmegaConf.register_new_resolver("gtsweep.new_dir", new_dir, use_cache=True)


def check_writable(directory: str | os.PathLike) -> None:
    """A one-line BadInput unless ``directory`` can be created and written."""
    try:
        Path(directory).mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        raise BadInput(f"cannot write the output directory {directory}: {e.strerror or e}") from None


def output_root(args: list[str], multirun: bool) -> tuple[str, bool]:
    """The directory a run will write under and whether it was given: ``hydra.run.dir``/``hydra.sweep.dir``, else
    the default root (``outputs`` or ``multirun``)."""
    key = "hydra.sweep.dir=" if multirun else "hydra.run.dir="
    explicit = [a[len(key):] for a in args if a.startswith(key)]
    return (explicit[-1], True) if explicit else ("multirun" if multirun else "outputs", False)


def prepare_output(args: list[str], multirun: bool) -> None:
    """Before Hydra writes anything: the output directory must be writable, and a given one must be free."""
    root, explicit = output_root(args, multirun)
    check_writable(root)
    if explicit:
        claim(Path(root))


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


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` (once: later signals are ignored while it cleans up)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in interrupts.SIGNALS}
    for s in interrupts.SIGNALS:
        signal.signal(s, interrupts.on_signal)
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
        interrupts.clear()


def interruption(error: BaseException) -> Interrupted | None:
    """The :class:`Interrupted` behind ``error``: Ray's compiled code turns an exception raised by a signal
    handler during ``ray.wait`` into a ``SystemError`` caused by it."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, Interrupted):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def stop_workers() -> None:
    """Shut down Ray if this process started or joined it, then end Ray's processes of this command that outlived
    it (a Ctrl-C that reaches the whole process group while Ray starts can kill the raylet before its agents)."""
    ray = sys.modules.get("ray")
    if ray is None:
        return
    if ray.is_initialized():
        with contextlib.suppress(Exception):
            ray.shutdown()
    for pid in leftover_ray_processes():
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


def leftover_ray_processes(proc: Path = Path("/proc")) -> list[int]:
    """Ray's processes (``ray::...``, raylet, GCS) in this process's group that are this process's descendants or
    orphans (parent 1): what this command started and nothing else's (Linux; elsewhere none)."""
    me, group, parents, ray_pids = os.getpid(), os.getpgrp(), {}, set()
    for entry in proc.glob("[0-9]*"):
        try:
            pid = int(entry.name)
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            parents[pid] = int(fields[1])
            if int(fields[2]) == group and pid != me:
                program = (entry / "cmdline").read_bytes().split(b"\0", 1)[0]
                if program.startswith(b"ray::") or os.path.basename(program) in (b"raylet", b"gcs_server"):
                    ray_pids.add(pid)
        except (OSError, ValueError, IndexError):
            continue

    def ours(pid: int) -> bool:
        seen = set()
        while pid not in (0, 1) and pid not in seen:
            seen.add(pid)
            pid = parents.get(pid, 0)
            if pid == me:
                return True
        return False
    return sorted(p for p in ray_pids if parents.get(p) == 1 or ours(p))


def resume_command() -> str:
    """The command that continues this run: the user's command as typed (``sys.orig_argv``, which gtsweep's
    rewrite of ``sys.argv`` leaves alone) with ``resume=true``."""
    typed = list(getattr(sys, "orig_argv", []))
    if typed[1:3] == ["-m", "gtsweep"]:
        args = typed[3:]
    else:  # called from Python (tests, scripts): the arguments Hydra got
        args = [a for a in sys.argv[1:] if not a.startswith("hydra.searchpath=")]
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


def exit_interrupted(error: Interrupted, kept: str) -> None:
    """One line on stderr (what is kept, how to continue), exit code 128 + the signal (130 SIGINT, 143 SIGTERM)."""
    print(f"gtsweep: interrupted by {error.name}; {kept}; to continue: {resume_command()}", file=sys.stderr)
    sys.exit(128 + error.signum)
