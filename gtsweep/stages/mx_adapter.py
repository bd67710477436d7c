"""TEMPORARY stand-in for the matcher/estimator registries of branch h-mx (deleted when it is merged)."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from gtsweep.core.registry import Method, Registry
from gtsweep.stages.match import match_descriptors
from gtsweep.stages.pose import estimate_pose


@dataclass(frozen=True)
class _Index:
    reference: np.ndarray
    norm: str
    ratio: float
    mutual: bool

    def match(self, test):
        return match_descriptors(test, self.reference, self.norm, self.ratio, self.mutual)


@dataclass(frozen=True)
class _BF:
    ratio: float = 0.7
    mutual: bool = False

    def index(self, reference, norm):
        return _Index(np.ascontiguousarray(reference), norm, self.ratio, self.mutual)


@dataclass(frozen=True)
class _Ransac:
    model: str = "similarity"
    iterations: int = 2000
    threshold: float = 3.0

    def estimate(self, test_xy, ref_xy, seed=0):
        return estimate_pose(test_xy, ref_xy, self.model, self.iterations, self.threshold, seed)


MATCHERS = Registry("matcher", [Method("matcher", "bf_ratio", "BF+ratio", _BF, {"ratio": 0.7, "mutual": False}),
                                Method("matcher", "mutual_nn", "mutual NN",
                                       functools.partial(_BF, ratio=1.0, mutual=True), {})])
ESTIMATORS = Registry("estimator", [Method("estimator", "ransac", "RANSAC", _Ransac,
                                           {"model": "similarity", "iterations": 2000, "threshold": 3.0})])


def applicability(matcher, norm):
    return None
