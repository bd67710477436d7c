"""MLflow stays true after resume: a cell computed again with another parameter replaces its child run, resume
continues the newest directory that holds a run of the command (a failed start is passed over, and it says which),
a parent left RUNNING by a killed process is closed KILLED before it is reopened, and the reason a run had stopped
is cleared from it when a resume finishes it."""
from __future__ import annotations

import json
import os
import sqlite3
import time
from pathlib import Path

import pytest

from gtsweep.orchestration.resume_pick import pick
from gtsweep.tracking.closing import LEFT_RUNNING, REASON_TAG, RESUMED_AFTER_TAG, clear_reason, mark_ended, reopen
from sweep_helpers import run_cli
from test_failures import _assert_true_record, _runs, _sweep


def _record(directory: Path, key: str = "k", cells: int = 0, when: float = 0) -> Path:
    directory.mkdir(parents=True)
    (directory / "sweep.json").write_text(json.dumps({"key": key}))
    for n in range(cells):
        (directory / "cells").mkdir(exist_ok=True)
        (directory / "cells" / f"c{n}.json").write_text("{}")
    for file in directory.rglob("*.json"):
        os.utime(file, (when, when))
    return directory / "sweep.json"


def test_resume_passes_over_a_start_that_failed_and_says_which_it_picked(tmp_path):
    ran = _record(tmp_path / "10-00-00", cells=2, when=1000)
    failed = _record(tmp_path / "10-05-00", when=2000)  # newer, but only its sweep.json: a start that failed
    other = _record(tmp_path / "10-06-00", key="other", cells=3, when=3000)
    picked = pick([ran, failed, other], "k")
    assert picked.directory == tmp_path / "10-00-00"
    assert picked.why == (f"resume=true continues {tmp_path / '10-00-00'}: the newest of 1 earlier run(s) of this "
                          f"command, 2 finished cell(s); passed over 1 of its directories that never started")
    later = _record(tmp_path / "11-00-00", cells=1, when=4000)
    (later.parent / "mlflow.json").write_text("{}")
    assert pick([ran, failed, later], "k").directory == later.parent
    nothing = pick([failed], "k")
    assert nothing.directory is None and "passed over 1" in nothing.why and "starting afresh" in nothing.why


@pytest.fixture
def client(tmp_path, existing_store):
    from mlflow.tracking import MlflowClient

    return MlflowClient(existing_store(tmp_path / "mlflow.db", tmp_path))


def test_a_parent_left_running_is_closed_killed_before_it_is_reopened(client):
    experiment = client.get_experiment_by_name("gtsweep").experiment_id
    run_id = client.create_run(experiment).info.run_id  # RUNNING, as a kill -9 leaves it
    seen = []
    original = client.update_run
    client.update_run = lambda rid, status: (seen.append(client.get_run(rid)), original(rid, status=status))[1]
    reopen(client, run_id)
    assert seen[0].info.status == "KILLED" and seen[0].data.tags[REASON_TAG] == LEFT_RUNNING
    assert client.get_run(run_id).info.status == "RUNNING"
    clear_reason(client, run_id)  # the resume finished it
    tags = client.get_run(run_id).data.tags
    assert REASON_TAG not in tags and tags[RESUMED_AFTER_TAG] == LEFT_RUNNING


def test_a_closed_parent_keeps_its_reason_until_reopened(client):
    experiment = client.get_experiment_by_name("gtsweep").experiment_id
    run_id = client.create_run(experiment).info.run_id
    assert mark_ended(client, run_id, "No space left on device: cells", "FAILED") == ""
    reopen(client, run_id)
    run = client.get_run(run_id)
    assert run.info.status == "RUNNING" and run.data.tags[REASON_TAG] == "No space left on device: cells"


@pytest.fixture
def store(tmp_path, existing_store):
    existing_store(tmp_path / "mlflow.db", tmp_path)


FAST_CONF = "defaults:\n  - /schema/detector/fast@_here_\n  - _self_\nfast:\n  params: {{threshold: {threshold}}}\n"


@pytest.mark.slow
def test_a_parameter_changed_before_resume_replaces_the_stale_children(tmp_path, store):
    """The issue's case: FAST's threshold changes from 10 to 40 in a --config-dir after its cells finished; the
    resume computes them again, deletes their old children (tagged stale) and MLflow's report equals the files'."""
    out, conf = tmp_path / "out", tmp_path / "myconf"
    (conf / "detector").mkdir(parents=True)
    args = ["--config-dir", str(conf), *_sweep(tmp_path, out), "detector=[fast,orb]"]
    (conf / "detector/fast.yaml").write_text(FAST_CONF.format(threshold=10))
    assert run_cli(args, tmp_path).returncode == 0
    parent = json.loads((out / "mlflow.json").read_text())["parent_run_id"]
    before = {r.info.run_id for r in _runs(tmp_path) if r.data.tags.get("gtsweep.cell", "").startswith("fast")}
    (conf / "detector/fast.yaml").write_text(FAST_CONF.format(threshold=40))
    resumed = run_cli([*args, "resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "2 kept from an earlier run" in resumed.stdout  # ORB's two cells; FAST's two computed again
    _assert_true_record(tmp_path, out)
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    for run_id in before:  # the stale children: deleted, and tagged why
        run = client.get_run(run_id)
        assert run.info.lifecycle_stage == "deleted" and run.data.tags["gtsweep.stale"].startswith("computed again")
    assert client.get_run(parent).info.status == "FINISHED"


@pytest.mark.slow
def test_a_start_that_failed_on_a_locked_store_is_not_what_resume_continues(tmp_path, store):
    """A run stops after some cells; the same command then fails to start (the store is locked) and leaves its
    directory; resume=true continues the first run's directory, and the record ends true."""
    from test_failures import FAIL_ON_THIRD_CELL, _patched

    first = _patched(tmp_path, FAIL_ON_THIRD_CELL.format(code="ENOSPC", message="No space left on device"),
                     _sweep(tmp_path, tmp_path / "unused")[:-1])
    assert first.returncode == 1, first.stderr
    (original,) = [p.parent for p in tmp_path.glob("outputs/*/*/mlflow.json")]
    time.sleep(1.1)  # the failed start gets a directory of its own (outputs/<date>/<time>)
    db = sqlite3.connect(tmp_path / "mlflow.db", isolation_level=None, timeout=1)
    db.execute("BEGIN EXCLUSIVE")
    try:
        failed = run_cli([*_sweep(tmp_path, tmp_path / "unused")[:-1], "mlflow.timeout_s=1"], tmp_path)
    finally:
        db.execute("ROLLBACK")
        db.close()
    assert failed.returncode != 0 and len(list(tmp_path.glob("outputs/*/*"))) == 2, failed.stderr
    resumed = run_cli([*_sweep(tmp_path, tmp_path / "unused")[:-1], "resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resume=true continues {Path('outputs') / original.relative_to(tmp_path / 'outputs')}" in \
        resumed.stderr.replace(str(tmp_path) + "/", ""), resumed.stderr
    assert "2 kept from an earlier run" in resumed.stdout
    _assert_true_record(tmp_path, original)
