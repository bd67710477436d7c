"""Peak resident memory and CPU time of a process tree (the driver, Ray's own processes and its workers), from /proc.

Used by ``make reproduce`` (the whole tree of each preset's process) and by ``benchmarks/`` (the driver and each
Ray worker apart). Linux only: elsewhere every figure is 0.
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _is_worker(pid: int) -> bool:
    """A Ray worker: its title is ``ray::<task>`` (setproctitle) or it runs Ray's ``default_worker.py``."""
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return command.startswith(b"ray::") or b"default_worker.py" in command


def _tree(pid: int, columns: tuple[int, ...], scale: float) -> dict[int, float]:
    """The sum of fields ``columns`` of /proc/<p>/stat (counted after the command name) times ``scale``, for
    ``pid`` and each of its descendants, by pid (empty where /proc is missing)."""
    children: dict[int, list[int]] = {}
    values: dict[int, float] = {}
    proc = Path("/proc")
    if not proc.is_dir():
        return {}
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(entry.name))
            values[int(entry.name)] = sum(int(fields[c]) for c in columns) * scale
        except (OSError, IndexError, ValueError):
            continue
    found, stack = {}, [pid]
    while stack:
        p = stack.pop()
        if p in values:
            found[p] = values[p]
        stack += children.get(p, [])
    return found


def tree_rss(pid: int) -> dict[int, int]:
    """Resident bytes of ``pid`` and each of its descendants, by pid (empty where /proc is missing)."""
    return {p: int(v) for p, v in _tree(pid, (21,), _PAGE).items()}


def tree_cpu(pid: int) -> dict[int, float]:
    """CPU seconds (user + system) each process of ``pid``'s tree has used so far, by pid."""
    return _tree(pid, (11, 12), 1 / _TICKS)


def cpu_split(before: dict[int, float], after: dict[int, float], driver: int) -> dict[str, float]:
    """CPU seconds used between two :func:`tree_cpu` snapshots, split into the ``driver`` process, Ray's workers
    and everything else in the tree (Ray's own processes: GCS, raylet, agents)."""
    split = {"driver": 0.0, "workers": 0.0, "ray": 0.0}
    for p, seconds in after.items():
        kind = "driver" if p == driver else "workers" if _is_worker(p) else "ray"
        split[kind] += seconds - before.get(p, 0.0)
    return split


@dataclass
class PeakMemory:
    """Samples the tree of ``pid`` every ``interval`` seconds in a thread, between ``start()`` and ``stop()``
    (or as a context manager). Peaks in bytes: ``total`` (whole tree at one instant), ``driver`` (``pid``
    itself), ``worker`` (the largest Ray worker) and ``workers`` (how many distinct workers were seen)."""

    pid: int = field(default_factory=os.getpid)
    interval: float = 0.5
    total: int = 0
    driver: int = 0
    worker: int = 0
    workers: int = 0

    def __post_init__(self):
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._seen: set[int] = set()

    def sample(self) -> None:
        tree = tree_rss(self.pid)
        self.total = max(self.total, sum(tree.values()))
        self.driver = max(self.driver, tree.get(self.pid, 0))
        for p, rss in tree.items():
            if p != self.pid and (p in self._seen or _is_worker(p)):
                self._seen.add(p)
                self.worker = max(self.worker, rss)
        self.workers = len(self._seen)

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.interval)

    def start(self) -> PeakMemory:
        self._thread = threading.Thread(target=self._loop, name="peak-memory", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> PeakMemory:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.sample()
        return self

    def __enter__(self) -> PeakMemory:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def line(self) -> str:
        mib = 2 ** 20
        text = f"peak memory: driver {self.driver / mib:.0f} MiB"
        if self.workers:
            text += f", largest of {self.workers} Ray workers {self.worker / mib:.0f} MiB"
        return text + f", whole process tree {self.total / mib:.0f} MiB"
