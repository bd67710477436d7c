"""Issue 28, items 3 and 6: two identical studies at once, non-finite poses, counts no memory holds, a tracking URI
in a folder that does not exist, Ctrl-C in the first instants, a double Ctrl-C with Ray: each one line, no
traceback, nothing left behind."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gtsweep.core.errors import BadInput
from sweep_helpers import cli_env, session_ends, session_processes, tiny_overrides


def _start(args: list[str], cwd: Path, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "gtsweep", *args], cwd=cwd, env=cli_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


# ------------------------------------------------------------------------------- item 3: identical studies
def test_a_second_owner_of_a_study_is_refused_and_a_dead_owner_frees_it(tmp_path):
    from gtsweep.experiments.optimize.optuna_study import study_lock

    storage = f"sqlite:///{tmp_path}/optuna.db"
    code = ("import sys, time; from gtsweep.experiments.optimize.optuna_study import own_study; "
            "own_study(sys.argv[1], 'same'); "
            "print('owned', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, storage], env=cli_env(), stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "owned"
        second = subprocess.run([sys.executable, "-c", code.replace("time.sleep(60)", "pass"), storage],
                                env=cli_env(), capture_output=True, text=True, timeout=60)
        assert second.returncode == 1 and "is being optimised by another run right now" in second.stderr
    finally:
        holder.kill()  # kill -9: the lock goes with the process
        holder.wait()
    freed = subprocess.run([sys.executable, "-c", code.replace("time.sleep(60)", "pass"), storage],
                           env=cli_env(), capture_output=True, text=True, timeout=60)
    assert freed.returncode == 0 and "owned" in freed.stdout, freed.stderr
    assert study_lock(storage, "same").parent == tmp_path


@pytest.mark.slow
def test_two_identical_studies_at_once_one_runs_the_other_stops_in_one_line(tmp_path):
    args = tiny_overrides(tmp_path, "experiment=optimize", "detector=[fast]", "runner.backend=serial",
                          "experiment.n_startup_trials=2", "experiment.n_trials=500",
                          "experiment.transforms.rotation.strengths=[45]", "experiment.transforms.noise.strengths=[20]",
                          f"experiment.storage=sqlite:///{tmp_path}/optuna.db", f"experiment.tuned_root={tmp_path}/t",
                          "mlflow.enabled=false")
    first = _start(args, tmp_path)  # a long study: still running when the second one starts
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".optuna-study-*.lock")) and time.monotonic() < deadline:
        time.sleep(0.1)
    second = _start(args, tmp_path)
    out2, err2 = second.communicate(timeout=300)
    time.sleep(3)
    assert first.poll() is None, first.communicate()[1][-2000:]  # the first goes on, untouched
    first.send_signal(signal.SIGINT)
    out1, err1 = first.communicate(timeout=120)
    assert first.returncode == 130 and "UpdateFinishedTrialError" not in err1, err1[-2000:]
    assert second.returncode == 2 and len(err2.strip().splitlines()) == 1, err2
    assert "is being optimised by another run right now" in err2


# ---------------------------------------------------------------------------------------- item 6: smaller
def test_non_finite_poses_are_bad_items_with_file_and_line(tmp_path):
    import dataset_fixtures as fx
    from gtsweep.datasets import load_dataset

    file = fx.csv_poses(tmp_path)
    lines = file.read_text().splitlines()
    for row, column, value in ((2, 1, "nan"), (3, 3, "inf"), (4, 2, "-inf")):
        cells = lines[row].split(",")
        cells[column] = value
        lines[row] = ",".join(cells)
    file.write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInput, match=f"{file}:3: x, y, theta, scale must be finite numbers"):
        load_dataset({"loader": "csv", "root": str(file)})
    dataset = load_dataset({"loader": "csv", "root": str(file), "skip_bad": True})
    assert [item.split(":")[1] for item in dataset.skipped] == ["3", "4", "5"]


def test_a_pose_matrix_with_nan_is_a_bad_item():
    from gtsweep.datasets.posefiles import Problems, pose_from_values

    problems = Problems(skip_bad=True)
    assert pose_from_values([1, 0, float("nan"), 0, 1, 0, 0, 0, 1], "poses.txt:7", problems) is None
    assert problems.skipped == ["poses.txt:7: pose values must be finite numbers (found nan or inf)"]


def test_counts_no_memory_can_hold_are_one_line_before_any_allocation(tmp_path):
    from gtsweep.datasets import load_dataset

    start = time.perf_counter()
    with pytest.raises(BadInput, match=r"dataset.n_incremental=1000000000000 asks for [\d,]+ GiB of views"):
        load_dataset({"loader": "synthetic", "n_incremental": 1_000_000_000_000, "cache_dir": str(tmp_path)})
    assert time.perf_counter() - start < 5


def test_a_tracking_uri_in_a_missing_folder_is_one_line_and_creates_nothing(tmp_path):
    from gtsweep.tracking.store import open_store

    missing = tmp_path / "nonexistent" / "dir"
    with pytest.raises(BadInput, match=f"the folder {missing} does not exist"):
        open_store({"tracking_uri": f"sqlite:///{missing}/x.db"}, "gtsweep")
    assert not (tmp_path / "nonexistent").exists()


@pytest.mark.parametrize("delay", [0.3, 0.6, 1.0])
def test_ctrl_c_in_the_first_instants_is_one_line(tmp_path, delay):
    run = _start(["runner.backend=serial", "mlflow.enabled=false"], tmp_path)
    time.sleep(delay)
    run.send_signal(signal.SIGINT)
    out, err = run.communicate(timeout=120)
    assert run.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert len(err.strip().splitlines()) == 1 and "interrupted by SIGINT" in err, err


#: Ray's agents starting, seen in the command's session: the raylet has just started them (they rename themselves
#: ``ray::...`` once their imports are done). The double Ctrl-C while the sweep's tasks run, and its resume:
#: test_interrupts.py::test_an_interrupted_sweep_is_killed_cleanly_and_resumes[ray-SIGINT-group].
AGENTS_STARTING = (b"dashboard/agent.py", b"runtime_env/agent/main.py", b"ray::DashboardAgent")


@pytest.mark.slow
def test_a_double_ctrl_c_leaves_no_ray_process_behind(tmp_path):
    """As a terminal does: SIGINT to the whole process group, twice, while Ray's agents start: one line, exit 130,
    no process of the command left (an agent the raylet started just before it died is found and ended)."""
    run = _start([*tiny_overrides(tmp_path), "runner.backend=ray", "mlflow.enabled=false"], tmp_path,
                 start_new_session=True)
    deadline = time.monotonic() + 180
    while not any(mark in command for command in session_processes(run.pid) for mark in AGENTS_STARTING):
        assert run.poll() is None and time.monotonic() < deadline, run.communicate()[1][-2000:]
        time.sleep(0.02)
    for _ in range(2):
        try:
            os.killpg(run.pid, signal.SIGINT)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    out, err = run.communicate(timeout=120)
    assert session_ends(run.pid) == []
    lines = [line for line in err.strip().splitlines() if not line.startswith("gtsweep: Ray cluster at ")]  # info
    assert run.returncode == 130, err[-2000:]
    assert "Traceback" not in err and len(lines) == 1 and "interrupted by SIGINT" in err, err


def test_leftover_ray_processes_are_this_commands_descendants_or_name_its_session(tmp_path):
    """A fake /proc: Ray's processes that descend from this process, or that name the Ray session it started (in
    their command line or their open files) and began after it, are ended, whatever their process group; another
    session's (a cluster started with ``ray start``, another command's), a non-Ray child, a process older than
    this one and this process itself are not."""
    from gtsweep.orchestration.cluster import leftover_ray_processes

    me, group, ray_dir = os.getpid(), os.getpgrp(), "/venv/site-packages/ray"
    mine, theirs = f"session_2026-11-24_18-39-06_293471_{me}", f"session_2026-11-24_18-39-06_293471_{me}1"

    def process(pid, ppid, pgrp, command, start=500, files=()):
        (tmp_path / str(pid) / "fd").mkdir(parents=True)
        rest = " ".join(["0"] * 16) + f" {start} 0 0"  # stat fields 6..21, then 22 (start time) and two more
        (tmp_path / str(pid) / "stat").write_text(f"{pid} (x y) S {ppid} {pgrp} {rest}")
        (tmp_path / str(pid) / "cmdline").write_bytes(command.encode())
        for fd, target in enumerate(files):
            (tmp_path / str(pid) / "fd" / str(fd)).symlink_to(target)
    agent = f"/usr/bin/python\0-u\0{ray_dir}/dashboard/agent.py\0--session-dir=/tmp/ray/"
    process(me, 1, group, "python\0-m\0gtsweep", start=400)
    process(900001, me, group, f"{ray_dir}/core/src/ray/raylet/raylet\0--x")    # child raylet: ours
    process(900002, 900001, group + 5, "ray::DashboardAgent")                     # grandchild, own group: ours
    process(900003, 1, group + 6, "ray::RuntimeEnvAgent", files=[f"/tmp/ray/{mine}/logs/runtime_env_agent.log"])
    process(900004, 1, group + 7, f"{agent}{mine}\0--node-id=1")                # orphan still starting: ours
    process(900005, 1, group, "ray::IDLE", files=[f"/tmp/ray/{theirs}/logs/worker-1.out"])  # another session
    process(900006, 1, group + 8, f"{agent}{theirs}")                            # a `ray start` cluster's agent
    process(900007, 1, group, f"{agent}{mine}", start=300)                       # older than this process
    process(900008, me, group, "sleep\0100")                                     # not Ray
    process(900009, 4242, group, "ray::IDLE")                                    # someone else's child
    process(900010, me, group, "/work/raylet-study/.venv/bin/python\0-m\0x")     # "raylet" in a path only
    process(900011, 1, group, f"tail\0-f\0/tmp/ray/{mine}/logs/raylet.out")      # names the session, not Ray
    assert leftover_ray_processes(tmp_path, ray_dir) == [900001, 900002, 900003, 900004]
    # the watchdog of a dead sweep (the owner, gone from /proc): the processes that name the sweep's session
    assert leftover_ray_processes(tmp_path, ray_dir, owner=int(f"{me}1")) == [900005, 900006]
