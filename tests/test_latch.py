"""gtsweep's LATCH: OpenCV's keypoints and descriptors, without OpenCV's read past the image.

The image is the head of a longer buffer whose tail is filled with 0 or 255: a descriptor that reads past the image
changes with the tail."""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.stages import keypoints as kp
from gtsweep.stages.describe import describe
from gtsweep.stages.latch import LATCH_create, kept_by_border

H, W = 120, 150


def _image_before(tail: int) -> np.ndarray:
    """A fixed random image whose memory is followed by ``tail`` bytes."""
    pixels = np.random.default_rng(7).integers(0, 256, (H, W), dtype=np.uint8)
    buffer = np.full(H * W + 8 * W, tail, dtype=np.uint8)
    buffer[:H * W] = pixels.ravel()
    return buffer[:H * W].reshape(H, W)


def _grid() -> np.ndarray:
    """Keypoints every quarter pixel along the right and bottom border bands (ties of both roundings included),
    at eight angles, as float32-exact (N, 7) rows."""
    xs, ys = np.meshgrid(np.arange(W - 32.0, W - 24.0, 0.25), np.arange(H - 32.0, H - 24.0, 0.25))
    angles = np.arange(0.0, 360.0, 45.0)
    n = xs.size * len(angles)
    rows = np.zeros((n, len(kp.COLUMNS)))
    rows[:, kp.X] = np.repeat(xs.ravel(), len(angles))
    rows[:, kp.Y] = np.repeat(ys.ravel(), len(angles))
    rows[:, kp.SIZE] = 12.0
    rows[:, kp.ANGLE] = np.tile(angles, xs.size)
    return kp.float32_exact(rows)


def _reads_past(kept: np.ndarray) -> np.ndarray:
    """The keypoints whose centre, rounded half up, is on the last kept column or row: they read past the image."""
    centre = np.floor(kept[:, [kp.X, kp.Y]] + 0.5)
    return (centre[:, 0] + 27 >= W) | (centre[:, 1] + 27 >= H)


def test_opencv_reads_past_the_image_and_ours_does_not():
    """Without its blur (sigma 0) OpenCV describes the caller's buffer, so its read past the image reads the tail
    this test wrote, and its descriptors follow the tail. With the blur (sigma 2, the default) it reads past its
    own blurred copy, heap memory that no caller controls: there only ours is checked, as the same whatever the
    tail (and every descriptor that stays inside the image is OpenCV's, below)."""
    keypoints = _grid()
    opencv = [cv2.xfeatures2d.LATCH_create(32, True, 3, 0.0).compute(_image_before(t), kp.to_keypoints(keypoints))
              for t in (0, 255)]
    differ = (opencv[0][1] != opencv[1][1]).any(axis=1)
    assert differ.any() and not differ[~_reads_past(kp.to_array(opencv[0][0]))].any()  # the defect, only there
    for sigma in (0.0, 2.0):
        ours = [LATCH_create(sigma=sigma).compute_array(_image_before(t), keypoints) for t in (0, 255)]
        assert np.array_equal(ours[0][0], ours[1][0]) and np.array_equal(ours[0][1], ours[1][1])


def test_the_same_keypoints_and_every_descriptor_that_stays_inside_the_image():
    keypoints = _grid()
    image = _image_before(0)
    found, expected = cv2.xfeatures2d.LATCH_create(32, True, 3, 2.0).compute(image, kp.to_keypoints(keypoints))
    kept, descriptors = LATCH_create().compute_array(image, keypoints)
    assert np.array_equal(kept, kp.to_array(found))  # OpenCV's border rule, ties to even
    outside = _reads_past(kept)
    assert 0 < outside.sum() < len(kept)
    assert np.array_equal(descriptors[~outside], expected[~outside])


def test_the_border_rule_by_hand():
    rows = np.zeros((5, len(kp.COLUMNS)))
    rows[:, kp.Y] = 60.0
    rows[:, kp.X] = [26.5, 27.0, 122.49, 122.5, 123.5]  # W - 27 = 123: rint 26 | 27 | 122 | 122 (even) | 124 (even)
    assert kept_by_border(rows, (H, W), 27).tolist() == [False, True, True, True, False]
    assert not kept_by_border(rows, (54, W), 27).any()  # an image no more than twice the border: nothing kept


def test_describe_uses_it_and_is_deterministic():
    image = _image_before(0).copy()
    keypoints = kp.to_array(cv2.ORB_create(200).detect(image))
    first = describe(image, keypoints, "latch", "orb")
    second = describe(_image_before(255), keypoints, "latch", "orb")
    assert len(first[0]) > 0
    assert np.array_equal(first[0], second[0]) and np.array_equal(first[1], second[1])
