"""One's own CSV data set: a data set too small for the pair rules stops in one line before any work, naming what it
found and the setting to change; ``dataset.px_per_mm`` is checked (the report's millimetres come from it); the pose
check names the convention that fits poses written in another one."""
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from dataset_fixtures import OWN_VIEW, own_csv, own_csv_rows
from gtsweep.core.errors import BadInput
from gtsweep.datasets import load_dataset
from gtsweep.datasets.posecheck import check_poses
from gtsweep.experiments.pairs.cells import PAIRS

TOO_FEW = ("24 images in 2 texture(s), at most 12 in one session; an absolute pair is two images whose footprints "
           "overlap >= absolute_min_overlap (0.1), from different sessions or >= absolute_min_gap (50) images apart "
           "in one: set dataset.absolute_min_gap=6 (or lower dataset.absolute_min_overlap)")


@pytest.fixture(scope="module")
def own(tmp_path_factory):
    return own_csv(tmp_path_factory.mktemp("own"))


def test_twelve_images_per_texture_have_no_absolute_pair_and_say_which_setting(own):
    dataset = load_dataset({"loader": "csv", "root": str(own)})
    assert len(dataset.pairs("incremental")) == 12 and dataset.pairs("absolute") == []
    assert dataset.empty_kinds == {"absolute": TOO_FEW}
    smaller_gap = load_dataset({"loader": "csv", "root": str(own), "absolute_min_gap": 6})
    assert len(smaller_gap.pairs("absolute")) == 16 and smaller_gap.empty_kinds == {}
    assert load_dataset({"loader": "csv", "root": str(own), "n_incremental": 0}).empty_kinds == {
        "incremental": "dataset.n_incremental is 0", "absolute": TOO_FEW}


class Grid:
    transforms = {"incremental": {"kind": "pairs"}, "absolute": {"kind": "pairs"}, "rotation": {"kind": "synthetic"}}


def test_the_sweep_stops_before_any_work_on_a_pair_kind_it_lacks(own):
    with pytest.raises(BadInput) as stopped:
        PAIRS.load_data({"dataset": {"loader": "csv", "root": str(own)}}, Grid())
    assert str(stopped.value) == f"data set 'csv' has no absolute pairs: {TOO_FEW}"
    data = PAIRS.load_data({"dataset": {"loader": "csv", "root": str(own), "absolute_min_gap": 6}}, Grid())
    assert len(data.dataset.pairs("absolute")) == 16


@pytest.mark.parametrize("value", [0, -6.25, "6.25", True, float("inf")])
def test_px_per_mm_must_be_a_positive_number(own, value):
    with pytest.raises(BadInput, match=r"^dataset.px_per_mm must be a number > 0 \(pixels per millimetre of floor\)"):
        load_dataset({"loader": "csv", "root": str(own), "px_per_mm": value})
    assert load_dataset({"loader": "csv", "root": str(own), "px_per_mm": 12.5}).name == "csv"


def _written(own, written, name):
    return str(own_csv_rows(own.parent, written=written, name=name))


def test_poses_as_the_images_were_rendered_pass_the_check(own):
    found = check_poses(load_dataset({"loader": "csv", "root": str(own)}))
    assert (found.checked, found.measured, found.consistent) == (6, 6, True)
    assert found.agree == {"as written": 6, "theta negated": 0, "x and y swapped": 0,
                           "y pointing up (y and theta negated)": 0, "theta in radians": 0}
    assert found.line() == "pose check: the poses agree with the images on 6 of 6 pair(s) (largest corner distance " \
                           "0.0 px)"


@pytest.mark.parametrize("written, fits", [
    (lambda x, y, theta: (x, y, -theta), "theta negated or y pointing up (y and theta negated)"),
    pytest.param(lambda x, y, theta: (y, x, theta), "x and y swapped", marks=pytest.mark.slow),
    pytest.param(lambda x, y, theta: (x, y, math.radians(theta)), "theta in radians", marks=pytest.mark.slow),
])
def test_a_wrong_convention_is_named(own, written, fits):
    found = check_poses(load_dataset({"loader": "csv", "root": _written(own, written, "other.csv")}))
    assert not found.consistent and found.measured == 6 and found.agree["as written"] == 0
    assert found.line().startswith("pose check: the poses disagree with the images on 6 of 6 pair(s) (as written")
    assert found.line().endswith(f"they fit with {fits} (6 of 6): convert them to gtsweep's convention "
                                 f"(docs/own-data.md)")


@pytest.mark.slow
def test_the_sweep_stops_on_negated_theta_before_any_work(own):
    dataset = {"loader": "csv", "root": _written(own, lambda x, y, theta: (x, y, -theta), "negated.csv"),
               "absolute_min_gap": 6, "pose_check": True}
    with pytest.raises(BadInput, match=r"^pose check: the poses disagree .* they fit with theta negated or y "
                                        r"pointing up .*; or dataset.pose_check=false to run anyway$"):
        PAIRS.load_data({"dataset": dataset}, Grid())
    assert PAIRS.load_data({"dataset": {**dataset, "pose_check": False}}, Grid()).dataset.name == "csv"


def test_images_without_matching_features_are_not_judged(tmp_path):
    for name in [f"{t}/{i:03d}.png" for t in ("asphalt", "carpet") for i in range(12)]:
        (tmp_path / name).parent.mkdir(exist_ok=True)
        cv2.imwrite(str(tmp_path / name), np.full(OWN_VIEW, 128, np.uint8))  # blank: no feature
    found = check_poses(load_dataset({"loader": "csv", "root": str(own_csv_rows(tmp_path))}))
    assert (found.measured, found.consistent) == (0, True)
    assert found.line() == "pose check: none of 6 overlapping pair(s) had 15 matching features: the poses could " \
                           "not be checked"


@pytest.mark.slow
def test_the_check_command_says_it_in_one_line(own, tmp_path):
    csv = _written(own, lambda x, y, theta: (x, y, math.radians(theta)), "radians.csv")
    done = subprocess.run([sys.executable, "-m", "gtsweep.datasets", "check", "dataset=csv", f"dataset.root={csv}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stderr == ""
    assert done.stdout.startswith("pose check: the poses disagree with the images on 6 of 6 pair(s)")
    assert done.stdout.endswith("they fit with theta in radians (6 of 6): convert them to gtsweep's convention "
                                "(docs/own-data.md)\n")
