"""The pose check: do a data set's poses agree with its images, and if not, which common convention would fit?

On a few pairs whose poses say they overlap (incremental pairs: consecutive images, which overlap in any convention
that gets the positions roughly right), SIFT matches and a RANSAC similarity measure how the test image lies on the
reference image. The poses predict the same (``inv(reference.pose) @ test.pose``); they agree on a pair when the
predicted and measured maps put the test image's corners and centre within the survey's success radius (30 px) of
each other. Each pose is then read in the common mistaken conventions (theta negated, x and y swapped, the map's y
pointing up, theta in radians): when the poses as written disagree on most measured pairs, the convention that
agrees on most of them is named. Hloc's and COLMAP's users run such a check before trusting a localization number.

A pair whose images give too few matches (under :data:`MIN_INLIERS` RANSAC inliers) is not measured: it counts
neither way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from gtsweep.datasets.geometry import similarity_pose

#: RANSAC inliers a pair needs to be measured; the agreement radius in pixels (the survey's success radius).
MIN_INLIERS, AGREE_PX = 15, 30.0
#: How many incremental pairs the check measures (spread over the textures).
DEFAULT_PAIRS = 6
#: The common mistakes: how the true (x, y, theta in degrees) are found from the values as written.
CONVENTIONS: dict[str, Callable[[float, float, float], tuple[float, float, float]]] = {
    "as written": lambda x, y, theta: (x, y, theta),
    "theta negated": lambda x, y, theta: (x, y, -theta),
    "x and y swapped": lambda x, y, theta: (y, x, theta),
    "y pointing up (y and theta negated)": lambda x, y, theta: (x, -y, -theta),
    "theta in radians": lambda x, y, theta: (x, y, math.degrees(theta)),
}


@dataclass
class PoseCheck:
    """Pairs measured, and on how many of them each convention agrees with the images."""

    checked: int
    measured: int = 0
    agree: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CONVENTIONS, 0))
    worst_px: float = 0.0  # the largest corner distance of the poses as written, over the measured pairs

    @property
    def consistent(self) -> bool:
        """The poses as written agree on most measured pairs (or nothing could be measured)."""
        return self.measured == 0 or 2 * self.agree["as written"] > self.measured

    def fitting(self) -> list[str]:
        """The other conventions that agree on most measured pairs and on the most of them, in the order of
        :data:`CONVENTIONS` (several where the pairs cannot tell them apart)."""
        others = {name: n for name, n in self.agree.items() if name != "as written"}
        best = max(others.values())
        return [name for name, n in others.items() if n == best] if 2 * best > self.measured else []

    def line(self) -> str:
        """The verdict in one line."""
        if self.measured == 0:
            return (f"pose check: none of {self.checked} overlapping pair(s) had {MIN_INLIERS} matching features: "
                    f"the poses could not be checked")
        written = self.agree["as written"]
        if self.consistent:
            return (f"pose check: the poses agree with the images on {written} of {self.measured} pair(s) "
                    f"(largest corner distance {self.worst_px:.1f} px)")
        found = self.fitting()
        advice = (f"they fit with {' or '.join(found)} ({self.agree[found[0]]} of {self.measured}): convert them "
                  f"to gtsweep's convention (docs/own-data.md)" if found else
                  "no common convention fits (theta negated, x and y swapped, y up, radians): see docs/own-data.md")
        return (f"pose check: the poses disagree with the images on {self.measured - written} of {self.measured} "
                f"pair(s) (as written, the test image lands up to {self.worst_px:.0f} px from where its features "
                f"put it); {advice}")


def _row_values(pose: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, theta in degrees, scale) of a pose as :func:`similarity_pose` builds it."""
    return (float(pose[0, 2]), float(pose[1, 2]), math.degrees(math.atan2(pose[0, 1], pose[0, 0])),
            math.sqrt(abs(np.linalg.det(pose[:2, :2]))))


def read_as(pose: np.ndarray, convention: str) -> np.ndarray:
    """The pose the values of ``pose`` would give when written in ``convention``."""
    if convention == "as written":
        return np.asarray(pose, dtype=np.float64)
    x, y, theta, scale = _row_values(pose)
    return similarity_pose(*CONVENTIONS[convention](x, y, theta), scale)


def measure(reference: np.ndarray, test: np.ndarray) -> np.ndarray | None:
    """The 3x3 similarity taking test pixels to reference pixels, from SIFT matches (ratio 0.8) and RANSAC; None
    when fewer than :data:`MIN_INLIERS` matches agree."""
    sift = cv2.SIFT_create(nfeatures=2000)
    kp_ref, desc_ref = sift.detectAndCompute(reference, None)
    kp_test, desc_test = sift.detectAndCompute(test, None)
    if desc_ref is None or desc_test is None or len(kp_ref) < 2 or len(kp_test) < 2:
        return None
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_test, desc_ref, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
    if len(good) < MIN_INLIERS:
        return None
    src = np.float32([kp_test[m.queryIdx].pt for m in good])
    dst = np.float32([kp_ref[m.trainIdx].pt for m in good])
    cv2.setRNGSeed(0)
    found, inliers = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0)
    if found is None or int(inliers.sum()) < MIN_INLIERS:
        return None
    return np.vstack([found, [0.0, 0.0, 1.0]])


def corner_distance(predicted: np.ndarray, measured: np.ndarray, shape) -> float:
    """The largest distance between where ``predicted`` and ``measured`` put the test image's corners and centre."""
    h, w = shape[:2]
    points = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1], [(w - 1) / 2, (h - 1) / 2, 1]],
                      dtype=np.float64).T
    a, b = predicted @ points, measured @ points
    return float(np.max(np.hypot(*(a[:2] / a[2] - b[:2] / b[2]))))


def check_poses(dataset, n_pairs: int = DEFAULT_PAIRS) -> PoseCheck:
    """Measure up to ``n_pairs`` incremental pairs of ``dataset`` (spread over its textures) and count, per
    convention, the pairs whose poses agree with the images."""
    per_texture = max(1, -(-n_pairs // max(1, len(dataset.textures))))
    pairs = dataset.pairs("incremental", limit=per_texture)[:n_pairs]
    result = PoseCheck(checked=len(pairs))
    for pair in pairs:
        reference, test = pair.reference.load(), pair.test.load()
        measured = measure(reference, test)
        if measured is None:
            continue
        result.measured += 1
        for convention in CONVENTIONS:
            predicted = np.linalg.inv(read_as(pair.reference.pose, convention)) @ read_as(pair.test.pose, convention)
            distance = corner_distance(predicted, measured, test.shape)
            result.agree[convention] += distance <= AGREE_PX
            if convention == "as written":
                result.worst_px = max(result.worst_px, distance)
    return result
