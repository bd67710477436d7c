"""The data set interface the sweep uses: :class:`Sample`, :class:`Pair` and :class:`Dataset`."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import cv2
import numpy as np

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.datasets import geometry

SPLITS = ("optimisation", "synthetic")
PAIR_KINDS = ("incremental", "absolute")


def read_gray(path: str | Path) -> np.ndarray:
    """Read an image file as a 2-D uint8 gray image; BadInput naming the file if missing or corrupt."""
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        raise BadInput(f"cannot read image {path}: {error.strerror or error}") from None
    image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if image is None or image.ndim != 2 or 0 in image.shape:
        raise BadInput(f"cannot read image {path}: not a readable image (corrupt or unsupported format)")
    return image


@dataclass(frozen=True, eq=False)
class Sample:
    """One camera image: ``pose`` maps its pixels to map pixels (3x3 float64), or is None when unknown;
    ``max_pixels``: a larger image is downscaled to at most that many pixels on load (a data set without poses)."""

    id: str
    texture: str
    path: str | None
    pose: np.ndarray | None = None
    max_pixels: int | None = None

    def load(self) -> np.ndarray:
        """The image as 2-D uint8 gray."""
        if self.path is None:
            raise BadInput(f"sample {self.id} has no image file")
        image = read_gray(self.path)
        return downscaled(image, self.max_pixels) if self.max_pixels else image


def downscaled(image: np.ndarray, max_pixels: int) -> np.ndarray:
    """``image`` shrunk by one factor on both sides (area interpolation) to at most ``max_pixels`` pixels."""
    if image.size <= max_pixels:
        return image
    factor = (max_pixels / image.size) ** 0.5
    size = (max(1, int(image.shape[1] * factor)), max(1, int(image.shape[0] * factor)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


@dataclass(frozen=True, eq=False)
class Pair:
    """Two overlapping images of one texture; ``kind`` is "incremental" or "absolute"."""

    id: str
    texture: str
    kind: str
    reference: Sample
    test: Sample

    @property
    def H(self) -> np.ndarray:
        """3x3 homography mapping test pixels to reference pixels: ``inv(reference.pose) @ test.pose``."""
        return geometry.relative(self.reference.pose, self.test.pose)


def fingerprint_of(*parts) -> str:
    """A short stable hash of JSON-serialisable parts (arrays become nested lists)."""
    text = json.dumps(parts, sort_keys=True, default=_jsonable, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot fingerprint {type(value).__name__}")


#: Options of a loaded data set that change none of its images, pairs or poses (the report's scale, the pose check).
NOT_CONTENT = ("px_per_mm", "pose_check")


def content_fingerprint(name: str, options: Mapping, images: Mapping, pairs: Mapping | None) -> str:
    """Fingerprint of a loaded data set: its options (but those that change no image, pair or pose) and every chosen
    sample's path, file size and pose."""

    def describe(sample: Sample):
        size = Path(sample.path).stat().st_size if sample.path and Path(sample.path).exists() else None
        pose = None if sample.pose is None else np.round(sample.pose, 9)
        return [sample.id, sample.path, size, pose]

    listed = {split: [describe(s) for s in samples] for split, samples in images.items()}
    paired = {kind: [[p.id, describe(p.reference), describe(p.test)] for p in kind_pairs]
              for kind, kind_pairs in (pairs or {}).items()}
    return fingerprint_of(name, {k: v for k, v in options.items() if k not in NOT_CONTENT}, listed, paired)


@dataclass
class Dataset:
    """Images per split and pairs per kind, grouped by texture, as a loader found or rendered them.

    ``limit`` in :meth:`images` and :meth:`pairs` is per texture (the survey's counts are per texture).
    ``skipped`` lists bad items left out under ``skip_bad`` ("file:line: reason"); ``excluded`` lists items the
    data set itself marks unusable (e.g. HD Ground's invalid poses).
    """

    name: str
    textures: list[str]
    split_images: dict[str, list[Sample]]
    kind_pairs: dict[str, list[Pair]] | None
    content_hash: str
    skipped: list[str] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)
    no_pairs_reason: str = ""
    #: Why a pair kind has no pairs, and which setting to change (:func:`gtsweep.datasets.pairing.no_pairs_line`).
    empty_kinds: dict[str, str] = field(default_factory=dict)

    def images(self, split: str, textures: Iterable[str] | None = None, limit: int | None = None) -> list[Sample]:
        """Images of ``split`` ("optimisation", "synthetic", or an extra split such as "test")."""
        if split not in self.split_images:
            raise UnknownMethod("data set split", split, self.split_images)
        return _per_texture(self.split_images[split], self._textures(textures), limit)

    def pairs(self, kind: str, textures: Iterable[str] | None = None, limit: int | None = None) -> list[Pair]:
        """Pairs of ``kind`` ("incremental" or "absolute")."""
        if self.kind_pairs is None:
            raise BadInput(self.no_pairs_reason or f"data set '{self.name}' has no pairs")
        if kind not in self.kind_pairs:
            raise UnknownMethod("pair kind", kind, self.kind_pairs)
        return _per_texture(self.kind_pairs[kind], self._textures(textures), limit)

    def fingerprint(self) -> str:
        """Stable hash of what defines the content (configuration, file list, poses)."""
        return self.content_hash

    def _textures(self, textures) -> list[str]:
        if textures is None:
            return list(self.textures)
        chosen = [textures] if isinstance(textures, str) else list(textures)
        for texture in chosen:
            if texture not in self.textures:
                raise UnknownMethod(f"texture of data set '{self.name}'", texture, self.textures)
        return chosen


def _per_texture(items, textures: list[str], limit: int | None):
    """Items whose texture is in ``textures``, at most ``limit`` per texture, in their stored order."""
    if limit is not None and limit < 0:
        raise BadInput(f"limit must be >= 0, got {limit}")
    taken: dict[str, int] = {}
    result = []
    for item in items:
        if item.texture in textures and (limit is None or taken.get(item.texture, 0) < limit):
            taken[item.texture] = taken.get(item.texture, 0) + 1
            result.append(item)
    return result
