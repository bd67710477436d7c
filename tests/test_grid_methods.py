"""Matchers and pose estimators as grid dimensions: cells, NA, moved settings, one description per pair for every
matcher and estimator, the survey's cells unchanged, and what results, MLflow names and the report carry."""
import pandas as pd
import pytest

from gtsweep.cli import overrides as cli
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.evaluation import reuse
from gtsweep.experiments.kinds import run_sweep
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.report.tables import build_tables, table_cells
from gtsweep.tracking.tags import cell_names
from sweep_helpers import compose_config, read_cells, tiny_overrides

PARAMS = {"params": {}}


def _cfg(**over):
    cfg = {"detector": {"orb": PARAMS}, "selector": {"nms": {"params": {"n": 10}}},
           "descriptor": {"orb": PARAMS, "sift": PARAMS}, "transform": {"incremental": {"kind": "pairs"}},
           "matcher": {"bf_ratio": PARAMS, "flann": PARAMS}, "estimator": {"ransac": PARAMS, "magsac": PARAMS},
           "experiment": {"name": "pose"}}
    cfg.update(over)
    return cfg


def test_cells_are_the_product_with_matcher_and_estimator():
    grid = build_grid(_cfg())
    assert len(grid.cells) == 2 * 2 * 2  # descriptors x matchers x estimators
    assert {(c.matcher, c.estimator) for c in grid.cells} == {(m, e) for m in ("bf_ratio", "flann")
                                                                for e in ("magsac", "ransac")}
    keys = {c.key for c in grid.cells}
    # the survey's matcher and estimator leave a cell's key as it was; the others are appended
    assert "orb__nms__orb__incremental" in keys and "orb__nms__orb__incremental__flann__magsac" in keys
    assert "orb__nms__orb__incremental__magsac" in keys and len(keys) == len(grid.cells)
    cell = next(c for c in grid.cells if c.matcher == "flann" and c.estimator == "magsac")
    assert cell.methods == {"detector": "orb", "selector": "nms", "descriptor": "orb", "transform": "incremental",
                            "matcher": "flann", "estimator": "magsac"}
    assert grid.cell_config(cell, "fp", 0)["matcher"]["params"]["trees"] == 4  # full params, as recorded
    flann8 = build_grid(_cfg(matcher={"flann": {"params": {"trees": 8}}}))
    assert flann8.cell_hash(flann8.cells[0], "fp", 0) != grid.cell_hash(cell, "fp", 0)


def test_matching_has_no_estimator_and_detection_neither():
    matching = build_grid(_cfg(experiment={"name": "matching"}))
    assert len(matching.cells) == 2 * 2 and {c.estimator for c in matching.cells} == {None}
    assert "estimator" not in matching.cells[0].methods and not matching.estimators
    detection = build_grid(_cfg(experiment={"name": "detection"}))
    assert len(detection.cells) == 1 and detection.cells[0].methods == {
        "detector": "orb", "selector": "nms", "descriptor": None, "transform": "incremental"}


def test_a_config_without_the_groups_gets_the_survey_methods():
    cfg = _cfg()
    del cfg["matcher"], cfg["estimator"]
    grid = build_grid(cfg)
    assert {(c.matcher, c.estimator) for c in grid.cells} == {("bf_ratio", "ransac")}
    assert grid.matchers["bf_ratio"]["params"] == {"ratio": 0.7, "mutual": False}
    assert grid.estimators["ransac"]["params"] == {"model": "similarity", "iterations": 2000, "threshold": 3.0}


def test_a_forced_flann_index_on_binary_descriptors_is_na():
    grid = build_grid(_cfg(matcher={"flann": {"params": {"algorithm": "kdtree"}}}, estimator={"ransac": PARAMS}))
    reasons = {c.descriptor: c.na_reason for c in grid.cells}
    assert reasons["sift"] is None
    assert reasons["orb"] == "FLANN's kdtree index needs L2 descriptors, these are binary (Hamming)"


def test_unknown_names_bad_values_and_moved_settings_are_one_line():
    with pytest.raises(UnknownMethod,
                       match="unknown matcher 'knn'; valid choices: bf_ratio, flann, lightglue, mutual_nn"):
        build_grid(_cfg(matcher={"knn": PARAMS}))
    with pytest.raises(UnknownMethod, match="unknown estimator 'lo_ransac'"):
        build_grid(_cfg(estimator={"lo_ransac": PARAMS}))
    with pytest.raises(BadInput, match="trees must be an integer in \\[1, inf\\), got 0"):
        build_grid(_cfg(matcher={"flann": {"params": {"trees": 0}}}))
    with pytest.raises(BadInput, match="experiment.ratio moved to the matcher group: set matcher.bf_ratio.params"):
        build_grid(_cfg(experiment={"name": "pose", "ratio": 0.8}))
    with pytest.raises(BadInput, match="experiment.pose.iterations moved to the estimator group"):
        build_grid(_cfg(experiment={"name": "pose", "pose": {"iterations": 10, "max_position_error": 30.0}}))
    # the command line: where Hydra composes, one line each (exit code 2 in python -m gtsweep)
    with pytest.raises(UnknownMethod, match="unknown matcher 'knn'"):
        cli.compose_config(["matcher=knn"])
    with pytest.raises(BadInput, match="'experiment.ratio' moved to the matcher group: write "
                                       "matcher.bf_ratio.params.ratio="):
        cli.compose_config(["experiment.ratio=0.8"])
    with pytest.raises(BadInput, match="estimator 'cv_lmeds' has no parameter 'threshold'"):
        cli.compose_config(["estimator=[cv_lmeds]", "estimator.cv_lmeds.params.threshold=2.0"])
    assert list(cli.compose_config(["matcher=all"]).matcher) == ["bf_ratio", "flann", "lightglue", "mutual_nn"]


def test_mlflow_names_carry_matcher_and_estimator_only_when_several():
    grid = build_grid(_cfg(descriptor={"orb": PARAMS}))
    names = cell_names(grid.cells, several_selectors=False)
    assert names["orb__nms__orb__incremental"] == "orb·orb·inc·bf_ratio·ransac"
    assert names["orb__nms__orb__incremental__flann__magsac"] == "orb·orb·inc·flann·magsac"
    single = build_grid(_cfg(matcher={"bf_ratio": PARAMS}, estimator={"ransac": PARAMS}))
    assert set(cell_names(single.cells, several_selectors=False).values()) == {"orb·orb·inc", "orb·sift·inc"}


@pytest.mark.slow
def test_every_matcher_and_estimator_on_one_description_per_pair(tmp_path, monkeypatch):
    calls = []
    original = reuse.describe_timed

    def counting(image, keypoints, descriptor, *args, **kwargs):
        calls.append(descriptor)
        return original(image, keypoints, descriptor, *args, **kwargs)

    monkeypatch.setattr(reuse, "describe_timed", counting)
    base = ["runner.backend=serial", "mlflow.enabled=false", "detector=[orb]", "descriptor=[orb]",
            "transform=[incremental]"]
    everything = run_sweep(compose_config(tiny_overrides(tmp_path, *base, "matcher=all", "estimator=all")),
                           tmp_path / "all")
    assert len(everything.summaries) == 4 * 4
    assert all(s["status"] == ("na" if s["methods"]["matcher"] == "lightglue" else "ok")  # no LightGlue for ORB
               for s in everything.summaries)
    n_pairs = everything.summaries[0]["n_views"]
    assert calls == ["orb"] * 2 * n_pairs  # reference and test described once per pair for all 12 ok cells
    survey = run_sweep(compose_config(tiny_overrides(tmp_path, *base)), tmp_path / "survey")
    ours, theirs = read_cells(tmp_path / "all"), read_cells(tmp_path / "survey")
    key = "orb__nms__orb__incremental"
    pd.testing.assert_frame_equal(ours[key], theirs[key], check_exact=True)  # the survey's cell, unchanged
    table = pd.read_csv(tmp_path / "all" / "results.csv")
    assert list(table.columns[:6]) == ["detector", "selector", "descriptor", "transform", "matcher", "estimator"]
    table = table[table["status"] == "ok"]
    assert table["t_match"].gt(0).all() and table["t_pose"].gt(0).all()
    # per matcher, one match set: every estimator of a matcher sees the same matches
    assert table.groupby("matcher")["n_matches"].nunique().eq(1).all()
    tables = build_tables(everything.summaries)
    assert "table4_incremental_flann_magsac" in {t.name for t in tables} and len(tables) == 16  # LightGlue: NA
    assert "matcher FLANN, estimator MAGSAC++" in next(t.title for t in tables if t.name.endswith("flann_magsac"))
    assert {"matcher", "estimator"} <= set(table_cells(everything.summaries).cells.columns)
    assert [t.name for t in build_tables(survey.summaries)] == ["table4_incremental"]
    assert "matcher" not in table_cells(survey.summaries).cells.columns
