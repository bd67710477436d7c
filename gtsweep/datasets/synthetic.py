"""The embedded default data set: camera views rendered from procedural floors at known poses.

For each texture (the survey's six Micro-GPS types plus scikit-image's gravel, brick and grass photographs) a
floor much larger than one view is generated (:mod:`gtsweep.datasets.floors`), and views are cut from it with
``cv2.warpAffine`` at sampled similarity poses (x, y, θ, a small scale change for camera height), so every image
has exact ground truth. Pairs follow the survey's statistics (section 5.2): incremental pairs overlap 22.7 % on
average (some below 2 %) and turn 3° on average; absolute pairs overlap 43.7 % and turn 120° on average, and their
test image is re-lit as on another day (gamma, noise, blur, vignetting). Everything is seeded; the rendered PNGs
and an index are cached under ``<cache_dir>/datasets/<fingerprint>/``, written to a temporary folder and renamed
into place so an interrupted generation never leaves half a data set.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from gtsweep.datasets import floors, geometry
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset, Pair, Sample, fingerprint_of
from gtsweep.datasets.pairing import texture_rng
from gtsweep.errors import BadInput

GENERATOR_VERSION = 1
DEFAULTS = {
    "seed": 0,
    "cache_dir": ".gtsweep_cache",
    "textures": list(floors.FLOOR_TYPES),
    "view_size": [640, 480],
    "floor_size": 2000,
    "px_per_mm": floors.MICROGPS_PX_PER_MM,
    "n_optimisation": 3,
    "n_synthetic": 4,
    "n_incremental": 6,
    "n_absolute": 6,
    "scale_jitter": 0.02,
    "incremental": {"overlap_mean": 0.227, "overlap_min": 0.017, "overlap_max": 0.7, "rotation_mean": 3.0},
    "absolute": {"overlap_mean": 0.437, "overlap_min": 0.1, "overlap_max": 0.9, "rotation_mean": 120.0},
    "photometric": {"gamma": [0.6, 1.6], "noise_sigma": [0.0, 6.0], "blur_sigma": [0.0, 1.2],
                    "vignetting": [0.0, 0.35]},
}


def load(cfg: Mapping) -> Dataset:
    """The embedded data set of ``cfg`` (keys of conf/dataset/synthetic.yaml), rendered on first use."""
    options = opts.read(cfg, DEFAULTS, "synthetic")
    options = {**options, **{k: {**DEFAULTS[k], **(options.get(k) or {})}
                             for k in ("incremental", "absolute", "photometric")}}
    unknown = sorted(set(options["textures"]) - set(floors.FLOOR_TYPES))
    if unknown:
        raise BadInput(f"unknown texture(s) {', '.join(unknown)} for the synthetic data set; "
                       f"choices: {', '.join(floors.FLOOR_TYPES)}")
    width, height = _view_size(options)
    for key in ("n_optimisation", "n_synthetic", "n_incremental", "n_absolute"):
        opts.count(options, key)
    if options["floor_size"] < 2 * max(width, height):
        raise BadInput(f"dataset.floor_size must be at least twice the view size, got {options['floor_size']}")
    described = {k: v for k, v in options.items() if k not in ("cache_dir", "skip_bad", "root", "loader")}
    content_hash = fingerprint_of("synthetic", GENERATOR_VERSION, described)
    folder = Path(str(options["cache_dir"])).expanduser() / "datasets" / f"synthetic-{content_hash}"
    if not (folder / "index.json").exists():
        _render(options, folder)
    return _from_index(folder, content_hash)


def _view_size(options: Mapping) -> tuple[int, int]:
    size = options["view_size"]
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) and v >= 64 for v in size)):
        raise BadInput(f"dataset.view_size must be [width, height] with both >= 64, got {size!r}")
    return int(size[0]), int(size[1])


def _from_index(folder: Path, content_hash: str) -> Dataset:
    index = json.loads((folder / "index.json").read_text())

    def sample(entry) -> Sample:
        return Sample(entry["id"], entry["texture"], str(folder / entry["file"]), np.array(entry["pose"]))

    images = {split: [sample(e) for e in entries] for split, entries in index["images"].items()}
    pairs = {kind: [Pair(p["id"], p["texture"], kind, sample(p["reference"]), sample(p["test"]))
                    for p in entries] for kind, entries in index["pairs"].items()}
    return Dataset("synthetic", index["textures"], images, pairs, content_hash)


def _render(options: Mapping, folder: Path) -> None:
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}."))
    try:
        index = {"textures": list(options["textures"]), "images": {"optimisation": [], "synthetic": []},
                 "pairs": {"incremental": [], "absolute": []}}
        for texture in options["textures"]:
            _render_texture(texture, options, staging, index)
        (staging / "index.json").write_text(json.dumps(index))
        try:
            os.rename(staging, folder)
        except OSError:  # another process rendered the same data set first: keep theirs
            shutil.rmtree(staging, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _render_texture(texture: str, options: Mapping, out: Path, index: dict) -> None:
    rng = texture_rng(options["seed"], "synthetic", texture)
    side = int(options["floor_size"])
    floor = floors.make_floor(texture, rng, (side, side), float(options["px_per_mm"]))
    shape = (options["view_size"][1], options["view_size"][0])
    scatter = _PoseSampler(rng, floor.shape, shape, float(options["scale_jitter"]))

    def write(name: str, pose: np.ndarray, image: np.ndarray) -> dict:
        file = f"{texture}/{name}.png"
        (out / file).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / file), image)
        return {"id": f"{texture}/{name}", "texture": texture, "file": file, "pose": pose.tolist()}

    for split, key, tag in (("optimisation", "n_optimisation", "opt"), ("synthetic", "n_synthetic", "syn")):
        for i in range(options[key]):
            pose = scatter.single()
            index["images"][split].append(write(f"{tag}/{i:03d}", pose, render_view(floor, pose, shape)))
    for kind in ("incremental", "absolute"):
        for i in range(options[f"n_{kind}"]):
            reference, test = scatter.pair(options[kind])
            ref_image = render_view(floor, reference, shape)
            test_image = render_view(floor, test, shape)
            if kind == "absolute":
                test_image = relight(test_image, rng, options["photometric"])
            name = f"{kind}/{i:03d}"
            index["pairs"][kind].append({"id": f"{texture}/{name}", "texture": texture,
                                         "reference": write(f"{name}/reference", reference, ref_image),
                                         "test": write(f"{name}/test", test, test_image)})


def render_view(floor: np.ndarray, pose: np.ndarray, shape) -> np.ndarray:
    """The camera image at ``pose`` (image pixel -> floor pixel): ``image(p) = floor(pose @ p)``, bilinear."""
    h, w = shape
    view = cv2.warpAffine(floor, np.ascontiguousarray(pose[:2], dtype=np.float64), (w, h),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    return np.clip(np.rint(view), 0, 255).astype(np.uint8)


def relight(image: np.ndarray, rng: np.random.Generator, ranges: Mapping) -> np.ndarray:
    """A capture on another day: gamma, vignetting, blur and sensor noise drawn from ``ranges``."""
    h, w = image.shape
    values = image.astype(np.float32) / 255.0
    values = values ** rng.uniform(*ranges["gamma"])
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
    values *= 1.0 - rng.uniform(*ranges["vignetting"]) * r2
    blur = rng.uniform(*ranges["blur_sigma"])
    if blur > 0.05:
        values = cv2.GaussianBlur(values, (0, 0), blur)
    values = values * 255.0 + rng.normal(0.0, rng.uniform(*ranges["noise_sigma"]), values.shape)
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


class _PoseSampler:
    """Poses whose views lie inside the floor, singly or as pairs with a target overlap and rotation."""

    def __init__(self, rng: np.random.Generator, floor_shape, view_shape, scale_jitter: float):
        self.rng, self.view_shape, self.jitter = rng, view_shape, scale_jitter
        h, w = view_shape
        self.margin = 0.5 * math.hypot(w, h) * (1 + scale_jitter) + 2
        self.extent = (floor_shape[1] - 1 - self.margin, floor_shape[0] - 1 - self.margin)

    def _scale(self) -> float:
        return float(self.rng.uniform(1 - self.jitter, 1 + self.jitter))

    def _centre(self) -> np.ndarray:
        return self.rng.uniform((self.margin, self.margin), self.extent)

    def single(self) -> np.ndarray:
        cx, cy = self._centre()
        return geometry.centred_pose(cx, cy, float(self.rng.uniform(0, 360)), self._scale(), self.view_shape)

    def pair(self, stats: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """(reference, test) with overlap drawn around ``overlap_mean`` and |rotation| around ``rotation_mean``."""
        target = _beta_with_mean(self.rng, stats["overlap_mean"], stats["overlap_min"], stats["overlap_max"])
        rotation = _rotation_with_mean(self.rng, stats["rotation_mean"])
        theta = float(self.rng.uniform(0, 360))
        scales = self._scale(), self._scale()
        direction = self.rng.uniform(0, 2 * math.pi)
        unit = np.array([math.cos(direction), math.sin(direction)])

        def poses(distance: float, centre: np.ndarray):
            reference = geometry.centred_pose(*centre, theta, scales[0], self.view_shape)
            test_centre = centre + distance * unit
            return reference, geometry.centred_pose(*test_centre, theta + rotation, scales[1], self.view_shape)

        low, high = 0.0, 2.0 * max(self.view_shape) * (1 + self.jitter)  # overlap falls as the views part
        origin = np.zeros(2)
        for _ in range(50):
            mid = 0.5 * (low + high)
            if geometry.overlap(*poses(mid, origin), self.view_shape) > target:
                low = mid
            else:
                high = mid
        distance = 0.5 * (low + high)
        lo = np.maximum((self.margin, self.margin), np.array((self.margin,) * 2) - distance * unit)
        hi = np.minimum(self.extent, np.array(self.extent) - distance * unit)
        return poses(distance, self.rng.uniform(lo, hi))


def _beta_with_mean(rng: np.random.Generator, mean: float, low: float, high: float, concentration=6.0) -> float:
    """A draw in [low, high] from a Beta distribution whose mean (before clipping) is ``mean``."""
    a, b = mean * concentration, (1 - mean) * concentration
    return float(np.clip(rng.beta(a, b), low, high))


def _rotation_with_mean(rng: np.random.Generator, mean: float) -> float:
    """A signed rotation in degrees with mean magnitude ``mean``: exponential for small means (incremental pairs,
    mostly near 0), ``180 * Beta(k, 1)`` with mean ``180 k / (k + 1)`` for large ones (absolute pairs)."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if mean <= 30:
        return sign * float(min(rng.exponential(mean), 180.0))
    k = mean / (180.0 - mean)
    return sign * 180.0 * float(rng.beta(k, 1.0))
