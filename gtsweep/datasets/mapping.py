"""Data for absolute localization against a map (Micro-GPS, Zhang et al. ICRA 2019): a posed mapping run per
texture and queries, some of them from a floor that is not in the map.

- **Embedded** (``dataset=synthetic``): per texture a floor is generated (:mod:`gtsweep.datasets.floors`) and a
  mapping run rendered over it: views on a grid with ``map_overlap`` overlap between neighbours (small heading
  jitter, the data set's scale jitter), exact poses, ordered by distance from the floor's centre so that the map of
  the first ``n`` images is compact and the maps of ``map_images`` are nested. Queries are captured on "another day"
  (the absolute pairs' photometric block: gamma, gain, blur, vignetting, noise), any heading, centred inside the
  smallest map's area (``photometric: null``: no change). With a ``capture`` group (``dataset=survey``) every view
  is a frame of the moving camera instead, drawn as the pair data set's (:func:`synthetic.as_frame`: blur,
  exposure, lighting, sensor noise, tilt folded into the exact pose) and queries also on another ``day``; *foreign*
  queries are rendered the same way from another floor of the same texture (another
  seed; a photo floor mirrored) and must be rejected. Rendered once into
  ``<cache_dir>/datasets/mapping-<fingerprint>/`` (temporary folder, then renamed).
- **Micro-GPS** (``database.txt``) and **HD Ground** (``*.txt`` pose files): the posed images of a texture are its
  map, ``n_queries`` of them (evenly spaced) are held out as posed queries, images of the ``*.test`` lists are
  queries without ground truth (``n_unposed`` at most), and held-out images of another texture are foreign queries.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from gtsweep.core.atomic import respect_umask
from gtsweep.core.errors import BadInput
from gtsweep.datasets import floors, geometry, layout, photometric, synthetic
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Sample, fingerprint_of
from gtsweep.datasets.hdground import lists_images, texture_of
from gtsweep.datasets.pairing import texture_rng
from gtsweep.datasets.posefiles import Problems, read_hdground_poses, read_image_list, read_microgps_database

GENERATOR_VERSION = 1
#: The version of data sets with a ``capture`` group (their maps once ignored it and rendered without its physics):
#: bumped on its own so that the caches and fingerprints of the default data set stay as they were.
CAPTURE_GENERATOR_VERSION = 2
#: Options of the localization data (``experiment.*`` of conf/experiment/localization.yaml).
DEFAULTS = {"map_images": [4, 16], "map_overlap": 0.5, "n_queries": 4, "n_foreign": 2, "n_unposed": 10,
            "textures": None, "px_per_mm": None}
LOADERS = ("synthetic", "microgps", "hdground")
#: The floors mapped on the embedded data set when ``experiment.textures`` is null (a real data set: every floor
#: found, or ``dataset.textures``): one asphalt, one concrete, one wood, three floors of different character.
EMBEDDED_TEXTURES = ("fine_asphalt", "concrete", "wood")
#: Micro-GPS resolution (30 px = 4.8 mm).
MICROGPS_PX_PER_MM = floors.MICROGPS_PX_PER_MM


@dataclass(frozen=True)
class Query:
    """A query image to localize in the map of ``texture``; ``sample.pose`` is its true image -> map pose (None
    without ground truth); ``in_map`` False: taken on a floor that is not in the map."""

    sample: Sample
    texture: str
    in_map: bool


@dataclass
class LocalizationData:
    """Per texture the mapping images in map order (the map of size n is the first n), and the queries."""

    name: str
    maps: dict[str, list[Sample]]
    queries: list[Query]
    map_sizes: list[int]
    px_per_mm: float
    fingerprint: str

    def sizes(self, texture: str) -> list[int]:
        """The map sizes of ``texture`` (capped at its number of mapping images)."""
        total = len(self.maps[texture])
        return sorted({min(n, total) for n in self.map_sizes}) if self.map_sizes else [total]


def check(options: Mapping) -> dict:
    """The localization options completed with their defaults; BadInput for an unknown key or a bad value."""
    options = dict(options or {})
    merged = {**DEFAULTS, **{k: v for k, v in options.items() if k in DEFAULTS}}
    sizes = merged["map_images"]
    sizes = [sizes] if isinstance(sizes, int) else sizes
    if sizes is not None and (not isinstance(sizes, list) or not sizes or
                              any(isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 400 for n in sizes)):
        raise BadInput(f"experiment.map_images must be a list of integers in [1, 400] (or null: every posed "
                       f"image), got {merged['map_images']!r}")
    merged["map_images"] = sorted(set(sizes)) if sizes else None
    if not 0 <= float(merged["map_overlap"]) < 0.95:
        raise BadInput(f"experiment.map_overlap must lie in [0, 0.95), got {merged['map_overlap']!r}")
    for key in ("n_queries", "n_foreign", "n_unposed"):
        opts.count(merged, key)
    if merged["px_per_mm"] is not None and not float(merged["px_per_mm"]) > 0:
        raise BadInput(f"experiment.px_per_mm must be > 0 or null, got {merged['px_per_mm']!r}")
    return merged


def load_localization(dataset_cfg: Mapping, options: Mapping) -> LocalizationData:
    """The map and queries for ``dataset_cfg`` (a ``dataset`` node) and the localization ``options``."""
    dataset = opts.plain(dataset_cfg)
    loader = dataset.get("loader")
    if loader not in LOADERS:
        raise BadInput(f"experiment=localization needs dataset.loader in {', '.join(LOADERS)} (posed mapping "
                       f"images), got {loader!r}")
    options = check(options)
    if loader == "synthetic":
        return _synthetic(dataset, options)
    return _posed(loader, dataset, options)


# ------------------------------------------------------------------------------------------------ embedded
def map_poses(rng: np.random.Generator, n: int, view_size, overlap: float, jitter: float, centre) -> list:
    """``n`` mapping poses on a grid around ``centre`` (stride = (1 - overlap) x view), nearest to it first."""
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    stride = (1 - overlap) * np.asarray(view_size, dtype=np.float64)
    grid = np.stack(np.meshgrid(np.arange(cols) - (cols - 1) / 2, np.arange(rows) - (rows - 1) / 2), -1)
    offsets = grid.reshape(-1, 2) * stride
    order = np.lexsort((np.arctan2(offsets[:, 1], offsets[:, 0]), np.round(np.hypot(*offsets.T), 6)))[:n]
    shape = (view_size[1], view_size[0])
    return [geometry.centred_pose(*(np.asarray(centre) + offsets[i]), rng.normal(0.0, 3.0),
                                  rng.uniform(1 - jitter, 1 + jitter), shape) for i in order]


def _floor_side(options: Mapping) -> int:
    view, jitter = options["view_size"], float(options["scale_jitter"])
    n = max(options["map_images"])
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    extent = (1 - float(options["map_overlap"])) * np.array([view[0] * (cols - 1), view[1] * (rows - 1)])
    return int(math.ceil(extent.max() + 2 * layout.footprint_radius(view, jitter, synthetic.reach_px(options)) + 8))


def _plan(texture: str, options: Mapping, side: int) -> list[dict]:
    rng = texture_rng(options["seed"], texture, "mapping")
    view, jitter = options["view_size"], float(options["scale_jitter"])
    shape = (view[1], view[0])
    mapping = map_poses(rng, max(options["map_images"]), view, float(options["map_overlap"]), jitter,
                        (side / 2, side / 2))
    smallest = np.array([geometry.centre(p, shape) for p in mapping[:min(options["map_images"])]])
    box = (*smallest.min(axis=0), *smallest.max(axis=0))
    views = [{"id": f"{texture}/map/{k:04d}", "role": "map", "pose": pose, "params": None}
             for k, pose in enumerate(mapping)]
    for role, count in (("query", options["n_queries"]), ("foreign", options["n_foreign"])):
        for k in range(count):
            pose = geometry.centred_pose(*layout.uniform_in(rng, box), rng.uniform(0, 360),
                                         rng.uniform(1 - jitter, 1 + jitter), shape)
            params = None if options["photometric"] is None else photometric.draw(rng, options["photometric"])
            views.append({"id": f"{texture}/{role}/{k:03d}", "role": role, "pose": pose, "params": params})
    if options["capture"] is None:
        return views
    # frames of a moving camera, as the pair data set's views; queries are captured on another day
    return [synthetic.as_frame(texture, v, options, another_day=v["role"] != "map") for v in views]


def _render_texture(texture: str, options: Mapping, folder: Path) -> list[dict]:
    side = _floor_side(options)
    ppm = float(options["px_per_mm"])
    floor = floors.make_floor(texture, texture_rng(options["seed"], texture, "floor"), (side, side), ppm)
    if texture in floors.PHOTOS:  # one photograph per texture: another floor is its mirror image
        foreign = np.ascontiguousarray(floor[:, ::-1].T)
    else:
        foreign = floors.make_floor(texture, texture_rng(options["seed"], texture, "foreign floor"), (side, side),
                                    ppm)
    records = []
    for view in _plan(texture, options, side):
        rng = texture_rng(options["seed"], texture, view["id"], "capture")
        seen = foreign if view["role"] == "foreign" else floor
        image = synthetic.render_view(seen, view["pose"], options["view_size"][::-1], rng,
                                      float(options["sensor_noise"]), view["params"]) \
            if options["capture"] is None else synthetic.render_frame(seen, view, options, rng)
        file = Path("images") / f"{view['id'].replace('/', '_')}.png"
        if not cv2.imwrite(str(folder / file), image):
            raise BadInput(f"cannot write {folder / file}")
        records.append({**view, "texture": texture, "file": file.as_posix(), "pose": view["pose"].tolist()})
    return records


def embedded_textures(options: Mapping) -> list[str]:
    """The floors to map on the embedded data set: ``experiment.textures``, else :data:`EMBEDDED_TEXTURES`."""
    textures = options["textures"] or EMBEDDED_TEXTURES
    return [textures] if isinstance(textures, str) else list(textures)


def _synthetic(dataset: Mapping, options: dict) -> LocalizationData:
    base = synthetic.check(opts.read(dataset, synthetic.DEFAULTS, "synthetic"))
    textures = embedded_textures(options)
    synthetic.check({**base, "textures": textures})
    sizes = options["map_images"] or DEFAULTS["map_images"]
    content = {k: v for k, v in base.items() if k not in synthetic.NOT_CONTENT and k not in (
        "textures", "n_optimisation", "n_synthetic", "n_incremental", "n_absolute", "incremental", "absolute")}
    content = {**{k: list(v) if isinstance(v, tuple) else v for k, v in content.items()}, "textures": textures,
               **{k: options[k] for k in ("map_overlap", "n_queries", "n_foreign")}, "map_images": sizes}
    fingerprint = fingerprint_of("mapping", _version(base), content)
    folder = Path(str(base["cache_dir"])).expanduser() / "datasets" / f"mapping-{fingerprint}"
    if not (folder / "index.json").is_file():
        _render(folder, {**base, **content, "view_size": base["view_size"]})
    index = json.loads((folder / "index.json").read_text())
    maps: dict[str, list[Sample]] = {t: [] for t in textures}
    queries = []
    for view in index["views"]:
        path = str((folder / view["file"]).resolve())
        pose = np.array(view["pose"], dtype=np.float64)
        if view["role"] == "map":
            maps[view["texture"]].append(Sample(view["id"], view["texture"], path, pose))
        else:
            own = view["role"] == "query"
            queries.append(Query(Sample(view["id"], view["texture"], path, pose if own else None), view["texture"],
                                 own))
    ppm = float(options["px_per_mm"] or base["px_per_mm"])
    return LocalizationData("synthetic", maps, queries, sizes, ppm, fingerprint)


def _version(options: Mapping) -> int:
    return GENERATOR_VERSION if options["capture"] is None else CAPTURE_GENERATOR_VERSION


def _render(folder: Path, options: Mapping) -> None:
    folder.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{folder.name}-{os.getpid()}-", dir=folder.parent))
    try:
        respect_umask(work, directory=True)
        (work / "images").mkdir()
        views = [r for texture in options["textures"] for r in _render_texture(texture, options, work)]
        (work / "index.json").write_text(json.dumps({"generator_version": _version(options), "views": views}))
        try:
            os.rename(work, folder)
        except OSError:
            if not (folder / "index.json").is_file():
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


# ------------------------------------------------------------------------------------------- real data sets
def _posed(loader: str, dataset: Mapping, options: dict) -> LocalizationData:
    root = opts.root_folder(dataset, loader)
    problems = Problems(bool(dataset.get("skip_bad", False)))
    posed, tests = {}, {}
    if loader == "microgps":
        folders = {d.name: d for d in sorted(root.iterdir()) if (d / "database.txt").is_file()}
        if (root / "database.txt").is_file():
            folders = {root.name: root}
        for texture, folder in folders.items():
            posed[texture] = read_microgps_database(folder / "database.txt", problems)
            tests[texture] = [e for f in sorted(folder.glob("*.test")) for e in read_image_list(f, [folder], problems)]
    else:
        for file in [f for f in sorted(root.rglob("*.txt")) if lists_images(f)]:
            found, _ = read_hdground_poses(file, root, problems)  # poses marked invalid ("*") are left out
            posed.setdefault(texture_of(file, root), []).extend(found)
        for file in sorted(root.rglob("*.test")):
            tests.setdefault(texture_of(file, root), []).extend(read_image_list(file, [file.parent, root], problems))
    wanted = options["textures"] or dataset.get("textures")
    textures = opts.choose_textures({t for t, e in posed.items() if e}, wanted, root)
    if not textures:
        raise BadInput(f"{root}: no posed images found for a map")
    maps, held = {}, {}
    for texture in textures:
        entries = posed[texture]
        picks = np.unique(np.linspace(0, len(entries) - 1, options["n_queries"] + 2).round().astype(int)[1:-1]) \
            if options["n_queries"] and len(entries) > 2 else np.zeros(0, int)
        held[texture] = [entries[i] for i in picks]
        kept = np.setdiff1d(np.arange(len(entries)), picks)
        maps[texture] = [Sample(f"{texture}/{entries[i].listed_as}", texture, str(entries[i].path), entries[i].pose)
                         for i in kept]
    queries = [Query(Sample(f"{t}/{e.listed_as}", t, str(e.path), e.pose), t, True) for t in textures
               for e in held[t]]
    queries += [Query(Sample(f"{t}/{e.listed_as}", t, str(e.path), None), t, True) for t in textures
                for e in tests.get(t, [])[:options["n_unposed"]]]
    for k, texture in enumerate(textures):  # another texture's held-out images are not in this map
        others = [(t, e) for t in textures[k + 1:] + textures[:k] for e in held[t]][:options["n_foreign"]]
        queries += [Query(Sample(f"{t}/{e.listed_as}", texture, str(e.path), None), texture, False)
                    for t, e in others]
    ppm = float(options["px_per_mm"] or (MICROGPS_PX_PER_MM if loader == "microgps" else math.nan))
    listed = {t: [[s.id, s.path, np.round(s.pose, 9)] for s in maps[t]] for t in textures}
    asked = [[q.sample.id, q.texture, q.in_map] for q in queries]
    return LocalizationData(loader, maps, queries, options["map_images"], ppm,
                            fingerprint_of(loader, listed, asked, {k: v for k, v in options.items()}))


def covered_area(poses, shape) -> float:
    """Floor area (map px²) covered by the footprints of ``poses`` (images of ``shape``): their union rasterised
    with cells of ``step`` px, ``step`` chosen to keep the raster near 4 million cells (1 px for small maps)."""
    corners = np.concatenate([geometry.footprint(p, shape) for p in poses]).astype(np.float64)
    low = corners.min(axis=0)
    step = max(1.0, math.ceil(math.sqrt(np.prod(corners.max(axis=0) - low) / 4e6)))
    size = (np.ceil((corners.max(axis=0) - low) / step) + 2).astype(int)
    canvas = np.zeros((size[1], size[0]), np.uint8)
    for pose in poses:
        cv2.fillConvexPoly(canvas, np.rint((geometry.footprint(pose, shape) - low) / step).astype(np.int32), 1)
    return float(canvas.sum()) * step * step
