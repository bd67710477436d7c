"""Memory bounded by pixels: before any work, the largest image x the workers x the grid's cost per pixel must fit
the memory budget.

A method's memory grows with the image's pixels (SIFT's upsampled float pyramid, KAZE's nonlinear scale space, a
learned network's feature maps), so a data set's image count says little: one 20000 x 20000 px image (a few MB of
PNG) needs tens of GB. :func:`check_budget` refuses such a run in one line, with the image's size, what the run
would need, the budget and what to change (``dataset.max_pixels`` of a folder data set downscales larger images on
load; or fewer workers, or another method).

The cost per pixel of each method is measured (``benchmarks/bench_pixel_memory.py``: the peak resident memory a
method adds to a process, per pixel of a 2048 x 2048 px gray image, 1024 x 1024 for the learned ones; OpenCV 5.0.0,
torch on the CPU), rounded up (``aliked_n16rot`` runs ``aliked_n16``'s network: its figure); a descriptor's figure
is what it adds after its detector ran (the learned ones describe in their detection pass). A cell also holds its
views and their transformed copies and masks: :data:`VIEW_BYTES` per pixel, an allowance, not a measurement.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Iterable, Mapping

from gtsweep.core.errors import BadInput

#: Peak bytes per image pixel a detector adds (benchmarks/bench_pixel_memory.py on this project's machine).
DETECTOR_BYTES = {"harris": 33, "gftt": 33, "fast": 8, "agast": 15, "harris_laplace": 435, "sift": 234,
                  "surf": 76, "censure": 17, "brisk": 12, "orb": 6, "akaze": 108, "kaze": 520, "mser": 62,
                  "msd": 14, "xfeat": 115, "aliked_n16": 1741, "aliked_n16rot": 1741, "disk": 2803}
#: Peak bytes per image pixel a descriptor adds after its detector ran.
DESCRIPTOR_BYTES = {"orb": 1, "brief": 2, "latch": 1, "surf": 4, "sift": 19, "akaze": 2, "brisk": 10,
                    "freak": 2, "daisy": 135, "beblid": 2, "teblid": 2, "kaze": 2, "xfeat": 0, "aliked_n16": 0,
                    "aliked_n16rot": 0, "disk": 0}
#: A cell's views (uint8), their transformed copies and masks and float working copies: an allowance per pixel.
VIEW_BYTES = 24
#: The driver holds every image of the run (uint8) and Ray's object store a copy of it: bytes per pixel.
DRIVER_BYTES = 2
#: The share of this machine's memory a run may plan to use.
BUDGET_SHARE = 0.8


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file from its header, without decoding it ((0, 0) if unreadable: the loader
    reports a bad file)."""
    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # a header is not a decompression bomb
        try:
            with Image.open(path) as image:
                return image.size
        except (OSError, ValueError):
            return 0, 0
        finally:
            Image.MAX_IMAGE_PIXELS = limit


def image_pixels(samples: Iterable) -> tuple[tuple[int, str, tuple[int, int]], int]:
    """The largest image among ``samples`` (each with ``path`` and ``max_pixels``) as (pixels as loaded, path,
    (width, height) on disk), and the pixels of all of them as loaded; ((0, "", (0, 0)), 0) without files."""
    best, total = (0, "", (0, 0)), 0
    for path, cap in {(s.path, getattr(s, "max_pixels", None)) for s in samples if s.path}:
        width, height = image_size(path)
        pixels = min(width * height, cap) if cap else width * height
        best, total = max(best, (pixels, str(path), (width, height))), total + pixels
    return best, total


def samples_of(dataset) -> list:
    """Every image sample of a data set: its splits' and its pairs' (a pair's two views)."""
    samples = [s for split in (getattr(dataset, "split_images", None) or {}).values() for s in split]
    for pairs in (getattr(dataset, "kind_pairs", None) or {}).values():
        samples += [view for pair in pairs for view in (pair.reference, pair.test)]
    return samples


def grid_cost(cells) -> tuple[int, str]:
    """Bytes per pixel of the grid's costliest cell (its detector, its descriptor and :data:`VIEW_BYTES`), and the
    cell's methods; a method without a measured figure (declared in YAML) counts as the costliest measured one."""
    def cost(table: Mapping[str, int], name) -> int:
        return 0 if name is None else table.get(name, max(table.values()))

    return max(((VIEW_BYTES + cost(DETECTOR_BYTES, c.detector) + cost(DESCRIPTOR_BYTES, getattr(c, "descriptor", None)),
                 "+".join(m for m in (c.detector, getattr(c, "descriptor", None)) if m)) for c in cells),
               default=(VIEW_BYTES, "none"))


def workers(runner: Mapping) -> int:
    """How many images are processed at once on this machine: 1 serial, else Ray's CPUs (``runner.num_cpus``, or
    all of them)."""
    if (runner.get("backend") or "ray") == "serial":
        return 1
    return int(runner.get("num_cpus") or os.cpu_count() or 1)


def memory_budget() -> int | None:
    """Bytes a run may plan to use: :data:`BUDGET_SHARE` of this machine's memory (None where the OS does not
    say)."""
    from gtsweep.datasets.options import physical_memory

    total = physical_memory()
    return None if total is None else int(total * BUDGET_SHARE)


def check_budget(images: tuple[tuple[int, str, tuple[int, int]], int], cells, runner: Mapping,
                 budget: int | None) -> None:
    """One line, before any work, when the largest image times the workers times the grid's costliest cell per
    pixel, plus the driver's copies of every image (:data:`DRIVER_BYTES`), exceeds ``budget`` bytes."""
    (pixels, path, (width, height)), total = images
    if budget is None or not pixels:
        return
    per_pixel, cell = grid_cost(cells)
    n = workers(runner)
    need = pixels * per_pixel * n + total * DRIVER_BYTES
    if need <= budget:
        return
    fits = max(0, budget - total * DRIVER_BYTES) // (per_pixel * n)
    raise BadInput(f"the largest image, {path} ({width}x{height} px, {pixels / 1e6:.1f} Mpx as loaded), needs about "
                   f"{need / 2**30:.1f} GiB ({n} worker(s) x {per_pixel} B/px for {cell}, the grid's costliest "
                   f"cell, and the driver's copies of all images) but the memory budget is {budget / 2**30:.1f} GiB "
                   f"({BUDGET_SHARE:.0%} of this machine's memory); downscale the images to at most {fits:,} px "
                   f"(a folder data set: dataset.max_pixels={fits}), use fewer workers (runner.num_cpus) or leave "
                   f"out {cell}")


def check_dataset(dataset, cells, runner: Mapping) -> None:
    """:func:`check_budget` for a loaded data set on this machine (a remote Ray cluster's nodes are not this
    machine: not checked)."""
    if runner.get("address") not in (None, "local") and (runner.get("backend") or "ray") == "ray":
        return
    check_budget(image_pixels(samples_of(dataset)), cells, runner, memory_budget())
