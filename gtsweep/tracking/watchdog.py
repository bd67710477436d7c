"""A second process that closes a Ray sweep's record when the sweep process vanishes without a word.

When Ray's raylet dies mid-run, Ray ends the driver from its compiled code (no Python exception, no ``finally``,
no ``atexit``): the app cannot mark its MLflow parent run FAILED nor print how to resume. So before Ray starts,
:func:`watched` starts this module as a small process tied to the sweep by a pipe. Every end the app reaches
itself (a normal end, bad input, an interrupt, :func:`~gtsweep.cli.lifecycle.stop`) writes ``done`` to the
pipe and the watchdog leaves quietly. If the pipe closes without it, the sweep process died: the watchdog marks
the parent run (``mlflow.json`` in the output directory) FAILED with the cause — "the Ray cluster was lost (raylet
died)" when the sweep's own raylet ended before it, else "the sweep process died" —, ends the Ray processes of the
sweep's session (Ray's agents would otherwise outlive it by minutes) and prints the one
``gtsweep: error: ...`` line with the resume command. It ignores Ctrl-C and SIGTERM (the sweep handles those and
says ``done``) and never outlives the pipe, so it is never orphaned.
"""
from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
from pathlib import Path
from typing import Iterator

from gtsweep.core.errors import RAYLET_LOST, failure_line
from gtsweep.orchestration.cluster import end_ray_processes
from gtsweep.orchestration.resume_pick import kept_cells

DONE = b"done\n"
POLL_S = 0.5
PROCESS_DIED = "the sweep process died"
WATCH_DIR, WATCH_RESUME = "GTSWEEP_WATCH_OUTPUT_DIR", "GTSWEEP_WATCH_RESUME"


@contextlib.contextmanager
def watched(output_dir: Path, resume: str) -> Iterator[None]:
    """Run the body under a watchdog; leaving the body any Python way (return, exception, ``sys.exit``) says
    ``done``."""
    env = {**os.environ, WATCH_DIR: str(output_dir), WATCH_RESUME: resume}  # not in argv: no stray "raylet" there
    watchdog = subprocess.Popen([sys.executable, "-m", __name__, str(os.getpid())], stdin=subprocess.PIPE, env=env)
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            watchdog.stdin.write(DONE)
            watchdog.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            watchdog.wait(timeout=10)


def children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except (OSError, ValueError):
        return []


def raylet_of(pid: int) -> int | None:
    """The raylet the sweep process started (embedded Ray), if any."""
    for child in children(pid):
        with contextlib.suppress(OSError):
            if Path(f"/proc/{child}/comm").read_text().strip() == "raylet":
                return child
    return None


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return False


def wait_for_end(sweep_pid: int, pipe: int | None = None, find_raylet=raylet_of, parent=os.getppid) -> str | None:
    """Block until the pipe says ``done`` (None) or closes without it, then why the sweep ended: :data:`RAYLET_LOST`
    when its raylet ended while the sweep still lived, else :data:`PROCESS_DIED`. A kill -9 of the sweep ends its
    raylet too (Ray ties the raylet's life to its driver), just after: so the order counts, not who is gone. The
    raylet's end is seen at once through a pidfd (by polling where there is none)."""
    pipe = sys.stdin.fileno() if pipe is None else pipe
    raylet, watch, raylet_first, received = None, None, False, b""
    try:
        while True:
            readable, _, _ = select.select([pipe, *([watch] if watch is not None else [])], [], [], POLL_S)
            if pipe in readable:
                chunk = os.read(pipe, 64)
                received += chunk
                if DONE in received:
                    return None
                if not chunk:
                    return RAYLET_LOST if raylet_first else PROCESS_DIED
            elif raylet and not raylet_first and not alive(raylet):
                raylet_first = alive(sweep_pid)  # the raylet ended, the sweep has not (yet)
            if watch is not None and not alive(raylet):
                os.close(watch)
                watch = None
            if parent() != sweep_pid:  # reparented: the sweep is gone though someone still holds the pipe
                return RAYLET_LOST if raylet_first else PROCESS_DIED
            if raylet is None:
                raylet = find_raylet(sweep_pid)
                watch = _pidfd(raylet) if raylet else None
    finally:
        if watch is not None:
            os.close(watch)


def _pidfd(pid: int) -> int | None:
    """A file descriptor that becomes readable when ``pid`` ends (Linux 5.3+), or None."""
    with contextlib.suppress(AttributeError, OSError):
        return os.pidfd_open(pid)
    return None


def ray_package_dir() -> str | None:
    """Where Ray's package is installed (its scripts' path marks Ray's agents), without importing it."""
    import importlib.util

    spec = importlib.util.find_spec("ray")
    return os.path.dirname(spec.origin) if spec is not None and spec.origin else None


def mark_failed(output_dir: Path, cause: str) -> str:
    """Mark the sweep's parent run FAILED; "" when done or when there is none, else a note why not."""
    from gtsweep.core.rundirs import PARENT_RECORD
    from gtsweep.tracking.closing import mark_ended

    record = output_dir / PARENT_RECORD
    if not record.exists():  # MLflow off, or the sweep died before its parent run existed
        return ""
    parent = json.loads(record.read_text())
    return mark_ended(parent["tracking_uri"], parent["parent_run_id"], cause, "FAILED")


def main(argv: list[str]) -> int:
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_IGN)
    sweep_pid, output_dir, resume = int(argv[0]), Path(os.environ[WATCH_DIR]), os.environ[WATCH_RESUME]
    cause = wait_for_end(sweep_pid)
    if cause is None:
        return 0
    end_ray_processes(ray_package_dir(), owner=sweep_pid)  # its agents would linger for minutes
    marked = mark_failed(output_dir, cause)
    print(failure_line(cause, kept_cells(output_dir), marked, resume), file=sys.stderr, flush=True)
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
