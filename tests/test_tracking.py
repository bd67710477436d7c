"""MLflow: one parent per sweep, one child per cell with every metric, NA tags, no duplicates on resume, and a real
``mlflow server`` on loopback answering for the sweep's runs."""
from __future__ import annotations

import json
import urllib.request

import mlflow
import pytest
from omegaconf import OmegaConf

from gtsweep.experiments.kinds import run_sweep
from gtsweep.orchestration.cache import library_versions
from gtsweep.tracking.store import flatten
from gtsweep.tracking.sweep import SweepTracker, step_scale
from sweep_helpers import compose_config, mlflow_server, tiny_overrides

GRID = ["detector=[akaze,censure]", "descriptor=[akaze,brief]", "selector=[nms]",
        "transform=[incremental,rotation]", "transform.rotation.strengths=[0,90]", "runner.backend=serial"]
POSE_METRICS = {"repeatability", "ambiguity", "few_keypoints", "n_detected", "n_kp_test", "n_matches", "n_correct",
                "precision", "pose_success", "position_error", "orientation_error", "n_inliers", "time/t_detect",
                "time/t_describe", "time/t_match", "time/t_pose", "ci/pose_success_ci_low", "ci/pose_success_ci_high"}


def tracked_sweep(tmp_path, uri):
    cfg = compose_config(tiny_overrides(tmp_path, *GRID, f"mlflow.tracking_uri={uri}"))
    tracker = SweepTracker(cfg.mlflow, tmp_path / "run", OmegaConf.to_yaml(cfg, resolve=True), "test-run")
    outcome = run_sweep(cfg, tmp_path / "run", hooks=(tracker.log_cell,),
                        on_start=lambda grid, fp: tracker.start(grid, fp, library_versions()))
    tracker.end(outcome)
    return outcome, tracker


@pytest.fixture(scope="module")
def sweep_store(tmp_path_factory, existing_store):
    tmp_path = tmp_path_factory.mktemp("tracked")
    uri = existing_store(tmp_path / "mlflow.db", tmp_path)  # migrated once per session: these tests read its runs
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(tmp_path)  # MLflow's default artifact root is ./mlruns
        outcome, tracker = tracked_sweep(tmp_path, uri)
    return tmp_path, uri, outcome, tracker


def test_one_parent_and_one_child_per_cell(sweep_store):
    tmp_path, uri, outcome, tracker = sweep_store
    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["gtsweep"])
    parents = runs[runs["tags.mlflow.parentRunId"].isna()]
    children = runs[runs["tags.mlflow.parentRunId"] == tracker.parent_id]
    assert len(parents) == 1 and len(children) == len(outcome.summaries) == 2 * 2 * 2
    ok = children[children["tags.gtsweep.status"] == "ok"]
    na = children[children["tags.gtsweep.status"] == "na"]
    assert len(na) == 2 and (na["tags.gtsweep.reason"].str.contains("AKAZE")).all()
    client = mlflow.tracking.MlflowClient(uri)
    for run_id in ok["run_id"]:  # every metric is logged (NaN where undefined, e.g. ambiguity with no repeats)
        assert POSE_METRICS <= set(client.get_run(run_id).data.metrics), run_id
    assert ok["metrics.pose_success"].notna().all() and ok["metrics.repeatability"].notna().all()
    parent = parents.iloc[0]
    assert parent["tags.gtsweep.dataset_fingerprint"] == outcome.dataset_fingerprint
    assert parent["tags.gtsweep.version.opencv"].startswith("5.")
    assert ok["params.detector.params.threshold"].notna().any()  # the cell's full method configuration


def test_runs_read_as_the_ui_expects(sweep_store):
    """Model-development experiment, standard source tags, short child names, cell compute times, artifacts."""
    tmp_path, uri, outcome, tracker = sweep_store
    client = mlflow.tracking.MlflowClient(uri)
    experiment = client.get_experiment_by_name("gtsweep")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    children = client.search_runs([experiment.experiment_id], f"tags.mlflow.parentRunId = '{tracker.parent_id}'")
    names = {r.data.tags["gtsweep.cell"]: r.info.run_name for r in children}
    assert names["akaze__nms__brief__incremental"] == "akaze·brief·inc · test-run"  # the cell, then its sweep
    assert names["censure__nms__akaze__rotation"] == "censure·akaze·rot · test-run"
    pairings = {r.data.tags["gtsweep.cell"]: r.data.tags["gtsweep.pairing"] for r in children}
    assert pairings["akaze__nms__brief__incremental"] == "akaze·brief·inc · test-run"  # the saved view's groups
    summaries = {s["key"]: s for s in outcome.summaries}
    for run in children:
        tags = run.data.tags
        assert tags["mlflow.source.name"] == "python -m gtsweep" and tags["mlflow.source.type"] == "LOCAL"
        assert tags["mlflow.user"] and tags["mlflow.source.git.commit"]
        summary = summaries[tags["gtsweep.cell"]]
        if summary["status"] != "ok":
            continue
        assert run.info.start_time == round(summary["started"] * 1000)  # the cell's compute time
        assert run.info.end_time == round(summary["ended"] * 1000) >= run.info.start_time
        artifacts = [a.path for a in client.list_artifacts(run.info.run_id)]
        curves = ["strength_curves.png"] if summary["methods"]["transform"] == "rotation" else []
        assert artifacts == [*curves, "views.csv"]  # the cell's per-view rows (and curves), one name in every run
    parent = client.get_run(tracker.parent_id)
    assert parent.data.tags["mlflow.source.name"] == "python -m gtsweep"
    assert "mlflow ui --backend-store-uri " + uri in tracker.ui_hint()
    assert tracker.ui_hint().endswith(f"http://127.0.0.1:5000/#/experiments/{experiment.experiment_id}/runs"
                                      "?workflowType=machine_learning&viewStateShareKey=gtsweep-pairings")


def test_strength_curves_are_metric_steps(sweep_store):
    tmp_path, uri, outcome, tracker = sweep_store
    client = mlflow.tracking.MlflowClient(uri)
    run = mlflow.search_runs(experiment_names=["gtsweep"],
                             filter_string="tags.`gtsweep.cell` = 'akaze__nms__brief__rotation'").iloc[0]
    history = client.get_metric_history(run.run_id, "curves/pose_success_vs_strength")
    assert sorted(m.step for m in history) == [0, 90]
    incremental = mlflow.search_runs(experiment_names=["gtsweep"],
                                     filter_string="tags.`gtsweep.cell` = 'akaze__nms__brief__incremental'").iloc[0]
    assert not [c for c in incremental.index if "_vs_" in c and incremental[c] == incremental[c]]  # no series


def test_resumed_sweep_adds_no_duplicate_runs(sweep_store, monkeypatch):
    tmp_path, uri, outcome, tracker = sweep_store
    monkeypatch.chdir(tmp_path)
    before = len(mlflow.search_runs(experiment_names=["gtsweep"]))
    again, _ = tracked_sweep(tmp_path, uri)
    assert again.resumed == len(again.summaries)
    assert len(mlflow.search_runs(experiment_names=["gtsweep"])) == before


def test_flatten_and_step_scale():
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": "x"}) == {"a.b": "1", "a.c": "[1, 2]", "d": "x"}
    assert step_scale([0, 15, 90]) == 1 and step_scale([0.1, 1.0]) == 100


@pytest.mark.slow
def test_mlflow_server_serves_the_sweep(sweep_store, tmp_path):
    _, uri, outcome, tracker = sweep_store
    with mlflow_server(uri, tmp_path, "--default-artifact-root", str(tmp_path / "artifacts"), timeout=120) as base:
        with urllib.request.urlopen(f"{base}/api/2.0/mlflow/experiments/get-by-name?experiment_name=gtsweep") as r:
            experiment_id = json.load(r)["experiment"]["experiment_id"]
        query = json.dumps({"experiment_ids": [experiment_id], "max_results": 1000,
                            "filter": f"tags.mlflow.parentRunId = '{tracker.parent_id}'"}).encode()
        request = urllib.request.Request(f"{base}/api/2.0/mlflow/runs/search", data=query,
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request) as r:
            runs = json.load(r)["runs"]
        assert len(runs) == len(outcome.summaries)
