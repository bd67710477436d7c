"""Data set loaders on generated fixtures in their layouts (Micro-GPS, HD Ground, CSV, plain folder), including
the bad-input cases: missing or empty folder, corrupt image, pose line with 8 values, missing image, skip_bad."""
from __future__ import annotations

import os

import pytest

import dataset_fixtures as fx
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.datasets import load_dataset, overlap

POSED = {"n_optimisation": 1, "n_synthetic": 2, "n_incremental": 3, "n_absolute": 2, "absolute_min_gap": 4}


def _check_pairs_are_exact(dataset):
    """Each pair's H (from the listed poses) maps test pixels onto reference pixels of the same intensity: the
    fixture's images were rendered from one floor at those poses."""
    judged = 0
    for kind in ("incremental", "absolute"):
        for pair in dataset.pairs(kind):
            reference, test = pair.reference.load(), pair.test.load()
            assert reference.shape == test.shape == fx.VIEW
            assert overlap(pair.reference.pose, pair.test.pose, fx.VIEW) > 0
            exact, n = fx.transfer_error(reference, test, pair.H)
            if n >= 100:
                judged += 1
                assert exact < 2.0 < fx.transfer_error(reference, test, pair.H @ fx.SHIFT_2PX)[0], pair.id
    assert judged > 0


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


def test_hdground_pose_with_eight_values_names_file_and_line(tmp_path):
    first, _ = fx.hdground(tmp_path)
    lines = first.read_text().splitlines()
    lines[2] = lines[2].rsplit(" ", 1)[0]  # drop the trailing "1": 8 pose values on the same line
    first.write_text("\n".join(lines) + "\n")
    options = {"loader": "hdground", "root": str(tmp_path), **POSED}
    with pytest.raises(BadInput, match=f"{first}:3: pose needs 9 values, found 8"):
        load_dataset(options)
    dataset = load_dataset({**options, "skip_bad": True})
    assert dataset.skipped == [f"{first}:3: pose needs 9 values, found 8"]


def test_csv_bad_rows(tmp_path):
    file = fx.csv_poses(tmp_path)
    lines = file.read_text().splitlines()
    lines[3] = "missing.png,1,2,3"
    lines[5] = "img004.png,1,2"
    file.write_text("\n".join(lines) + "\n")
    options = {"loader": "csv", "root": str(tmp_path), **POSED}  # the folder holding one CSV works too
    with pytest.raises(BadInput, match=f"{file}:4: image missing.png does not exist"):
        load_dataset(options)
    dataset = load_dataset({**options, "skip_bad": True})
    assert [s.split(": ")[0] for s in dataset.skipped] == [f"{file}:4", f"{file}:6"]
    assert "found 3 values" in dataset.skipped[1]


def test_folder_corrupt_image_is_named_or_skipped(tmp_path):
    fx.image_folder(tmp_path)
    bad = tmp_path / "wood" / "01.png"
    bad.write_bytes(b"\x89PNG but truncated")
    options = {"loader": "folder", "root": str(tmp_path), "n_optimisation": 1}
    with pytest.raises(BadInput, match=f"cannot read image {bad}"):
        load_dataset(options)
    dataset = load_dataset({**options, "skip_bad": True})
    assert len(dataset.skipped) == 1 and str(bad) in dataset.skipped[0]
    assert len(dataset.images("synthetic", textures=["wood"])) == 2
    assert [s.id for s in dataset.images("optimisation", limit=1)] == ["asphalt/00.png", "wood/00.png"]


def test_microgps_pose_file_without_poses_at_the_end(tmp_path):
    database = fx.microgps(tmp_path)
    database.write_text(database.read_text() + "database/frame000000.pgm\n")
    with pytest.raises(BadInput, match=f"{database}:21: image database/frame000000.pgm has no pose line"):
        load_dataset({"loader": "microgps", "root": str(tmp_path), **POSED})


def test_loader_options_are_checked(tmp_path):
    fx.image_folder(tmp_path)
    with pytest.raises(BadInput, match="dataset loader 'folder' has no parameter 'n_pairs'"):
        load_dataset({"loader": "folder", "root": str(tmp_path), "n_pairs": 3})
    with pytest.raises(BadInput, match="no texture granite"):
        load_dataset({"loader": "folder", "root": str(tmp_path), "textures": ["granite"]})
