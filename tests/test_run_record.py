"""An interrupted reproduction resumes (gtsweep/reproduction/run_record.py): finished preset runs are kept, an
interrupted one runs again in its own output (the sweep keeps its finished cells), its wall time includes the cut
attempts, and a record of another plan is refused."""
import json
import os
import signal
import subprocess
import sys

import pytest

from gtsweep.core.errors import BadInput
from gtsweep.core.interrupts import Interrupted
from gtsweep.reproduction import rounds as preset_runs
from gtsweep.reproduction.run_record import RunRecord

PLAN = {"size": "decide", "presets": ["table4_incremental"], "alpha": 0.05, "tuned": "abc"}


class Clock:
    def __init__(self, now=1000.0):
        self.now = now

    def __call__(self):
        return self.now


def measured(seconds):
    return {"preset": "p", "output": "out", "wall_s": seconds, "peak_mb": 1.0, "cells": 1}


def interrupted(clock, seconds):
    def start():
        clock.now += seconds
        raise Interrupted(signal.SIGINT)
    return start


def test_a_finished_run_is_kept_and_an_interrupted_one_counts_its_cut_attempts(tmp_path):
    clock = Clock()
    record = RunRecord(tmp_path / "progress.json", PLAN, clock)
    assert record.run("round1/a", tmp_path / "a", lambda: measured(5.0))["attempts"] == 1
    with pytest.raises(Interrupted):
        record.run("round1/b", tmp_path / "b", interrupted(clock, 30.0))
    # a new process: the same plan resumes; a finished run comes back as it was
    resumed = RunRecord.resume(tmp_path / "progress.json", PLAN, clock)
    assert len(resumed) == 1 and resumed.get("round1/a")["wall_s"] == 5.0 and resumed.get("round1/b") is None
    assert resumed.interrupted_seconds() == 30.0
    with pytest.raises(Interrupted):  # cut a second time, after 12 s
        resumed.run("round1/b", tmp_path / "b", interrupted(clock, 12.0))
    again = RunRecord.resume(tmp_path / "progress.json", PLAN, clock)
    done = again.run("round1/b", tmp_path / "b", lambda: measured(40.0))
    assert done["wall_s"] == 40.0 + 30.0 + 12.0 and done["attempts"] == 3
    assert again.interrupted_seconds() == 0.0
    saved = json.loads((tmp_path / "progress.json").read_text())
    assert sorted(saved["finished"]) == ["round1/a", "round1/b"] and saved["attempts"] == {}


def test_an_attempt_killed_outright_ends_at_the_last_write_in_its_output(tmp_path):
    clock = Clock(1000.0)
    record = RunRecord(tmp_path / "progress.json", PLAN, clock)
    record.attempts["round1/b"] = {"output": str(tmp_path / "b"), "started": 1000.0, "ended": None,
                                   "earlier_s": 0.0, "tries": 1}  # as a kill -9 leaves it
    (tmp_path / "b" / "cells").mkdir(parents=True)
    (tmp_path / "b" / "cells" / "x.json").write_text("{}")
    os.utime(tmp_path / "b" / "cells" / "x.json", (1007.0, 1007.0))
    (tmp_path / "b.log").write_text("log")
    os.utime(tmp_path / "b.log", (1019.0, 1019.0))
    assert record.interrupted_seconds() == 19.0
    assert record.run("round1/b", tmp_path / "b", lambda: measured(1.0))["wall_s"] == 20.0


def test_a_running_attempt_saves_a_heartbeat_and_one_killed_outright_ends_at_it(tmp_path):
    """A run killed with its session (no signal, nothing written for minutes: Ray's workers write nothing until
    a cell is done) still counts the time it ran, up to its last heartbeat."""
    import time
    clock = Clock(1000.0)
    record = RunRecord(tmp_path / "progress.json", PLAN, clock, heartbeat_s=0.01)
    beats = []

    def start():
        for now in (1030.0, 1060.0, 1090.0):
            clock.now = now
            waited = time.monotonic()
            while time.monotonic() - waited < 10:  # until the heartbeat has saved this time
                time.sleep(0.005)
                saved = json.loads((tmp_path / "progress.json").read_text())["attempts"]["round1/b"]
                if saved["alive"] == now:
                    beats.append(now)
                    break
        return measured(90.0)

    assert record.run("round1/b", tmp_path / "b", start)["wall_s"] == 90.0
    assert beats == [1030.0, 1060.0, 1090.0]
    # as a killed process leaves it: started, alive 75 s later, never ended, nothing written in its output
    killed = RunRecord(tmp_path / "progress2.json", PLAN, clock)
    killed.attempts["round1/c"] = {"output": str(tmp_path / "c"), "started": 1000.0, "ended": None,
                                   "alive": 1075.0, "earlier_s": 0.0, "tries": 1}
    assert killed.interrupted_seconds() == 75.0


def test_a_record_of_another_plan_or_an_unreadable_one_is_refused(tmp_path):
    RunRecord(tmp_path / "progress.json", PLAN).save()
    with pytest.raises(BadInput, match=r"another plan: alpha 0.05 \(now 0.1\), tuned 'abc' \(now 'def'\); run it "
                                       r"as before to resume it, or pass --fresh"):
        RunRecord.resume(tmp_path / "progress.json", {**PLAN, "alpha": 0.1, "tuned": "def"})
    (tmp_path / "progress.json").write_text("{not json")
    with pytest.raises(BadInput, match="cannot read the unfinished reproduction's record"):
        RunRecord.resume(tmp_path / "progress.json", PLAN)
    assert len(RunRecord.resume(tmp_path / "none.json", PLAN)) == 0


def _cell(detector, descriptor):
    return {"detector": detector, "selector": "nms", "descriptor": descriptor, "transform": "incremental"}


def test_rounds_resume_after_an_interrupt_without_running_a_finished_run_again(tmp_path, monkeypatch):
    """Round 2 is cut after writing one new cell; the resumed rounds run only round 2, and its new cell is not
    replaced by round 1's copy."""
    calls, cut = [], {"once": True}

    def fake_run(preset, overrides, work, uri, cache=None):
        out = work / preset
        calls.append(work.name)
        (out / "cells").mkdir(parents=True, exist_ok=True)
        for d, s in (("censure", "brief"), ("sift", "sift")):
            path = out / "cells" / f"{d}__{s}.json"
            # round 1 writes both; round 2's first attempt re-evaluates censure, then is cut; a resumed sweep
            # keeps the cells it finds finished
            if work.name == "round1" or (cut["once"] and d == "censure") or not path.exists():
                path.write_text(json.dumps({"key": f"{d}__{s}", "methods": _cell(d, s), "round": work.name}))
            if work.name == "round2" and cut["once"]:
                cut["once"] = False
                raise Interrupted(signal.SIGTERM)
        return {"preset": preset, "output": out, "wall_s": 2.0, "peak_mb": 1.0, "cache_hit_rate": 0.0,
                "mlflow_runs": 1, "cells": 2}

    monkeypatch.setattr(preset_runs, "run_preset", fake_run)
    judged = []

    def needed(k, latest):
        judged.append(k)
        return {"table4_incremental": None} if k == 0 else {}

    rounds = ((1, 6, 6), (2, 12, 12))
    record = RunRecord(tmp_path / "progress.json", PLAN)
    with pytest.raises(Interrupted):
        preset_runs.run_rounds(["table4_incremental"], needed, tmp_path, rounds=rounds, log=lambda m: None,
                               record=record)
    assert calls == ["round1", "round2"] and judged == [0]
    resumed = RunRecord.resume(tmp_path / "progress.json", PLAN)
    runs = preset_runs.run_rounds(["table4_incremental"], needed, tmp_path, rounds=rounds, log=lambda m: None,
                                  record=resumed)
    assert calls == ["round1", "round2", "round2"] and judged == [0, 0, 1]  # round 1 judged again, not run again
    assert [(r["round"], r["attempts"]) for r in runs] == [(1, 1), (2, 2)]
    cells = tmp_path / "round2" / "table4_incremental" / "cells"
    assert json.loads((cells / "censure__brief.json").read_text())["round"] == "round2"


def test_stopping_a_preset_run_lets_it_finish_its_clean_up_or_kills_it_after_the_grace(tmp_path):
    marker = tmp_path / "stopped"
    trap = ("import signal, sys, time, pathlib\n"
            "def handler(s, f):\n"
            f"    pathlib.Path({str(marker)!r}).write_text('clean')\n"
            "    sys.exit(130)\n"
            "signal.signal(signal.SIGINT, handler)\n"
            "print('ready', flush=True)\n"
            "time.sleep(60)\n")
    process = subprocess.Popen([sys.executable, "-c", trap], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "ready"
    preset_runs.stop(process)
    assert process.returncode == 130 and marker.read_text() == "clean"
    deaf = subprocess.Popen([sys.executable, "-c", "import signal, time; signal.signal(signal.SIGINT, "
                             "signal.SIG_IGN); print('ready', flush=True); time.sleep(60)"],
                            stdout=subprocess.PIPE, text=True)
    assert deaf.stdout.readline().strip() == "ready"
    preset_runs.stop(deaf, grace=0.5)
    assert deaf.returncode == -signal.SIGKILL


def test_the_command_resumes_its_own_plan_refuses_another_and_starts_fresh_when_asked(tmp_path, monkeypatch,
                                                                                    capsys):
    from gtsweep.reproduction import command as reproduce

    ran, stop_at = [], {"preset": "table5_absolute"}

    def fake_run(preset, overrides, work, uri, cache=None):
        ran.append(preset)
        if preset == stop_at["preset"]:
            stop_at["preset"] = None
            raise Interrupted(signal.SIGINT)
        return {"preset": preset, "output": work / preset, "wall_s": 1.0, "peak_mb": 1.0, "cache_hit_rate": 0.0,
                "mlflow_runs": 1, "cells": 1}

    monkeypatch.setattr(preset_runs, "run_preset", fake_run)
    monkeypatch.setattr(reproduce, "write_document", lambda *a, **k: tmp_path / "REPRODUCTION.md")
    monkeypatch.setattr(reproduce.signal, "signal", lambda *a: None)  # the test process keeps pytest's handlers
    args = ["--size", "tiny", "--presets", "table4_incremental", "table5_absolute", "--work", str(tmp_path / "w"),
            "--docs", str(tmp_path)]
    assert reproduce.main(args) == 130
    assert "interrupted by SIGINT; 1 preset run(s) finished and kept in" in capsys.readouterr().err
    with pytest.raises(SystemExit, match=r"^gtsweep.reproduce: error: .* another plan: alpha 0.05 \(now 0.1\)"):
        reproduce.main([*args, "--alpha", "0.1"])
    assert reproduce.main(args) == 0
    assert ran == ["table4_incremental", "table5_absolute", "table5_absolute"]
    assert "resuming the reproduction in" in capsys.readouterr().out
    assert reproduce.main(args) == 0  # a finished reproduction: the same command runs it again from scratch
    assert reproduce.main([*args, "--fresh"]) == 0
    assert ran[3:] == ["table4_incremental", "table5_absolute"] * 2
