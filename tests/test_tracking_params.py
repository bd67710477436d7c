"""What a sweep logs for MLflow's users: params that filter, unique run names, metric prefixes, the saved view and
the per-strength figure, each against hand-worked expectations on a sqlite store in tmp_path."""
from __future__ import annotations

import json

import mlflow
import pytest
from mlflow.tracking import MlflowClient

from gtsweep.experiments.pairs.grid import Cell
from gtsweep.tracking.figures import strength_figure
from gtsweep.tracking.metricnames import mlflow_name, summary_name
from gtsweep.tracking.params import batches, cell_params, config_params, method_tags, options_by_name, parsed_config
from gtsweep.tracking.tags import child_name, cluster_tags, pairing_label, unique_name
from gtsweep.tracking.views import VIEW_KEY, pairings_state, runs_url, save_pairings_view
from sweep_helpers import compose_config, tiny_overrides


@pytest.fixture
def client(tmp_path, monkeypatch, existing_store):
    """A new experiment in a migrated store (the session's copy: MLflow's migrations take seconds each time)."""
    monkeypatch.chdir(tmp_path)  # MLflow's default artifact root is ./mlruns
    client = MlflowClient(existing_store(tmp_path / "mlflow.db", tmp_path))
    return client, client.create_experiment("e")


def test_metric_names_group_intervals_timings_and_series_and_read_back():
    expected = {"pose_success": "pose_success", "n_matches": "n_matches", "ambiguity": "ambiguity",
                "pose_success_ci_low": "ci/pose_success_ci_low", "precision_ci_high": "ci/precision_ci_high",
                "t_detect": "time/t_detect", "t_query": "time/t_query",
                "precision_vs_strength": "curves/precision_vs_strength",
                "localization_success_vs_map_images": "curves/localization_success_vs_map_images",
                "made_up_vs_nothing": "made_up_vs_nothing"}  # not a step key: not a series
    assert {name: mlflow_name(name) for name in expected} == expected
    assert {name: summary_name(key) for name, key in expected.items()} == {name: name for name in expected}
    assert summary_name("precision_ci_low") == "precision_ci_low"  # runs logged before the prefixes


def test_options_by_name_keeps_the_option_as_written():
    loaded = [("", "gtsweep"), ("detector", "detector/tuned/sift"), ("detector", "detector/orb"),
              ("descriptor", "descriptor/brief"), ("dataset", "dataset/synthetic"), ("_global_", "sweeps/smoke"),
              ("hydra", "hydra/config")]
    assert options_by_name(loaded) == {"detector": {"sift": "tuned/sift", "orb": "orb"},
                                       "descriptor": {"brief": "brief"}, "dataset": {"synthetic": "synthetic"}}


def test_cell_params_name_every_dimension_of_the_cell():
    cell = Cell("sift", "nms", "brief", "incremental", matcher="bf_ratio", estimator="ransac")
    method_config = {"detector": {"params": {"sigma": 1.6}}, "selector": {"params": {"n": 1000}},
                     "descriptor": {"params": {}}, "transform": {"kind": "pairs"},
                     "experiment": {"name": "pose"}, "matcher": {"params": {"ratio": 0.7}}}
    config = {"seed": 1, "dataset": {"name": "synthetic", "n_incremental": 1, "textures": ["carpet", "wood"],
                                     "cache_dir": ".gtsweep_cache", "incremental": {"overlap_mean": 0.2}}}
    params = cell_params(cell, method_config, config, "fp123", {"detector": {"sift": "tuned/sift"}})
    assert params == {"detector": "tuned/sift", "selector": "nms", "descriptor": "brief", "transform": "incremental",
                      "matcher": "bf_ratio", "estimator": "ransac", "seed": "1", "dataset": "synthetic",
                      "dataset.name": "synthetic",
                      "dataset.n_incremental": "1", "dataset.textures": '["carpet", "wood"]',
                      "dataset.fingerprint": "fp123", "detector.params.sigma": "1.6", "selector.params.n": "1000",
                      "transform.kind": "pairs", "experiment.name": "pose", "matcher.params.ratio": "0.7"}
    assert method_tags(cell)["gtsweep.method.detector"] == "sift"
    detection = Cell("orb", "nms", None, "rotation")
    assert "descriptor" not in cell_params(detection, {}, {}, "fp", {}) and "seed" not in cell_params(
        detection, {}, {}, "fp", {})


def test_config_params_flatten_the_composed_config():
    config = parsed_config("seed: 0\ndataset: {name: synthetic, view_size: [640, 480]}\n"
                           "detector: {sift: {params: {sigma: 1.6}}}\n")
    assert config_params(config, "fp") == {"seed": "0", "dataset.name": "synthetic", "dataset.view_size": "[640, 480]",
                                           "detector.sift.params.sigma": "1.6", "dataset.fingerprint": "fp"}
    assert parsed_config("config: [") == {} and parsed_config("just text") == {}
    sizes = [len(b) for b in batches({f"k{i}": str(i) for i in range(230)})]
    assert sizes == [100, 100, 30]  # MLflow's 100 params per log_batch call


def test_unique_name_numbers_repeats_within_the_experiment(client):
    client, experiment = client
    assert unique_name(client, experiment, "seed=1") == "seed=1"
    client.create_run(experiment, run_name="seed=1")
    client.create_run(experiment, run_name="seed=10")  # a longer name with the same start is no repeat
    assert unique_name(client, experiment, "seed=1") == "seed=1 (2)"
    client.create_run(experiment, run_name="seed=1 (2)")
    assert unique_name(client, experiment, "seed=1") == "seed=1 (3)"
    client.create_run(experiment, run_name="it's 50%_off")
    assert unique_name(client, experiment, "it's 50%_off") == "it's 50%_off (2)"  # quote and wildcards
    assert child_name("sift·brief·inc", "seed=1 (2)") == "sift·brief·inc · seed=1 (2)"


def test_a_pairing_groups_one_sweeps_repeats_only():
    assert pairing_label("sift·brief·inc", "sweeps=smoke (2)") == "sift·brief·inc · sweeps=smoke (2)"
    # the jobs of a multirun: the multirun's run, then the job's setting without its seeds
    assert pairing_label("sift·brief·inc", "multirun seed=0,1", "seed=1") == "sift·brief·inc · multirun seed=0,1"
    assert pairing_label("sift·brief·inc", "m", "matcher=[flann] dataset.seed=2 seed=1") == \
        "sift·brief·inc · m · matcher=[flann]"


def test_saved_view_is_an_experiment_tag_the_ui_reads(client):
    client, experiment = client
    save_pairings_view(client, experiment, "gtsweep.cell")
    envelope = json.loads(client.get_experiment(experiment).tags[f"mlflow.sharedViewState.{VIEW_KEY}"])
    assert envelope["name"] == "gtsweep: pairings" and envelope["createdAt"] == envelope["updatedAt"]
    state = json.loads(envelope["state"])
    assert state == json.loads(json.dumps(pairings_state("gtsweep.cell")))
    assert state["searchFilter"] == "tags.`gtsweep.cell` LIKE '%'"
    assert "params.`detector`" in state["selectedColumns"] and "metrics.`pose_success`" in state["selectedColumns"]
    assert "params.`seed`" not in state["selectedColumns"]  # a group's mean of seeds would read 0.333
    assert state["groupBy"] == {"aggregateFunction": "average",
                                "groupByKeys": [{"mode": "tag", "groupByData": "gtsweep.pairing"}]}
    assert [s["name"] for s in state["compareRunSections"]] == [
        "Model metrics", "curves", "ci", "time", "sweep", "System metrics"] and state["isAccordionReordered"]
    save_pairings_view(client, experiment, "gtsweep.cell")  # unchanged: not rewritten
    assert json.loads(client.get_experiment(experiment).tags[f"mlflow.sharedViewState.{VIEW_KEY}"]) == envelope
    assert runs_url("http://h:5/", "7") == \
        "http://h:5/#/experiments/7/runs?workflowType=machine_learning&viewStateShareKey=gtsweep-pairings"


def test_strength_figure_has_labelled_axes():
    summary = {"methods": {"transform": "rotation"},
               "by_strength": {"0.0": {"pose_success": 1.0, "precision": 0.9},
                               "90.0": {"pose_success": 0.5, "precision": None}}}
    figure = strength_figure(summary, "pose", "sift·brief·rot")
    axes = figure.axes
    assert [(a.get_xlabel(), a.get_ylabel()) for a in axes] == [
        ("rotation angle (deg)", "pose_success (share)"), ("rotation angle (deg)", "precision (share)")]
    assert list(axes[0].lines[0].get_xdata()) == [0.0, 90.0] and list(axes[0].lines[0].get_ydata()) == [1.0, 0.5]
    assert figure.get_suptitle() == "sift·brief·rot"
    assert strength_figure({"by_strength": {"0.0": {"precision": 1.0}}}, "pose", "x") is None  # one strength
    assert strength_figure({"methods": {}, "by_strength": {"0.0": {"t_detect": 1.0}, "1.0": {}}}, "pose", "x") is None


def test_sweep_runs_filter_by_every_dimension_and_read_back(tmp_path, monkeypatch):
    """A tracked sweep: seed, method and data-set params filter; the parent has the config; the report's reader
    gets the intervals back from the ci/ metrics."""
    from omegaconf import OmegaConf

    from gtsweep.experiments.kinds import run_sweep
    from gtsweep.orchestration.cache import library_versions
    from gtsweep.tracking.readback import summaries_from_mlflow, views_from_mlflow
    from gtsweep.tracking.sweep import SweepTracker

    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = compose_config(tiny_overrides(tmp_path, "seed=1", "experiment=detection", "detector=[orb]",
                                        "selector=[nms]", "transform=[rotation]", "transform.rotation.strengths=[0,90]",
                                        "runner.backend=serial", f"mlflow.tracking_uri={uri}"))
    tracker = SweepTracker(cfg.mlflow, tmp_path / "run", OmegaConf.to_yaml(cfg, resolve=True), "seed=1")
    outcome = run_sweep(cfg, tmp_path / "run", hooks=(tracker.log_cell,),
                        on_start=lambda grid, fp: tracker.start(grid, fp, library_versions()))
    tracker.end(outcome)
    mlflow.set_tracking_uri(uri)
    for query in ("params.seed = '1'", "params.detector = 'orb'", "params.dataset = 'synthetic'",
                  f"params.`dataset.fingerprint` = '{outcome.dataset_fingerprint}'"):
        found = mlflow.search_runs(experiment_names=["gtsweep"], filter_string=query)
        assert set(found["tags.mlflow.runName"]) >= {"orb·nms·rot · seed=1"}, query
    parent = MlflowClient(uri).get_run(tracker.parent_id).data
    assert parent.params["dataset.n_synthetic"] == "1" and parent.params["selector.nms.params.n"] == "1000"
    assert parent.metrics["sweep/cells"] == 1  # the sweep's totals in their own chart section
    (summary,) = outcome.summaries
    (read,) = summaries_from_mlflow(tracker.parent_id, uri)
    assert read["methods"]["detector"] == "orb" and read["metrics"]["repeatability_ci_low"] == pytest.approx(
        summary["metrics"]["repeatability_ci_low"])
    assert sorted(read["by_strength"]) == ["0.0", "90.0"]
    assert list(views_from_mlflow(tracker.parent_id, uri)) == [summary["key"]]


def test_cluster_of_the_run_record_becomes_tags():
    record = {"cells": 4, "cluster": {"backend": "ray", "address": "10.0.0.5:6379", "nodes": 2, "cpus": 8}}
    assert cluster_tags(record) == {"gtsweep.cluster.backend": "ray", "gtsweep.cluster.address": "10.0.0.5:6379",
                                    "gtsweep.cluster.nodes": "2", "gtsweep.cluster.cpus": "8"}
    assert cluster_tags({"cells": 4}) == {} and cluster_tags({"cluster": {}}) == {}


def test_a_composed_job_names_its_methods_as_written(monkeypatch, tmp_path):
    """Hydra's defaults list of a real composition: a method file with a defaults list (its schema first) is its
    own ``_self_`` entry there, and still names the option as written (``tuned/sift``)."""
    from hydra import compose, initialize_config_module
    from hydra.core.hydra_config import HydraConfig

    from gtsweep.cli.overrides import register_all
    from gtsweep.cli.search import PRIMARY_MODULE, PRIMARY_NAME
    from gtsweep.tracking.params import written_options

    monkeypatch.chdir(tmp_path)
    args = ["detector=[tuned/sift,orb]", "descriptor=[brief]"]
    register_all()
    with initialize_config_module(config_module=PRIMARY_MODULE, version_base=None):
        cfg = compose(config_name=PRIMARY_NAME, overrides=args, return_hydra_config=True)
        HydraConfig.instance().set_config(cfg)
        written = written_options()
    assert written["detector"] == {"sift": "tuned/sift", "orb": "orb"}
    assert written["descriptor"] == {"brief": "brief"}
