"""A content-addressed keypoint cache on disk: each detection is computed once and reused by every descriptor.

:func:`detect_cached` is the one way a task detects (the sweep's detection tasks and the optimiser's trials).

The key hashes everything that determines a detection: the image bytes, the detection mask, the detector and
selector with their parameters, and the library versions. One ``.npz`` file per entry, written to a temporary name
and renamed into place, so a reader sees a whole entry or none. An entry also holds the key it was written for and a
checksum of its numbers: a truncated, empty, bit-flipped or misplaced (copied over another) entry is a miss, removed,
recomputed and counted (``corrupt``). A cache that cannot be written is a warning and the run goes on without it.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import sys
import tempfile
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import plain
from gtsweep.evaluation.evaluate import detect_raw, select_detected
from gtsweep.orchestration.settings import default

# The pseudo-selector under which a detector's unselected output is cached (files raw-<key>.npz).
RAW = "raw"


@lru_cache(maxsize=1)
def library_versions() -> dict:
    """Versions that change detection results, and which SURF runs (OpenCV's nonfree one or gtsweep's port)."""
    from gtsweep.stages.surf import implementation_name

    try:
        own = metadata.version("gtsweep")
    except metadata.PackageNotFoundError:
        own = "source"
    return {"opencv": cv2.__version__, "numpy": np.__version__, "gtsweep": own, "surf": implementation_name()}


def image_hash(image: np.ndarray, mask: np.ndarray | None):
    """The part of :func:`detection_key` that reads the pixels (a ``hashlib`` object): hashed once, it keys every
    detection of the image (the selected one and the detector's raw output)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(image).tobytes())
    h.update(str(image.shape).encode())
    if mask is not None:
        h.update(np.ascontiguousarray(mask).tobytes())
    return h


def detection_key(image: np.ndarray, mask: np.ndarray | None, detector: str, detector_cfg: dict,
                  selector: str, selector_cfg: dict, versions: dict | None = None, hashed=None) -> str:
    """The cache key of one detection + selection; ``hashed``: :func:`image_hash` of ``image`` and ``mask``."""
    h = (image_hash(image, mask) if hashed is None else hashed).copy()
    described = [detector, detector_cfg, selector, selector_cfg, versions or library_versions()]
    h.update(json.dumps(described, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _checksum(key: str, keypoints: np.ndarray, n_detected: int, seconds: float) -> str:
    h = hashlib.sha256(key.encode())
    h.update(f"{keypoints.dtype.str}{keypoints.shape}{int(n_detected)}{float(seconds)!r}".encode())
    h.update(np.ascontiguousarray(keypoints).tobytes())
    return h.hexdigest()


class KeypointCache:
    """Keypoints by key in ``directory`` (None: memory only). Counts this object's lookups: ``hits``, ``misses``,
    ``corrupt`` (bad entries found, removed and recomputed) and ``write_errors`` (after the first, it stops writing).

    Entries are also kept in memory for the object's life, so one task that sees the same reference image under
    several transform strengths reads it once. ``keep_raw``: whether a detector's raw output goes to disk (see
    :func:`detect_cached`).
    """

    def __init__(self, directory: str | os.PathLike | None, keep_raw: bool = True):
        self.directory = Path(directory) if directory else None
        self.keep_raw = keep_raw
        self.hits = self.misses = self.corrupt = self.write_errors = 0
        self._memory: dict[str, tuple] = {}

    def _path(self, key: str) -> Path:
        return self.directory / key[:2] / f"{key}.npz"

    def get(self, key: str, count: bool = True):
        """``(keypoints, n_detected, seconds)`` for ``key``, or None (a miss); ``count=False``: not counted."""
        found = self._memory.get(key)
        if found is None and self.directory is not None:
            found = self._read(self._path(key), key)
            if found is not None:
                self._memory[key] = found
        if count:
            self.hits += found is not None
            self.misses += found is None
        return found

    def _read(self, path: Path, key: str):
        """The entry at ``path`` if it is whole and was written for ``key``; a bad one is removed (None)."""
        try:
            with np.load(path, allow_pickle=False) as entry:
                found = entry["keypoints"], int(entry["n_detected"]), float(entry["seconds"])
                verified = str(entry["key"]) == key and str(entry["checksum"]) == _checksum(key, *found)
                found = (found[0].astype(np.float64), *found[1:])  # stored as float32 where that is exact
        except FileNotFoundError:
            return None
        except Exception:  # truncated, empty, not a zip, bad CRC, missing fields, an older format
            verified = False
        if verified:
            return found
        self.corrupt += 1
        try:
            path.unlink(missing_ok=True)
        except OSError:
            pass
        return None

    def put(self, key: str, keypoints: np.ndarray, n_detected: int, seconds: float, store: bool = True) -> None:
        """Keep an entry in memory and, with ``store``, on disk."""
        self._memory[key] = (keypoints, n_detected, seconds)
        if self.directory is None or self.write_errors or not store:
            return
        keypoints = compact(keypoints)
        fields = {"keypoints": keypoints, "n_detected": n_detected, "seconds": seconds, "key": key,
                  "checksum": _checksum(key, keypoints, n_detected, seconds)}
        self.write_errors += not write_entry(self._path(key), fields)  # else the task goes on with its memory


def compact(keypoints: np.ndarray) -> np.ndarray:
    """The keypoint array as float32 when that holds every value exactly (OpenCV's keypoints are float32, octave and
    class_id small integers), else as it is: half the disk, the same numbers read back."""
    single = keypoints.astype(np.float32)
    return single if np.array_equal(single, keypoints) else keypoints


def write_entry(path: Path, fields: dict) -> bool:
    """One ``.npz`` cache entry written whole or not at all; False when it cannot be (full disk, read-only
    folder)."""
    entry = io.BytesIO()  # numpy's zip writer makes many small writes and seeks: in memory, then one write
    np.savez(entry, **fields)
    try:
        write_atomically(path, lambda f: f.write(entry.getbuffer()))
    except OSError:
        return False
    return True


def _map_checksum(key: str, value: np.ndarray) -> str:
    h = hashlib.sha256(f"{key}{value.dtype.str}{value.shape}".encode())
    h.update(value.tobytes())
    return h.hexdigest()


class DenseMapCache:
    """Dense per-image maps of learned descriptors on disk under ``<directory>/dense/`` (None: none kept), e.g.
    XFeat's descriptor map: computed once per image and sampled at every detector's keypoints, so a pairing
    table's XFeat column runs the network once per image instead of once per detector. ``get_or_compute(key,
    compute)`` returns the stored map or ``compute()``'s, stored; entries carry their key and a checksum as
    the keypoint cache's do (a bad one is recomputed and replaced). XFeat's map of a 1288×964 view: 4.9 MB.
    Counts ``hits``, ``misses`` and ``write_errors`` (after the first, it stops writing)."""

    def __init__(self, directory: str | os.PathLike | None):
        self.directory = Path(directory) / "dense" if directory else None
        self.hits = self.misses = self.write_errors = 0

    def get_or_compute(self, key: str, compute) -> np.ndarray:
        path = None if self.directory is None else self.directory / key[:2] / f"{key}.npz"
        if path is not None:
            try:
                with np.load(path, allow_pickle=False) as entry:
                    value = entry["value"]
                    if str(entry["key"]) == key and str(entry["checksum"]) == _map_checksum(key, value):
                        self.hits += 1
                        return value
            except Exception:  # missing, truncated, not a zip, bad CRC, missing fields: computed again
                pass
        self.misses += 1
        value = np.ascontiguousarray(compute())
        if path is not None and not self.write_errors:  # a failed write: the task goes on without storing
            self.write_errors += not write_entry(path, {"value": value, "key": key,
                                                        "checksum": _map_checksum(key, value)})
        return value


def detector_key_config(detector: str, detector_params: dict) -> dict:
    """What a detection's key says of its detector: its parameters, and the device it computes on where that is
    not the CPU (:func:`gtsweep.stages.device.current`; CPU keys are the ones they were before devices)."""
    from gtsweep.stages import device as devices

    return {"params": detector_params, **devices.key_entry("detector", detector, devices.current())}


def detect_cached(cache: KeypointCache, image: np.ndarray, mask: np.ndarray | None, detector: str,
                  detector_params: dict, selector: str, selector_params: dict):
    """Detect and select through ``cache``: ``(keypoints, n_detected, seconds)``.

    The detector's own output is cached too (under the pseudo-selector ``raw``), so every selector of one
    detection (survey Table 2) selects from one detector call; ``seconds`` is that call's time plus the selection's.
    Only the selected lookup counts as a hit or miss. The raw output goes to disk only when the cache's
    ``keep_raw`` is set (the runner sets it where a run selects from one detection more than one way): it is the
    bulk of the cache (tens of thousands of keypoints against the 1000 selected; ~0.3 GB per synthetic image of
    survey Table 3).
    """
    hashed = image_hash(image, mask)
    described = detector_key_config(detector, detector_params)
    key = detection_key(image, mask, detector, described, selector, {"params": selector_params}, hashed=hashed)
    found = cache.get(key)
    if found is None:
        raw_key = f"{RAW}-" + detection_key(image, mask, detector, described, RAW, {}, hashed=hashed)
        raw = cache.get(raw_key, count=False)
        if raw is None:
            raw = detect_raw(image, mask, detector, detector_params)
            cache.put(raw_key, *raw, store=cache.keep_raw)
        found = select_detected(raw, image.shape, selector, selector_params)
        cache.put(key, *found)
    return found


def cache_state(cfg: Mapping) -> tuple[str | None, str]:
    """The keypoint cache's absolute directory (``cache.dir``) and a note for run.json. None when
    ``cache.enabled`` is false, or when the directory cannot be written: then one warning line on stderr."""
    cache_cfg = plain(cfg.get("cache")) or {}
    if not cache_cfg.get("enabled", default("cache.enabled")):
        return None, "off: cache.enabled=false"
    directory = Path(cache_cfg["dir"]).resolve()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        reason = f"cannot write {directory}: {e.strerror or e}"
        print(f"gtsweep: warning: running without a keypoint cache ({reason})", file=sys.stderr)
        return None, f"off: {reason}"
    return str(directory), f"on: {directory}"


def cache_directory(cfg: Mapping) -> str | None:
    """The keypoint cache's directory, or None (see :func:`cache_state`)."""
    return cache_state(cfg)[0]
