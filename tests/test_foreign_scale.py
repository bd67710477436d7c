"""Foreign keypoints described at their own scale (gtsweep.stages.scales, experiment.foreign_scale; issue 25).

Hand-worked checks: a keypoint's size picks the SIFT octave/layer or ORB level its own detector would have given
it; describing there equals describing the same keypoint in the image downscaled by that level's factor; a SIFT or
ORB keypoint stripped of its octave is described bit for bit as its own family describes it; every other
descriptor ignores the octave field, so the option changes nothing for it.
"""
import math

import cv2
import numpy as np
import pytest

from gtsweep.cli.overrides import compose_config
from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.experiments.kinds import EXPERIMENTS
from gtsweep.orchestration.settings import check_settings
from gtsweep.stages import keypoints as kp
from gtsweep.stages import scales
from gtsweep.stages.describe import DESCRIPTORS, describe, descriptor_params
from gtsweep.stages.detect import detect

OPTIONS = scales.FOREIGN_SCALES


def _texture(shape=(240, 320), blur=2.0, seed=3) -> np.ndarray:
    noise = np.random.default_rng(seed).random(shape) * 255
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), blur), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def _keypoints(x, y, size, angle=30.0, octave=0.0) -> np.ndarray:
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    rows = np.zeros((x.size, len(kp.COLUMNS)))
    rows[:, kp.X], rows[:, kp.Y], rows[:, kp.SIZE] = x.ravel(), y.ravel(), size
    rows[:, kp.ANGLE], rows[:, kp.RESPONSE], rows[:, kp.OCTAVE], rows[:, kp.CLASS_ID] = angle, 1.0, octave, -1
    return rows


def _strongest(image, detector, n=300):
    return kp.sort_by_response(detect(image, detector))[:n]


# --- SIFT ------------------------------------------------------------------------------------------------------------

def test_sift_size_to_octave_and_layer_by_hand():
    sift = cv2.SIFT_create()  # nOctaveLayers 3, sigma 1.6: size = 3.2 * 2^(octave + layer / 3)
    shape = (240, 320)  # octaves -1 .. cvRound(log2(480) - 2) - 1 = 6
    assert scales.sift_octave_range(shape) == (-1, 6)
    sizes = np.array([3.2 * 2 ** (2 + 1 / 3), 3.2 * 2 ** (1 / 3), 3.2 * 2 ** 1, 3.0, 0.5, 1000.0])
    packed = scales.sift_own_octaves(sizes, sift, shape)
    octave, layer = scales.unpack_sift_octave(packed)
    # 2 + 1/3 octaves: octave 2 layer 1; 1/3: octave 0 layer 1; exactly 1 octave = octave 0, layer 3 (layers 1..3);
    # 3 px: log2(3 / 3.2) * 3 = -0.28 -> layer 0 = octave -1 layer 3; 0.5 px and 1000 px: the ends of the range
    assert octave.tolist() == [2, 0, 0, -1, -1, 6]
    assert layer.tolist() == [1, 1, 3, 3, 1, 3]
    # the sub-layer offset in bits 16..23 as SIFT packs it: round((xi + 0.5) * 255); xi = 0 -> 128
    assert (packed[0] >> 16) == 128 and packed[0] == 2 | 1 << 8 | 128 << 16
    assert (packed[3] >> 16) == round((math.log2(3 / 3.2) * 3 + 0.5) * 255)


def test_sift_keypoints_stripped_of_their_octave_are_described_as_sift_describes_them():
    image = _texture()
    own = _strongest(image, "sift")
    assert len(np.unique(scales.unpack_sift_octave(own[:, kp.OCTAVE])[0])) >= 3  # several octaves, -1 included
    stripped = own.copy()
    stripped[:, kp.OCTAVE] = 0
    native_kept, native = describe(image, own, "sift", "sift")
    foreign_kept, foreign = describe(image, stripped, "sift", "censure", "own")
    # the size alone gives back SIFT's octave and layer (sub-layer offsets |xi| < 0.5), hence the same bytes
    assert np.array_equal(scales.unpack_sift_octave(foreign_kept[:, kp.OCTAVE])[1],
                          scales.unpack_sift_octave(native_kept[:, kp.OCTAVE])[1])
    assert np.array_equal(foreign, native)
    _, at_octave0 = describe(image, stripped, "sift", "censure", "octave0")
    assert not np.array_equal(at_octave0, native)


def test_sift_describes_a_large_keypoint_as_in_the_image_downscaled_to_its_octave():
    big = _texture((960, 1280), blur=4.0, seed=1)
    small = cv2.resize(big, (320, 240), interpolation=cv2.INTER_AREA)  # 4x smaller: octave 2
    ys, xs = np.mgrid[200:760:80, 200:1080:80]
    size = 3.2 * 2 ** (2 + 1 / 3)  # octave 2, layer 1; in the 4x smaller image octave 0, layer 1
    _, own = describe(big, _keypoints(xs, ys, size), "sift", "censure", "own")
    _, octave0 = describe(big, _keypoints(xs, ys, size), "sift", "censure", "octave0")
    _, reference = describe(small, _keypoints(xs / 4, ys / 4, size / 4), "sift", "censure", "own")

    def cosine(a, b):
        return (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)

    # measured: own 0.993..0.999, octave 0 at most 0.91 (it samples the full resolution at the finest blur)
    assert cosine(own, reference).min() > 0.98
    assert cosine(own, reference).min() > cosine(octave0, reference).max()


# --- ORB -------------------------------------------------------------------------------------------------------------

def test_orb_size_to_pyramid_level_by_hand():
    orb = DESCRIPTORS.get("orb").build({})  # patchSize 31, scaleFactor 1.2, nlevels 8
    sizes = np.array([31.0, 31 * 1.2, 31 * 1.44, 7.0, 31 * 1.2 ** 2.6, 500.0])
    assert scales.orb_own_levels(sizes, orb, (240, 320)).tolist() == [0, 1, 2, 0, 3, 7]


def test_orb_describes_a_keypoint_at_level_2_as_in_the_image_downscaled_twice_by_1_2():
    image = _texture((480, 640), blur=3.0)
    # ORB's level 2: the image resized (INTER_LINEAR_EXACT) to 1/1.2 and that again to 1/1.44 (cvRound sizes)
    level1 = cv2.resize(image, (round(640 / 1.2), round(480 / 1.2)), interpolation=cv2.INTER_LINEAR_EXACT)
    scale2 = np.float32(1.2) ** 2
    level2 = cv2.resize(level1, (round(640 / float(scale2)), round(480 / float(scale2))),
                        interpolation=cv2.INTER_LINEAR_EXACT)
    xs, ys = np.meshgrid([144.0, 288.0, 432.0], [115.2, 230.4, 345.6])  # x / 1.44 far from half pixels
    size = 31 * 1.44
    kept, own = describe(image, _keypoints(xs, ys, size), "orb", "censure", "own")
    assert (kept[:, kp.OCTAVE] == 2).all()
    _, reference = describe(level2, _keypoints(xs / 1.44, ys / 1.44, 31.0), "orb", "censure", "own")
    assert len(own) == xs.size and np.array_equal(own, reference)
    _, octave0 = describe(image, _keypoints(xs, ys, size), "orb", "censure", "octave0")
    assert not np.array_equal(octave0, own)


def test_orb_keypoints_stripped_of_their_level_are_described_as_orb_describes_them():
    image = _texture((480, 640), blur=3.0)
    own = _strongest(image, "orb", 500)
    assert len(np.unique(own[:, kp.OCTAVE])) >= 4
    stripped = own.copy()
    stripped[:, kp.OCTAVE] = 0
    native_kept, native = describe(image, own, "orb", "orb")
    foreign_kept, foreign = describe(image, stripped, "orb", "censure", "own")
    assert np.array_equal(foreign_kept, native_kept) and np.array_equal(foreign, native)


# --- every option ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("pairing", [("sift", "sift"), ("orb", "orb"), ("akaze", "akaze"), ("surf", "surf")])
def test_native_pairings_are_the_same_under_every_option(pairing):
    detector, descriptor = pairing
    image = _texture((240, 320))
    keypoints = _strongest(image, detector, 200)
    results = [describe(image, keypoints, descriptor, detector, option) for option in OPTIONS]
    for kept, descriptors in results[1:]:
        assert np.array_equal(kept, results[0][0]) and np.array_equal(descriptors, results[0][1])


#: Descriptors that ignore the octave field (scale_space None): no pyramid chosen by it.
IGNORING = [d for d in DESCRIPTORS.names() if DESCRIPTORS.get(d).scale_space is None
            and DESCRIPTORS.get(d).only_detectors is None]


def test_only_sift_and_orb_read_the_octave_field():
    assert {d for d in DESCRIPTORS.names() if DESCRIPTORS.get(d).scale_space} == {"sift", "orb"}
    assert {"brief", "latch", "brisk", "freak", "daisy", "beblid", "teblid", "surf", "xfeat"} <= set(IGNORING)


@pytest.mark.parametrize("descriptor", IGNORING)
def test_descriptors_that_ignore_the_octave_give_the_same_bytes_whatever_it_holds(descriptor):
    image = _texture((240, 320))
    keypoints = _strongest(image, "brisk", 150)  # oriented, sizes 10-70 px, octaves 0-5
    extractor = DESCRIPTORS.get(descriptor).build(descriptor_params({"params": {}}, "brisk"))
    zero, scrambled = keypoints.copy(), keypoints.copy()
    zero[:, kp.OCTAVE] = 0
    scrambled[:, kp.OCTAVE] = np.random.default_rng(0).integers(0, 6, len(keypoints))
    kept0, desc0 = extractor.compute(image, kp.to_keypoints(zero))
    kept1, desc1 = extractor.compute(image, kp.to_keypoints(scrambled))
    assert len(kept0) > 0 and np.array_equal(desc0, desc1)
    assert np.array_equal(kp.to_array(kept0)[:, :kp.OCTAVE], kp.to_array(kept1)[:, :kp.OCTAVE])
    # hence the three options give the same descriptors too
    results = [describe(image, keypoints, descriptor, "brisk", option) for option in OPTIONS]
    assert all(np.array_equal(r[1], results[0][1]) for r in results[1:])


def test_octave0_is_octave_zero_and_passthrough_the_raw_octave():
    image = _texture((480, 640), blur=3.0)
    keypoints = _keypoints([200.0, 300.0], [200.0, 250.0], 31 * 1.2 ** 3, octave=3)
    assert describe(image, keypoints, "orb", "akaze", "octave0")[0][:, kp.OCTAVE].tolist() == [0, 0]
    raw_kept, raw = describe(image, keypoints, "orb", "akaze", "passthrough")
    own_kept, own = describe(image, keypoints, "orb", "akaze", "own")  # size 31 * 1.2^3: level 3 too
    assert raw_kept[:, kp.OCTAVE].tolist() == [3, 3] and np.array_equal(raw, own)


def test_passthrough_octaves_outside_the_pyramid_are_one_line_errors():
    image = _texture((240, 320))
    msd_like = _keypoints([100.0, 150.0], [100.0, 120.0], 20.0, octave=12)  # MSD writes levels 0-16
    with pytest.raises(GtsweepError, match=r"passthrough: octaves 12\.\.12 read as SIFT octaves.*-1\.\.6$"):
        describe(image, msd_like, "sift", "msd", "passthrough")
    sift_packed = _keypoints([100.0], [100.0], 20.0, octave=2 | 1 << 8 | 128 << 16)
    with pytest.raises(GtsweepError, match="read as ORB pyramid levels"):
        describe(image, sift_packed, "orb", "msd", "passthrough")
    kept, _ = describe(image, msd_like, "sift", "msd", "own")  # own: the size's octave, whatever the raw value
    assert len(kept) == 2


def test_a_bad_option_is_one_line_before_any_work():
    with pytest.raises(BadInput, match="foreign_scale must be one of own, octave0, passthrough"):
        describe(_texture(), _keypoints([50.0], [50.0], 10.0), "sift", "orb", "octave1")
    with pytest.raises(BadInput, match="experiment.foreign_scale must be one of own, octave0, passthrough"):
        compose_config(["experiment=pose", "experiment.foreign_scale=octave1"])
    cfg = compose_config(["experiment=pose"])
    assert cfg.experiment.foreign_scale == "own"
    cfg.experiment.foreign_scale = "octave 0"
    with pytest.raises(BadInput, match="experiment.foreign_scale"):
        check_settings(cfg, EXPERIMENTS.get("pose").settings)  # the pose entry's rules
