"""Data sets: the embedded default (rendered from procedural floors) and loaders for real layouts.

``load_dataset(cfg)`` builds a :class:`Dataset` from the Hydra ``dataset`` node; ``cfg["loader"]`` picks one of
:data:`DATASETS`. A data set gives images per split ("optimisation", "synthetic") and pairs per kind
("incremental", "absolute"); a pair's ``H`` maps test pixels to reference pixels, from the poses.
"""
from __future__ import annotations

from typing import Callable, Mapping

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.datasets import csvposes, folder, hdground, microgps, synthetic
from gtsweep.datasets.core import PAIR_KINDS, SPLITS, Dataset, Pair, Sample, read_gray
from gtsweep.datasets.geometry import overlap, rotation_deg
from gtsweep.datasets.options import plain

DATASETS: dict[str, Callable[[Mapping], Dataset]] = {
    "synthetic": synthetic.load,
    "microgps": microgps.load,
    "hdground": hdground.load,
    "folder": folder.load,
    "csv": csvposes.load,
}

__all__ = ["DATASETS", "Dataset", "PAIR_KINDS", "Pair", "SPLITS", "Sample", "load_dataset", "overlap",
           "read_gray", "rotation_deg"]


def load_dataset(cfg: Mapping) -> Dataset:
    """The data set described by ``cfg`` (a DictConfig or dict with a ``loader`` key)."""
    options = plain(cfg)
    loader = options.get("loader")
    if loader is None:
        raise BadInput(f"dataset.loader is missing; choices: {', '.join(DATASETS)}")
    if loader not in DATASETS:
        raise UnknownMethod("dataset loader", str(loader), DATASETS)
    return DATASETS[loader](options)
