"""Small sweeps on the embedded data set for the integration tests."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd

from gtsweep.cli.overrides import compose_config  # noqa: F401  (re-exported for the tests)
from gtsweep.core.paths import PROJECT_DIR

#: A tiny embedded data set: two textures, small views, a couple of images and pairs each.
TINY_DATASET = ["dataset.textures=[gravel,carpet]", "dataset.view_size=[320,240]", "dataset.n_optimisation=1",
                "dataset.n_synthetic=1", "dataset.n_incremental=2", "dataset.n_absolute=2"]


def tiny_overrides(tmp_path: Path, *extra: str) -> list[str]:
    return [*TINY_DATASET, f"dataset.cache_dir={tmp_path}/data", f"cache.dir={tmp_path}/cache",
            "runner.progress=false", "runner.shard_size=1", *extra]


def cli_env() -> dict:
    """The environment for ``python -m gtsweep`` subprocesses (the package imported from this checkout), without
    the ``MLFLOW_TRACKING_URI`` that ``mlflow.set_tracking_uri`` in an earlier test exports to children."""
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    return {**env, "PYTHONPATH": str(PROJECT_DIR)}


def run_cli(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m gtsweep ARGS`` in ``cwd``."""
    return subprocess.run([sys.executable, "-m", "gtsweep", *args], cwd=cwd, env=cli_env(), capture_output=True,
                          text=True, timeout=timeout)


def science_columns(frame: pd.DataFrame) -> pd.DataFrame:
    """A cell's rows without the timing columns (the numbers that must be identical between runs)."""
    return frame[[c for c in frame.columns if not c.startswith("t_")]]


def read_cells(directory: Path) -> dict[str, pd.DataFrame]:
    return {p.stem: science_columns(pd.read_csv(p)) for p in sorted((directory / "cells").glob("*.csv"))}


def assert_same_cells(a: Path, b: Path) -> None:
    """Both sweeps wrote the same cells with identical numbers (timings aside)."""
    ours, theirs = read_cells(a), read_cells(b)
    assert ours.keys() == theirs.keys() and ours
    for key in ours:
        pd.testing.assert_frame_equal(ours[key], theirs[key], check_exact=True, obj=key)
