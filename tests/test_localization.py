"""experiment=localization (issue 19): a map of posed rendered views localizes a query rendered at a known pose
within 1 px and 0.1 deg, rejects a query from another floor, and its grid gives NA and one-line errors for matchers
and estimators as for detectors and descriptors."""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from omegaconf import OmegaConf

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.datasets import floors
from gtsweep.datasets.geometry import centred_pose
from gtsweep.datasets.mapping import check, covered_area, load_localization, map_poses
from gtsweep.datasets.pairing import texture_rng
from gtsweep.datasets.synthetic import render_view
from gtsweep.evaluation.evaluate import detect_and_select
from gtsweep.experiments.localization.cells import build_localization_grid
from gtsweep.stages.describe import describe
from gtsweep.stages.localize import Acceptance, FeatureMap, build_map, judge, localize, orientation, pose_columns, vote
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.pose import ESTIMATORS

VIEW = (320, 240)  # (w, h)
SHAPE = (240, 320)
CONF = Path(__file__).resolve().parents[1] / "conf"


def _features(image):
    keypoints, _, _ = detect_and_select(image, None, "sift", {}, "nms", {"n": 600})
    kept, descriptors = describe(image, keypoints, "sift", "sift")
    return kept, descriptors


@pytest.fixture(scope="module", params=["synthetic", pytest.param("survey", marks=pytest.mark.slow)])
def rendered(request, tmp_path_factory):
    """A mapping run, a query at a known pose inside it and a query from another floor of the same texture, with
    the image shape. ``synthetic``: a 2 x 2 run over a procedural asphalt floor (no noise) and queries rendered
    here. ``survey``: dataset=survey's own localization data (1288 x 964 frames of the moving camera: blur,
    exposure, lighting, sensor noise, tilt in the exact pose; queries also from another day), map of 4 images."""
    if request.param == "survey":
        dataset = {**OmegaConf.to_container(OmegaConf.load(CONF / "dataset" / "survey.yaml")),
                   "cache_dir": str(tmp_path_factory.mktemp("survey"))}
        data = load_localization(dataset, {"map_images": [4], "n_queries": 1, "n_foreign": 1,
                                           "textures": ["fine_asphalt"]})
        shape = (964, 1288)
        parts = [(*_features(_read(s.path)), s.pose, shape, 0.0) for s in data.maps["fine_asphalt"]]
        query, foreign = data.queries
        assert query.in_map and not foreign.in_map
        return build_map(parts), query.sample.pose, _features(_read(query.sample.path)), \
            _features(_read(foreign.sample.path)), shape
    side = 900
    floor = floors.make_floor("fine_asphalt", texture_rng(0, "fine_asphalt", "floor"), (side, side), 6.25)
    other = floors.make_floor("fine_asphalt", texture_rng(1, "fine_asphalt", "floor"), (side, side), 6.25)
    poses = map_poses(np.random.default_rng(0), 4, VIEW, 0.5, 0.0, (side / 2, side / 2))
    parts = [(*_features(render_view(floor, p, SHAPE)), p, SHAPE, 0.0) for p in poses]
    truth = centred_pose(side / 2 + 37.25, side / 2 - 21.5, 73.0, 1.0, SHAPE)
    return build_map(parts), truth, _features(render_view(floor, truth, SHAPE)), \
        _features(render_view(other, truth, SHAPE)), SHAPE


def _read(path):
    return cv2.imread(path, cv2.IMREAD_GRAYSCALE)


def _localize(feature_map, features, shape=SHAPE, voting=True):
    index = MATCHERS.get("bf_ratio").build({}).index(feature_map.descriptors, "l2")
    estimators = {"ransac": ESTIMATORS.get("ransac").build({})}
    result = localize(*features, shape, feature_map, index, estimators, Acceptance(10, 0.0), voting=voting)
    return result["poses"]["ransac"]


@pytest.mark.parametrize("voting", [True, False])
def test_query_at_a_known_pose_is_localized_within_1_px_and_0_1_deg(rendered, voting):
    feature_map, truth, query, _, shape = rendered
    estimate, _, accepted = _localize(feature_map, query, shape, voting)
    verdict = judge(pose_columns(estimate.matrix, shape), truth, shape)
    assert accepted and verdict["within"]
    assert verdict["position_error"] < 1.0
    assert verdict["orientation_error"] < 0.1


def test_query_from_another_floor_is_rejected(rendered):
    feature_map, _, _, foreign, shape = rendered
    estimate, _, accepted = _localize(feature_map, foreign, shape)
    assert not accepted
    assert estimate.n_inliers < 10


def _index(dataset: dict, tmp_path) -> tuple[dict, list]:
    """The embedded localization data of a small ``dataset`` (one floor, 2 map images, 1 query, 1 foreign) and
    its index records."""
    dataset = {"loader": "synthetic", "cache_dir": str(tmp_path), "view_size": [160, 120], **dataset}
    data = load_localization(dataset, {"map_images": [2], "n_queries": 1, "n_foreign": 1,
                                       "textures": ["fine_asphalt"]})
    folder = tmp_path / "datasets" / f"mapping-{data.fingerprint}"
    return data, json.loads((folder / "index.json").read_text())["views"]


def test_without_photometric_ranges_queries_get_no_photometric_change(tmp_path):
    _, views = _index({"photometric": None}, tmp_path)
    assert [v["role"] for v in views] == ["map", "map", "query", "foreign"]
    assert all(v["params"] is None and "frame" not in v for v in views)


def test_with_capture_physics_every_view_is_a_frame_and_queries_are_from_another_day(tmp_path):
    data, views = _index({"photometric": None, "capture": {}, "day": {}}, tmp_path)
    for view in views:
        pose = np.array(view["pose"])
        assert view["params"] is None and set(view["frame"]) >= {"exposure_ms", "pitch_deg", "travel_deg"}
        assert (view["day"] is not None) == (view["role"] != "map")  # queries and foreign ones: another day
        # the tilt is in the exact pose: a homography whose centre stays where the layout put it
        assert pose[2, 2] == 1.0 and np.abs(pose[2, :2]).max() > 0
    tilted = data.maps["fine_asphalt"][0].pose
    assert orientation(tilted, (120, 160)) != pytest.approx(orientation(tilted), abs=1e-9)


def test_pose_columns_and_judge_by_hand():
    pose = centred_pose(100.0, 50.0, 0.0, 1.0, (11, 21))  # centre (10, 5) of a 21 x 11 image lands on (100, 50)
    columns = pose_columns(pose, (11, 21))
    assert columns["est_x"] == pytest.approx(100.0) and columns["est_y"] == pytest.approx(50.0)
    assert columns["est_theta"] == pytest.approx(0.0)
    turned = centred_pose(103.0, 54.0, -2.0, 1.0, (11, 21))  # matrix convention: atan2(P[1,0], P[0,0]) = +2 deg
    verdict = judge(pose_columns(turned, (11, 21)), pose, (11, 21))
    assert verdict["position_error"] == pytest.approx(5.0)
    assert verdict["orientation_error"] == pytest.approx(2.0)
    assert not verdict["within"]  # 2 deg > 1.5 deg
    assert judge(pose_columns(None, (11, 21)), pose, (11, 21))["within"] is False


def test_vote_keeps_the_consistent_matches():
    """Three matches say "query centre at (500, 500), rotated 90 deg"; one says elsewhere."""
    centre = (10.0, 10.0)
    query_xy = np.array([[0.0, 0.0], [20.0, 0.0], [10.0, 30.0], [0.0, 0.0]])
    rotation = np.array([[0.0, -1.0], [1.0, 0.0]])  # +90 deg in the matrix convention
    map_xy = (query_xy - centre) @ rotation.T + 500.0
    map_xy[3] = [900.0, 100.0]
    kept = vote(query_xy, np.zeros(4), map_xy, np.full(4, 90.0), centre, cell=20.0)
    assert kept.tolist() == [True, True, True, False]


def test_build_map_keeps_each_floor_point_once():
    """Two identical views: the second one's features all lie inside the first one's footprint."""
    keypoints = np.zeros((3, 7))
    keypoints[:, :2] = [[50.0, 50.0], [100.0, 60.0], [150.0, 100.0]]
    keypoints[:, 3] = [10.0, -1.0, 350.0]
    descriptors = np.arange(3 * 4, dtype=np.float32).reshape(3, 4)
    pose = centred_pose(500.0, 500.0, 0.0, 1.0, SHAPE)
    feature_map = build_map([(keypoints, descriptors, pose, SHAPE, 0.5), (keypoints, descriptors, pose, SHAPE, 0.25)])
    assert len(feature_map) == 3 and feature_map.image.tolist() == [0, 0, 0]
    assert np.allclose(feature_map.xy, keypoints[:, :2] + pose[:2, 2])
    assert np.isnan(feature_map.angle[1]) and feature_map.angle[2] == pytest.approx(350.0)
    assert feature_map.build_seconds.sum() == pytest.approx(0.75)
    both = build_map([(keypoints, descriptors, pose, SHAPE, 0.5), (keypoints, descriptors, pose, SHAPE, 0.25)],
                     dedupe=False)
    assert len(both) == 6 and len(both.first(1)) == 3
    assert both.nbytes == 6 * (2 * 4 + 4 + 4 * 4 + 4)


def test_covered_area_of_two_half_overlapping_views():
    a = centred_pose(500.0, 500.0, 0.0, 1.0, (100, 200))
    b = centred_pose(600.0, 500.0, 0.0, 1.0, (100, 200))
    assert covered_area([a, b], (100, 200)) == pytest.approx(300 * 100, rel=0.05)


def test_localization_options_are_checked():
    assert check({})["map_images"] == [4, 16]
    with pytest.raises(BadInput, match="map_images"):
        check({"map_images": [0]})
    with pytest.raises(BadInput, match="map_overlap"):
        check({"map_overlap": 1.0})
    with pytest.raises(BadInput, match="loader"):
        load_localization({"loader": "folder", "root": "/tmp"}, {})


def _cfg(**groups):
    base = {"detector": {"sift": {"params": {}}, "akaze": {"params": {}}}, "selector": {"nms": {"params": {}}},
            "descriptor": {"sift": {"params": {}}, "akaze": {"params": {}}},
            "matcher": {"bf_ratio": {"params": {}}}, "estimator": {"ransac": {"params": {}}},
            "experiment": {"name": "localization"}, "seed": 0}
    return OmegaConf.create({**base, **groups})


def test_grid_marks_na_pairings_and_matchers():
    grid = build_localization_grid(_cfg(matcher={"bf_ratio": {"params": {}},
                                                 "flann": {"params": {"algorithm": "lsh"}}}))
    reasons = {c.key: c.na_reason for c in grid.cells}
    assert len(grid.cells) == 4 * 2  # pairings x matchers x estimators
    assert "only describes" in reasons["sift__nms__akaze__bf_ratio__ransac"]
    # a binary (LSH) index for real-valued descriptors
    assert "lsh index needs HAMMING" in reasons["sift__nms__sift__flann__ransac"]
    assert reasons["akaze__nms__akaze__flann__ransac"] is None
    assert reasons["sift__nms__sift__bf_ratio__ransac"] is None


@pytest.mark.parametrize("groups, error, text", [
    ({"matcher": {"nope": {"params": {}}}}, UnknownMethod, "unknown matcher 'nope'; valid choices"),
    ({"estimator": {"ransac": {"params": {"iterations": 0}}}}, BadInput, "iterations"),
    ({"matcher": {"bf_ratio": {"params": {"radius": 3}}}}, BadInput, "has no parameter 'radius'"),
    ({"experiment": {"name": "localization", "min_inliers": 1}}, BadInput, "experiment.min_inliers"),
])
def test_grid_errors_are_one_line(groups, error, text):
    with pytest.raises(error, match=text) as raised:
        build_localization_grid(_cfg(**groups))
    assert "\n" not in str(raised.value)


def test_feature_map_of_first_images():
    feature_map = FeatureMap(np.zeros((5, 2), np.float32), np.zeros(5, np.float32), np.zeros((5, 2), np.uint8),
                             np.array([0, 0, 1, 2, 2], np.int32), np.array([1.0, 2.0, 3.0]))
    assert len(feature_map.first(2)) == 3 and feature_map.first(2).build_seconds.tolist() == [1.0, 2.0]
    assert math.isclose(feature_map.first(3).build_seconds.sum(), 6.0)


def test_microgps_database_is_the_map_and_test_lists_are_unposed_queries(tmp_path):
    from dataset_fixtures import microgps

    microgps(tmp_path, "carpet", n=10)
    microgps(tmp_path, "tiles", n=6)
    data = load_localization({"loader": "microgps", "root": str(tmp_path)},
                             {"n_queries": 2, "n_foreign": 1, "map_images": None})
    assert sorted(data.maps) == ["carpet", "tiles"]
    assert len(data.maps["carpet"]) == 8 and len(data.maps["tiles"]) == 4  # 2 held out each
    own = [q for q in data.queries if q.texture == "carpet" and q.in_map]
    assert sum(q.sample.pose is not None for q in own) == 2  # held out, with ground truth
    assert sum(q.sample.pose is None for q in own) == 1  # the .test list: no pose, estimates only
    foreign = [q for q in data.queries if q.texture == "carpet" and not q.in_map]
    assert len(foreign) == 1 and foreign[0].sample.id.startswith("tiles/")
    assert data.sizes("carpet") == [8] and data.px_per_mm == pytest.approx(6.25)


def test_localization_on_a_real_data_set_maps_every_floor_found(tmp_path):
    """``experiment=localization dataset=microgps dataset.root=...``: every texture folder is a map (the embedded
    data set's three floor names are not asked of a real one); ``dataset.textures`` still picks."""
    from dataset_fixtures import microgps
    from gtsweep.datasets.mapping import EMBEDDED_TEXTURES, embedded_textures
    from sweep_helpers import compose_config

    microgps(tmp_path, "cs4_hallway_long_packed", n=6)
    microgps(tmp_path, "fc_hallway_long_packed", n=5)
    cfg = OmegaConf.to_container(compose_config(["experiment=localization", "dataset=microgps",
                                                 f"dataset.root={tmp_path}"]), resolve=True)
    data = load_localization(cfg["dataset"], cfg["experiment"])
    assert sorted(data.maps) == ["cs4_hallway_long_packed", "fc_hallway_long_packed"]
    # 4 queries held out of each: 6 - 4 = 2 and 5 - 3 = 2 mapping images (linspace picks of 5 images repeat)
    assert [len(data.maps[t]) for t in sorted(data.maps)] == [2, 2]
    picked = OmegaConf.to_container(compose_config(["experiment=localization", "dataset=microgps",
                                                    f"dataset.root={tmp_path}",
                                                    "dataset.textures=[fc_hallway_long_packed]"]), resolve=True)
    assert list(load_localization(picked["dataset"], picked["experiment"]).maps) == ["fc_hallway_long_packed"]
    # the embedded data set keeps its three floors unless experiment.textures names others
    assert embedded_textures(check({})) == list(EMBEDDED_TEXTURES) == ["fine_asphalt", "concrete", "wood"]
    assert embedded_textures(check({"textures": "carpet"})) == ["carpet"]


def test_run_writes_per_query_rows_and_reuses_the_cached_map(tmp_path):
    from gtsweep.experiments.localization.cells import run_localization

    cfg = _cfg(detector={"akaze": {"params": {}}}, descriptor={"akaze": {"params": {}}},
               estimator={"ransac": {"params": {}}, "cv_ransac": {"params": {}}},
               dataset={"loader": "synthetic", "cache_dir": str(tmp_path / "c"), "view_size": [320, 240]},
               experiment={"name": "localization", "textures": ["fine_asphalt"], "map_images": [1, 4],
                           "n_queries": 2, "n_foreign": 1, "min_inliers": 10},
               runner={"backend": "serial", "shard_size": 2},
               cache={"enabled": True, "dir": str(tmp_path / "c" / "keypoints")})
    first = run_localization(cfg, tmp_path / "run1")
    assert [s["status"] for s in first.summaries] == ["ok", "ok"]
    rows = __import__("pandas").read_csv(tmp_path / "run1" / "cells" / "akaze__nms__akaze__bf_ratio__ransac.csv")
    assert len(rows) == 3 * 2  # queries x map sizes
    assert {"query", "localized", "est_x", "est_y", "est_theta", "position_error", "t_query"} <= set(rows.columns)
    assert rows.loc[rows.in_map == 0, "position_error"].isna().all()
    assert rows.loc[rows.in_map == 0, "localized"].eq(0).all()  # the foreign floor is rejected
    assert first.summaries[0]["metrics"]["false_localization"] == 0.0
    assert first.stats.detection_tasks == 2  # 4 mapping images in shards of 2, once for both estimators
    again = run_localization(cfg, tmp_path / "run1")  # resume: finished cells with the same config are kept
    assert again.resumed == 2 and again.summaries == first.summaries
    second = run_localization(cfg, tmp_path / "run2")
    assert second.stats.detection_tasks == 0  # the map came from the map cache
    assert second.summaries[0]["metrics"] == first.summaries[0]["metrics"] or math.isclose(
        second.summaries[0]["metrics"]["localization_success"], first.summaries[0]["metrics"]["localization_success"])


def test_report_rebuilds_from_a_localization_run(tmp_path, capsys):
    from gtsweep.experiments.report_command import main

    cells = tmp_path / "cells"
    cells.mkdir()
    summary = {"key": "k", "status": "ok", "experiment": "localization",
               "methods": {"detector": "sift", "selector": "nms", "descriptor": "sift", "matcher": "flann",
                           "estimator": "ransac"},
               "metrics": {"localization_success": 0.5, "localization_success_ci_low": 0.1,
                           "localization_success_ci_high": 0.9, "false_localization": 0.0, "t_query": 0.2},
               "by_map_images": {"4.0": {"localization_success": 1.0, "t_query": 0.1, "map_bytes": 2e6},
                                 "16.0": {"localization_success": 0.0, "t_query": 0.3, "map_bytes": 8e6}}}
    (cells / "k.json").write_text(__import__("json").dumps(summary))
    assert main([str(tmp_path), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert "| sift/sift | flann | ransac | 50 % [10 %, 90 %] | 0 % |" in printed
    assert "| sift / sift / flann / ransac | 100 %, 100 ms | 0 %, 300 ms |" in printed
    assert "| 8.00 |" in printed  # MB of the largest map


def test_hdground_pose_files_are_the_map(tmp_path):
    from dataset_fixtures import hdground

    hdground(tmp_path, "office_carpet", n=10)
    data = load_localization({"loader": "hdground", "root": str(tmp_path)}, {"n_queries": 3, "map_images": None})
    posed = [q for q in data.queries if q.sample.pose is not None]
    assert len(posed) == 3 and all(q.in_map for q in posed)
    assert len(data.maps["office_carpet"]) + 3 == 9  # one pose of the 10 is marked invalid
    assert math.isnan(data.px_per_mm)  # HD Ground's README gives none: map bytes per m2 need experiment.px_per_mm
