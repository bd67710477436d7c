"""The metric schema is the one contract: aggregations by hand, undeclared columns rejected, and a metric added by
one schema entry reaching results.csv, MLflow and the report with no other edit."""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import mlflow
import numpy as np
import pandas as pd
import pytest

from gtsweep.core.errors import GtsweepError
from gtsweep.evaluation import schema
from gtsweep.experiments.kinds import run_sweep
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.results import summarize, summary_table
from gtsweep.report.output import write_report
from gtsweep.tracking.readback import summaries_from_mlflow
from gtsweep.tracking.sweep import SweepTracker
from sweep_helpers import compose_config, tiny_overrides

NAN = math.nan


@pytest.fixture
def toy(request):
    """Declare ``metric`` for one test only, in the rows of experiment ``kind`` (``request.param``: both)."""
    metric, kind = request.param
    rows = schema.ROWS[kind]
    schema.register(metric)
    schema.ROWS[kind] = dataclasses.replace(rows, metrics=(*rows.metrics, metric.name))
    yield metric
    schema.ROWS[kind] = rows
    schema.unregister(metric.name)


MATCH_SHARE = schema.Metric("match_share", "share", "matches per described test keypoint (a test's)",
                            per_view=lambda rows: rows["n_matches"] / rows["n_described_test"])


def test_mean_skips_undefined_views():
    rows = pd.DataFrame({"image": ["a", "b", "c", "d"], "ambiguity": [1.0, NAN, 2.0, np.inf]})
    metrics = summarize(rows, "detection")["metrics"]
    assert metrics["ambiguity"] == 1.5
    # bootstrap interval over the two finite views {1, 2}: every resample mean lies in [1, 2]
    assert 1.0 <= metrics["ambiguity_ci_low"] <= 1.5 <= metrics["ambiguity_ci_high"] <= 2.0
    assert math.isnan(summarize(rows.iloc[[1]], "detection")["metrics"]["ambiguity"])


@pytest.mark.parametrize("toy", [(schema.Metric("pooled", "share", "Σ correct / Σ matches (test)",
                                                aggregation="ratio", of=("n_correct", "n_matches")), "matching")],
                         indirect=True)
def test_ratio_pools_over_views(toy):
    # per view 1/2 and 9/10 (mean 0.7); pooled (1 + 9) / (2 + 10) = 10/12; the NaN view is left out
    rows = pd.DataFrame({"n_correct": [1, 9, NAN], "n_matches": [2, 10, 4], "strength": [0.0, 90.0, 90.0]})
    summary = summarize(rows, "matching")
    assert summary["metrics"]["pooled"] == pytest.approx(10 / 12)
    assert summary["by_strength"]["90.0"]["pooled"] == 0.9
    assert math.isnan(summarize(rows.assign(n_matches=0, n_correct=0), "matching")["metrics"]["pooled"])


@pytest.mark.parametrize("toy", [(schema.Metric("found", "share", "views with a hit (test)", aggregation="rate"),
                                 "detection")], indirect=True)
def test_rate_is_the_share_of_ones(toy):
    rows = pd.DataFrame({"found": [1.0, 0.0, 1.0, NAN]})
    assert summarize(rows, "detection")["metrics"]["found"] == pytest.approx(2 / 3)
    with pytest.raises(GtsweepError, match="'found' is a rate"):
        summarize(pd.DataFrame({"found": [0.5]}), "detection")


def test_precision_is_pooled_and_the_per_view_mean_is_kept_beside_it():
    # two views: 1 of 1 match correct (1.0) and 1 of 9 (0.111): per view (1 + 1/9) / 2 = 0.5556; pooled 2/10 = 0.2
    rows = pd.DataFrame({"n_correct": [1, 1], "n_matches": [1, 9], "precision": [1.0, 1 / 9]})
    metrics = summarize(rows, "matching")["metrics"]
    assert metrics["precision"] == pytest.approx(0.2) and metrics["precision_per_view"] == pytest.approx(5 / 9)
    # the pooled interval resamples views: {1/1, 1/9} gives 2/2, 2/18 and 2/10 -> [1/9, 1]
    assert metrics["precision_ci_low"] == pytest.approx(1 / 9) and metrics["precision_ci_high"] == pytest.approx(1.0)


def test_rates_get_wilson_intervals():
    rows = pd.DataFrame({"pose_success": [1.0] * 8 + [0.0] * 2})
    metrics = summarize(rows, "pose")["metrics"]
    assert metrics["pose_success"] == 0.8
    assert metrics["pose_success_ci_low"] == pytest.approx(0.490162, abs=1e-6)
    assert metrics["pose_success_ci_high"] == pytest.approx(0.943318, abs=1e-6)


def test_undeclared_column_is_one_clear_error():
    rows = pd.DataFrame({"image": ["a"], "repeatability": [0.5], "new_score": [1.0]})
    with pytest.raises(GtsweepError) as error:
        summarize(rows, "detection")
    message = str(error.value)
    assert "'new_score'" in message and schema.SCHEMA_FILE in message and "\n" not in message
    with pytest.raises(GtsweepError, match="'pose_success'.*detection experiment"):  # declared, other experiment
        summarize(rows.drop(columns="new_score").assign(pose_success=1.0), "detection")


def test_schema_declares_every_row_column():
    declared = {*schema.META, *schema.METRICS}
    assert set(schema.STEP_KEYS) <= set(schema.META)
    assert {"n_test_valid", "n_ref_valid", "n_repeated", "n_kp_ref", "n_described_ref", "n_described_test",
            "n_inliers", "t_detect", "t_describe", "t_match", "t_pose", "view", "texture"} <= declared
    assert {e: schema.headline(e) for e in schema.ROWS} == {
        "detection": "repeatability", "matching": "precision", "pose": "pose_success",
        "localization": "localization_success"}
    with pytest.raises(GtsweepError, match="already declared"):
        schema.register(schema.METRICS["precision"])


def test_summary_table_orders_columns_by_schema():
    summaries = [{"methods": {"detector": "sift", "descriptor": None}, "status": "ok",
                  "metrics": {"t_detect": 0.1, "old_metric": 2.0, "repeatability": 0.5}},
                 {"methods": {"detector": "orb", "descriptor": None}, "status": "na", "reason": "no mask"}]
    table = summary_table(summaries)
    assert list(table.columns) == ["detector", "descriptor", "status", "reason", "repeatability", "t_detect",
                                   "old_metric"]


def test_terminal_summary_shows_the_schema_headline():
    from gtsweep.experiments.pairs.summary import headline_tables

    methods = {"detector": "sift", "selector": "nms", "descriptor": None, "transform": "rotation"}
    outcome = SimpleNamespace(grid=SimpleNamespace(experiment={"name": "detection"}), summaries=[
        {"methods": methods, "status": "ok", "n_views": 18, "metrics": {"t_detect": 0.1, "repeatability": 0.5}}])
    ((title, pivot),) = headline_tables(outcome).items()
    assert title == "repeatability (18 views per cell; transforms: rotation)" and pivot.loc["sift", "nms"] == "0.50"
    assert schema.experiment_of({"methods": {"descriptor": "brief"}, "metrics": {"precision": 1.0}}) == "matching"


@pytest.mark.parametrize("toy", [(MATCH_SHARE, "matching")], indirect=True)
def test_one_schema_entry_reaches_results_mlflow_and_report(toy, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = compose_config(tiny_overrides(
        tmp_path, "experiment=matching", "detector=[censure]", "descriptor=[brief]", "selector=[nms]",
        "transform=[rotation]", "transform.rotation.strengths=[0,90]", "runner.backend=serial",
        f"mlflow.tracking_uri={uri}"))
    tracker = SweepTracker(cfg.mlflow, tmp_path / "run", "config: yes", "schema-test")
    outcome = run_sweep(cfg, tmp_path / "run", hooks=(tracker.log_cell,),
                        on_start=lambda grid, fp: tracker.start(grid, fp, library_versions()))
    tracker.end(outcome)

    views = pd.read_csv(next((tmp_path / "run" / "cells").glob("*.csv")))
    expected = (views["n_matches"] / views["n_described_test"]).mean()
    assert np.allclose(views["match_share"], views["n_matches"] / views["n_described_test"])  # per view too
    results = pd.read_csv(tmp_path / "run" / "results.csv")
    assert results.loc[0, "match_share"] == pytest.approx(expected) and 0 < expected <= 1
    assert list(results.columns).index("match_share") > list(results.columns).index("t_match")  # schema order

    client = mlflow.tracking.MlflowClient(uri)
    (child,) = client.search_runs([tracker.experiment_id], f"tags.mlflow.parentRunId = '{tracker.parent_id}'")
    assert child.data.metrics["match_share"] == pytest.approx(expected)
    history = client.get_metric_history(child.info.run_id, "curves/match_share_vs_strength")
    assert sorted(m.step for m in history) == [0, 90]

    for source, summaries in (("files", outcome.summaries), ("mlflow", summaries_from_mlflow(tracker.parent_id, uri))):
        _, files = write_report(summaries, tmp_path / source, plots=False)
        assert {"cells.md", "cells.csv", "cells.tex"} <= {f.name for f in files}
        cells = pd.read_csv(tmp_path / source / "cells.csv")
        assert cells.loc[0, "match_share (share)"] == float(f"{expected:.2f}"), source  # header: name (unit)
        assert "match_share (share)" in (tmp_path / source / "cells.md").read_text()
