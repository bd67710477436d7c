"""Shared fixtures: real texture photographs that scikit-image ships (no download); an MLflow store made once."""
import contextlib
from pathlib import Path

import gtsweep  # noqa: F401 - before NumPy: it pins NumPy's and OpenBLAS's CPU paths (gtsweep.core.numeric_backends)
import cv2
import numpy as np
import pytest
import skimage.data

import gtsweep.experiments  # noqa: F401 - the experiment kinds registered (their rows in the metric schema)


@pytest.fixture(scope="session")
def gravel_1288x964() -> np.ndarray:
    """scikit-image's gravel photograph upsampled to the survey's image size (1288 x 964)."""
    return cv2.resize(skimage.data.gravel(), (1288, 964), interpolation=cv2.INTER_CUBIC)


@pytest.fixture(scope="session")
def gravel_small() -> np.ndarray:
    """A 320 x 240 crop of the gravel photograph."""
    return np.ascontiguousarray(skimage.data.gravel()[100:340, 50:370])


@pytest.fixture(scope="session")
def empty_store_file(tmp_path_factory):
    """A sqlite MLflow store as gtsweep's first sweep creates it (migrated, experiment "gtsweep", no run), made once
    per session: MLflow's migrations take seconds each time."""
    from gtsweep.tracking.store import open_store

    folder = tmp_path_factory.mktemp("empty_store")
    open_store({"tracking_uri": f"sqlite:///{folder / 'mlflow.db'}"}, "gtsweep")
    return folder / "mlflow.db"


@pytest.fixture(scope="session")
def existing_store(empty_store_file):
    """``place(db, cwd)``: write at ``db`` the store a first sweep run in ``cwd`` would have left before its first
    run — for tests of what happens to a sweep's record, not of the store's creation (that is tested where sweeps
    open one fresh store at once: test_interrupts.py). Its experiments' artifact locations are ``cwd/mlruns/<id>``,
    as MLflow sets them when the store is created in ``cwd``."""
    import sqlite3

    def place(db, cwd):
        with contextlib.closing(sqlite3.connect(empty_store_file)) as source, \
                contextlib.closing(sqlite3.connect(db)) as target:
            source.backup(target)
            target.execute("UPDATE experiments SET artifact_location = ? || '/' || experiment_id",
                           (str(Path(cwd).resolve() / "mlruns"),))
            target.commit()
        return f"sqlite:///{db}"

    return place
