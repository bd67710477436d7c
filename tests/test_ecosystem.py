"""Small pieces of being a good citizen: Ray's options, MLflow run names, tuned-config headers, the combined table
of a multirun, what a report's titles say they were computed on."""
from __future__ import annotations

import json
import logging

import pandas as pd
import pytest

from gtsweep.core.errors import BadInput
from gtsweep.experiments.kinds import combine_multirun as combine
from gtsweep.experiments.optimize.tuned_files import storage_label
from gtsweep.experiments.pairs.grid import Cell
from gtsweep.orchestration import dashboard, executor
from gtsweep.report.combine import mean_summary
from gtsweep.report.tables import sample_note
from gtsweep.tracking.tags import cell_names, overrides_name


def test_ray_options_hide_rays_warnings_and_the_dashboard_unless_asked(monkeypatch):
    options = executor.ray_options({})
    assert options["include_dashboard"] is False and options["logging_level"] == logging.ERROR
    assert executor.ray_options({"ray_log_level": "warning"})["logging_level"] == logging.WARNING
    monkeypatch.setattr(dashboard, "_dashboard_missing", lambda: "No module named 'aiohttp_cors'")
    with pytest.raises(BadInput, match=r"runner.dashboard=true needs Ray's dashboard: pip install 'ray\[default\]'"):
        executor.ray_options({"dashboard": True})
    monkeypatch.setattr(dashboard, "_dashboard_missing", lambda: None)
    assert executor.ray_options({"dashboard": True})["include_dashboard"] is True


def test_a_ray_without_its_dependency_check_falls_back_to_aiohttp(monkeypatch):
    import importlib.util
    import sys
    import types

    monkeypatch.setitem(sys.modules, "ray._private.utils", types.ModuleType("ray._private.utils"))
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    assert dashboard._dashboard_missing() == "No module named 'aiohttp'"
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: object())
    assert dashboard._dashboard_missing() is None


def test_run_names_fit_the_name_column():
    cells = [Cell("sift", "nms", "brief", "incremental"), Cell("orb", "anms", None, "rotation")]
    assert cell_names(cells, several_selectors=False) == {"sift__nms__brief__incremental": "sift·brief·inc",
                                                          "orb__anms__-__rotation": "orb·anms·rot"}
    assert cell_names(cells[:1], several_selectors=True) == {"sift__nms__brief__incremental": "sift·nms·brief·inc"}
    assert overrides_name(["seed=1", "hydra.run.dir=x"], "job") == "seed=1"
    assert overrides_name([], "job 3") == "job 3" and len(overrides_name(["a=" + "x" * 99], "")) == 40
    assert overrides_name(["sweeps=smoke", "dataset.n_incremental=2", "runner.num_cpus=2"], "x") == "sweeps=smoke"
    assert overrides_name(["runner.num_cpus=1,2"], "x") == "runner.num_cpus=1,2"  # only settings: then those


def test_tuned_headers_name_no_path_of_this_machine(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert storage_label(f"sqlite:///{tmp_path}/.gtsweep_cache/optuna.db") == "sqlite:///.gtsweep_cache/optuna.db"
    assert storage_label("sqlite:////elsewhere/deep/optuna.db") == "sqlite:///optuna.db"
    assert storage_label("postgresql://me:secret@db/optuna") == "postgresql://me:***@db/optuna"


def _summary(key, seed_value, status="ok", views=9):
    detector, selector, descriptor, transform = key.split("__")
    return {"key": key, "status": status, "experiment": "pose", "n_views": views, "hash": "h",
            "methods": {"detector": detector, "selector": selector, "descriptor": descriptor, "transform": transform},
            "metrics": {"pose_success": seed_value, "precision": 0.5}}


def _two_repeats(tmp_path, key="seed"):
    for job, (seed, value) in enumerate([(0, 0.4), (1, 0.6)]):
        cells = tmp_path / str(job) / "cells"
        cells.mkdir(parents=True)
        summary = _summary("orb__nms__orb__incremental", value)
        (cells / f"{summary['key']}.json").write_text(json.dumps(summary))
        (tmp_path / str(job) / "sweep.json").write_text(json.dumps(
            {"overrides": [f"{key}={seed}", "detector=[orb]", "descriptor=[orb]"]}))
    return combine(tmp_path, plots=False)


def test_a_multirun_combines_seeds_as_repeats(tmp_path):
    files = _two_repeats(tmp_path)
    rows = pd.read_csv(tmp_path / "combined" / "all_results.csv")
    assert sorted(rows["seed"]) == [0, 1] and set(rows["setting"]) == {"all"}
    summary = pd.read_csv(tmp_path / "combined" / "summary.csv").iloc[0]
    assert summary["n"] == 2 and summary["pose_success_mean"] == pytest.approx(0.5)
    assert summary["pose_success_std"] == pytest.approx(0.1414, abs=1e-4)
    summary = (tmp_path / "combined" / "summary.md").read_text()
    assert "0.500 ± 0.141 (2)" in summary and "pose_success (share): mean ± std (n) |" in summary
    table = tmp_path / "combined" / "report" / "table4_incremental.md"
    assert table in files and "| ORB | 0.50 (0.70) |" in table.read_text()  # the mean, beside the paper's
    assert summary.splitlines()[2] == ("Varied: seed: RANSAC's and the synthetic transforms' draws only, on the same "
                                       "images and pairs (fixed by dataset.seed; -m dataset.seed=0,1 varies them).")


def test_dataset_seeds_are_repeats_that_vary_the_data(tmp_path):
    _two_repeats(tmp_path, "dataset.seed")
    rows = pd.read_csv(tmp_path / "combined" / "all_results.csv")
    assert sorted(rows["seed"]) == [0, 1] and set(rows["setting"]) == {"all"}
    summary = (tmp_path / "combined" / "summary.md").read_text()
    assert "0.500 ± 0.141 (2)" in summary
    assert summary.splitlines()[2] == "Varied: dataset.seed: the images and pairs are drawn anew for each repeat."


def test_mean_summary_keeps_failed_repeats_out():
    ok, failed = _summary("a__nms__b__rotation", 0.8), _summary("a__nms__b__rotation", None, status="error")
    assert mean_summary([failed, ok])["metrics"]["pose_success"] == 0.8
    assert mean_summary([failed])["status"] == "error"


def test_titles_say_what_a_table_was_computed_on():
    part = pd.DataFrame({"status": ["ok", "ok", "na"], "n_views": [27, 27, None],
                         "transform": ["incremental", "incremental", "incremental"]})
    assert sample_note(part) == "27 pairs per cell; transforms: incremental"
    part = pd.DataFrame({"status": ["ok", "ok"], "n_views": [12, 36], "transform": ["rotation", "noise"]})
    assert sample_note(part) == "12–36 views per cell; transforms: noise, rotation"
