"""Absolute localization against a whole ground map (Micro-GPS, Zhang et al. ICRA 2019; the survey's outlook).

The survey evaluates image *pairs* and ends with "we are interested in absolute localization performance using
different matching and pose estimation methods". Micro-GPS localizes a query against every feature of a posed map:
SIFT, approximate nearest neighbours, voting for the query's position, then RANSAC. Here:

- :func:`build_map`: the features of posed mapping images in map coordinates (keypoints through each image's
  image -> map pose), their descriptors stacked. With ``dedupe`` a floor point is kept from the first mapping
  image that sees it: features inside an earlier image's footprint (shrunk by ``margin`` px) are dropped, so the
  ratio test is not fooled by the same point seen in overlapping images (a coarse coverage raster, no loop over
  features).
- :func:`vote`: each match votes for the query's centre in map coordinates, from the keypoints' orientations (scale
  1: a ground camera at fixed height, as Micro-GPS); matches near the most voted cell of a coarse grid are kept.
- :func:`localize`: match (any matcher's index), optionally vote, estimate the query -> map similarity (any
  estimator), accept it with at least ``min_inliers`` inliers and an inlier ratio of at least ``min_inlier_ratio``.
- :func:`judge`: position and orientation error of the query's centre against its true pose, in map pixels, and
  success within the survey's thresholds (30 px, 1.5 deg).

Orientation here is ``atan2(P[1, 0], P[0, 0])`` of a 3x3 image -> map pose (degrees). OpenCV keypoint angles
satisfy ``rotation(test -> reference) = angle_reference - angle_test`` in that convention.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.stages import keypoints as kp

#: Rows of the coverage raster per map pixel (1/4 resolution is plenty for footprints hundreds of px wide).
_RASTER = 0.25


@dataclass(frozen=True)
class FeatureMap:
    """The map of one floor: per feature its map position ``xy`` (float32), orientation in the map frame
    ``angle`` (deg; NaN without one), descriptor row and mapping image ``image`` (index into the mapping order).
    ``build_seconds[i]``: detection and description time of mapping image i."""

    xy: np.ndarray
    angle: np.ndarray
    descriptors: np.ndarray
    image: np.ndarray
    build_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return len(self.xy)

    def first(self, n_images: int) -> FeatureMap:
        """The map of the first ``n_images`` mapping images (the maps of a sweep over map size are nested)."""
        keep = self.image < n_images
        return FeatureMap(self.xy[keep], self.angle[keep], self.descriptors[keep], self.image[keep],
                          self.build_seconds[:n_images])

    @property
    def nbytes(self) -> int:
        """Memory of the features themselves: descriptors, positions, orientations, image ids (no index)."""
        return int(self.xy.nbytes + self.angle.nbytes + self.descriptors.nbytes + self.image.nbytes)


def orientation(pose: np.ndarray, shape=None) -> float:
    """``atan2(P[1, 0], P[0, 0])`` of a 3x3 pose, in degrees; with the image ``shape`` (h, w), of the pose's
    Jacobian at the image centre (the same for affine poses; right for a tilted camera's homography)."""
    pose = np.asarray(pose, dtype=np.float64)
    linear = pose
    if shape is not None and not _affine(pose):
        h, w = shape[:2]
        centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        scale = pose[2, :2] @ centre + pose[2, 2]
        linear = (pose[:2, :2] - np.outer(to_map(centre, pose)[0], pose[2, :2])) / scale
    return math.degrees(math.atan2(linear[1, 0], linear[0, 0]))


def _affine(pose: np.ndarray) -> bool:
    return pose[2, 0] == 0.0 and pose[2, 1] == 0.0 and pose[2, 2] == 1.0


def to_map(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Image points ``(N, 2)`` through the 3x3 image -> map ``pose`` (a homography: a tilted camera's pose)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pose = np.asarray(pose, dtype=np.float64)
    mapped = pts @ pose[:2, :2].T + pose[:2, 2]
    return mapped if _affine(pose) else mapped / (pts @ pose[2, :2] + pose[2, 2])[:, None]


def _footprint(pose: np.ndarray, shape, margin: float) -> np.ndarray:
    h, w = shape[:2]
    corners = np.array([[margin, margin], [w - 1 - margin, margin], [w - 1 - margin, h - 1 - margin],
                        [margin, h - 1 - margin]])
    return to_map(corners, pose)


def build_map(parts, dedupe: bool = True, margin: float = 16.0) -> FeatureMap:
    """The map from ``parts``: per mapping image, in mapping order, ``(keypoints (N, 7), descriptors, pose,
    shape, seconds)`` (keypoints in image pixels, aligned with the descriptor rows; ``pose`` image -> map)."""
    if not parts:
        raise BadInput("a map needs at least one mapping image")
    mapped = [to_map(k[:, :2], pose) for k, _, pose, _, _ in parts]
    keep = [np.ones(len(m), dtype=bool) for m in mapped]
    if dedupe:
        keep = _first_sighting(mapped, [(pose, shape) for _, _, pose, shape, _ in parts], margin)
    angles = [np.where(k[:, kp.ANGLE] >= 0, k[:, kp.ANGLE] + orientation(pose, shape), np.nan) % 360.0
              for k, _, pose, shape, _ in parts]
    descriptors = [d for _, d, _, _, _ in parts]
    return FeatureMap(
        xy=np.concatenate([m[k] for m, k in zip(mapped, keep)]).astype(np.float32),
        angle=np.concatenate([a[k] for a, k in zip(angles, keep)]).astype(np.float32),
        descriptors=np.ascontiguousarray(np.concatenate([d[k] for d, k in zip(descriptors, keep)])),
        image=np.concatenate([np.full(int(k.sum()), i, np.int32) for i, k in enumerate(keep)]),
        build_seconds=np.array([p[4] for p in parts], dtype=np.float64))


def _first_sighting(mapped, poses, margin: float) -> list[np.ndarray]:
    """Per image, the features outside every earlier image's footprint shrunk by ``margin`` (coverage raster)."""
    corners = np.concatenate([_footprint(p, s, 0.0) for p, s in poses] + [np.zeros((1, 2))])
    low = np.floor(corners.min(axis=0)) - 1
    size = (np.ceil((corners.max(axis=0) - low) * _RASTER) + 2).astype(int)
    if size.prod() > 1 << 28:
        raise BadInput(f"map of {size[0] / _RASTER:.0f} x {size[1] / _RASTER:.0f} px is too large to dedupe "
                       f"(experiment.map_dedupe=false)")
    covered = np.zeros((size[1], size[0]), np.uint8)
    keep = []
    for points, (pose, shape) in zip(mapped, poses):
        cells = np.clip(((points - low) * _RASTER).astype(int), 0, size - 1)
        keep.append(covered[cells[:, 1], cells[:, 0]] == 0)
        polygon = np.rint((_footprint(pose, shape, margin) - low) * _RASTER).astype(np.int32)
        cv2.fillConvexPoly(covered, polygon, 1)
    return keep


def vote(query_xy: np.ndarray, query_angle: np.ndarray, map_xy: np.ndarray, map_angle: np.ndarray, centre,
         cell: float) -> np.ndarray:
    """Micro-GPS-style voting: the mask of matches whose vote for the query centre falls in the most voted cell
    of a ``cell``-px grid or one of its 8 neighbours. Match i votes ``map_xy[i] + R(rho_i) (centre - query_xy[i])``
    with ``rho_i = map_angle[i] - query_angle[i]``; matches without orientations vote as rotation 0."""
    if len(query_xy) == 0:
        return np.zeros(0, dtype=bool)
    rho = np.radians(np.nan_to_num(np.asarray(map_angle, np.float64) - np.asarray(query_angle, np.float64)))
    offset = np.asarray(centre, np.float64) - np.asarray(query_xy, np.float64)
    votes = np.column_stack([np.cos(rho) * offset[:, 0] - np.sin(rho) * offset[:, 1],
                             np.sin(rho) * offset[:, 0] + np.cos(rho) * offset[:, 1]]) + map_xy
    cells = np.floor(votes / cell).astype(np.int64)
    unique, counts = np.unique(cells, axis=0, return_counts=True)
    top = unique[np.argmax(counts)]
    return np.all(np.abs(cells - top) <= 1, axis=1)


@dataclass(frozen=True)
class Acceptance:
    """When a pose is accepted: at least ``min_inliers`` inliers and inliers / matches >= ``min_inlier_ratio``."""

    min_inliers: int = 10
    min_inlier_ratio: float = 0.0

    def accepts(self, n_inliers: int, n_matches: int) -> bool:
        return n_inliers >= self.min_inliers and n_matches > 0 and n_inliers / n_matches >= self.min_inlier_ratio


def localize(query_kps: np.ndarray, query_desc: np.ndarray, shape, feature_map: FeatureMap, index, estimators,
             acceptance: Acceptance, voting: bool = True, vote_cell: float = 60.0, seed: int = 0) -> dict:
    """Localize one query against ``feature_map`` through its matcher ``index`` (``index.match(desc) -> (M, 2)``
    of query and map feature indices) with every estimator of ``estimators`` (``{name: est}``, ``est.estimate(
    query_xy, map_xy, seed) -> PoseEstimate``). Returns ``n_matches``, ``n_voted``, ``t_match``, ``t_vote`` and
    ``{"poses": {name: (PoseEstimate, seconds, accepted)}}``; the ``n_voted`` matches (all of them without voting)
    reach the estimators, and the inlier ratio of the acceptance rule is taken over them."""
    h, w = shape[:2]
    start = time.perf_counter()
    matches = np.asarray(index.match(query_desc), dtype=np.int64).reshape(-1, 2) if len(feature_map) and len(
        query_desc) else np.zeros((0, 2), np.int64)
    t_match = time.perf_counter() - start
    n_matches = len(matches)
    start = time.perf_counter()
    if voting and len(matches):
        q_angle = np.where(query_kps[matches[:, 0], kp.ANGLE] >= 0, query_kps[matches[:, 0], kp.ANGLE], np.nan)
        matches = matches[vote(query_kps[matches[:, 0], :2], q_angle, feature_map.xy[matches[:, 1]],
                               feature_map.angle[matches[:, 1]], ((w - 1) / 2, (h - 1) / 2), vote_cell)]
    t_vote = time.perf_counter() - start
    query_xy = query_kps[matches[:, 0], :2]
    map_xy = feature_map.xy[matches[:, 1]].astype(np.float64)
    poses = {}
    for name, estimator in estimators.items():
        start = time.perf_counter()
        estimate = estimator.estimate(query_xy, map_xy, seed)
        seconds = time.perf_counter() - start
        accepted = estimate.matrix is not None and acceptance.accepts(estimate.n_inliers, len(matches))
        poses[name] = (estimate, seconds, accepted)
    return {"n_matches": n_matches, "n_voted": len(matches), "t_match": t_match, "t_vote": t_vote, "poses": poses}


def pose_columns(matrix: np.ndarray | None, shape) -> dict:
    """``est_x``, ``est_y`` (map px of the image centre) and ``est_theta`` (deg) of an image -> map pose."""
    if matrix is None:
        return {"est_x": math.nan, "est_y": math.nan, "est_theta": math.nan}
    h, w = shape[:2]
    x, y = to_map(np.array([[(w - 1) / 2, (h - 1) / 2]]), matrix)[0]
    return {"est_x": float(x), "est_y": float(y), "est_theta": orientation(matrix, shape)}


def judge(estimated: dict, true_pose: np.ndarray, shape, max_position_error: float = 30.0,
          max_orientation_error: float = 1.5) -> dict:
    """Errors of ``estimated`` (:func:`pose_columns`) against ``true_pose`` and whether they are within the
    survey's thresholds (Zhang et al.: 30 px, 1.5 deg)."""
    truth = pose_columns(true_pose, shape)
    position = math.hypot(estimated["est_x"] - truth["est_x"], estimated["est_y"] - truth["est_y"])
    turn = abs((estimated["est_theta"] - truth["est_theta"] + 180.0) % 360.0 - 180.0)
    if not math.isfinite(position):
        return {"position_error": math.nan, "orientation_error": math.nan, "within": False}
    return {"position_error": position, "orientation_error": turn,
            "within": position < max_position_error and turn < max_orientation_error}
