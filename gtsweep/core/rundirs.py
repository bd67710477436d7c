"""A run's output directory, its own: ``hydra.run.dir`` / ``hydra.sweep.dir`` default to
``${gtsweep.new_dir:outputs/<date>/<time>}``, which claims the folder with an exclusive ``mkdir`` (``<time>-2``,
``-3``... when a run started in the same second holds it); a directory given explicitly is locked for the run's life.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from gtsweep.core.errors import BadInput

LOCK_FILE = ".gtsweep.lock"
#: What a run writes in its output directory, named once.
CELLS = "cells"                    # a record (and per-view rows) per finished cell
RESULTS = "results.csv"            # the cells' summaries
REPORT = "report"                  # the run's tables and plots
RUN_RECORD = "run.json"            # the sweep's record: its grid, cluster, outcome
PARENT_RECORD = "mlflow.json"      # the sweep's MLflow parent run
SWEEP_RECORD = "sweep.json"        # the command's key (resume finds the run by it) and overrides
MULTIRUN_RECORD = "multirun.json"  # a multirun's key, swept keys and MLflow run
COMBINED = "combined"              # a multirun's tables across its jobs
#: The settings ``${gtsweep.new_dir:...}`` may stand in; anywhere else (a planted file) it creates nothing.
RUN_DIR_KEYS = ("hydra.run.dir", "hydra.sweep.dir")
_claimed: dict = {}  # (setting, base) -> the folder claimed for it
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
    from omegaconf import OmegaConf

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
    from filelock import FileLock, Timeout

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
