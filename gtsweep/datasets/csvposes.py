"""Loader for a CSV of posed images: rows ``image,x,y,theta[,scale]`` (an optional header row may name the
columns, and may add a ``texture`` column).

``image`` is relative to the CSV's folder; (x, y) is the map position of the image's pixel (0, 0) (the pose's
translation, as in HD Ground); ``theta`` is the Micro-GPS orientation in degrees; ``scale`` (default 1) is map
pixels per image pixel. Without a texture column the texture is the image's first folder (or the CSV's folder
name). The CSV is one recording session: pairs are built as for Micro-GPS.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import Dataset
from gtsweep.datasets.geometry import similarity_pose
from gtsweep.datasets.pairing import POSED_DEFAULTS, posed_dataset
from gtsweep.datasets.posefiles import Entry, Problems, finite, floats, resolve_image

DEFAULTS = dict(POSED_DEFAULTS)
COLUMNS = ("image", "x", "y", "theta", "scale")


def csv_file(root: Path) -> Path:
    """``root`` if it is a file, else the single ``*.csv`` inside the folder."""
    if not root.exists():
        raise BadInput(f"data set file {root} does not exist")
    if root.is_file():
        return root
    found = sorted(root.glob("*.csv"))
    if len(found) != 1:
        raise BadInput(f"{root}: expected one *.csv file, found {len(found)}")
    return found[0]


def read_rows(file: Path, problems: Problems) -> dict[str, list[Entry]]:
    """Posed entries per texture, in file order; bad rows and missing images go to ``problems``."""
    try:
        with file.open(newline="", encoding="utf-8") as handle:
            rows = [(n, [c.strip() for c in row]) for n, row in enumerate(csv.reader(handle), 1) if any(row)]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise BadInput(f"cannot read {file}: {error}") from None
    columns = list(COLUMNS)
    first = rows[0][1] if rows else []
    if len(first) > 1 and all(floats([cell]) is None for cell in first[1:4]):  # a header: no number in x, y, theta
        columns = [c.lower() for c in rows.pop(0)[1]]
        if columns[:4] != list(COLUMNS[:4]):
            raise BadInput(f"{file}:1: header must start with image,x,y,theta, found {','.join(columns)}")
    entries: dict[str, list[Entry]] = {}
    for number, cells in rows:
        where = f"{file}:{number}"
        if len(cells) not in (4, 5, 6) or len(cells) > len(columns):
            problems.report(where, f"expected {','.join(columns[:4])}[,{','.join(columns[4:])}], "
                                   f"found {len(cells)} values")
            continue
        row = dict(zip(columns, cells))
        values = floats([row["x"], row["y"], row["theta"], row.get("scale") or "1"])
        if not finite(values) or values[3] <= 0:
            found = ",".join(cells[1:])
            problems.report(where, f"x, y, theta, scale must be finite numbers (scale > 0), found {found}")
            continue
        path = resolve_image(row["image"], [file.parent])
        if path is None:
            problems.report(where, f"image {row['image']} does not exist")
            continue
        parts = Path(row["image"]).parts
        texture = row.get("texture") or (parts[0] if len(parts) > 1 else file.parent.name)
        found = entries.setdefault(texture, [])
        found.append(Entry(path, row["image"], similarity_pose(*values), where, str(file), len(found)))
    return entries


def load(cfg: Mapping) -> Dataset:
    """Build the data set from ``cfg`` (keys of conf/dataset/csv.yaml); ``root`` is the CSV or its folder."""
    options = opts.read(cfg, DEFAULTS, "csv")
    if options["root"] in (None, ""):
        raise BadInput("dataset.root is required for loader 'csv' (the CSV file or its folder)")
    file = csv_file(Path(str(options["root"])).expanduser())
    problems = Problems(options["skip_bad"])
    entries = read_rows(file, problems)
    if not entries and not problems.skipped:
        raise BadInput(f"{file}: no images listed")
    chosen = opts.choose_textures(entries, options["textures"], file)
    return posed_dataset("csv", file.parent, options, {t: entries[t] for t in chosen}, problems)
