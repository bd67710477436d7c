"""The edges of a run: a setting that needs a missing package refused before anything exists, and a signal after
the final summary that leaves the exit code alone."""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from gtsweep.cli.overrides import compose_config
from gtsweep.core import interrupts
from gtsweep.core.errors import BadInput
from gtsweep.orchestration import dashboard
from sweep_helpers import cli_env, tiny_overrides


def test_the_dashboard_without_its_packages_is_refused_in_the_pre_flight(monkeypatch):
    monkeypatch.setattr(dashboard, "_dashboard_missing", lambda: "No module named 'aiohttp_cors'")
    with pytest.raises(BadInput, match=r"runner.dashboard=true needs Ray's dashboard: pip install 'ray\[default\]' "
                                       r"\(No module named 'aiohttp_cors'\)"):
        compose_config(["runner.dashboard=true", "detector=[orb]"])
    compose_config(["runner.dashboard=true", "runner.backend=serial", "detector=[orb]"])  # no Ray, no dashboard: fine


@pytest.mark.slow
@pytest.mark.skipif(dashboard._dashboard_missing() is None, reason="Ray's dashboard is installed here")
def test_the_dashboard_refusal_creates_no_directory_and_no_mlflow_run(tmp_path):
    result = subprocess.run([sys.executable, "-m", "gtsweep", "runner.dashboard=true", "detector=[orb]"],
                            cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no outputs/, no mlflow.db


def test_signals_after_the_run_finished_are_ignored():
    previous = {s: signal.getsignal(s) for s in interrupts.SIGNALS}
    try:
        for s in interrupts.SIGNALS:
            signal.signal(s, interrupts.on_signal)
        interrupts.finished()
        assert all(signal.getsignal(s) == signal.SIG_IGN for s in interrupts.SIGNALS)
        interrupts.on_signal(signal.SIGINT, None)  # a handler restored later does nothing either
        interrupts._exit_quietly(signal.SIGINT, None)
        assert interrupts._pending == []
    finally:
        interrupts._finished["done"] = False
        for s, handler in previous.items():
            signal.signal(s, handler)


#: The sweep, with a pause after its summary: a signal then certainly arrives after the result is out.
PAUSE_AFTER_SUMMARY = """
import sys, time
import gtsweep.cli.app as app

original = app._sweep

def _sweep(*args, **kwargs):
    original(*args, **kwargs)
    print("SUMMARY PRINTED", flush=True)
    time.sleep(2)

app._sweep = _sweep
from gtsweep.cli import main
main()
"""


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_after_the_summary_keeps_the_exit_code(tmp_path, sig):
    script = tmp_path / "pause.py"
    script.write_text(textwrap.dedent(PAUSE_AFTER_SUMMARY))
    args = tiny_overrides(tmp_path, "runner.backend=serial", "mlflow.enabled=false", "report.plots=false",
                          "detector=[orb]", "descriptor=[orb]", "transform=[incremental]")
    sweep = subprocess.Popen([sys.executable, str(script), *args], cwd=tmp_path, env=cli_env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in sweep.stdout:
        if line.startswith("SUMMARY PRINTED"):
            sweep.send_signal(sig)
            break
    out, err = sweep.communicate(timeout=120)
    assert sweep.returncode == 0 and "interrupted" not in err, err
