"""Make ``tests/data/surf_reference.npz``: OpenCV's own SURF results on two small real texture crops.

Needs an OpenCV built with ``OPENCV_ENABLE_NONFREE=ON`` (the PyPI wheels exclude SURF), kept outside the
project's environment, e.g.::

    PYTHONPATH=/tmp/cvnonfree-prefix/python /tmp/cvnonfree/bin/python tools/make_surf_reference.py

It stores, per image (320x240 crops of scikit-image's ``gravel`` and ``brick``): the crop; OpenCV's keypoints
(x, y, size, angle, response, octave, class_id) for the default parameters, upright, a detection mask and one
non-default parameter set; descriptors (64 and 128, upright and not) of the strongest keypoints; and the
keypoints kept and descriptors computed for a fixed set of foreign keypoints (any size, angle and octave, some
at or beyond the border). Descriptors are stored as float16 to keep the file small.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import skimage.data

CROPS = {"gravel": (slice(100, 340), slice(60, 380)), "brick": (slice(200, 440), slice(150, 470))}
#: Descriptor rows kept per configuration (the strongest keypoints come first in OpenCV's order).
DESCRIPTOR_ROWS = 300
#: A non-default parameter set (hessianThreshold, nOctaves, nOctaveLayers).
OTHER_PARAMS = (400.0, 3, 2)


def keypoint_rows(keypoints) -> np.ndarray:
    """``(N, 7)`` float32 rows (x, y, size, angle, response, octave, class_id): exact for OpenCV's fields."""
    return np.array([(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave, k.class_id) for k in keypoints],
                    dtype=np.float32).reshape(-1, 7)


def foreign_keypoints(shape, seed=7, count=120) -> np.ndarray:
    """Keypoints another detector could give: random positions (some outside), sizes 0.5-120, angles, octaves."""
    rng = np.random.default_rng(seed)
    rows, cols = shape
    x = rng.uniform(-60, cols + 60, count)
    y = rng.uniform(-60, rows + 60, count)
    size = rng.choice([0.5, 3.0, 7.0, 12.5, 20.0, 31.0, 45.0, 80.0, 120.0], count)
    angle = rng.uniform(0, 360, count)
    octave = rng.integers(-1, 8, count)
    return np.column_stack([x, y, size, angle, np.zeros(count), octave, -np.ones(count)]).astype(np.float32)


def mask_for(shape) -> np.ndarray:
    """A disc of radius 0.4 * min(shape) centred in the image (uint8, 255 inside)."""
    mask = np.zeros(shape, np.uint8)
    cv2.circle(mask, (shape[1] // 2, shape[0] // 2), int(0.4 * min(shape)), 255, -1)
    return mask


def reference(name: str, image: np.ndarray) -> dict:
    out = {f"{name}_image": image}
    for upright in (False, True):
        tag = "_upright" if upright else ""
        for extended in (False, True):
            surf = cv2.xfeatures2d.SURF_create(100, 4, 3, extended, upright)
            kps, desc = surf.detectAndCompute(image, None)
            out[f"{name}_kp{tag}"] = keypoint_rows(kps)
            out[f"{name}_desc{128 if extended else 64}{tag}"] = desc[:DESCRIPTOR_ROWS].astype(np.float16)
    surf = cv2.xfeatures2d.SURF_create()
    out[f"{name}_kp_mask"] = keypoint_rows(surf.detect(image, mask_for(image.shape)))
    out[f"{name}_kp_other"] = keypoint_rows(cv2.xfeatures2d.SURF_create(*OTHER_PARAMS).detect(image))
    given = foreign_keypoints(image.shape)
    kps = [cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o), int(c))
           for x, y, s, a, r, o, c in given]
    kept, desc = surf.compute(image, kps)
    out[f"{name}_foreign_in"] = given
    out[f"{name}_foreign_kp"] = keypoint_rows(kept)
    out[f"{name}_foreign_desc64"] = desc.astype(np.float16)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default_out = Path(__file__).resolve().parents[1] / "tests/data/surf_reference.npz"
    parser.add_argument("--out", type=Path, default=default_out)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    cv2.xfeatures2d.SURF_create()  # fails fast without a nonfree build
    data = {}
    for name, crop in CROPS.items():
        image = np.ascontiguousarray(getattr(skimage.data, name)()[crop])
        data.update(reference(name, image))
        print(f"{name}: {len(data[f'{name}_kp'])} keypoints, {len(data[f'{name}_foreign_kp'])} of "
              f"{len(data[f'{name}_foreign_in'])} foreign keypoints kept")
    data["opencv_version"] = np.array(cv2.__version__)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **data)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
