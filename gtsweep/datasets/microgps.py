"""Loader for the Micro-GPS layout (Zhang et al., ICRA 2019; ``zhangaigh/micro-gps-cpp``).

``<root>/<texture>/database.txt``: per image a relative path line and a 9-value pose line (image -> map);
``<root>/<texture>/*.test``: test sequences as image paths without poses (exposed as the extra split "test").
"""
from __future__ import annotations

from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset
from gtsweep.datasets.pairing import POSED_DEFAULTS, posed_dataset
from gtsweep.datasets.posefiles import Problems, read_image_list, read_microgps_database

DEFAULTS = dict(POSED_DEFAULTS)


def load(cfg: Mapping) -> Dataset:
    """Build the data set from ``cfg`` (keys of conf/dataset/microgps.yaml)."""
    options = opts.read(cfg, DEFAULTS, "microgps")
    root = opts.root_folder(options, "microgps")
    folders = {d.name: d for d in sorted(root.iterdir()) if (d / "database.txt").is_file()}
    if (root / "database.txt").is_file():
        folders = {root.name: root}
    if not folders:
        raise BadInput(f"{root}: no texture folder with a database.txt (expected <root>/<texture>/database.txt)")
    problems = Problems(options["skip_bad"])
    entries, tests = {}, {}
    for texture in opts.choose_textures(folders, options["textures"], root):
        folder = folders[texture]
        entries[texture] = read_microgps_database(folder / "database.txt", problems)
        tests[texture] = [e for test_file in sorted(folder.glob("*.test"))
                          for e in read_image_list(test_file, [folder], problems)]
    entries = {t: e for t, e in entries.items() if e}
    return posed_dataset("microgps", root, options, entries, problems, extra_splits={"test": tests})
