"""dataset.skip_first: a window of a data set computes only the images or pairs after the skipped ones, and those
keep their ids, poses and pixels (the reproduction's targeted rows rest on it)."""
import cv2
import numpy as np
import pytest
import yaml

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import CONF_DIR
from gtsweep.datasets import load_dataset


@pytest.fixture(scope="module")
def options(tmp_path_factory):
    base = yaml.safe_load((CONF_DIR / "dataset" / "synthetic.yaml").read_text())
    return {**base, "textures": ["gravel", "wood"], "view_size": [160, 120], "n_synthetic": 5, "n_incremental": 4,
            "n_absolute": 3, "cache_dir": str(tmp_path_factory.mktemp("cache"))}


def _pixels(sample):
    return cv2.imread(str(sample.path), cv2.IMREAD_UNCHANGED)


def test_window_keeps_ids_poses_and_pixels(options):
    full = load_dataset(options)
    part = load_dataset({**options, "skip_first": {"synthetic": 3, "incremental": 2}})
    assert [s.id for s in part.images("synthetic")] == [
        "gravel/synthetic/003", "gravel/synthetic/004", "wood/synthetic/003", "wood/synthetic/004"]
    assert [p.id for p in part.pairs("incremental")] == [
        "gravel/incremental/002", "gravel/incremental/003", "wood/incremental/002", "wood/incremental/003"]
    assert len(part.pairs("absolute")) == 6  # a split without a skip count keeps everything
    images = {s.id: s for s in full.images("synthetic")}
    for s in part.images("synthetic"):
        assert np.array_equal(_pixels(s), _pixels(images[s.id]))
        assert np.array_equal(np.asarray(s.pose), np.asarray(images[s.id].pose))
    pairs = {p.id: p for p in full.pairs("incremental")}
    for p in part.pairs("incremental"):
        assert np.array_equal(_pixels(p.test), _pixels(pairs[p.id].test))
        assert np.array_equal(np.asarray(p.H), np.asarray(pairs[p.id].H))


def test_no_window_keeps_the_fingerprint(options):
    """skip_first: null (the default) leaves every existing fingerprint as it was (tuned files carry them)."""
    assert load_dataset(options).fingerprint() == load_dataset({**options, "skip_first": None}).fingerprint()


@pytest.mark.parametrize("skip", [{"synthetc": 1}, {"synthetic": -1}, {"synthetic": 1.5}, [3], "3"])
def test_bad_window_is_one_line(options, skip):
    with pytest.raises(BadInput, match="skip_first"):
        load_dataset({**options, "skip_first": skip})
