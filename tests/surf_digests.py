"""Digests of gtsweep's NumPy SURF output, which ``tests/test_surf_identity.py`` pins.

Rewrites of the SURF code must give the same keypoints and descriptors bit for bit (or else bump
``gtsweep.stages.surf.IMPLEMENTATION_VERSION``, which enters the keypoint-cache and reuse keys). The digests are
SHA-256 of the arrays' bytes (keypoints as float64 ``(N, 7)`` rows, descriptors float32), so the test stores a few
hundred bytes instead of the arrays. Run this with the code whose output is the reference and paste what it prints::

    python tests/surf_digests.py            # the reference crops (fast)
    python tests/surf_digests.py --survey   # also one 1288x964 survey view (renders it: ~15 s)
"""
from __future__ import annotations

import argparse
import hashlib
from pathlib import Path

import numpy as np

from gtsweep.stages.surf import NumpySURF

REFERENCE = Path(__file__).resolve().parent / "data" / "surf_reference.npz"
#: (extended, upright) variants pinned on every image.
VARIANTS = ((False, False), (True, False), (False, True), (True, True))
#: The survey view pinned: its data set overrides, texture and split.
SURVEY_VIEW = ("coarse_asphalt", "synthetic", 0)


def digest(*arrays: np.ndarray) -> str:
    """SHA-256 (first 16 hex digits) of the arrays' dtypes, shapes and bytes."""
    h = hashlib.sha256()
    for array in arrays:
        array = np.ascontiguousarray(array)
        h.update(f"{array.dtype.str}{array.shape}".encode())
        h.update(array.tobytes())
    return h.hexdigest()[:16]


def variant_name(extended: bool, upright: bool) -> str:
    return ("extended" if extended else "plain") + ("_upright" if upright else "")


def crop_outputs(reference: dict) -> dict[str, str]:
    """Digests of detect-and-compute (every variant) and of compute on the foreign keypoints, per crop."""
    out = {}
    for name in ("gravel", "brick"):
        image = reference[f"{name}_image"]
        for extended, upright in VARIANTS:
            kps, desc = NumpySURF(extended=extended, upright=upright).detect_and_compute_array(image)
            out[f"{name}/{variant_name(extended, upright)}"] = digest(kps, desc)
        kept, desc = NumpySURF().compute_array(image, reference[f"{name}_foreign_in"])
        out[f"{name}/foreign"] = digest(kept, desc)
    return out


def survey_view() -> np.ndarray:
    """The pinned 1288x964 survey view (rendered by the survey data set; cached in .gtsweep_cache)."""
    from gtsweep.cli.overrides import compose_config
    from gtsweep.datasets import load_dataset

    texture, split, index = SURVEY_VIEW
    cfg = compose_config(["dataset=survey", f"dataset.textures=[{texture}]", "dataset.n_synthetic=1",
                          "dataset.n_incremental=0", "dataset.n_absolute=0", "dataset.n_optimisation=0"])
    return load_dataset(cfg.dataset).images(split)[index].load()


def view_outputs(image: np.ndarray) -> dict:
    """Digests on a survey view: the image, detect-and-compute (plain and extended), and compute on the 1000
    strongest (NMS) SURF keypoints and on SIFT's (foreign: small windows, enlarged), with their row counts and
    the first four values of their first descriptors (float32, exactly)."""
    from gtsweep.stages.describe import describe
    from gtsweep.stages.detect import detect
    from gtsweep.stages.select import select_nms

    out = {"image": digest(image)}
    for extended in (False, True):
        kps, desc = NumpySURF(extended=extended).detect_and_compute_array(image)
        out[f"view/{variant_name(extended, False)}"] = digest(kps, desc)
    for detector in ("surf", "sift"):
        keypoints = select_nms(detect(image, detector, None), image.shape, n=1000)
        kept, desc = describe(image, keypoints, "surf", detector)
        out[f"view/nms1000_{detector}"] = digest(kept, desc)
        out[f"view/nms1000_{detector}/rows"] = len(desc)
        out[f"view/nms1000_{detector}/first"] = [float(v) for v in desc[0, :4]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survey", action="store_true", help="also the 1288x964 survey view")
    args = parser.parse_args()
    with np.load(REFERENCE) as data:
        digests = crop_outputs({key: data[key] for key in data.files})
    if args.survey:
        digests.update(view_outputs(survey_view()))
    for key, value in digests.items():
        print(f'    "{key}": {value!r},')


if __name__ == "__main__":
    main()
