"""Data sets: the embedded default (rendered from procedural floors) and loaders for real layouts.

``load_dataset(cfg)`` builds a :class:`Dataset` from the Hydra ``dataset`` node; ``cfg["loader"]`` picks one of
:data:`DATASETS`, whose entry holds the loader's options and their defaults (each loader module's ``DEFAULTS``).
A data set gives images per split ("optimisation", "synthetic") and pairs per kind ("incremental", "absolute");
a pair's ``H`` maps test pixels to reference pixels, from the poses.
"""
from __future__ import annotations

from types import ModuleType
from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.core.registry import Method, Registry
from gtsweep.datasets import csvposes, folder, hdground, microgps, synthetic
from gtsweep.datasets import options as opts
from gtsweep.datasets.core import PAIR_KINDS, SPLITS, Dataset, Pair, Sample, read_gray
from gtsweep.datasets.geometry import overlap, rotation_deg


def _loader(name: str, label: str, module: ModuleType) -> Method:
    """A loader module as a registry entry: ``module.load(options)``, its options' defaults."""
    return Method("dataset loader", name, label, lambda **options: module.load(options),
                  {**opts.COMMON, **module.DEFAULTS})


DATASETS: Registry[Method] = Registry("dataset loader", [
    _loader("synthetic", "embedded synthetic floors", synthetic),
    _loader("microgps", "Micro-GPS", microgps),
    _loader("hdground", "HD Ground", hdground),
    _loader("folder", "folder of images", folder),
    _loader("csv", "CSV of poses", csvposes),
])

__all__ = ["DATASETS", "Dataset", "PAIR_KINDS", "Pair", "SPLITS", "Sample", "load_dataset", "overlap",
           "read_gray", "rotation_deg"]


def load_dataset(cfg: Mapping) -> Dataset:
    """The data set described by ``cfg`` (a DictConfig or dict with a ``loader`` key); an unknown option or one
    of the wrong type is a one-line BadInput naming the loader's options."""
    options = opts.plain(cfg)
    loader = options.get("loader")
    if loader is None:
        raise BadInput(f"dataset.loader is missing; choices: {', '.join(DATASETS)}")
    method = DATASETS.get(loader)
    return method.create(**method.params(options))
