"""A content-addressed keypoint cache on disk: each detection is computed once and reused by every descriptor.

:func:`detect_cached` is the one way a task detects (the sweep's detection tasks and the optimiser's trials).

The key hashes everything that determines a detection: the image bytes, the detection mask, the detector and
selector with their parameters, and the library versions. One ``.npz`` file per entry (parallel writers never share
a file), written to a temporary name and renamed into place, so a reader sees a whole entry or none.
"""
from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import plain
from gtsweep.evaluation.evaluate import detect_and_select


@lru_cache(maxsize=1)
def library_versions() -> dict:
    """Versions that change detection results, and which SURF runs (OpenCV's nonfree one or gtsweep's port)."""
    from gtsweep.stages.surf import opencv_surf_available

    try:
        own = metadata.version("gtsweep")
    except metadata.PackageNotFoundError:
        own = "source"
    surf = "opencv" if opencv_surf_available() else "gtsweep-numpy"
    return {"opencv": cv2.__version__, "numpy": np.__version__, "gtsweep": own, "surf": surf}


def detection_key(image: np.ndarray, mask: np.ndarray | None, detector: str, detector_cfg: dict,
                  selector: str, selector_cfg: dict, versions: dict | None = None) -> str:
    """The cache key of one detection + selection."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(image).tobytes())
    h.update(str(image.shape).encode())
    if mask is not None:
        h.update(np.ascontiguousarray(mask).tobytes())
    described = [detector, detector_cfg, selector, selector_cfg, versions or library_versions()]
    h.update(json.dumps(described, sort_keys=True, default=str).encode())
    return h.hexdigest()


class KeypointCache:
    """Keypoints by key in ``directory`` (None: memory only); ``hits`` and ``misses`` count this object's lookups.

    Entries are also kept in memory for the object's life, so one task that sees the same reference image under
    several transform strengths reads it once.
    """

    def __init__(self, directory: str | os.PathLike | None):
        self.directory = Path(directory) if directory else None
        self.hits = 0
        self.misses = 0
        self._memory: dict[str, tuple] = {}

    def _path(self, key: str) -> Path:
        return self.directory / key[:2] / f"{key}.npz"

    def get(self, key: str):
        """``(keypoints, n_detected, seconds)`` for ``key``, or None (a miss)."""
        if key in self._memory:
            self.hits += 1
            return self._memory[key]
        if self.directory is not None:
            try:
                with np.load(self._path(key)) as entry:
                    found = entry["keypoints"], int(entry["n_detected"]), float(entry["seconds"])
                self.hits += 1
                self._memory[key] = found
                return found
            except (FileNotFoundError, OSError, KeyError, ValueError):
                pass  # absent or unreadable: recompute (and overwrite)
        self.misses += 1
        return None

    def put(self, key: str, keypoints: np.ndarray, n_detected: int, seconds: float) -> None:
        self._memory[key] = (keypoints, n_detected, seconds)
        if self.directory is None:
            return
        write_atomically(self._path(key), lambda f: np.savez_compressed(f, keypoints=keypoints,
                                                                         n_detected=n_detected, seconds=seconds))


def detect_cached(cache: KeypointCache, image: np.ndarray, mask: np.ndarray | None, detector: str,
                  detector_params: dict, selector: str, selector_params: dict):
    """Detect and select through ``cache``: ``(keypoints, n_detected, seconds)``; a miss is one detector call."""
    key = detection_key(image, mask, detector, {"params": detector_params}, selector, {"params": selector_params})
    found = cache.get(key)
    if found is None:
        found = detect_and_select(image, mask, detector, detector_params, selector, selector_params)
        cache.put(key, *found)
    return found


def cache_directory(cfg: Mapping) -> str | None:
    """The keypoint cache's absolute directory (``cache.dir``), or None when ``cache.enabled`` is false."""
    cache_cfg = plain(cfg.get("cache")) or {}
    return str(Path(cache_cfg["dir"]).resolve()) if cache_cfg.get("enabled", True) else None
