"""Data sets: the embedded default's exact ground truth, determinism, cache and pair statistics; each loader on a
generated fixture in its layout, with the bad-input cases."""
from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

import dataset_fixtures as fx
from gtsweep.datasets import __main__ as stats_command
from gtsweep.datasets import load_dataset, overlap, rotation_deg, synthetic
from gtsweep.errors import BadInput, UnknownMethod

SMALL = {"loader": "synthetic", "textures": ["concrete", "gravel"], "view_size": [160, 120], "floor_size": 800,
         "n_optimisation": 1, "n_synthetic": 1, "n_incremental": 3, "n_absolute": 3}


def small(tmp_path, **over):
    return load_dataset({**SMALL, "cache_dir": str(tmp_path), **over})


# --- the embedded data set ---------------------------------------------------------------------------------------

def test_ground_truth_is_exact(tmp_path):
    dataset = small(tmp_path)
    for pair in dataset.pairs("incremental"):
        ref, test = pair.reference.load(), pair.test.load()
        h, w = test.shape
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)

        def error(H):
            mapped = H @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
            mx, my = (mapped[:2] / mapped[2]).reshape(2, h, w).astype(np.float32)
            inside = (mx >= 1) & (mx <= w - 2) & (my >= 1) & (my <= h - 2)
            warped = cv2.remap(ref.astype(np.float32), mx, my, cv2.INTER_LINEAR)
            return np.abs(warped - test)[inside].mean(), inside.sum()

        exact, n = error(pair.H)
        shifted, _ = error(pair.H @ np.array([[1, 0, 2.0], [0, 1, 0], [0, 0, 1]]))
        if n < 200:  # an almost non-overlapping pair: too few pixels to judge
            continue
        assert exact < 2.0 and shifted > 4 * exact, (pair.id, exact, shifted)


def test_same_seed_same_bytes_other_seed_other_images(tmp_path):
    a, b = small(tmp_path / "a"), small(tmp_path / "b")
    c = small(tmp_path / "c", seed=1)
    first = [s.load().tobytes() for s in a.images("synthetic")]
    assert first == [s.load().tobytes() for s in b.images("synthetic")]
    assert first != [s.load().tobytes() for s in c.images("synthetic")]
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()


def test_second_load_reads_the_cache(tmp_path, monkeypatch):
    small(tmp_path)
    monkeypatch.setattr(synthetic, "_render", lambda *a: pytest.fail("rendered twice"))
    again = small(tmp_path)
    assert len(again.pairs("absolute")) == 3 * 2
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith(".synthetic-")]  # no staging left behind


def test_pair_statistics_follow_the_survey(tmp_path):
    dataset = small(tmp_path, textures=["wood"], n_incremental=60, n_absolute=60, n_synthetic=0)
    stats = stats_command.pair_statistics(dataset)
    assert abs(stats["incremental"]["overlap_mean"] - 0.227) < 0.05
    assert stats["incremental"]["overlap_min"] < 0.05 and abs(stats["incremental"]["rotation_mean"] - 3) < 1.5
    assert abs(stats["absolute"]["overlap_mean"] - 0.437) < 0.07
    assert abs(stats["absolute"]["rotation_mean"] - 120) < 20
    assert "0.227" in stats_command.format_statistics("synthetic", stats)


def test_views_stay_inside_the_floor_and_absolute_tests_are_relit(tmp_path):
    dataset = small(tmp_path)
    for pair in dataset.pairs("absolute"):
        assert overlap(pair.reference.pose, pair.test.pose, (120, 160)) >= 0.1
        assert 0 <= rotation_deg(pair.reference.pose, pair.test.pose) <= 180
    with pytest.raises(BadInput, match="unknown texture"):
        small(tmp_path, textures=["marble"])


def test_stats_command(tmp_path, capsys):
    overrides = [f"dataset.cache_dir={tmp_path}", "dataset.textures=[tiles]", "dataset.view_size=[160,120]",
                 "dataset.floor_size=800", "dataset.n_incremental=4", "dataset.n_absolute=4"]
    assert stats_command.main(overrides) == 0
    assert "incremental" in capsys.readouterr().out
    assert stats_command.main(["dataset=microgps", f"dataset.root={tmp_path}/missing"]) == 2
    assert "does not exist" in capsys.readouterr().err


# --- loaders ---------------------------------------------------------------------------------------------------

POSED = {"n_optimisation": 1, "n_synthetic": 2, "n_incremental": 3, "n_absolute": 2, "absolute_min_gap": 4}


def _check_pairs_are_exact(dataset):
    """Every pair's H maps test pixels onto the same floor point as the reference (poses were used to render)."""
    for kind in ("incremental", "absolute"):
        for pair in dataset.pairs(kind):
            assert pair.reference.load().shape == pair.test.load().shape == fx.VIEW
            assert overlap(pair.reference.pose, pair.test.pose, fx.VIEW) > 0
            centre = np.array([31.5, 23.5, 1.0])
            np.testing.assert_allclose(pair.reference.pose @ pair.H @ centre, pair.test.pose @ centre, atol=1e-9)


def test_microgps_layout(tmp_path):
    fx.microgps(tmp_path)
    dataset = load_dataset({"loader": "microgps", "root": str(tmp_path), **POSED})
    assert dataset.textures == ["carpet"]
    assert len(dataset.images("optimisation")) == 1 and len(dataset.images("synthetic")) == 2
    assert len(dataset.pairs("incremental")) == 3 and len(dataset.pairs("absolute")) >= 1
    assert len(dataset.images("test")) == 1 and dataset.images("test")[0].pose is None
    _check_pairs_are_exact(dataset)


def test_hdground_layout_both_line_styles_and_invalid_poses(tmp_path):
    fx.hdground(tmp_path)
    dataset = load_dataset({"loader": "hdground", "root": str(tmp_path), **POSED})
    assert dataset.textures == ["office_carpet"]
    assert len(dataset.excluded) == 1 and "marked invalid" in dataset.excluded[0]
    listed = {s.id for split in ("optimisation", "synthetic") for s in dataset.images(split)}
    listed |= {p.reference.id for k in ("incremental", "absolute") for p in dataset.pairs(k)}
    assert not any(i.endswith("i0000009.png") for i in listed)  # the invalid pose's image is never used
    _check_pairs_are_exact(dataset)


def test_csv_layout(tmp_path):
    fx.csv_poses(tmp_path)
    dataset = load_dataset({"loader": "csv", "root": str(tmp_path / "poses.csv"), **POSED})
    assert len(dataset.pairs("incremental")) == 3
    _check_pairs_are_exact(dataset)


def test_folder_layout_has_images_but_no_pairs(tmp_path):
    fx.image_folder(tmp_path)
    dataset = load_dataset({"loader": "folder", "root": str(tmp_path), "n_optimisation": 1})
    assert dataset.textures == ["asphalt", "wood"]
    assert len(dataset.images("optimisation")) == 2 and len(dataset.images("synthetic")) == 6
    with pytest.raises(BadInput, match="no poses"):
        dataset.pairs("incremental")


# --- bad input ---------------------------------------------------------------------------------------------------

def test_missing_and_empty_folders(tmp_path):
    for loader in ("microgps", "hdground", "folder"):
        with pytest.raises(BadInput, match="does not exist"):
            load_dataset({"loader": loader, "root": str(tmp_path / "nope")})
        (tmp_path / loader).mkdir()
        with pytest.raises(BadInput, match=str(tmp_path / loader)):
            load_dataset({"loader": loader, "root": str(tmp_path / loader)})
    with pytest.raises(UnknownMethod, match="dataset loader"):
        load_dataset({"loader": "kitti"})
    with pytest.raises(BadInput, match="dataset.root is required"):
        load_dataset({"loader": "microgps", "root": "???"})


def _broken_microgps(tmp_path, problem: str):
    database = fx.microgps(tmp_path)
    lines = database.read_text().splitlines()
    if problem == "corrupt image":
        (database.parent / lines[4]).write_bytes(b"not an image at all")
    elif problem == "eight values":
        lines[5] = " ".join(lines[5].split()[:8])
    elif problem == "missing image":
        os.remove(database.parent / lines[6])
    database.write_text("\n".join(lines) + "\n")
    return database


@pytest.mark.parametrize("problem, message, line", [
    ("eight values", "9", 6), ("missing image", "does not exist", 7), ("corrupt image", "cannot read image", None)])
def test_bad_items_name_file_and_line_or_are_skipped(tmp_path, problem, message, line):
    database = _broken_microgps(tmp_path, problem)
    options = {"loader": "microgps", "root": str(tmp_path), **POSED, "n_synthetic": 9, "n_optimisation": 0}
    with pytest.raises(BadInput) as error:
        load_dataset(options)
    text = str(error.value)
    assert message in text and "\n" not in text
    if line is not None:
        assert f"{database}:{line}" in text
    dataset = load_dataset({**options, "skip_bad": True})
    assert len(dataset.skipped) == 1 and message in dataset.skipped[0]
    assert len(dataset.images("synthetic")) == 9
