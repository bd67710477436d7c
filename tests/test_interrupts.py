"""Issue 14, the process-level cases: sweeps started at once, and Ctrl-C / SIGTERM.

Two sweeps started at once in a new directory both succeed, each in its own output directory and MLflow parent,
and leave a store the next sweep can use (two rounds in a row). Several processes opening one fresh sqlite store
at once all succeed (five rounds). An interrupted sweep (Ray or serial) or study stops its workers, marks its MLflow
run KILLED, prints one line with the command that resumes it and exits 130 (SIGINT) or 143 (SIGTERM); the resume
finishes.
"""
from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

from sweep_helpers import cli_env, run_cli, session_ends, tiny_overrides

pytestmark = pytest.mark.slow

ROUNDS = 5  # fresh stores opened at once by three processes (the race itself, cheap)
#: Whole sweeps started in pairs: every round costs two sweeps; the races inside are tested at their own level,
#: the store's five times (test_processes_opening_one_fresh_store_at_once), the same-second output directory
#: exactly (test_reliability.py::test_runs_started_in_the_same_second_get_their_own_directory).
SWEEP_ROUNDS = 2
AT_ONCE = ["descriptor=[orb]", "transform=[incremental]", "runner.backend=serial", "report.plots=false",
           "runner.progress=false", "dataset.textures=[gravel]", "dataset.view_size=[320,240]",
           "dataset.n_incremental=2", "dataset.n_absolute=2"]


def _start(args: list[str], cwd: Path, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "gtsweep", *args], cwd=cwd, env=cli_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


def _runs(uri: str) -> pd.DataFrame:
    """Every run of the store: run_id, status, ``tags.*`` and ``params.*`` columns (the fluent API would export
    the URI to the sweeps this test starts next)."""
    from mlflow.tracking import MlflowClient

    from gtsweep.tracking.store import store_lock

    with store_lock(uri):  # the sweep may be creating the store right now
        client = MlflowClient(uri)
    runs = client.search_runs([e.experiment_id for e in client.search_experiments()], max_results=10000)
    return pd.DataFrame([{"run_id": r.info.run_id, "status": r.info.status, "tags.mlflow.parentRunId": None,
                          **{f"tags.{k}": v for k, v in r.data.tags.items()},
                          **{f"params.{k}": v for k, v in r.data.params.items()}} for r in runs])


def test_two_sweeps_started_at_once_in_a_new_directory(tmp_path):
    data = [f"dataset.cache_dir={tmp_path}/data"]
    for round_ in range(SWEEP_ROUNDS):
        cwd = tmp_path / f"round{round_}"
        cwd.mkdir()
        first = _start(["detector=[orb]", *AT_ONCE, *data], cwd)
        time.sleep(0.3)
        second = _start(["detector=[akaze]", *AT_ONCE, *data], cwd)
        for sweep in (first, second):
            out, err = sweep.communicate(timeout=300)
            assert sweep.returncode == 0, f"round {round_}: {err[-3000:]}"
        tables = sorted(cwd.glob("outputs/*/*/results.csv"))
        assert len(tables) == 2, f"round {round_}: {tables}"  # one output directory per sweep
        assert sorted(pd.read_csv(t)["detector"].tolist()[0] for t in tables) == ["akaze", "orb"]
        for table in tables:
            assert pd.read_csv(table)["detector"].nunique() == 1
        runs = _runs(f"sqlite:///{cwd}/mlflow.db")
        parents = runs[runs["tags.mlflow.parentRunId"].isna()]
        assert len(parents) == 2 and set(parents["status"]) == {"FINISHED"}
        for _, parent in parents.iterrows():  # each parent holds its own sweep's cells only
            children = runs[runs["tags.mlflow.parentRunId"] == parent["run_id"]]
            detector = pd.read_csv(Path(parent["tags.gtsweep.output_dir"]) / "results.csv")["detector"][0]
            assert len(children) == 1 and set(children["params.detector"]) == {detector}
    # the store stays usable, and resume=true finds each sweep's own directory
    resumed = run_cli(["detector=[orb]", *AT_ONCE, *data, "resume=true"], cwd)
    assert resumed.returncode == 0 and "1 kept from an earlier run" in resumed.stdout, resumed.stderr[-2000:]
    assert len(list(cwd.glob("outputs/*/*/results.csv"))) == 2


OPEN_STORE = textwrap.dedent("""
    import sys
    import mlflow.tracking
    from gtsweep.tracking.store import open_store
    folder, rounds = sys.argv[1], int(sys.argv[2])
    for round_ in range(rounds):  # every process opens the same fresh store at the same moment, once per round
        print("ready", flush=True)
        sys.stdin.readline()  # the test lets every process go at once
        client, experiment = open_store({"tracking_uri": f"sqlite:///{folder}/store{round_}.db"}, "gtsweep")
        client.set_terminated(client.create_run(experiment).info.run_id)
""")


def test_processes_opening_one_fresh_store_at_once(tmp_path):
    """What Hydra's joblib launcher does: parallel jobs open one new sqlite store together. Each round starts when
    every process has imported MLflow and said it is ready."""
    procs = [subprocess.Popen([sys.executable, "-c", OPEN_STORE, str(tmp_path), str(ROUNDS)], env=cli_env(),
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(3)]
    for round_ in range(ROUNDS):
        ready = [p.stdout.readline() for p in procs]
        assert ready == ["ready\n"] * 3, (round_, [p.communicate(timeout=300)[1][-800:] for p in procs])
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
    errors = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0] * 3, [e[-800:] for e in errors]
    for round_ in range(ROUNDS):
        assert len(_runs(f"sqlite:///{tmp_path}/store{round_}.db")) == 3, round_


# -------------------------------------------------------------------------------------------------- signals
def _interrupt(tmp_path: Path, args: list[str], sig: int, group: bool, ready,
               times: int = 1) -> tuple[subprocess.Popen, str]:
    sweep = _start(args, tmp_path, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and sweep.poll() is None and not ready():
        time.sleep(0.2)
    assert sweep.poll() is None, "finished before the signal: make the work larger"
    time.sleep(0.5)
    for _ in range(times):  # an impatient user presses Ctrl-C twice
        os.killpg(sweep.pid, sig) if group else os.kill(sweep.pid, sig)  # Ctrl-C reaches the whole group
        time.sleep(0.2)
    _, err = sweep.communicate(timeout=120)
    return sweep, err


def _one_resume_line(err: str, code: int, sweep) -> str:
    assert sweep.returncode == code, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("gtsweep: interrupted") and "resume=true" in last, err[-3000:]
    return last.split("to continue: ", 1)[1]


@pytest.mark.parametrize("backend,sig,group,times", [("ray", signal.SIGINT, True, 2), ("ray", signal.SIGTERM, False, 1),
                                                     ("serial", signal.SIGINT, True, 1)],
                         ids=["ray-SIGINT-group", "ray-SIGTERM", "serial-SIGINT-group"])
def test_an_interrupted_sweep_is_killed_cleanly_and_resumes(tmp_path, backend, sig, group, times, existing_store):
    """With Ray, Ctrl-C twice to the whole group (Ray's own processes get it too): exit 130 all the same (no crash
    in Ray's exit code) and no process of the command left (test_bounded.py: the same while Ray's agents start).
    The store exists already (its creation by sweeps at once: the tests above)."""
    uri = existing_store(tmp_path / "mlflow.db", tmp_path)
    grid = ["detector=[akaze,censure,orb,sift]", "descriptor=[brief,latch,sift]", "selector=[nms]",
            "transform=[incremental]", f"runner.backend={backend}", "runner.num_cpus=1",
            f"mlflow.tracking_uri={uri}", "report.plots=false"]
    args = tiny_overrides(tmp_path, *grid)
    sweep, err = _interrupt(tmp_path, args, sig, group, lambda: list(tmp_path.glob("outputs/*/*/cells/*.json")),
                            times)
    command = _one_resume_line(err, 128 + sig, sweep)
    assert session_ends(sweep.pid) == []
    kept = len(list(tmp_path.glob("outputs/*/*/cells/*.json")))
    parents = _runs(uri).query("`tags.mlflow.parentRunId`.isna()", engine="python")
    assert list(parents["status"]) == ["KILLED"]
    assert shlex.split(command)[:3] == ["python", "-m", "gtsweep"] and shlex.split(command)[-1] == "resume=true"
    resumed = run_cli(shlex.split(command)[3:], tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"{kept} kept from an earlier run" in resumed.stdout
    parents = _runs(uri).query("`tags.mlflow.parentRunId`.isna()", engine="python")
    assert list(parents["status"]) == ["FINISHED"]


def test_an_interrupted_study_is_killed_cleanly(tmp_path, existing_store):
    uri = existing_store(tmp_path / "mlflow.db", tmp_path)
    args = tiny_overrides(tmp_path, "experiment=optimize", "detector=[fast]", "runner.backend=serial",
                          "experiment.n_trials=200", "experiment.n_startup_trials=2",
                          f"experiment.storage=sqlite:///{tmp_path}/optuna.db",
                          f"experiment.tuned_root={tmp_path}/conf",
                          f"mlflow.tracking_uri={uri}")

    def trial_logged() -> bool:
        return len(_runs(uri)) >= 2

    study, err = _interrupt(tmp_path, args, signal.SIGINT, True, trial_logged)
    _one_resume_line(err, 130, study)
    runs = _runs(uri)
    assert list(runs[runs["tags.gtsweep.role"] == "study"]["status"]) == ["KILLED"]
