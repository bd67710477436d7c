"""Memory bounded by pixels: the largest image x the workers x the grid's costliest cell per pixel (plus the driver's
copies of every image) must fit the budget; a 20000 x 20000 px PNG is refused in one line before any work, a
6000 x 4000 px image is not."""
from __future__ import annotations

import resource
import subprocess
import sys
from collections import namedtuple

import cv2
import numpy as np
import pytest

from gtsweep.core.errors import BadInput
from gtsweep.datasets.core import Sample, downscaled
from gtsweep.datasets.pixels import check_budget, grid_cost, image_pixels
from sweep_helpers import cli_env

Cell = namedtuple("Cell", "detector descriptor")
#: conf/config.yaml's grid: akaze, censure, sift x brief, orb, sift.
DEFAULT_GRID = [Cell(d, s) for d in ("akaze", "censure", "sift") for s in ("brief", "orb", "sift")]
BUDGET_24_GIB = int(0.8 * 24 * 2**30)


def test_the_costliest_cell_of_the_default_grid():
    assert grid_cost(DEFAULT_GRID) == (24 + 234 + 19, "sift+sift")
    assert grid_cost([Cell("my_declared", None)]) == (24 + 2803, "my_declared")  # unmeasured: the costliest


def test_a_6000_by_4000_image_is_not_refused_on_a_24_gb_machine():
    image = ((6000 * 4000, "big.png", (6000, 4000)), 6000 * 4000)
    check_budget(image, DEFAULT_GRID, {"backend": "ray", "num_cpus": 2}, BUDGET_24_GIB)
    check_budget(image, DEFAULT_GRID, {"backend": "serial"}, BUDGET_24_GIB)


def test_a_20000_by_20000_image_is_refused_with_need_budget_and_what_to_change():
    image = ((20000 * 20000, "huge.png", (20000, 20000)), 20000 * 20000)
    with pytest.raises(BadInput) as refused:
        check_budget(image, DEFAULT_GRID, {"backend": "serial"}, BUDGET_24_GIB)
    assert str(refused.value) == (
        "the largest image, huge.png (20000x20000 px, 400.0 Mpx as loaded), needs about 103.9 GiB (1 worker(s) x "
        "277 B/px for sift+sift, the grid's costliest cell, and the driver's copies of all images) but the memory "
        "budget is 19.2 GiB (80% of this machine's memory); downscale the images to at most 71,537,339 px (a folder "
        "data set: dataset.max_pixels=71537339), use fewer workers (runner.num_cpus) or leave out sift+sift")


@pytest.fixture(scope="module")
def huge_png(tmp_path_factory):
    """A 20000 x 20000 px gray PNG (a gradient: a few MB on disk), alone in a folder data set."""
    folder = tmp_path_factory.mktemp("huge") / "images"
    folder.mkdir()
    image = np.empty((20000, 20000), np.uint8)
    image[:] = (np.arange(20000) % 251).astype(np.uint8)
    cv2.imwrite(str(folder / "huge.png"), image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return folder


def test_the_size_is_read_from_the_header_and_max_pixels_caps_it(huge_png):
    path = str(huge_png / "huge.png")
    assert image_pixels([Sample("a", "t", path)]) == ((400_000_000, path, (20000, 20000)), 400_000_000)
    assert image_pixels([Sample("a", "t", path, None, 24_000_000)])[0][0] == 24_000_000
    assert downscaled(np.zeros((4000, 6000), np.uint8), 6_000_000).shape == (2000, 3000)


def _peak_gib_of(args: list[str], cwd) -> tuple[subprocess.CompletedProcess, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    result = subprocess.run([sys.executable, "-m", "gtsweep", *args], cwd=cwd, env=cli_env(), capture_output=True,
                            text=True, timeout=600)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    assert peak >= before
    return result, peak * 1024 / 2**30


FOLDER = ["dataset=folder", "experiment=detection", "transform=[rotation]", "transform.rotation.strengths=[0,90]",
          "runner.backend=serial", "mlflow.enabled=false", "report.plots=false", "runner.progress=false",
          "dataset.n_optimisation=0"]


@pytest.mark.slow
def test_a_folder_with_a_20000_by_20000_png_is_refused_before_work_under_4_gb(huge_png, tmp_path):
    result, peak = _peak_gib_of([f"dataset.root={huge_png}", *FOLDER], tmp_path)
    assert result.returncode == 2, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "20000x20000 px" in result.stderr, result.stderr
    assert peak < 4, peak
    assert not list(tmp_path.glob("outputs/*/*/cells/*.json")) and not (tmp_path / "mlflow.db").exists()


@pytest.mark.slow
def test_max_pixels_downscales_it_and_the_run_stays_under_4_gb(huge_png, tmp_path):
    result, peak = _peak_gib_of([f"dataset.root={huge_png}", *FOLDER, "dataset.max_pixels=24000000",
                                 "detector=[orb]"], tmp_path)
    assert result.returncode == 0, result.stderr
    assert peak < 4, peak
