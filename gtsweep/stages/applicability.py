"""Which descriptor can describe which detector's keypoints: the survey's NA cells (section 5.2).

The rule needs both families, so it lives here rather than in either registry:

- the AKAZE descriptor needs AKAZE keypoints (it reads their nonlinear scale level from ``class_id``), and the KAZE
  descriptor KAZE keypoints;
- DAISY needs keypoints with an orientation;
- the ORB descriptor needs keypoints on its own pyramid scales, which excludes SIFT (the survey's LIFT too; our
  learned stand-in XFeat gives fixed-size keypoints at octave 0, which ORB describes).

NA means only this: a pairing the rule allows and that fails when run is an error, never NA.
"""
from __future__ import annotations

import numpy as np

from gtsweep.core.errors import NotApplicable
from gtsweep.stages import describe
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import DETECTORS


def applicability(detector: str, descriptor: str) -> str | None:
    """``None`` when ``descriptor`` can describe ``detector``'s keypoints, else the reason it cannot."""
    det, desc = DETECTORS.get(detector), DESCRIPTORS.get(descriptor)
    if desc.only_detectors is not None and detector not in desc.only_detectors:
        allowed = ", ".join(DETECTORS.get(d).label for d in desc.only_detectors)
        return f"the {desc.label} descriptor only describes {allowed} keypoints"
    if detector in desc.excluded_detectors:
        return f"{desc.excluded_detectors[detector]}; {det.label} keypoints are not"
    if desc.requires_orientation and not det.orientation:
        return f"the {desc.label} descriptor needs oriented keypoints; {det.label} gives no orientation"
    return None


def describe_timed(image: np.ndarray, keypoints: np.ndarray, name: str, detector: str,
                   foreign_scale: str | None = None, *, dense=None, **params):
    """:func:`gtsweep.stages.describe.describe_timed` for one pairing: :class:`NotApplicable` first when the
    survey's rule says the pairing cannot be evaluated."""
    reason = applicability(detector, name)
    if reason is not None:
        raise NotApplicable(reason)
    return describe.describe_timed(image, keypoints, name, detector, foreign_scale, dense=dense, **params)
