"""Issue 28, items 2 and 4: a run that stops abnormally — kill -9, a full disk, an unwritable ``cells/``, a full
artifact store, a locked ``mlflow.db`` — ends in one line (exit 1, the cause, the resume command), leaves no MLflow
run RUNNING once resumed, loses no finished cell, and its MLflow record gives the same report as its files."""
from __future__ import annotations

import contextlib
import io
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from sweep_helpers import cli_env, run_cli

pytestmark = pytest.mark.slow

SWEEP = ["detector=[orb,akaze]", "descriptor=[orb,brief]", "transform=[incremental]", "runner.backend=serial",
         "report.plots=false", "runner.progress=false", "dataset.textures=[gravel]", "dataset.view_size=[320,240]",
         "dataset.n_incremental=2", "dataset.n_absolute=2"]
N_CELLS = 4


@pytest.fixture(autouse=True)
def _store(tmp_path, existing_store):
    """The sweeps' store (./mlflow.db) exists, as after an earlier sweep: these tests are about a run's record."""
    existing_store(tmp_path / "mlflow.db", tmp_path)


def _sweep(tmp_path: Path, out: Path) -> list[str]:
    return [*SWEEP, f"dataset.cache_dir={tmp_path}/data", f"cache.dir={tmp_path}/cache", f"hydra.run.dir={out}"]


def _runs(cwd: Path) -> list:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{cwd / 'mlflow.db'}")
    return client.search_runs([e.experiment_id for e in client.search_experiments()], max_results=10000)


def _patched(tmp_path: Path, patch: str, args: list[str]) -> subprocess.CompletedProcess:
    """``python -m gtsweep ARGS`` with ``patch`` (Python) applied first: a failure injected mid-run."""
    script = tmp_path / "patched_gtsweep.py"
    script.write_text(textwrap.dedent(patch) + "\nfrom gtsweep.cli import main\nmain()\n")
    return subprocess.run([sys.executable, str(script), *args], cwd=tmp_path, env=cli_env(), capture_output=True,
                          text=True, timeout=600)


def _assert_failed_then_resumed(tmp_path: Path, out: Path, result, cause: str) -> None:
    """One line naming ``cause`` with the resume command, exit 1, the parent FAILED, finished cells kept; the
    resume finishes every cell with no run left RUNNING, and MLflow's report equals the files'."""
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 1, result.stderr
    assert len(lines) == 1 and cause in lines[0] and "resume=true" in lines[0], result.stderr
    assert "Traceback" not in result.stderr
    parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
    status = {r.info.run_id: r.info.status for r in _runs(tmp_path)}
    assert status[parent] == "FAILED"
    assert [s for s in status.values() if s == "RUNNING"] == []  # nor is a child being logged left RUNNING
    kept = len(list((out / "cells").glob("*.json")))
    resumed = run_cli(_sweep(tmp_path, out) + ["resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{kept} kept from an earlier run" in resumed.stdout
    _assert_true_record(tmp_path, out)


def _assert_true_record(tmp_path: Path, out: Path, n_cells: int = N_CELLS) -> None:
    runs = _runs(tmp_path)
    assert [r.info.status for r in runs if r.info.status == "RUNNING"] == []
    parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent]
    assert sorted(r.data.tags["gtsweep.cell"] for r in children) == sorted(p.stem for p in (out / "cells").glob(
        "*.json")) and len(children) == n_cells
    files = _report(tmp_path, [str(out), "--out", str(tmp_path / "from_files")])
    mlflow = _report(tmp_path, [parent, "--mlflow", "--out", str(tmp_path / "from_mlflow")])
    assert mlflow.replace("from_mlflow", "X") == files.replace("from_files", "X")


def _report(cwd: Path, args: list[str]) -> str:
    """What ``python -m gtsweep.report --no-plots ARGS`` prints in ``cwd`` (its own ``main``, run in this process:
    no interpreter to start and no imports to repeat, twice per test)."""
    from gtsweep.experiments.report_command import main

    printed, saved = io.StringIO(), os.environ.pop("MLFLOW_TRACKING_URI", None)  # as cli_env(): the default store
    try:
        with contextlib.chdir(cwd), contextlib.redirect_stdout(printed):
            code = main(["--no-plots", *args])
    finally:
        if saved is not None:
            os.environ["MLFLOW_TRACKING_URI"] = saved
    assert code == 0, printed.getvalue()
    return printed.getvalue()


FAIL_ON_THIRD_CELL = """
import errno
import gtsweep.orchestration.results as results

written = []
original = results.ResultStore.write_cell

def write_cell(self, key, *args, **kwargs):
    written.append(key)
    if len(written) == 3:
        raise OSError(errno.{code}, "{message}", str(self.cells_dir / f"{{key}}.csv"))
    return original(self, key, *args, **kwargs)

results.ResultStore.write_cell = write_cell
"""


@pytest.mark.parametrize("code, message", [("ENOSPC", "No space left on device"), ("EACCES", "Permission denied")])
def test_a_write_error_mid_run_is_one_line_and_the_parent_fails(tmp_path, code, message):
    out = tmp_path / "out"
    result = _patched(tmp_path, FAIL_ON_THIRD_CELL.format(code=code, message=message), _sweep(tmp_path, out))
    _assert_failed_then_resumed(tmp_path, out, result, f"{message}: {out / 'cells'}")


def test_a_full_disk_on_a_small_filesystem(tmp_path):
    mount = tmp_path / "small"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], capture_output=True).returncode:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        free = os.statvfs(mount).f_bavail * os.statvfs(mount).f_frsize
        (mount / "filler").write_bytes(b"\0" * (free - 16 * 4096))  # 16 pages left: a few cells fit, not all
        out = mount / "out"
        result = run_cli(_sweep(tmp_path, out), tmp_path)
        assert result.returncode == 1 and "No space left on device" in result.stderr, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
        parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
        assert {r.info.run_id: r.info.status for r in _runs(tmp_path)}[parent] == "FAILED"
        (mount / "filler").unlink()
        resumed = run_cli(_sweep(tmp_path, out) + ["resume=true"], tmp_path)
        assert resumed.returncode == 0, resumed.stderr
        _assert_true_record(tmp_path, out)
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_full_artifact_store_is_one_line_and_the_parent_fails(tmp_path):
    patch = """
    import errno
    from mlflow.tracking import MlflowClient

    calls = []
    original = MlflowClient.log_artifact

    def log_artifact(self, run_id, local_path, artifact_path=None):
        calls.append(local_path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device", "mlruns/artifacts")
        return original(self, run_id, local_path, artifact_path)

    MlflowClient.log_artifact = log_artifact
    """
    out = tmp_path / "out"
    _assert_failed_then_resumed(tmp_path, out, _patched(tmp_path, patch, _sweep(tmp_path, out)),
                                "No space left on device: mlruns/artifacts")


def test_a_locked_mlflow_store_is_one_line_and_the_parent_fails_once_it_is_free(tmp_path):
    """Another process holds ``mlflow.db`` locked (an open write transaction) past SQLite's wait: the run stops
    with one line; the lock is gone a little later and the parent is then marked FAILED. SQLite's wait is MLflow's
    ``PRAGMA busy_timeout`` (20 s), cut to BUSY_SECONDS in the sweep process: the same error, sooner."""
    patch = f"""
    import re, sqlite3, threading, time
    import sqlalchemy
    import gtsweep.orchestration.results as results

    @sqlalchemy.event.listens_for(sqlalchemy.engine.Engine, "before_cursor_execute", retval=True)
    def shorter_wait(connection, cursor, statement, parameters, context, executemany):
        return re.sub(r"busy_timeout = [0-9]+", "busy_timeout = {BUSY_SECONDS * 1000}", statement), parameters

    original = results.ResultStore.write_cell
    locked = []

    def hold_lock():
        db = sqlite3.connect({str(tmp_path / 'mlflow.db')!r}, isolation_level=None)
        db.execute("BEGIN EXCLUSIVE")
        time.sleep({LOCK_SECONDS})
        db.execute("ROLLBACK")

    def write_cell(self, key, *args, **kwargs):
        if not locked:
            locked.append(threading.Thread(target=hold_lock, daemon=True))
            locked[0].start()
            time.sleep(0.5)
        return original(self, key, *args, **kwargs)

    results.ResultStore.write_cell = write_cell
    """
    out = tmp_path / "out"
    _assert_failed_then_resumed(tmp_path, out, _patched(tmp_path, patch, _sweep(tmp_path, out)),
                                "the MLflow store is locked")


#: The lock outlasts the first write's wait (0.5 s + BUSY_SECONDS) and ends within the FAILED mark's wait after it
#: (0.5 s + 2 BUSY_SECONDS): 3 s to spare on either side.
BUSY_SECONDS, LOCK_SECONDS = 6, 9.5


@pytest.mark.parametrize("attempt", range(3))
def test_kill_9_at_a_random_moment_then_resume_leaves_a_true_record(tmp_path, attempt):
    out = tmp_path / "out"
    sweep = subprocess.Popen([sys.executable, "-m", "gtsweep", *_sweep(tmp_path, out)], cwd=tmp_path, env=cli_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    random.seed(attempt)
    deadline = time.monotonic() + 120
    while not (out / "mlflow.json").exists() and sweep.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)  # the parent run exists: from here on a kill can leave a child half-logged
    time.sleep(random.uniform(0, 2.5))  # cells are logged within seconds of the parent run on this grid
    sweep.send_signal(signal.SIGKILL)
    sweep.wait(timeout=60)
    resumed = run_cli(_sweep(tmp_path, out) + ["resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    _assert_true_record(tmp_path, out)


def test_a_child_left_running_is_replaced_on_resume(tmp_path):
    """The kill's worst moment, made certain: a child run created, no metrics, RUNNING."""
    out = tmp_path / "out"
    assert run_cli(_sweep(tmp_path, out), tmp_path).returncode == 0
    parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    victim = next(r for r in _runs(tmp_path) if r.data.tags.get("mlflow.parentRunId") == parent)
    client.delete_run(victim.info.run_id)
    client.create_run(victim.info.experiment_id, tags={**victim.data.tags})  # half-logged: tags only, RUNNING
    (out / "results.csv").unlink()
    resumed = run_cli(_sweep(tmp_path, out) + ["resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    _assert_true_record(tmp_path, out)


RAY_SWEEP = ["runner.backend=ray", "runner.num_cpus=2", "transform=[incremental,absolute]"]
RAY_CELLS = 2 * N_CELLS  # enough cells that some are still running when the raylet is killed after the first


def _raylet_of(pid: int) -> int | None:
    """The raylet of the embedded Ray that process ``pid`` started (its child named ``raylet``)."""
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return None
    for child in children:
        try:
            if Path(f"/proc/{child}/comm").read_text().strip() == "raylet":
                return int(child)
        except OSError:
            continue
    return None


def test_a_raylet_killed_mid_run_is_one_line_and_the_parent_fails(tmp_path):
    """Ray ends the driver from its compiled code when its raylet dies; the watchdog still closes the record."""
    out = tmp_path / "out"
    args = [*_sweep(tmp_path, out), *RAY_SWEEP]
    sweep = subprocess.Popen([sys.executable, "-m", "gtsweep", *args], cwd=tmp_path, env=cli_env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        raylet, deadline = None, time.monotonic() + 300
        while sweep.poll() is None and time.monotonic() < deadline:
            raylet = raylet or _raylet_of(sweep.pid)
            if raylet and any((out / "cells").glob("*.json")):
                break
            time.sleep(0.02)
        assert raylet is not None and sweep.poll() is None, "the sweep ended before its first cell was written"
        os.kill(raylet, signal.SIGKILL)  # this sweep's own raylet, by pid
        _, stderr = sweep.communicate(timeout=300)  # the watchdog holds stderr until it has said its line
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.communicate()
    errors = [line for line in stderr.splitlines() if line.startswith("gtsweep: error:")]
    assert sweep.returncode == 1, stderr
    assert len(errors) == 1, stderr
    assert "the Ray cluster was lost (raylet died)" in errors[0] and errors[0].endswith("resume=true"), errors
    assert "Traceback" not in stderr
    kept = len(list((out / "cells").glob("*.json")))
    assert 1 <= kept < RAY_CELLS and f"{kept} finished cell(s) kept" in errors[0]
    parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
    assert {r.info.run_id: r.info.status for r in _runs(tmp_path)}[parent] == "FAILED"
    resumed = run_cli([*args, "resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{kept} kept from an earlier run" in resumed.stdout
    _assert_true_record(tmp_path, out, RAY_CELLS)
