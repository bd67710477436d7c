"""The embedded default data set: camera views rendered from procedural floors at known poses.

Per texture a floor is generated from the seed (:mod:`gtsweep.datasets.floors`), views are placed on it
(:mod:`gtsweep.datasets.layout`) and rendered with ``cv2.warpAffine`` at their exact pose (image -> map), then
"captured" with sensor noise; absolute test views also get a different day's photometry
(:mod:`gtsweep.datasets.photometric`). With a ``capture`` group (``dataset=survey``) every view is a frame of a
moving camera instead (:mod:`gtsweep.datasets.capture`: motion blur, auto-exposure, the robot's lighting, shot
and read noise, tilt folded into the pose), and absolute test views also a capture of another ``day``. Views are written
once as PNGs with an ``index.json`` under ``<cache_dir>/datasets/synthetic-<fingerprint>/`` (built in a temporary
folder, then renamed, so an interrupted run never leaves half a data set); later loads only read the index. The
temporary folder's name holds the writer's pid: the next load removes those of writers that died (killed mid-render).
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np
import yaml

from gtsweep.core.atomic import respect_umask
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.numeric_backends import numpy_dispatch_pinned
from gtsweep.core.paths import CONF_DIR
from gtsweep.datasets import capture, floors, geometry, layout, photometric
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset, Pair, Sample, fingerprint_of
from gtsweep.datasets.pairing import texture_rng

#: Bump when rendering changes, so old caches are not reused.
GENERATOR_VERSION = 2
#: The options and their defaults, written once: conf/dataset/synthetic.yaml (its comments say what each does).
DEFAULTS = {key: value for key, value in yaml.safe_load((CONF_DIR / "dataset" / "synthetic.yaml").read_text()).items()
            if key != "loader"}
PAIR_LAWS = {kind: DEFAULTS[kind] for kind in ("incremental", "absolute")}
#: Keys added after the first release: at their default (None) they are left out of the fingerprint, so caches,
#: studies and results of configs without them stay as they were. Law keys: layout.rotation_targets.
LATER_KEYS = ("rotation_law", "crossing", "heading_noise_deg")
NEW_OPTIONS = ("separate_optimisation", "capture", "day", "skip_first")
SPLITS = ("optimisation", "synthetic", "incremental", "absolute")
#: Options that do not change the rendered content.
NOT_CONTENT = ("loader", "root", "skip_bad", "cache_dir", "name")


def check(options: dict) -> dict:
    """Validate the options; returns them with ``view_size`` as a tuple (w, h)."""
    textures = [options["textures"]] if isinstance(options["textures"], str) else list(options["textures"] or [])
    if not textures:
        raise BadInput(f"dataset.textures is empty; choices: {', '.join(floors.FLOOR_TYPES)}")
    for texture in textures:
        if texture not in floors.FLOOR_TYPES:
            raise UnknownMethod("texture of the synthetic data set", texture, floors.FLOOR_TYPES)
    size = options["view_size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2 or any(not isinstance(v, int) or v < 16 for v in size):
        raise BadInput(f"dataset.view_size must be [width, height] with integers >= 16, got {size}")
    opts.check_fits(options, {"n_optimisation": 1, "n_synthetic": 1, "n_incremental": 2, "n_absolute": 2},
                    view_bytes=int(size[0]) * int(size[1]), copies=len(textures))
    if not 0 <= float(options["scale_jitter"]) < 0.5:
        raise BadInput(f"dataset.scale_jitter must lie in [0, 0.5), got {options['scale_jitter']}")
    nested = {key: _merged(key, options[key]) for key in ("incremental", "absolute")}
    for key in ("incremental", "absolute"):
        if nested[key]["rotation_law"] not in (None, "power", "revisit"):
            raise UnknownMethod(f"dataset.{key}.rotation_law", nested[key]["rotation_law"], ("power", "revisit"))
        if nested[key]["rotation_law"] == "revisit":
            layout.revisit_weights(nested[key])
    nested["photometric"] = None if options["photometric"] is None else _merged("photometric", options["photometric"])
    nested["capture"] = capture.check(options["capture"], capture.FRAME_DEFAULTS)
    nested["day"] = capture.check(options["day"], capture.DAY_DEFAULTS)
    nested["skip_first"] = check_skip(options.get("skip_first"))
    return {**options, **nested, "textures": textures, "view_size": (int(size[0]), int(size[1]))}


def check_skip(skip) -> dict | None:
    """``skip_first``: None, or per split (:data:`SPLITS`) a count >= 0 of its first images or pairs to leave out."""
    if skip is None:
        return None
    if not isinstance(skip, Mapping) or not set(skip) <= set(SPLITS):
        raise BadInput(f"dataset.skip_first must map splits ({', '.join(SPLITS)}) to counts, got {skip}")
    for split, count in skip.items():
        if not isinstance(count, int) or isinstance(count, bool) or count < 0:
            raise BadInput(f"dataset.skip_first.{split} must be an integer >= 0, got {count!r}")
    return {k: int(v) for k, v in skip.items()}


def _kept(view: dict, skip: Mapping | None) -> bool:
    """Whether a view survives ``skip_first``: its image's or pair's number (the id's last number for an image,
    the pair's for a pair view) is at least its split's skip count."""
    if not skip:
        return True
    item = view.get("pair") or view["id"]
    return int(item.rsplit("/", 1)[1]) >= skip.get(view["split"], 0)


def _merged(key: str, given) -> dict:
    """A nested option group completed with its defaults; unknown keys raise BadInput."""
    given = dict(given or {})
    unknown = sorted(set(given) - set(DEFAULTS[key]))
    if unknown:
        raise BadInput(f"unknown key(s) dataset.{key}.{', '.join(unknown)}; valid: {', '.join(DEFAULTS[key])}")
    return {**DEFAULTS[key], **given}


def reach_px(options: Mapping) -> float:
    """How far camera tilt can move a view's corner (0 without a capture group)."""
    frame = options["capture"]
    if frame is None or float(frame["tilt_deg"]) == 0:
        return 0.0
    return capture.tilt_reach_px(float(frame["tilt_deg"]), options["view_size"],
                                 capture.focal_px(frame, options["px_per_mm"]))


def floor_side(texture: str, options: Mapping) -> int:
    """Floor side in pixels: ``floor_size``, or 4 view widths (procedural) / the upsampled photo (photos), at
    least what a pair needs (and an optimisation band, with ``separate_optimisation``)."""
    view, jitter, reach = options["view_size"], float(options["scale_jitter"]), reach_px(options)
    if options["floor_size"] is not None:
        return int(options["floor_size"])
    separate = bool(options["separate_optimisation"])
    if texture in floors.PHOTOS:
        return max(int(512 * float(options["photo_upsample"])), layout.required_side(view, jitter, separate, reach))
    return max(4 * view[0], layout.required_side(view, jitter, True, reach))


def plan_texture(texture: str, options: Mapping, floor: layout.Floor) -> list[dict]:
    """The views of one texture: dicts with id, split (or pair kind and role), pose and photometric params. Each
    split draws from its own stream and each pair from its own generator, so the first n views of a split are the
    same for any larger count (a sequential reproduction adds images without moving the earlier ones). With
    ``skip_first``, the first images or pairs of a split are drawn as always and then left out: the others keep
    their ids, poses and pixels (a reproduction computes only the images a test reads)."""
    view, jitter = options["view_size"], float(options["scale_jitter"])
    views = []
    for split, box, key in (("optimisation", floor.optimisation_box, "n_optimisation"),
                            ("synthetic", floor.main_box, "n_synthetic")):
        rng = texture_rng(options["seed"], texture, "poses", split)  # a stream per split: counts never interact
        for k, pose in enumerate(layout.single_views(rng, options[key], box, view, jitter)):
            views.append({"id": f"{texture}/{split}/{k:03d}", "split": split, "pose": pose, "params": None})
    for kind in ("incremental", "absolute"):
        rng = texture_rng(options["seed"], texture, "poses", kind)
        for k, (reference, test, target) in enumerate(
                layout.pair_views(rng, options[f"n_{kind}"], floor, view, jitter, options[kind])):
            pair_id = f"{texture}/{kind}/{k:03d}"
            params = photometric.draw(texture_rng(options["seed"], pair_id, "photometric"), options["photometric"]) \
                if kind == "absolute" and options["photometric"] is not None else None
            views.append({"id": f"{pair_id}/reference", "split": kind, "pose": reference, "params": None,
                          "pair": pair_id, "target_overlap": target})
            views.append({"id": f"{pair_id}/test", "split": kind, "pose": test, "params": params,
                          "pair": pair_id, "target_overlap": target})
    if options["capture"] is not None:
        views = [frame_of(texture, view, views, options) for view in views]
    return [view for view in views if _kept(view, options.get("skip_first"))]


def frame_of(texture: str, view: dict, views: list[dict], options: Mapping) -> dict:
    """``view`` of the pair data set as a frame of a moving camera (:func:`as_frame`); an absolute test view is
    also captured on another day.

    Travel: an incremental pair's frames are taken in sequence, so the camera moved from the reference's centre
    to the test's; other views travel in a random direction."""
    shape = options["view_size"][::-1]
    travel = None
    if view["split"] == "incremental":
        pair = [v["pose"] for v in views if v.get("pair") == view["pair"]]
        step = geometry.centre(pair[1], shape) - geometry.centre(pair[0], shape)
        local = np.linalg.inv(view["pose"][:2, :2]) @ step  # map direction -> image direction (before tilt)
        travel = float(np.degrees(np.arctan2(local[1], local[0])))
    another_day = view["split"] == "absolute" and view["id"].endswith("/test")
    return as_frame(texture, view, options, travel, another_day)


def as_frame(texture: str, view: dict, options: Mapping, travel_deg: float | None = None,
             another_day: bool = False) -> dict:
    """``view`` as a frame of a moving camera: its capture parameters (own generator per view id), the tilt folded
    into the pose (exact ground truth), the direction of travel in the image (``travel_deg``, else random) and,
    with ``another_day`` and a ``day`` group, another day's parameters (``render_frame`` applies them)."""
    rng = texture_rng(options["seed"], texture, view["id"], "frame")
    frame = capture.draw_frame(rng, options["capture"])
    shape = options["view_size"][::-1]
    travel = float(rng.uniform(0.0, 360.0))  # drawn in any case: a view's later draws never depend on its travel
    if travel_deg is not None:
        travel = travel_deg
    focal = capture.focal_px(options["capture"], options["px_per_mm"])
    tilted = view["pose"] @ capture.tilt(frame["pitch_deg"], frame["roll_deg"], shape, focal)
    day = None
    if another_day and options["day"] is not None:
        day = capture.draw_day(rng, options["day"])
    return {**view, "pose": tilted / tilted[2, 2], "frame": {**frame, "travel_deg": travel}, "day": day}


def radiance_at(floor: np.ndarray, pose: np.ndarray, shape) -> np.ndarray:
    """The floor seen at ``pose`` (float32, ``shape`` = (h, w)): ``image(p) = floor(pose @ p)`` (bicubic; a
    perspective warp when the pose holds a tilt)."""
    h, w = shape
    pose = np.asarray(pose, dtype=np.float64)
    floor = floor.astype(np.float32, copy=False)
    flags, border = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, cv2.BORDER_REFLECT
    if np.allclose(pose[2], (0.0, 0.0, 1.0), rtol=0, atol=0):
        return cv2.warpAffine(floor, pose[:2], (w, h), flags=flags, borderMode=border)
    return cv2.warpPerspective(floor, pose, (w, h), flags=flags, borderMode=border)


def render_view(floor: np.ndarray, pose: np.ndarray, shape, rng: np.random.Generator | None = None,
                sensor_noise: float = 0.0, params: Mapping | None = None) -> np.ndarray:
    """The uint8 camera image (``shape`` = (h, w)) at ``pose`` (:func:`radiance_at`), captured with
    ``sensor_noise`` and optional photometric ``params`` (see :func:`photometric.capture`)."""
    radiance = radiance_at(floor, pose, shape)
    return photometric.capture(radiance, rng if rng is not None else np.random.default_rng(0), sensor_noise, params)


def render_frame(floor: np.ndarray, view: Mapping, options: Mapping, rng: np.random.Generator) -> np.ndarray:
    """A view of a ``capture`` data set: the floor at its pose, another day's floor for an absolute test view
    (:func:`capture.day`), then the frame's capture (:func:`capture.capture`) and any photometric params."""
    shape = options["view_size"][::-1]
    radiance = radiance_at(floor, view["pose"], shape)
    if view.get("day") is not None:
        radiance = capture.day(radiance, rng, view["day"], float(options["px_per_mm"]))
    image = capture.capture(radiance, rng, view["frame"], options["capture"], float(options["px_per_mm"]),
                            view["frame"]["travel_deg"])
    return image if view["params"] is None else photometric.capture(image, rng, 0.0, view["params"])


def render_texture(texture: str, options: Mapping, folder: Path) -> list[dict]:
    """Generate the floor, render and write every view of ``texture``; returns its index records."""
    side = floor_side(texture, options)
    floor_plan = layout.plan_floor(side, options["view_size"], float(options["scale_jitter"]), reach_px(options),
                                   bool(options["separate_optimisation"]))
    floor = floors.make_floor(texture, texture_rng(options["seed"], texture, "floor"), (side, side),
                              float(options["px_per_mm"]))
    shape = options["view_size"][::-1]
    records = []
    for view in plan_texture(texture, options, floor_plan):
        noise_rng = texture_rng(options["seed"], texture, view["id"], "capture")
        image = render_view(floor, view["pose"], shape, noise_rng, float(options["sensor_noise"]), view["params"]) \
            if options["capture"] is None else render_frame(floor, view, options, noise_rng)
        file = Path("images") / f"{view['id'].replace('/', '_')}.png"
        if not cv2.imwrite(str(folder / file), image):
            raise BadInput(f"cannot write {folder / file}")
        records.append({**view, "texture": texture, "file": file.as_posix(), "pose": view["pose"].tolist(),
                        "floor_side": side})
    return records


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_dead_leftovers(folder: Path, max_age_s: float = 86400) -> None:
    """Remove the temporary folders ``.synthetic-<fingerprint>-<pid>-*`` in ``folder`` whose writer is gone (and
    those without a pid, written by older versions, after ``max_age_s``)."""
    for leftover in folder.glob(".synthetic-*"):
        parts = leftover.name.split("-")
        try:
            dead = not _alive(int(parts[2])) if len(parts) > 3 and parts[2].isdigit() else \
                time.time() - leftover.stat().st_mtime > max_age_s
        except OSError:
            continue
        if dead:
            shutil.rmtree(leftover, ignore_errors=True)


def render(options: Mapping, target: Path) -> None:
    """Render the whole data set into ``target`` atomically (temporary folder, then rename)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}-{os.getpid()}-", dir=target.parent))
    try:
        respect_umask(work, directory=True)  # mkdtemp makes it 0700, and it becomes the data set's folder
        (work / "images").mkdir()
        start = time.perf_counter()
        records = [r for texture in options["textures"] for r in render_texture(texture, options, work)]
        index = {"generator_version": GENERATOR_VERSION, "options": _content_options(options),
                 "seconds": round(time.perf_counter() - start, 3), "views": records}
        (work / "index.json").write_text(json.dumps(index, indent=1))
        try:
            os.rename(work, target)
        except OSError:
            if not (target / "index.json").is_file():  # not another process finishing first
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def _content_options(options: Mapping) -> dict:
    """What defines the rendered content; options added later are left out at their default (None)."""
    content = {k: (list(v) if isinstance(v, tuple) else v) for k, v in options.items()
               if k not in NOT_CONTENT and not (k in NEW_OPTIONS and v is None)}
    for key in ("incremental", "absolute"):
        content[key] = {k: v for k, v in content[key].items() if not (k in LATER_KEYS and v is None)}
    return content


def from_index(folder: Path, fingerprint: str, name: str = "synthetic") -> Dataset:
    """The data set described by ``folder/index.json``."""
    try:
        index = json.loads((folder / "index.json").read_text())
    except (OSError, ValueError) as error:
        raise BadInput(f"cannot read the data set cache {folder / 'index.json'}: {error}") from None
    images: dict[str, list[Sample]] = {"optimisation": [], "synthetic": []}
    by_pair: dict[str, dict[str, Sample]] = {}
    for view in index["views"]:
        sample = Sample(view["id"], view["texture"], str((folder / view["file"]).resolve()),
                        np.array(view["pose"], dtype=np.float64))
        if view["split"] in images:
            images[view["split"]].append(sample)
        else:
            by_pair.setdefault(view["pair"], {})[view["id"].rsplit("/", 1)[1]] = sample
    pairs: dict[str, list[Pair]] = {"incremental": [], "absolute": []}
    for pair_id, members in by_pair.items():
        texture, kind, _ = pair_id.split("/")
        pairs[kind].append(Pair(pair_id, texture, kind, members["reference"], members["test"]))
    textures = list(index["options"]["textures"])
    return Dataset(str(name), textures, images, pairs, fingerprint)


def _unpinned_paths() -> tuple[str, ...]:
    """What the fingerprint adds in a process whose NumPy runs its AVX-512 loops (imported before gtsweep): such a
    process renders some views to other bytes, so its data set is another, cached and hashed apart."""
    return () if numpy_dispatch_pinned() else ("numpy AVX-512 loops",)


def load(cfg: Mapping) -> Dataset:
    """The embedded data set for ``cfg`` (keys of conf/dataset/synthetic.yaml), rendered on first use."""
    options = check(opts.read(cfg, DEFAULTS, "synthetic"))
    fingerprint = fingerprint_of(GENERATOR_VERSION, _content_options(options), *_unpinned_paths())
    folder = Path(str(options["cache_dir"])).expanduser() / "datasets" / f"synthetic-{fingerprint}"
    if folder.parent.is_dir():
        remove_dead_leftovers(folder.parent)
    if not (folder / "index.json").is_file():
        render(options, folder)
    return from_index(folder, fingerprint, options.get("name") or "synthetic")


def generation_seconds(dataset: Dataset, cache_dir: str | Path) -> float | None:
    """Rendering time recorded in the cache index of ``dataset`` (None if unknown)."""
    index = Path(cache_dir) / "datasets" / f"synthetic-{dataset.fingerprint()}" / "index.json"
    try:
        return float(json.loads(index.read_text())["seconds"])
    except (OSError, ValueError, KeyError):
        return None
