"""Loader for a plain folder of images (no poses), for the synthetic-transform experiments.

Images directly in the root form one texture named after the root; each sub-folder with images is a texture.
Per texture, in name order, the first ``n_optimisation`` images are the optimisation split and the rest (at most
``n_synthetic``) the synthetic split; a texture with no images left over uses all of them for the synthetic split.
``max_pixels`` (null: none) downscales a larger image on load to at most that many pixels (no poses to rescale).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset, Sample, content_fingerprint, read_gray
from gtsweep.datasets.posefiles import Problems

DEFAULTS = {"textures": None, "n_optimisation": 3, "n_synthetic": None, "max_pixels": None}
NO_POSES = "data set 'folder' has no poses: it cannot give incremental pairs; use it with synthetic transforms"


def find_images(root: Path) -> dict[str, list[Path]]:
    """Image files per texture (root's own images, and one texture per sub-folder), sorted by path."""
    found: dict[str, list[Path]] = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in opts.IMAGE_SUFFIXES):
        parts = path.relative_to(root).parts
        found.setdefault(parts[0] if len(parts) > 1 else root.name, []).append(path)
    return found


def readable(paths: list[Path], problems: Problems, wanted: int | None) -> list[Path]:
    """The first ``wanted`` paths (all if None) that read as images; bad ones go to ``problems``."""
    good = []
    for path in paths:
        if wanted is not None and len(good) == wanted:
            break
        try:
            read_gray(path)
        except BadInput as error:
            problems.report(str(path), str(error))
            continue
        good.append(path)
    return good


def load(cfg: Mapping) -> Dataset:
    """Build the data set from ``cfg`` (keys of conf/dataset/folder.yaml)."""
    options = opts.read(cfg, DEFAULTS, "folder")
    root = opts.root_folder(options, "folder")
    n_opt = opts.count(options, "n_optimisation")
    n_syn = opts.count(options, "n_synthetic", allow_none=True)
    max_pixels = opts.count(options, "max_pixels", allow_none=True) or None
    found = find_images(root)
    if not found:
        raise BadInput(f"{root}: no images found ({', '.join(opts.IMAGE_SUFFIXES)})")
    problems = Problems(options["skip_bad"])
    images: dict[str, list[Sample]] = {"optimisation": [], "synthetic": []}
    textures = []
    for texture in opts.choose_textures(found, options["textures"], root):
        good = readable(found[texture], problems, None if n_syn is None else n_opt + n_syn)
        if not good:
            continue
        textures.append(texture)
        samples = [Sample(p.relative_to(root).as_posix(), texture, str(p), None, max_pixels) for p in good]
        images["optimisation"].extend(samples[:n_opt])
        rest = samples[n_opt:] or samples
        images["synthetic"].extend(rest if n_syn is None else rest[:n_syn])
    if not textures:
        raise BadInput(f"{root}: no readable image")
    fingerprint = content_fingerprint("folder", options, images, None)
    return Dataset("folder", textures, images, None, fingerprint, skipped=problems.skipped, no_pairs_reason=NO_POSES)
