"""Loader for the HD Ground layout (Schmid et al., ICRA 2022; README of ``JanFabianSchmid/HD_Ground``).

Pose files ``*.txt`` anywhere under the root list image paths with poses "a b c d e f 0 0 1" (image -> map),
on the same line or on alternating lines; a pose starting with ``*`` is marked invalid by the data set and is
left out (listed in ``Dataset.excluded``). The texture is the first folder below the root (or the file's stem
for pose files in the root). Each pose file is one recording session. ``*.test`` files (paths only) give the
extra split "test". A ``.txt`` whose first entry is not an image path (e.g. a readme) is ignored.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset
from gtsweep.datasets.pairing import POSED_DEFAULTS, posed_dataset
from gtsweep.datasets.posefiles import Problems, numbered_lines, read_hdground_poses, read_image_list

DEFAULTS = dict(POSED_DEFAULTS)


def texture_of(file: Path, root: Path) -> str:
    """First folder of ``file`` below ``root``, or the file's stem if it lies in the root."""
    parts = file.relative_to(root).parts
    return parts[0] if len(parts) > 1 else file.stem


def lists_images(file: Path) -> bool:
    """Whether the file's first non-empty line starts with an image path."""
    for _, text in numbered_lines(file):
        return text.split()[0].lower().endswith(opts.IMAGE_SUFFIXES)
    return False


def load(cfg: Mapping) -> Dataset:
    """Build the data set from ``cfg`` (keys of conf/dataset/hdground.yaml)."""
    options = opts.read(cfg, DEFAULTS, "hdground")
    root = opts.root_folder(options, "hdground")
    pose_files = [f for f in sorted(root.rglob("*.txt")) if lists_images(f)]
    if not pose_files:
        raise BadInput(f"{root}: no pose file (*.txt listing image paths and poses) found")
    by_texture: dict[str, list[Path]] = {}
    for file in pose_files:
        by_texture.setdefault(texture_of(file, root), []).append(file)
    problems = Problems(options["skip_bad"])
    entries, tests, invalid = {}, {}, []
    for texture in opts.choose_textures(by_texture, options["textures"], root):
        for file in by_texture[texture]:
            found, marked = read_hdground_poses(file, root, problems)
            entries.setdefault(texture, []).extend(found)
            invalid.extend(marked)
    for test_file in sorted(root.rglob("*.test")):
        texture = texture_of(test_file, root)
        if texture in entries:
            tests.setdefault(texture, []).extend(read_image_list(test_file, [test_file.parent, root], problems))
    entries = {t: e for t, e in entries.items() if e}
    return posed_dataset("hdground", root, options, entries, problems, extra_splits={"test": tests},
                         excluded=invalid)
