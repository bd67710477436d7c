"""The watchdog of a Ray sweep (gtsweep.tracking.watchdog): silent when the sweep ends by itself (any Python way),
one line, a FAILED parent run and its cause when the sweep process vanishes (as when Ray ends it for a dead
raylet). A real process stands in for the sweep; the raylet case itself is in test_failures.py (slow)."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

from sweep_helpers import cli_env

RESUME = "python -m gtsweep x=1 resume=true"


def _sweep_process(tmp_path: Path, body: str) -> subprocess.CompletedProcess:
    """A process that runs ``body`` under the watchdog with ``tmp_path/out`` as its output directory."""
    script = textwrap.dedent(f"""
        import os, sys
        from pathlib import Path
        from gtsweep.tracking.watchdog import watched
        with watched(Path({str(tmp_path / 'out')!r}), {RESUME!r}):
        """) + textwrap.indent(textwrap.dedent(body), "    ")
    return subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=cli_env(), capture_output=True,
                          text=True, timeout=120)


def _cells(tmp_path: Path, n: int) -> None:
    (tmp_path / "out" / "cells").mkdir(parents=True)
    for i in range(n):
        (tmp_path / "out" / "cells" / f"c{i}.json").write_text("{}")


def test_a_sweep_that_ends_by_itself_leaves_the_watchdog_silent(tmp_path):
    _cells(tmp_path, 1)
    for body, code in (("pass", 0), ("sys.exit(1)", 1), ("raise SystemExit(130)", 130)):
        result = _sweep_process(tmp_path, body)
        assert (result.returncode, result.stderr) == (code, ""), body


def test_a_vanished_sweep_gets_one_line_with_the_resume_command(tmp_path):
    _cells(tmp_path, 2)
    result = _sweep_process(tmp_path, "os._exit(1)  # as Ray's compiled code ends the driver")
    assert result.returncode == 1
    assert result.stderr.splitlines() == [f"gtsweep: error: the sweep process died; 2 finished cell(s) kept in "
                                          f"{tmp_path / 'out'}; to continue: {RESUME}"]


def test_a_vanished_sweep_has_its_parent_run_marked_failed(tmp_path, existing_store):
    from mlflow.tracking import MlflowClient

    _cells(tmp_path, 0)
    uri = existing_store(tmp_path / "mlflow.db", tmp_path)  # migrated once per session
    client = MlflowClient(uri)
    run = client.create_run(client.create_experiment("x"))
    (tmp_path / "out" / "mlflow.json").write_text(json.dumps({"parent_run_id": run.info.run_id,
                                                              "tracking_uri": uri}))
    result = _sweep_process(tmp_path, "os._exit(1)")
    assert "the sweep process died" in result.stderr
    after = client.get_run(run.info.run_id)
    assert after.info.status == "FAILED" and after.data.tags["gtsweep.reason"] == "the sweep process died"


def _ends(first: str) -> str | None:
    """What :func:`wait_for_end` says when two stand-in processes, "sweep" (its pipe's writer) and "raylet", end
    in the order ``first`` then the other, 0.3 s apart."""
    import os
    import threading
    import time

    from gtsweep.tracking.watchdog import wait_for_end

    read, write = os.pipe()
    sweep, raylet = (subprocess.Popen(["sleep", "60"]) for _ in range(2))
    found = []

    def end(process):
        process.kill()
        process.wait()
        if process is sweep:  # a dead process's pipe closes
            os.close(write)

    def events():
        time.sleep(0.6)
        order = (sweep, raylet) if first == "sweep" else (raylet, sweep)
        end(order[0])
        time.sleep(0.3)
        end(order[1])

    thread = threading.Thread(target=events)
    thread.start()
    try:
        found.append(wait_for_end(sweep.pid, read, find_raylet=lambda pid: raylet.pid, parent=lambda: sweep.pid))
    finally:
        thread.join()
        os.close(read)
    return found[0]


def test_a_kill_of_the_sweep_is_not_taken_for_a_lost_raylet():
    """kill -9 of the driver ends its raylet too, just after: the cause is the sweep's death, not the raylet's."""
    from gtsweep.tracking.watchdog import PROCESS_DIED, RAYLET_LOST

    assert _ends("sweep") == PROCESS_DIED
    assert _ends("raylet") == RAYLET_LOST


def test_a_kill_9_of_a_ray_sweep_leaves_no_ray_agent_behind(tmp_path):
    """kill -9 of the driver while Ray's agents run: the watchdog says the sweep process died (not the raylet) and
    ends the session's Ray processes, which would otherwise linger for minutes."""
    import os
    import signal
    import time

    import pytest

    from sweep_helpers import session_ends, session_processes, tiny_overrides

    pytest.importorskip("ray")
    sweep = subprocess.Popen([sys.executable, "-m", "gtsweep", *tiny_overrides(tmp_path), "runner.backend=ray",
                              "mlflow.enabled=false"], cwd=tmp_path, env=cli_env(), text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 180
    while not any(b"ray::RuntimeEnvAgent" in c or b"ray::DashboardAgent" in c for c in session_processes(sweep.pid)):
        assert sweep.poll() is None and time.monotonic() < deadline, sweep.communicate()[1][-2000:]
        time.sleep(0.1)
    os.kill(sweep.pid, signal.SIGKILL)
    _, err = sweep.communicate(timeout=60)
    assert session_ends(sweep.pid, timeout=30) == []
    assert "the sweep process died" in err and "raylet" not in err, err[-2000:]


test_a_kill_9_of_a_ray_sweep_leaves_no_ray_agent_behind = \
    __import__("pytest").mark.slow(test_a_kill_9_of_a_ray_sweep_leaves_no_ray_agent_behind)
