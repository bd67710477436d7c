"""Rounds of --size decide run only the cells the undecided findings read (gtsweep/reproduction/rounds.py):
the overrides that cut a preset's grid to them, and the rounds with the preset runs replaced by a fake that writes
cell files (no gtsweep process)."""
import json
from pathlib import Path

import pandas as pd

from gtsweep.reproduction import rounds as preset_runs
from gtsweep.reproduction.findings import FINDINGS
from gtsweep.reproduction.rounds import preset_options, restriction, run_rounds
from gtsweep.reproduction.sequential import needed_cells


def _cell(detector, selector="nms", descriptor=None, transform="absolute"):
    return {"detector": detector, "selector": selector, "descriptor": descriptor, "transform": transform}


def test_a_pose_grid_is_cut_to_the_pairings_and_selectors_needed():
    available = [_cell(d, "anms" if d == "mser" else "nms", s) for d in ("censure", "sift", "mser", "xfeat")
                 for s in ("brief", "orb", "sift")]
    needed = [c for c in available if c["detector"] in ("censure", "mser") and c["descriptor"] != "sift"]
    overrides, extra = restriction(available, needed)
    assert overrides == ["pairings=[[censure,brief],[censure,orb],[mser,brief],[mser,orb]]"] and extra == 0
    assert restriction(available, available) == ([], 0)


def test_a_detection_grid_keeps_each_detectors_survey_selector_and_counts_what_it_cannot_leave_out():
    available = [_cell(d, s, transform=t) for d in ("sift", "mser", "fast") for s in ("nms", "anms")
                 for t in ("rotation", "noise")]
    table3 = [c for c in available if c["selector"] == ("anms" if c["detector"] == "mser" else "nms")]
    assert restriction(available, table3) == (["++selector_for={fast:nms,mser:anms,sift:nms}"], 0)
    # a detection grid has no pairings: without the preset's option names a detector needed for no cell stays
    no_fast = [c for c in available if c["detector"] != "fast" and c["transform"] == "rotation"]
    assert restriction(available, no_fast) == (["transform=[rotation]"], 2)
    # with them its detectors are cut, named as the preset names them, in the preset's order
    options = {"fast": "tuned/fast", "mser": "tuned/mser", "sift": "tuned/sift"}
    assert restriction(available, no_fast, options) == (["detector=[tuned/mser,tuned/sift]", "transform=[rotation]"],
                                                        0)
    assert restriction(available, table3, options) == (["++selector_for={fast:nms,mser:anms,sift:nms}"], 0)


def test_a_presets_options_are_its_defaults_lists():
    options = preset_options("table3_detectors")
    assert len(options) == 13 and options["sift"] == "tuned/sift" and options["mser"] == "tuned/mser"
    assert preset_options("table3_detectors", "transform") == {t: t for t in ("rotation", "translation", "noise",
                                                                              "gamma")}
    assert preset_options("not_a_preset") == {}


def test_the_table_3_findings_need_every_detector_with_its_survey_selector(tmp_path):
    cells = tmp_path / "cells"
    cells.mkdir()
    for d in ("sift", "mser", "harris"):
        for s in ("nms", "anms"):
            (cells / f"{d}_{s}.json").write_text(json.dumps({"key": f"{d}_{s}", "methods": _cell(d, s, None,
                                                                                               "rotation"),
                                                            "status": "ok"}))
    needed = needed_cells([FINDINGS[2]], {"table3_detectors": {"output": tmp_path}})["table3_detectors"]
    assert sorted((c["detector"], c["selector"]) for c in needed) == [("harris", "nms"), ("mser", "anms"),
                                                                     ("sift", "nms")]


def test_rounds_cut_each_preset_to_the_cells_still_needed_and_carry_the_others(tmp_path, monkeypatch):
    calls = []

    def fake_run(preset, overrides, work, uri, cache=None):
        out = work / preset
        calls.append((preset, list(overrides), sorted(p.name for p in (out / "cells").glob("*.json"))
                      if out.exists() else []))
        (out / "cells").mkdir(parents=True, exist_ok=True)
        pairs = [("censure", "brief"), ("censure", "orb"), ("sift", "sift")]
        cut = next((o for o in overrides if o.startswith("pairings=")), None)
        for d, s in pairs:
            if cut is None or f"[{d},{s}]" in cut:
                methods = _cell(d, "nms", s, "incremental")
                (out / "cells" / f"{d}__{s}.json").write_text(json.dumps({"key": f"{d}__{s}", "methods": methods}))
        return {"preset": preset, "output": out, "wall_s": 1.0, "peak_mb": 1.0, "cache_hit_rate": 0.0,
                "mlflow_runs": 1, "cells": 3 if cut is None else cut.count("],[") + 1}

    monkeypatch.setattr(preset_runs, "run_preset", fake_run)

    def needed(k, latest):
        return {"table4_incremental": [_cell("censure", "nms", "brief", "incremental")]} if k == 0 else {}

    runs = run_rounds(["table4_incremental"], needed, tmp_path, rounds=((1, 6, 6), (2, 12, 12), (4, 25, 25)),
                      log=lambda m: None)
    assert [(r["round"], r["cells"], r["cells_needed"], r["extra_cells"]) for r in runs] == [(1, 3, 3, 0),
                                                                                             (2, 1, 1, 0)]
    (_, first, before_first), (_, second, before_second) = calls
    assert not any(o.startswith("pairings=") for o in first) and before_first == []
    assert second[-1] == "pairings=[[censure,brief]]" and "dataset.n_incremental=12" in second
    # round 2 started from round 1's cells: the two it does not run stay, at round 1's count
    assert before_second == ["censure__brief.json", "censure__orb.json", "sift__sift.json"]
    assert preset_runs.spent(runs, "table4_incremental", 1) == 1.0
    # no per-view timings in these fake cells: no task work to scale, the first round's other costs as measured
    assert preset_runs.full_protocol_estimate(runs) == 1.0


def test_the_cells_of_every_finding_of_a_preset_together(tmp_path):
    """Table 5's two findings: the collapse reads unoriented detectors with ORB/BRIEF/LATCH/SIFT, the other every
    detector of the pools: XFeat (in neither pool) is left out of the round."""
    rows = [dict(detector=d, selector="nms", descriptor=s, transform="absolute") for d in ("censure", "sift", "xfeat")
            for s in ("brief", "xfeat")]
    cells = tmp_path / "cells"
    cells.mkdir()
    for k, methods in enumerate(rows):
        (cells / f"c{k}.json").write_text(json.dumps({"key": f"c{k}", "methods": methods, "status": "ok"}))
    latest = {"table5_absolute": {"output": tmp_path}}
    collapse = needed_cells([FINDINGS[6]], latest)["table5_absolute"]
    assert [(c["detector"], c["descriptor"]) for c in collapse] == [("censure", "brief")]
    both = pd.DataFrame(needed_cells([FINDINGS[6], FINDINGS[7]], latest)["table5_absolute"])
    assert set(both["detector"]) == {"censure", "sift"} and len(both) == 4


def test_a_preset_runs_in_its_work_folder_with_absolute_paths(tmp_path, monkeypatch):
    """A relative work folder (``collect --work .gtsweep_cache/...``): the sweep runs in that folder, so its output,
    cache and store are given as absolute paths (relative ones would land under the folder a second time)."""
    import subprocess

    seen = {}

    class Stopped(Exception):
        pass

    def popen(args, cwd, **kwargs):
        seen.update(args=args, cwd=cwd)
        raise Stopped

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(subprocess, "Popen", popen)
    try:
        preset_runs.run_preset("table3_detectors", [], Path("work/scratch"), "sqlite:///x.db", Path("work/cache"))
    except Stopped:
        pass
    given = dict(a.split("=", 1) for a in seen["args"] if a.startswith(("hydra.run.dir=", "cache.dir=")))
    assert seen["cwd"] == tmp_path / "work" / "scratch"
    assert given == {"hydra.run.dir": str(tmp_path / "work" / "scratch" / "table3_detectors"),
                     "cache.dir": str(tmp_path / "work" / "cache")}
