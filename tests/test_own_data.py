"""One's own CSV data set: a data set too small for the pair rules stops in one line before any work, naming what it
found and the setting to change; ``dataset.px_per_mm`` is checked (the report's millimetres come from it)."""
import pytest
from dataset_fixtures import own_csv

from gtsweep.core.errors import BadInput
from gtsweep.datasets import load_dataset
from gtsweep.orchestration.skeleton import PAIRS

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
    assert len(smaller_gap.pairs("absolute")) == 24 and smaller_gap.empty_kinds == {}
    assert load_dataset({"loader": "csv", "root": str(own), "n_incremental": 0}).empty_kinds == {
        "incremental": "dataset.n_incremental is 0", "absolute": TOO_FEW}


class Grid:
    transforms = {"incremental": {"kind": "pairs"}, "absolute": {"kind": "pairs"}, "rotation": {"kind": "synthetic"}}


def test_the_sweep_stops_before_any_work_on_a_pair_kind_it_lacks(own):
    with pytest.raises(BadInput) as stopped:
        PAIRS.load_data({"dataset": {"loader": "csv", "root": str(own)}}, Grid())
    assert str(stopped.value) == f"data set 'csv' has no absolute pairs: {TOO_FEW}"
    data = PAIRS.load_data({"dataset": {"loader": "csv", "root": str(own), "absolute_min_gap": 6}}, Grid())
    assert len(data.dataset.pairs("absolute")) == 24


@pytest.mark.parametrize("value", [0, -6.25, "6.25", True, float("inf")])
def test_px_per_mm_must_be_a_positive_number(own, value):
    with pytest.raises(BadInput, match=r"^dataset.px_per_mm must be a number > 0 \(pixels per millimetre of floor\)"):
        load_dataset({"loader": "csv", "root": str(own), "px_per_mm": value})
    assert load_dataset({"loader": "csv", "root": str(own), "px_per_mm": 12.5}).name == "csv"
