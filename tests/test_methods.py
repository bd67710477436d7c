"""Every detector x descriptor pairing runs on a 1288x964 texture image, except exactly the survey's NA pairings."""
import numpy as np
import pytest
import yaml

from gtsweep.core.errors import BadInput, NotApplicable, UnknownMethod
from gtsweep.core.paths import CONF_DIR
from gtsweep.stages import keypoints as kp
from gtsweep.stages.applicability import applicability
from gtsweep.stages.applicability import describe_timed as describe_applicable
from gtsweep.stages.describe import DESCRIPTORS, describe, descriptor_params
from gtsweep.stages.detect import DETECTORS, detect
from gtsweep.stages.select import select_nms

DETECTOR_NAMES = ("harris", "gftt", "fast", "agast", "harris_laplace", "sift", "surf", "censure", "brisk", "orb",
                  "akaze", "kaze", "mser", "msd", "xfeat", "aliked_n16", "aliked_n16rot", "disk")
DESCRIPTOR_NAMES = ("orb", "brief", "latch", "surf", "sift", "akaze", "brisk", "freak", "daisy", "beblid", "teblid",
                    "kaze", "xfeat", "aliked_n16", "aliked_n16rot", "disk")
# torch's learned methods take seconds per full-size image on 2 cores: tests/test_learned.py runs them on small
# images, every other detector's keypoints included; the full-size loops below leave them out.
TORCH_LEARNED = ("aliked_n16", "aliked_n16rot", "disk")
# Keypoints without an orientation: KAZE computes its own only when describing, HarrisLaplace reports 0, and XFeat
# (our stand-in for LIFT, which had one: survey 0.66 with DAISY) gives none.
UNORIENTED = ("harris", "gftt", "fast", "agast", "harris_laplace", "censure", "kaze", "mser", "msd", "xfeat",
              *TORCH_LEARNED)

# The survey's NA rules (Tables 4 and 5, section 5.2), and nothing else is NA.
EXPECTED_NA = {
    ("sift", "orb"),  # the ORB descriptor needs keypoints on its own pyramid scales; SIFT's are not
    *[(d, "daisy") for d in UNORIENTED],  # DAISY needs oriented keypoints
    *[(d, "akaze") for d in DETECTOR_NAMES if d != "akaze"],  # the AKAZE descriptor only on AKAZE keypoints
    *[(d, "kaze") for d in DETECTOR_NAMES if d != "kaze"],  # the KAZE descriptor only on KAZE keypoints
}


def _config(group, name):
    return yaml.safe_load((CONF_DIR / group / f"{name}.yaml").read_text())[name]


@pytest.fixture(scope="module")
def selected(gravel_1288x964):
    """1000 strongest keypoints per detector (as in the survey), with the detector's configured parameters."""
    return {name: select_nms(detect(gravel_1288x964, name, **_config("detector", name)["params"]),
                             gravel_1288x964.shape, 1000)
            for name in DETECTORS if name not in TORCH_LEARNED}


def test_registries_hold_the_methods_the_na_set_is_written_for():
    assert list(DETECTORS) == list(DETECTOR_NAMES) and list(DESCRIPTORS) == list(DESCRIPTOR_NAMES)
    assert {name for name in DETECTORS if not DETECTORS[name].orientation} == set(UNORIENTED)


def test_na_pairings_are_exactly_the_survey_rules():
    na = {(d, s) for d in DETECTORS for s in DESCRIPTORS if applicability(d, s) is not None}
    assert na == EXPECTED_NA


@pytest.mark.slow
def test_every_applicable_pairing_runs(gravel_1288x964, selected):
    """Each pairing outside EXPECTED_NA describes most of its keypoints; any error fails the test."""
    for detector, keypoints in selected.items():
        assert len(keypoints) > 0, detector
        for descriptor in (d for d in DESCRIPTORS if d not in TORCH_LEARNED):
            params = descriptor_params(_config("descriptor", descriptor), detector)
            if (detector, descriptor) in EXPECTED_NA:
                with pytest.raises(NotApplicable) as info:
                    describe_applicable(gravel_1288x964, keypoints, descriptor, detector, **params)
                assert info.value.reason, "an NA pairing must say why"
                continue
            kept, desc, _ = describe_applicable(gravel_1288x964, keypoints, descriptor, detector, **params)
            assert len(kept) == len(desc) > 0.5 * len(keypoints), (detector, descriptor, len(kept))
            assert np.isfinite(kept[:, :3]).all()


def test_applicability_reasons_name_the_requirement():
    assert "AKAZE" in applicability("sift", "akaze")
    assert "orientation" in applicability("censure", "daisy")
    assert "ORB" in applicability("sift", "orb")
    assert "KAZE" in applicability("akaze", "kaze")
    assert applicability("akaze", "akaze") is None
    assert applicability("censure", "orb") is None  # runs; collapses on rotated pairs, as in the survey


def test_detector_capabilities_match_their_output(gravel_1288x964):
    image = gravel_1288x964[:480, :640]
    for name in ("sift", "akaze", "orb", "brisk"):
        assert DETECTORS[name].orientation
        assert np.ptp(detect(image, name)[:, kp.ANGLE]) > 0
    for name in ("censure", "fast", "gftt", "harris_laplace", "mser"):
        assert not DETECTORS[name].orientation
        assert (detect(image, name)[:, kp.ANGLE] == -1).all()


def test_mser_response_is_detection_order(gravel_1288x964):
    found = detect(gravel_1288x964[:480, :640], "mser")
    # the first region found gets the largest response: N, N-1, ..., 1
    assert np.array_equal(found[:, kp.RESPONSE], np.arange(len(found), 0, -1))


def test_mask_is_honoured(gravel_1288x964):
    mask = np.zeros(gravel_1288x964.shape, np.uint8)
    mask[100:400, 200:600] = 255
    for name in ("sift", "fast", "akaze", "orb", "censure"):
        found = detect(gravel_1288x964, name, mask)
        assert len(found) > 0
        assert found[:, 0].min() >= 199 and found[:, 0].max() <= 600 and found[:, 1].min() >= 99, name


def test_bad_names_and_parameters_give_one_line():
    image = np.zeros((64, 64), np.uint8)
    with pytest.raises(UnknownMethod, match="valid choices: .*sift"):
        detect(image, "sifft")
    with pytest.raises(BadInput, match="nfeaturez"):
        detect(image, "orb", nfeaturez=10)
    with pytest.raises(BadInput, match="2-D uint8"):
        detect(image.astype(np.float32), "orb")
    for error in (UnknownMethod("detector", "x", ["a"]), BadInput("y")):
        assert "\n" not in str(error)


def test_descriptor_octave_is_reset_for_foreign_keypoints(gravel_1288x964):
    # SIFT packs octave/layer into a large integer; ORB or SIFT on such foreign keypoints would try to allocate
    # ~68 GB. BRIEF on SIFT keypoints and SIFT on MSD-like octaves must simply work.
    image = gravel_1288x964[:480, :640]
    keypoints = select_nms(detect(image, "sift"), image.shape, 300)
    assert keypoints[:, kp.OCTAVE].max() > 255
    kept, desc = describe(image, keypoints, "latch", "sift")
    assert len(kept) == len(desc) > 200
    fake_msd = keypoints.copy()
    fake_msd[:, kp.OCTAVE] = 14
    kept, desc = describe(image, fake_msd, "sift", "msd")
    assert desc.shape[1] == 128


def test_per_detector_descriptor_params():
    cfg = {"params": {"scale_factor": 5.0, "n_bits": 100}, "per_detector": {"sift": {"scale_factor": 6.75}}}
    assert descriptor_params(cfg, "sift") == {"scale_factor": 6.75, "n_bits": 100}
    assert descriptor_params(cfg, "fast") == {"scale_factor": 5.0, "n_bits": 100}
