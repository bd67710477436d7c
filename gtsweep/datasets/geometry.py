"""Pose geometry shared by all data sets.

A pose is a 3x3 float64 matrix mapping image pixels to map pixels (Micro-GPS convention, Zhang et al. ICRA
2019); its orientation is ``atan2(pose[0, 1], pose[0, 0])`` as in the Micro-GPS code.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from gtsweep.evaluation.metrics import jacobian


def similarity_pose(x: float, y: float, theta_deg: float, scale: float = 1.0) -> np.ndarray:
    """Pose (image -> map) with translation (x, y), Micro-GPS orientation ``theta_deg`` and ``scale``.

    ``orientation_deg(similarity_pose(x, y, t)) == t``: the linear part is ``scale * [[c, s], [-s, c]]``.
    """
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))
    return np.array([[scale * c, scale * s, x], [-scale * s, scale * c, y], [0.0, 0.0, 1.0]])


def centred_pose(cx: float, cy: float, theta_deg: float, scale: float, shape) -> np.ndarray:
    """Pose whose image centre lands on map point (cx, cy); ``shape`` is the image's (h, w)."""
    pose = similarity_pose(0.0, 0.0, theta_deg, scale)
    h, w = shape[:2]
    offset = pose[:2, :2] @ np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    pose[:2, 2] = (cx, cy) - offset
    return pose


def orientation_deg(pose: np.ndarray, shape=None) -> float:
    """Orientation of a pose in degrees (Micro-GPS: ``atan2(pose[0, 1], pose[0, 0])``); with the image ``shape``
    (h, w), of the pose's Jacobian at the image centre (the same for affine poses; right for tilted ones)."""
    linear = pose if shape is None else jacobian(pose, ((shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0))
    return math.degrees(math.atan2(linear[0, 1], linear[0, 0]))


def rotation_deg(pose_a: np.ndarray, pose_b: np.ndarray, shape=None) -> float:
    """Absolute relative orientation of two poses in degrees, in [0, 180] (``shape``: see orientation_deg)."""
    diff = orientation_deg(pose_a, shape) - orientation_deg(pose_b, shape)
    return abs((diff + 180.0) % 360.0 - 180.0)


def footprint(pose: np.ndarray, shape) -> np.ndarray:
    """The image's outline in the map: 4x2 float32 corners (pixel-area edges -0.5 .. w-0.5), counter-clockwise."""
    h, w = shape[:2]
    corners = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]])
    mapped = corners @ np.asarray(pose, dtype=np.float64).T
    return (mapped[:, :2] / mapped[:, 2:]).astype(np.float32)


def overlap(pose_a: np.ndarray, pose_b: np.ndarray, shape) -> float:
    """Intersection area of the two image footprints in the map divided by the image area (in pixels of a).

    ``shape`` is the common image (h, w). Areas in the map are converted to image pixels with pose_a's scale.
    """
    h, w = shape[:2]
    area, _ = cv2.intersectConvexConvex(_convex(footprint(pose_a, shape)), _convex(footprint(pose_b, shape)))
    scale_sq = abs(np.linalg.det(np.asarray(pose_a, dtype=np.float64)[:2, :2]))
    return float(max(area, 0.0) / (scale_sq * h * w))


def _convex(points: np.ndarray) -> np.ndarray:
    """Corners in the orientation OpenCV expects (its hull keeps them consistent under reflections)."""
    return cv2.convexHull(points)


def centre(pose: np.ndarray, shape) -> np.ndarray:
    """Map position of the image centre."""
    h, w = shape[:2]
    return (np.asarray(pose, dtype=np.float64) @ np.array([(w - 1) / 2.0, (h - 1) / 2.0, 1.0]))[:2]


def relative(pose_reference: np.ndarray, pose_test: np.ndarray) -> np.ndarray:
    """Homography test pixel -> reference pixel: ``inv(pose_reference) @ pose_test``."""
    return np.linalg.inv(np.asarray(pose_reference, dtype=np.float64)) @ np.asarray(pose_test, dtype=np.float64)
