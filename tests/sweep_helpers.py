"""Small sweeps on the embedded data set for the integration tests."""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Iterator

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


def session_processes(session: int) -> list[bytes]:
    """The command lines of the processes in ``session`` (a command started with ``start_new_session=True``)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if os.getsid(int(entry.name)) == session:
                    found.append((entry / "cmdline").read_bytes().replace(b"\0", b" ")[:120])
            except (OSError, ProcessLookupError):
                continue
    return found


def session_ends(session: int, timeout: float = 3) -> list[bytes]:
    """What is left in ``session`` ``timeout`` seconds after its command ended: [] as soon as it is empty (no
    process can join an empty session), else the processes still there at the end."""
    deadline = time.monotonic() + timeout
    while (left := session_processes(session)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return left


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


@contextlib.contextmanager
def mlflow_server(uri: str, cwd: Path, *extra: str, timeout: float = 180) -> Iterator[str]:
    """``mlflow server`` on a free port of 127.0.0.1 over the store ``uri``: its base address once ``/health``
    answers; SIGTERM to its process group afterwards."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = subprocess.Popen(
        [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri, "--host", "127.0.0.1",
         "--port", str(port), "--workers", "1", *extra], cwd=cwd, env=cli_env(), stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + timeout
        while True:
            try:
                with urllib.request.urlopen(f"{base}/health", timeout=2) as response:
                    if response.status == 200:
                        break
            except OSError:
                pass
            assert server.poll() is None and time.time() < deadline, "mlflow server did not come up"
            time.sleep(0.1)
        yield base
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)


def checked_jobs(args: list[str], tmp_path: Path, monkeypatch) -> list[list[str]]:
    """Run ``python -m gtsweep -m ARGS`` in ``tmp_path`` with a task that runs nothing: the sweeper's checks of
    every job (a mistake: SystemExit 2), and the overrides of the jobs it launched."""
    from hydra.core.hydra_config import HydraConfig

    import gtsweep.cli.app
    from gtsweep.cli import main

    launched = []
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gtsweep.cli.app, "app", lambda cfg: launched.append(list(HydraConfig.get().overrides.task)))
    main(["-m", *args, "mlflow.enabled=false", "hydra/hydra_logging=none", "hydra/job_logging=none"])
    return launched
