"""Splits and pairs from posed image lists (Micro-GPS, HD Ground, CSV).

Images are taken in file order as time order. Incremental pairs are consecutive images of one recording
session (as in the survey: "taken in direct sequence"); absolute pairs are overlapping images of different
sessions or far apart in one session ("taken at different times"). Overlaps come from the poses.
Selection is a seeded shuffle of the candidates; images are read (checked) only when chosen, so a large data
set costs one read per used image.
"""
from __future__ import annotations

import zlib
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from gtsweep.core.errors import BadInput
from gtsweep.datasets import geometry
from gtsweep.datasets.core import Dataset, Pair, Sample, content_fingerprint, read_gray
from gtsweep.datasets.posefiles import Entry, Problems

#: Options shared by the loaders of posed data sets (see conf/dataset/microgps.yaml).
POSED_DEFAULTS = {
    "textures": None,
    "seed": 0,
    "n_optimisation": 3,
    "n_synthetic": 100,
    "n_incremental": 100,
    "n_absolute": 100,
    "incremental_min_overlap": 0.01,
    "absolute_min_overlap": 0.1,
    "absolute_min_gap": 50,
    "pose_check": True,  # the sweep checks the poses against the images first (gtsweep.datasets.posecheck)
}


def texture_rng(seed: int, *keys: str) -> np.random.Generator:
    """A generator that depends only on the seed and the given names (stable when other textures change)."""
    return np.random.default_rng([int(seed)] + [zlib.crc32(key.encode()) for key in keys])


class ImageChecker:
    """Reads each image once; a corrupt file or a size unlike the texture's first image is a problem."""

    def __init__(self, problems: Problems):
        self.problems = problems
        self.verdict: dict[Path, bool] = {}
        self.shape: dict[str, tuple[int, int]] = {}

    def ok(self, entry: Entry, texture: str) -> bool:
        if entry.path not in self.verdict:
            self.verdict[entry.path] = self._check(entry, texture)
        return self.verdict[entry.path]

    def _check(self, entry: Entry, texture: str) -> bool:
        try:
            shape = read_gray(entry.path).shape
        except BadInput as error:
            self.problems.report(entry.where, str(error))
            return False
        expected = self.shape.setdefault(texture, shape)
        if shape != expected:
            self.problems.report(entry.where, f"image {entry.listed_as} is {shape[1]}x{shape[0]}, "
                                              f"other images of {texture} are {expected[1]}x{expected[0]}")
            return False
        return True


def select_texture(texture: str, entries: Sequence[Entry], options: Mapping, checker: ImageChecker,
                   sample_of: Callable[[Entry], Sample]) -> tuple[dict[str, list[Sample]], dict[str, list[Pair]]]:
    """Optimisation and synthetic images and both kinds of pairs for one texture."""
    rng = texture_rng(options["seed"], texture)
    order = rng.permutation(len(entries))
    chosen: list[int] = []
    for i in order:
        if len(chosen) == options["n_optimisation"] + options["n_synthetic"]:
            break
        if checker.ok(entries[i], texture):
            chosen.append(int(i))
    n_opt = min(options["n_optimisation"], len(chosen))
    optimisation = sorted(chosen[:n_opt])
    images = {"optimisation": [sample_of(entries[i]) for i in optimisation],
              "synthetic": [sample_of(entries[i]) for i in sorted(chosen[n_opt:])]}
    for i in order:  # learn the texture's image size even when no single image was asked for
        if texture in checker.shape:
            break
        checker.ok(entries[i], texture)
    if texture not in checker.shape:
        return images, {"incremental": [], "absolute": []}
    shape = checker.shape[texture]
    free = np.ones(len(entries), dtype=bool)
    free[optimisation] = False
    pairs = {}
    for kind, candidates, min_overlap, n in (
        ("incremental", _consecutive(entries, free), options["incremental_min_overlap"], options["n_incremental"]),
        ("absolute", _far_apart(entries, free, shape, options["absolute_min_gap"]),
         options["absolute_min_overlap"], options["n_absolute"]),
    ):
        picked = _take_pairs(candidates[rng.permutation(len(candidates))], entries, shape, min_overlap, n,
                             lambda e: checker.ok(e, texture))
        pairs[kind] = [Pair(f"{texture}/{kind}/{k:03d}", texture, kind, sample_of(entries[a]), sample_of(entries[b]))
                       for k, (a, b) in enumerate(sorted(picked))]
    return images, pairs


def _consecutive(entries: Sequence[Entry], free: np.ndarray) -> np.ndarray:
    """Index pairs (i, i+1) of the same session, both free."""
    same = np.array([entries[i].session == entries[i + 1].session for i in range(len(entries) - 1)], dtype=bool)
    first = np.flatnonzero(same & free[:-1] & free[1:]) if len(entries) > 1 else np.zeros(0, dtype=int)
    return np.stack([first, first + 1], axis=1) if len(first) else np.zeros((0, 2), dtype=int)


def _far_apart(entries: Sequence[Entry], free: np.ndarray, shape, min_gap: int) -> np.ndarray:
    """Index pairs whose footprints may intersect, from different sessions or >= min_gap apart in one."""
    if len(entries) < 2:
        return np.zeros((0, 2), dtype=int)
    centres = np.array([geometry.centre(e.pose, shape) for e in entries])
    scales = np.sqrt(np.abs([np.linalg.det(e.pose[:2, :2]) for e in entries]))
    reach = float(np.hypot(*shape) * scales.max())
    close = cKDTree(centres).query_pairs(reach, output_type="ndarray")
    if len(close) == 0:
        return np.zeros((0, 2), dtype=int)
    close = np.sort(close, axis=1)
    sessions = np.array([e.session for e in entries])
    orders = np.array([e.order for e in entries])
    a, b = close[:, 0], close[:, 1]
    keep = free[a] & free[b] & ((sessions[a] != sessions[b]) | (np.abs(orders[a] - orders[b]) >= min_gap))
    return close[keep]


def _take_pairs(candidates: np.ndarray, entries: Sequence[Entry], shape, min_overlap: float, n: int,
                readable: Callable[[Entry], bool]) -> list[tuple[int, int]]:
    """The first ``n`` candidates whose overlap is at least ``min_overlap`` and whose images read."""
    picked = []
    for a, b in candidates:
        if len(picked) == n:
            break
        if geometry.overlap(entries[a].pose, entries[b].pose, shape) < min_overlap:
            continue
        if readable(entries[a]) and readable(entries[b]):
            picked.append((int(a), int(b)))
    return picked


def posed_dataset(name: str, root: Path, options: Mapping, entries: Mapping[str, list[Entry]],
                  problems: Problems, extra_splits: Mapping[str, Mapping[str, list[Entry]]] | None = None,
                  excluded: Sequence[str] = ()) -> Dataset:
    """A :class:`Dataset` from posed entries per texture (``extra_splits``: e.g. "test" lists without poses)."""
    textures = sorted(entries)
    if not textures:
        raise BadInput(f"{root}: no posed images found")
    samples: dict[Path, Sample] = {}

    def sample_of(entry: Entry, texture: str) -> Sample:
        if entry.path not in samples:
            listed = entry.path.relative_to(root).as_posix() if entry.path.is_relative_to(root) else str(entry.path)
            samples[entry.path] = Sample(listed, texture, str(entry.path), entry.pose)
        return samples[entry.path]

    checker = ImageChecker(problems)
    images: dict[str, list[Sample]] = {"optimisation": [], "synthetic": []}
    pairs: dict[str, list[Pair]] = {"incremental": [], "absolute": []}
    for texture in textures:
        texture_images, texture_pairs = select_texture(texture, entries[texture], options, checker,
                                                       lambda e, t=texture: sample_of(e, t))
        for split, chosen in texture_images.items():
            images[split].extend(chosen)
        for kind, chosen in texture_pairs.items():
            pairs[kind].extend(chosen)
    for split, per_texture in (extra_splits or {}).items():
        images[split] = [sample_of(e, t) for t in sorted(per_texture) for e in per_texture[t]]
    fingerprint = content_fingerprint(name, options, images, pairs)
    empty = {kind: no_pairs_line(kind, entries, options) for kind in pairs if not pairs[kind]}
    return Dataset(name, textures, images, pairs, fingerprint, skipped=problems.skipped, excluded=list(excluded),
                   empty_kinds=empty)


def no_pairs_line(kind: str, entries: Mapping[str, Sequence[Entry]], options: Mapping) -> str:
    """Why the pair rules found no ``kind`` pair among ``entries`` (per texture), and the setting to change."""
    if not options[f"n_{kind}"]:
        return f"dataset.n_{kind} is 0"
    sessions: dict[tuple, int] = {}
    for texture, listed in entries.items():
        for entry in listed:
            sessions[texture, entry.session] = sessions.get((texture, entry.session), 0) + 1
    longest = max(sessions.values(), default=0)
    found = (f"{sum(map(len, entries.values()))} images in {len(entries)} texture(s), at most {longest} in one "
             f"session")
    overlap = f"{kind}_min_overlap"
    if kind == "incremental":
        return (f"{found}; an incremental pair is two consecutive images of one session whose footprints overlap "
                f">= {overlap} ({options[overlap]:g}): add images along a path or lower dataset.{overlap}")
    gap = options["absolute_min_gap"]
    return (f"{found}; an absolute pair is two images whose footprints overlap >= {overlap} ({options[overlap]:g}), "
            f"from different sessions or >= absolute_min_gap ({gap}) images apart in one: set "
            f"dataset.absolute_min_gap={max(1, longest // 2)} (or lower dataset.{overlap})")
