"""Reading a loader's options from the Hydra ``dataset`` node (or a plain dict)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

from gtsweep.core import config
from gtsweep.core.errors import BadInput

#: Keys every loader accepts. ``px_per_mm``: the images' scale (pixels per millimetre of floor), for the report's
#: millimetres; None: pixels only.
COMMON = {"loader": None, "root": None, "skip_bad": False, "px_per_mm": None}


def plain(cfg: Mapping) -> dict:
    """A plain dict from a DictConfig or mapping; a missing mandatory value (``???``) raises BadInput."""
    return dict(config.plain(cfg, "dataset"))


def read(cfg: Mapping, defaults: Mapping[str, Any], loader: str) -> dict:
    """``defaults`` updated with ``cfg`` (whose keys :func:`gtsweep.datasets.load_dataset` has checked against
    the loader's registry entry); a missing mandatory value (``???``) raises BadInput."""
    merged = {**COMMON, **defaults, **plain(cfg), "loader": loader}
    for key, value in merged.items():
        if value == "???":
            raise BadInput(f"dataset.{key} is required (give it on the command line, e.g. dataset.{key}=...)")
    ppm = merged["px_per_mm"]
    if ppm is not None and (isinstance(ppm, bool) or not isinstance(ppm, (int, float)) or not 0 < ppm < float("inf")):
        raise BadInput(f"dataset.px_per_mm must be a number > 0 (pixels per millimetre of floor) or null, got {ppm!r}")
    return merged


def root_folder(options: Mapping, loader: str) -> Path:
    """The existing folder ``options['root']``; BadInput naming it otherwise."""
    root = options.get("root")
    if root in (None, ""):
        raise BadInput(f"dataset.root is required for loader '{loader}' (e.g. dataset.root=/path/to/data)")
    path = Path(str(root)).expanduser()
    if not path.exists():
        raise BadInput(f"data set folder {path} does not exist")
    if not path.is_dir():
        raise BadInput(f"data set folder {path} is not a folder")
    return path


def count(options: Mapping, key: str, allow_none: bool = False) -> int | None:
    """A non-negative integer option."""
    value = options.get(key)
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise BadInput(f"dataset.{key} must be a non-negative integer, got {value!r}")
    return value


def physical_memory() -> int | None:
    """Bytes of RAM of this machine (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def check_fits(options: Mapping, keys: dict[str, int], view_bytes: int, copies: int) -> None:
    """The views that counts ``keys`` ask for (``{key: views per item}``, e.g. 2 per pair), ``copies`` times (one
    per texture), must fit in this machine's memory: a count nobody can hold is one line before any work, never an
    attempt to allocate terabytes."""
    memory = physical_memory()
    if memory is None:
        return
    for key, views in keys.items():
        need = count(options, key) * views * view_bytes * copies
        if need > memory:
            raise BadInput(f"dataset.{key}={options[key]} asks for {need / 2**30:,.0f} GiB of views "
                           f"({copies} texture(s)); this machine has {memory / 2**30:,.1f} GiB")


def choose_textures(found, wanted, root: Path) -> list[str]:
    """The textures to load: all ``found`` ones, or the ``wanted`` list (each must exist)."""
    found = sorted(found)
    if wanted is None:
        return found
    wanted = [wanted] if isinstance(wanted, str) else list(wanted)
    missing = [t for t in wanted if t not in found]
    if missing:
        raise BadInput(f"{root}: no texture {', '.join(missing)}; found: {', '.join(found) or 'none'}")
    return wanted


#: File name endings the folder-based loaders take as images.
IMAGE_SUFFIXES = (".png", ".pgm", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm")
