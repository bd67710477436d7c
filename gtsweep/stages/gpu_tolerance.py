"""How far a learned method's numbers on a GPU may differ from the same method's on the CPU.

A GPU runs other kernels in another summation order, so its scores, positions and descriptors differ from the CPU's
in the last bits, and a keypoint near the top-k cut can swap with its neighbour. gtsweep accepts a device when,
on the same image:

- keypoints: at least :data:`KEYPOINT_SHARE` (99 %) of the keypoints (of the larger set) have a mutual nearest
  neighbour in the other set within :data:`KEYPOINT_RADIUS` (0.5 px);
- descriptors: every such pair's descriptors have a cosine of at least :data:`DESCRIPTOR_COSINE` (0.999), and
  so do the descriptors of the same given positions (a learned descriptor on another detector's keypoints);
- poses: the same verdict (pose found within the survey's error bounds, or not) for every pair of a sweep.

:func:`compare` and :func:`same_verdicts` check these; ``benchmarks/gpu_check.py`` runs them on a GPU machine.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

KEYPOINT_RADIUS = 0.5
KEYPOINT_SHARE = 0.99
DESCRIPTOR_COSINE = 0.999


@dataclass(frozen=True)
class Agreement:
    """How two runs' keypoints and descriptors of one image agree."""

    keypoints: tuple[int, int]  #: counts of the two runs
    matched_share: float  #: share of the larger set with a mutual nearest neighbour within the radius
    min_cosine: float  #: smallest descriptor cosine among those pairs (1.0 without descriptors)

    @property
    def passed(self) -> bool:
        return self.matched_share >= KEYPOINT_SHARE and self.min_cosine >= DESCRIPTOR_COSINE


def mutual_pairs(xy_a: np.ndarray, xy_b: np.ndarray, radius: float = KEYPOINT_RADIUS):
    """Index arrays ``(rows of a, rows of b)`` of the keypoints that are each other's nearest neighbour and at
    most ``radius`` px apart."""
    xy_a, xy_b = np.asarray(xy_a, np.float64).reshape(-1, 2), np.asarray(xy_b, np.float64).reshape(-1, 2)
    if len(xy_a) == 0 or len(xy_b) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    dist, to_b = cKDTree(xy_b).query(xy_a)
    _, to_a = cKDTree(xy_a).query(xy_b)
    rows = np.flatnonzero((to_a[to_b] == np.arange(len(xy_a))) & (dist <= radius))
    return rows, to_b[rows]


def cosines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cosine similarity of two ``(N, D)`` arrays (two zero rows count as identical)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    norms = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    both_zero = ~a.any(axis=1) & ~b.any(axis=1)
    return np.where(both_zero, 1.0, np.sum(a * b, axis=1) / np.where(norms > 0, norms, 1.0))


def compare(xy_a: np.ndarray, xy_b: np.ndarray, descriptors_a: np.ndarray | None = None,
            descriptors_b: np.ndarray | None = None) -> Agreement:
    """The :class:`Agreement` of run a's keypoints ``xy_a`` (N, 2) and descriptors with run b's."""
    rows_a, rows_b = mutual_pairs(xy_a, xy_b)
    larger = max(len(xy_a), len(xy_b))
    share = 1.0 if larger == 0 else len(rows_a) / larger
    min_cosine = 1.0
    if descriptors_a is not None and descriptors_b is not None and len(rows_a):
        min_cosine = float(cosines(np.asarray(descriptors_a)[rows_a], np.asarray(descriptors_b)[rows_b]).min())
    return Agreement((len(xy_a), len(xy_b)), share, min_cosine)


def same_positions(descriptors_a: np.ndarray, descriptors_b: np.ndarray) -> float:
    """The smallest cosine between two runs' descriptors of the same given positions (row for row)."""
    if len(descriptors_a) != len(descriptors_b):
        raise ValueError(f"{len(descriptors_a)} against {len(descriptors_b)} descriptors of the same positions")
    return float(cosines(descriptors_a, descriptors_b).min()) if len(descriptors_a) else 1.0


def same_verdicts(verdicts_a: Sequence[bool], verdicts_b: Sequence[bool]) -> bool:
    """Whether two runs gave every pair the same pose verdict (in the same pair order)."""
    return len(verdicts_a) == len(verdicts_b) and all(bool(a) == bool(b) for a, b in zip(verdicts_a, verdicts_b))
