"""Which earlier output directory ``resume=true`` continues.

Every run records its command's key in ``sweep.json`` as soon as Hydra made its directory, so a start that failed
right after (a locked ``mlflow.db``, a refused setting) leaves a directory that holds the key but no run. Resume
continues the newest directory of the same key that **holds a run** (a finished cell, an MLflow parent run or a run
record), newest by its last write, and says which one and why; a directory that never started is passed over.
"""
from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from gtsweep.core.rundirs import CELLS, PARENT_RECORD, RUN_RECORD, SWEEP_RECORD

#: Files of a run that started: its MLflow parent run and its run record (cells are under ``cells/``).
RUN_FILES = (PARENT_RECORD, RUN_RECORD)


@dataclass(frozen=True)
class Pick:
    """The directory resume continues (None: none), and the line that says why."""

    directory: Path | None
    why: str


def finished_cells(directory: Path) -> int:
    return len(list((directory / CELLS).glob("*.json")))


def kept_cells(directory: Path) -> str:
    """What a stopped run keeps, in words."""
    return f"{finished_cells(directory)} finished cell(s) kept in {directory}"


def holds_run(directory: Path) -> bool:
    """``directory`` holds a run that started: a finished cell, an MLflow parent run or a run record."""
    return finished_cells(directory) > 0 or any((directory / name).exists() for name in RUN_FILES)


def last_write(directory: Path) -> float:
    """When the run in ``directory`` last wrote: its newest cell or run file."""
    files = [*(directory / CELLS).glob("*.json"), *(directory / n for n in RUN_FILES), directory / SWEEP_RECORD]
    return max((f.stat().st_mtime for f in files if f.exists()), default=0.0)


def pick(records: list[Path], key: str) -> Pick:
    """Among ``records`` (``sweep.json`` files), the directory of the newest run of the command ``key``."""
    same = [r.parent for r in records if _key(r) == key]
    started = [d for d in same if holds_run(d)]
    passed = len(same) - len(started)
    skipped = f"; passed over {passed} of its directories that never started" if passed else ""
    if not started:
        return Pick(None, f"resume=true but no earlier run of this command was found{skipped}; starting afresh")
    newest = max(started, key=last_write)
    return Pick(newest, f"resume=true continues {newest}: the newest of {len(started)} earlier run(s) of this "
                        f"command, {finished_cells(newest)} finished cell(s){skipped}")


def _key(record: Path) -> str | None:
    try:
        return json.loads(record.read_text()).get("key")
    except (OSError, ValueError, AttributeError):
        return None


def command_key(overrides) -> str:
    """What identifies "the same command" for resume: its overrides, without resume and hydra settings."""
    kept = sorted(o for o in overrides if not o.startswith(("resume=", "hydra.")))
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()[:16]


def earlier_run(key: str, multirun: bool, root: Path | None = None) -> Path | None:
    """The newest output directory (a multirun's, for ``multirun``) of an earlier command with ``key`` that holds a
    run (:func:`pick`, which says which and why)."""
    pattern = f"multirun/*/*/*/{SWEEP_RECORD}" if multirun else f"outputs/*/*/{SWEEP_RECORD}"
    picked = pick(list((root or Path.cwd()).glob(pattern)), key)
    print(f"gtsweep: {picked.why}", file=sys.stderr)
    if picked.directory is None:
        return None
    return picked.directory.parent if multirun else picked.directory
