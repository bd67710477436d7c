"""Feature description (survey section 2.3): a registry of descriptors, their norms and their requirements.

A descriptor declares which keypoints it can describe (``only_detectors``, ``excluded_detectors``,
``requires_orientation``); :mod:`gtsweep.stages.applicability` turns that into the survey's NA cells (section 5.2),
since it needs the detectors' capabilities too. Foreign keypoints (another detector family's) get the octave field
of the descriptor's own scale space that their size implies (``scale_space``; ``experiment.foreign_scale``
chooses another option: :mod:`gtsweep.stages.scales`), and keypoints without an orientation are described upright
(angle 0).
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.registry import Method, Registry, lazy_factory, reason_line, spec_declare
from gtsweep.stages import keypoints as kp
from gtsweep.stages import scales
from gtsweep.stages.latch import LATCH_create
from gtsweep.stages.learned import ALIKED_VARIANTS

_x = cv2.xfeatures2d
HAMMING, L2 = "hamming", "l2"


def _first_octave(prepared: np.ndarray) -> int:
    """The octave OpenCV's SIFT builds its pyramid from for these keypoints: the lowest, at most 0."""
    return min(int(scales.unpack_sift_octave(prepared[:, kp.OCTAVE].astype(np.int64))[0].min()), 0)


#: How a descriptor with ``together`` groups keypoint sets of one image into calls (sets of one group are
#: described by one call, with the descriptors separate calls give): DAISY's cost is a pass over the image and a
#: keypoint's descriptor does not depend on the others; SIFT's pyramid depends only on the lowest octave given.
TOGETHER = {"image": lambda prepared: 0, "first_octave": _first_octave}


@dataclass(frozen=True, kw_only=True)
class DescriptorSpec(Method):
    """A descriptor, how its vectors are compared, and what keypoints it can describe."""

    norm: str  # HAMMING for binary, L2 for real-valued descriptors
    requires_orientation: bool = False
    only_detectors: tuple[str, ...] | None = None  # None: any detector
    excluded_detectors: dict[str, str] = field(default_factory=dict)  # detector -> reason
    learned: bool = False
    #: How it reads a keypoint's octave field (a key of :data:`gtsweep.stages.scales.SCALE_SPACES`); None: it
    #: ignores the field, and foreign keypoints get octave 0.
    scale_space: str | None = None
    #: Several keypoint sets of one image (every detector's, every reference count) can be described in one
    #: call, grouped as :data:`TOGETHER` says, with the descriptors separate calls give: ``image`` (DAISY, whose
    #: cost is a pass over the image: 280 ms for 1 keypoint or 1000 on a 1288×964 view), ``first_octave`` (SIFT,
    #: whose pyramid is built from the lowest octave given); None: one call per set (:func:`describe_batch`).
    together: str | None = None

    def __post_init__(self):
        if self.norm not in (HAMMING, L2):
            raise BadInput(f"descriptor '{self.name}': norm must be {HAMMING} (binary) or {L2}, got {self.norm!r}")
        if self.together is not None and self.together not in TOGETHER:
            raise BadInput(f"descriptor '{self.name}': together must be one of {', '.join(TOGETHER)} or null, "
                           f"got {self.together!r}")
        if self.scale_space is not None and self.scale_space not in scales.SCALE_SPACES:
            raise BadInput(f"descriptor '{self.name}': scale_space must be one of "
                           f"{', '.join(scales.SCALE_SPACES)} or null, got {self.scale_space!r}")


_descriptor = functools.partial(DescriptorSpec, "descriptor")
_ORB_SCALES = "the ORB descriptor needs keypoints on its own pyramid scales (survey 5.2)"
_NONLINEAR = {"extended": False, "upright": False}  # KAZE's M-SURF, and SURF's own switches
_LEARNED = functools.partial(lazy_factory, "gtsweep.stages.learned")
_BLID = {"scale_factor": 5.0}  # BEBLID/TEBLID; per_detector in their YAML adapts it to each keypoint size

DESCRIPTORS: Registry[DescriptorSpec] = Registry("descriptor", [
    _descriptor("orb", "ORB", cv2.ORB_create, {"edgeThreshold": 31, "patchSize": 31, "WTA_K": 2}, norm=HAMMING,
                excluded_detectors={"sift": _ORB_SCALES}, scale_space="orb"),
    # The survey's BRIEF uses the keypoint orientation (it collapses on unoriented keypoints for absolute pairs).
    _descriptor("brief", "BRIEF", _x.BriefDescriptorExtractor_create, {"bytes": 32, "use_orientation": True},
                norm=HAMMING),
    # OpenCV's LATCH, given one reflected column and row beyond the image it otherwise reads past
    # (gtsweep.stages.latch): the same keypoints and descriptors, deterministic at the border.
    _descriptor("latch", "LATCH", LATCH_create,
                {"bytes": 32, "rotationInvariance": True, "half_ssd_size": 3, "sigma": 2.0}, norm=HAMMING),
    _descriptor("surf", "SURF", lazy_factory("gtsweep.stages.surf", "SURF_create"),
                {"hessianThreshold": 100.0, "nOctaves": 4, "nOctaveLayers": 3, **_NONLINEAR}, norm=L2),
    _descriptor("sift", "SIFT", cv2.SIFT_create, {"nOctaveLayers": 3, "sigma": 1.6}, norm=L2,
                scale_space="sift", together="first_octave"),
    # descriptor_type 5 = DESCRIPTOR_MLDB
    _descriptor("akaze", "AKAZE", _x.AKAZE_create,
                {"descriptor_type": 5, "descriptor_size": 0, "descriptor_channels": 3}, norm=HAMMING,
                only_detectors=("akaze",)),
    _descriptor("brisk", "BRISK", _x.BRISK_create, {"thresh": 30, "octaves": 3, "patternScale": 1.0},
                norm=HAMMING),
    _descriptor("freak", "FREAK", _x.FREAK_create,
                {"orientationNormalized": True, "scaleNormalized": True, "patternScale": 22.0, "nOctaves": 4},
                norm=HAMMING),
    # norm 100 = NRM_NONE
    _descriptor("daisy", "DAISY", _x.DAISY_create,
                {"radius": 15.0, "q_radius": 3, "q_theta": 8, "q_hist": 8, "norm": 100, "interpolation": True,
                 "use_orientation": True}, norm=L2, requires_orientation=True, together="image"),
    # Beyond the survey: learned binary descriptors shipped with OpenCV, KAZE, and the learned XFeat.
    _descriptor("beblid", "BEBLID", _x.BEBLID_create, {**_BLID, "n_bits": 100}, norm=HAMMING),  # 512 bits
    _descriptor("teblid", "TEBLID", _x.TEBLID_create, {**_BLID, "n_bits": 102}, norm=HAMMING),  # 256 bits
    _descriptor("kaze", "KAZE", _x.KAZE_create, _NONLINEAR, norm=L2, only_detectors=("kaze",)),
    _descriptor("xfeat", "XFeat", lazy_factory("gtsweep.stages.xfeat", "XFeat_create"), {}, norm=L2,
                learned=True),
    # ALIKED and DISK describe any keypoints (gtsweep.stages.learned): 128 floats, L2.
    *(_descriptor(name, label, functools.partial(_LEARNED("ALIKED_create"), model_name=model), {}, norm=L2,
                  learned=True, extra="learned") for name, label, model in ALIKED_VARIANTS),
    _descriptor("disk", "DISK", _LEARNED("DISK_create"), {}, norm=L2, learned=True, extra="learned"),
], spec=DescriptorSpec, make=spec_declare(DescriptorSpec, "descriptor"))

#: Detectors whose keypoints carry an ``octave`` that the same-named descriptor understands.
_OWN_OCTAVE = {"orb", "sift", "akaze", "kaze", "brisk", "surf"}


def descriptor_params(descriptor_cfg: dict, detector: str) -> dict:
    """The parameters of a descriptor config for keypoints of ``detector``.

    A config holds ``params`` and optionally ``per_detector: {<detector>: {<param>: value}}`` overrides (e.g. the
    sampling scale of BEBLID/TEBLID, which depends on the detector's keypoint size convention).
    """
    params = dict(descriptor_cfg.get("params") or {})
    params.update((descriptor_cfg.get("per_detector") or {}).get(detector) or {})
    return params


def describe(image: np.ndarray, keypoints: np.ndarray, name: str, detector: str, foreign_scale: str | None = None,
             **params):
    """Describe ``keypoints`` (an ``(N, 7)`` array from ``detector``) in ``image`` with descriptor ``name``.

    Returns ``(kept_keypoints, descriptors)``: descriptors may drop keypoints (e.g. near the border), so the
    returned keypoints are the ones aligned with the descriptor rows. Binary descriptors are uint8, real-valued
    ones float32. ``foreign_scale`` (one of :data:`gtsweep.stages.scales.FOREIGN_SCALES`, None: ``own``) says
    where foreign keypoints are described. It does not judge the pairing: :mod:`gtsweep.stages.applicability` says which
    the survey calls NA.
    """
    kept, descriptors, _ = describe_timed(image, keypoints, name, detector, foreign_scale, **params)
    return kept, descriptors


def describe_timed(image: np.ndarray, keypoints: np.ndarray, name: str, detector: str,
                   foreign_scale: str | None = None, *, dense=None, **params):
    """:func:`describe` plus the wall time in seconds of the descriptor call itself. ``dense``: where a
    descriptor that samples a dense per-image map (XFeat) keeps it between calls
    (:class:`gtsweep.orchestration.cache.DenseMapCache`); the descriptors are the same without it."""
    spec = DESCRIPTORS.get(name)
    extractor = spec.build(params)
    if dense is not None and hasattr(extractor, "use_dense_cache"):
        extractor.use_dense_cache(dense)
    prepared = prepare_keypoints(keypoints, detector, spec, extractor, np.shape(image)[:2],
                                 scales.check_foreign_scale(foreign_scale))
    if len(prepared) == 0:
        return kp.empty(), _empty_descriptors(spec, extractor), 0.0
    start = time.perf_counter()
    try:
        if hasattr(extractor, "compute_array"):  # gtsweep's own extractors (NumPy SURF): arrays in and out
            kept, descriptors = extractor.compute_array(image, kp.float32_exact(prepared))
        else:
            found, descriptors = extractor.compute(image, kp.to_keypoints(prepared))
            kept = kp.to_array(found) if descriptors is not None else kp.empty()
    except cv2.error as e:
        raise GtsweepError(f"descriptor '{name}' failed on {detector} keypoints: {reason_line(e)}") from None
    seconds = time.perf_counter() - start
    if descriptors is None or len(kept) == 0:
        return kp.empty(), _empty_descriptors(spec, extractor), seconds
    return kept, np.ascontiguousarray(descriptors), seconds


def describe_batch(image: np.ndarray, requests: list[tuple[str, np.ndarray]], name: str,
                   foreign_scale: str | None = None, **params) -> list[tuple[np.ndarray, np.ndarray, float] | None]:
    """:func:`describe_timed` for several keypoint sets of one image (``requests``: ``(detector, keypoints)``)
    with as few calls as a descriptor that can describe them ``together`` allows: one for DAISY, one per first
    octave for SIFT. Each set's ``(kept, descriptors, seconds)`` equals its own call's, the seconds aside: a
    call's time is shared equally by the sets it served; None for a set whose keypoints cannot be prepared (its
    own call raises why). Raises :class:`GtsweepError` when a call drops or
    reorders keypoints (the descriptor cannot describe sets together); a failed call raises as
    :func:`describe_timed`'s does."""
    spec = DESCRIPTORS.get(name)
    if spec.together is None:
        raise GtsweepError(f"descriptor '{name}' cannot describe several keypoint sets in one call")
    extractor = spec.build(params)
    foreign_scale = scales.check_foreign_scale(foreign_scale)
    results: list[tuple | None] = [(kp.empty(), _empty_descriptors(spec, extractor), 0.0)] * len(requests)
    prepared, groups = [], {}
    for i, (detector, keypoints) in enumerate(requests):
        try:
            prepared.append(prepare_keypoints(keypoints, detector, spec, extractor, np.shape(image)[:2],
                                              foreign_scale))
        except GtsweepError:  # e.g. octaves the survey's pass-through cannot express: None, its own call says why
            prepared.append(kp.empty())
            results[i] = None
            continue
        if len(prepared[i]):
            groups.setdefault(TOGETHER[spec.together](prepared[i]), []).append(i)
    for members in groups.values():
        batch = np.concatenate([prepared[i] for i in members])
        start = time.perf_counter()
        try:
            found, descriptors = extractor.compute(image, kp.to_keypoints(batch))
        except cv2.error as e:
            raise GtsweepError(f"descriptor '{name}' failed on {', '.join(requests[i][0] for i in members)} "
                               f"keypoints: {reason_line(e)}") from None
        share = (time.perf_counter() - start) / len(members)
        kept = kp.to_array(found) if descriptors is not None else kp.empty()
        if descriptors is None or len(kept) != len(batch):
            raise GtsweepError(f"descriptor '{name}' kept {len(kept)} of {len(batch)} keypoints: it cannot "
                               f"describe several keypoint sets in one call")
        end = 0
        for i in members:
            part = slice(end, end + len(prepared[i]))
            results[i] = kept[part].copy(), np.ascontiguousarray(descriptors[part]), share
            end = part.stop
    return results


def prepare_keypoints(keypoints: np.ndarray, detector: str, spec: DescriptorSpec, extractor, shape,
                      foreign_scale: str = scales.OWN) -> np.ndarray:
    """A copy of ``keypoints`` as descriptor ``spec`` (built as ``extractor``) is given them in an image of
    ``shape``: the octave field of foreign keypoints set by ``foreign_scale`` (:mod:`gtsweep.stages.scales`; own
    keypoints keep theirs), unoriented keypoints at angle 0."""
    prepared = np.array(keypoints, dtype=np.float64, copy=True).reshape(-1, len(kp.COLUMNS))
    if detector != spec.name or detector not in _OWN_OCTAVE:
        prepared[:, kp.OCTAVE] = scales.foreign_octaves(
            prepared[:, kp.SIZE], prepared[:, kp.OCTAVE], spec.scale_space, foreign_scale, extractor, shape,
            f"descriptor '{spec.name}' on {detector} keypoints")
    prepared[prepared[:, kp.ANGLE] < 0, kp.ANGLE] = 0.0
    return prepared


def _empty_descriptors(spec: DescriptorSpec, extractor) -> np.ndarray:
    dtype = np.uint8 if spec.norm == HAMMING else np.float32
    return np.zeros((0, int(extractor.descriptorSize())), dtype=dtype)
