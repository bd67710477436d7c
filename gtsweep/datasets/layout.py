"""Where camera views of the embedded data set lie on their floor: poses of single views and of pairs.

Pair statistics follow the survey (section 4): incremental pairs ("taken in direct sequence") overlap 22.7 % on
average, as little as 1.7 %, with 3 degrees mean rotation; absolute pairs ("taken at different times") overlap
43.7 % on average with 120 degrees mean rotation. Overlaps are drawn from a Beta distribution with the target
mean, clipped to [min, max]; rotations |dtheta| = max * u ** (1 / p) with p = mean / (max - mean), which has
the target mean (p = 2, the triangular law on [0, 180], for absolute pairs of dataset=synthetic); dataset=survey's
absolute pairs are revisits instead (:func:`revisit_weights`: same-direction, opposite and crossing traversals
mixed so that the mean is 120 degrees exactly). Draws are stratified (one per
quantile stratum, shuffled) so that small samples already match the targets. The translation direction is
uniform; its length is solved for the target overlap by bisection (the overlap of two centred, centrally
symmetric footprints falls monotonically along any ray).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy import stats
from scipy.stats import qmc

from gtsweep.core.errors import BadInput
from gtsweep.datasets import geometry

#: Pixels kept between a footprint and the floor's edge (room for the interpolation kernel).
MARGIN = 3.0


@dataclass(frozen=True)
class Floor:
    """A square floor of ``side`` pixels; centres of optimisation views lie in ``optimisation_box`` and all
    others in ``main_box`` (x0, y0, x1, y1); the boxes' footprints are disjoint when the floor is big enough."""

    side: int
    radius: float
    optimisation_box: tuple[float, float, float, float]
    main_box: tuple[float, float, float, float]


def footprint_radius(view_size, scale_jitter: float, reach_px: float = 0.0) -> float:
    """Largest distance from a view's centre to its footprint, plus a margin (and ``reach_px``: how far a
    camera tilt can move a corner)."""
    w, h = view_size
    return 0.5 * math.hypot(w, h) * (1 + scale_jitter) + MARGIN + reach_px


def required_side(view_size, scale_jitter: float, separate_optimisation: bool, reach_px: float = 0.0) -> int:
    """Smallest floor side that holds any pair (two footprints up to a diagonal apart)."""
    radius = footprint_radius(view_size, scale_jitter, reach_px)
    span = 2 * radius + math.hypot(*view_size) * (1 + scale_jitter)
    return int(math.ceil(span + (2 * radius if separate_optimisation else 0) + 2))


def plan_floor(side: int, view_size, scale_jitter: float, reach_px: float = 0.0,
               require_separate: bool = False) -> Floor:
    """Regions of a floor of ``side`` pixels; optimisation views get their own band if it fits (the band's
    footprints then never meet the others': the boxes of centres lie two radii apart). ``require_separate``:
    BadInput instead of sharing the floor."""
    radius = footprint_radius(view_size, scale_jitter, reach_px)
    if side < required_side(view_size, scale_jitter, False, reach_px):
        raise BadInput(f"dataset floor of {side} px is too small for {view_size[0]}x{view_size[1]} views: "
                       f"needs at least {required_side(view_size, scale_jitter, False, reach_px)} px")
    full = (radius, radius, side - radius, side - radius)
    if side < required_side(view_size, scale_jitter, True, reach_px):
        if require_separate:
            raise BadInput(f"dataset floor of {side} px has no room for a separate optimisation band: needs "
                           f"{required_side(view_size, scale_jitter, True, reach_px)} px")
        return Floor(side, radius, full, full)
    return Floor(side, radius, (radius, radius, side - radius, radius), (radius, 3 * radius, side - radius,
                                                                          side - radius))


def stratified(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` uniform draws in [0, 1): the first ``n`` points of a scrambled one-dimensional Sobol sequence
    (``scipy.stats.qmc``), so one per stratum [k/n, (k+1)/n) when ``n`` is a power of two, evenly spread for any
    ``n``, and the first ``n`` of any larger count the same points: adding pairs never moves the earlier ones."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # balance warning for n not a power of two
        return qmc.Sobol(1, scramble=True, seed=rng).random(n).ravel() if n else np.zeros(0)


def overlap_targets(rng: np.random.Generator, n: int, law: Mapping) -> np.ndarray:
    """Target overlaps: Beta with mean ``overlap_mean`` and ``overlap_concentration``, clipped."""
    mean, k = float(law["overlap_mean"]), float(law["overlap_concentration"])
    if not 0 < mean < 1 or k <= 0:
        raise BadInput(f"dataset overlap_mean must lie in (0, 1) and overlap_concentration be > 0, "
                       f"got {mean}, {k}")
    values = stats.beta.ppf(stratified(rng, n), mean * k, (1 - mean) * k)
    return np.clip(values, float(law["overlap_min"]), float(law["overlap_max"]))


def revisit_weights(law: Mapping) -> tuple[float, float, float]:
    """(same, opposite, crossing) weights of the revisit law whose mean rotation is ``rotation_mean``.

    A revisit re-traverses a path in the same direction (|r| = |N(0, s)|, mean m = s sqrt(2 / pi)), in the
    opposite one (|r| = 180 - |N(0, s)|, mean 180 - m) or crosses it (|r| uniform on [0, 180], mean 90), s being
    ``heading_noise_deg``. With the crossing share c given, the mean is (1 - c) m + o (180 - 2 m) + 90 c, so
    o = (mean - 90 c - (1 - c) m) / (180 - 2 m) and same = 1 - c - o (exact up to the folded normal's mass
    beyond 180 degrees, below 1e-9 for s <= 30).
    """
    crossing, noise, mean = float(law["crossing"]), float(law["heading_noise_deg"]), float(law["rotation_mean"])
    m = noise * math.sqrt(2.0 / math.pi)
    opposite = (mean - 90.0 * crossing - (1.0 - crossing) * m) / (180.0 - 2.0 * m)
    same = 1.0 - crossing - opposite
    if not (0 <= crossing <= 1 and 0 < noise <= 30 and same >= 0 and opposite >= 0):
        raise BadInput(f"dataset revisit law: no mixture of crossing {crossing} and heading noise {noise} deg has "
                       f"mean rotation {mean} (same {same:.3f}, opposite {opposite:.3f})")
    return same, opposite, crossing


def revisit_mean(law: Mapping) -> float:
    """Analytic mean rotation of the revisit law (equals ``rotation_mean`` by construction)."""
    same, opposite, crossing = revisit_weights(law)
    m = float(law["heading_noise_deg"]) * math.sqrt(2.0 / math.pi)
    return same * m + opposite * (180.0 - m) + crossing * 90.0


def revisit_share_below(law: Mapping, degrees: float) -> float:
    """Analytic share of revisit rotations below ``degrees`` (<= 90): same-direction ones within it, crossings."""
    same, opposite, crossing = revisit_weights(law)
    noise = float(law["heading_noise_deg"])
    return float(same * stats.halfnorm.cdf(degrees / noise) + opposite * stats.halfnorm.sf((180 - degrees) / noise)
                 + crossing * degrees / 180.0)


def revisit_magnitudes(u: np.ndarray, law: Mapping) -> np.ndarray:
    """|rotation| (degrees) at quantile levels ``u`` of the revisit law (:func:`revisit_weights`)."""
    same, opposite, crossing = revisit_weights(law)
    noise = float(law["heading_noise_deg"])
    folded = stats.halfnorm.ppf
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.clip(np.where(
            u < same, noise * folded(u / same),
            np.where(u < same + opposite, 180.0 - noise * folded((u - same) / max(opposite, 1e-12)),
                     180.0 * (u - same - opposite) / max(crossing, 1e-12))), 0.0, 180.0)


def rotation_targets(rng: np.random.Generator, n: int, law: Mapping) -> np.ndarray:
    """Signed rotations (degrees): ``rotation_law`` "revisit" (:func:`revisit_magnitudes`), else (null, the
    default) |r| = max * u ** (1 / p), p = mean / (max - mean)."""
    if law.get("rotation_law") == "revisit":
        return revisit_magnitudes(stratified(rng, n), law) * rng.choice([-1.0, 1.0], size=n)
    mean, top = float(law["rotation_mean"]), float(law["rotation_max"])
    if not 0 < mean < top <= 180:
        raise BadInput(f"dataset rotation_mean must lie in (0, rotation_max] and rotation_max <= 180, "
                       f"got {mean}, {top}")
    magnitude = top * stratified(rng, n) ** ((top - mean) / mean)
    return magnitude * rng.choice([-1.0, 1.0], size=n)


def distance_for_overlap(target: float, direction: float, rotation: float, scales, view_size) -> float:
    """Centre distance along ``direction`` (radians) at which two views overlap by ``target``.

    Returns 0 if even concentric views overlap less than ``target`` (large rotations of a non-square view).
    """
    shape = (view_size[1], view_size[0])
    reference = geometry.centred_pose(0.0, 0.0, 0.0, scales[0], shape)

    def overlap_at(distance: float) -> float:
        test = geometry.centred_pose(distance * math.cos(direction), distance * math.sin(direction), rotation,
                                     scales[1], shape)
        return geometry.overlap(reference, test, shape)

    if overlap_at(0.0) <= target:
        return 0.0
    low, high = 0.0, math.hypot(*view_size) * max(scales)
    for _ in range(40):
        middle = (low + high) / 2
        low, high = (middle, high) if overlap_at(middle) > target else (low, middle)
    return (low + high) / 2


def uniform_in(rng: np.random.Generator, box, shrink_x: float = 0.0, shrink_y: float = 0.0) -> np.ndarray:
    """A point uniform in ``box`` shrunk by the given half-extents."""
    x0, y0, x1, y1 = box
    return np.array([rng.uniform(x0 + shrink_x, x1 - shrink_x), rng.uniform(y0 + shrink_y, y1 - shrink_y)])


def single_views(rng: np.random.Generator, n: int, box, view_size, scale_jitter: float) -> list[np.ndarray]:
    """Poses of ``n`` independent views: centre uniform in ``box``, orientation uniform, scale 1 +- jitter."""
    shape = (view_size[1], view_size[0])
    return [geometry.centred_pose(*uniform_in(rng, box), rng.uniform(0, 360),
                                  rng.uniform(1 - scale_jitter, 1 + scale_jitter), shape) for _ in range(n)]


def pair_views(rng: np.random.Generator, n: int, floor: Floor, view_size, scale_jitter: float,
               law: Mapping) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``n`` (reference pose, test pose, target overlap) with overlaps and rotations following ``law``."""
    shape = (view_size[1], view_size[0])
    overlaps, rotations = overlap_targets(rng, n, law), rotation_targets(rng, n, law)
    result = []
    for target, rotation, own in zip(overlaps, rotations, rng.spawn(n)):  # a generator per pair: prefix-stable
        scales = own.uniform(1 - scale_jitter, 1 + scale_jitter, 2)
        direction, heading = own.uniform(0, 2 * math.pi), own.uniform(0, 360)
        distance = distance_for_overlap(float(target), direction, float(rotation), scales, view_size)
        turned = direction - math.radians(heading)  # the solved geometry, turned with the reference's heading
        step = distance * np.array([math.cos(turned), math.sin(turned)])
        middle = uniform_in(own, floor.main_box, abs(step[0]) / 2, abs(step[1]) / 2)
        reference = geometry.centred_pose(*(middle - step / 2), heading, scales[0], shape)
        test = geometry.centred_pose(*(middle + step / 2), heading + rotation, scales[1], shape)
        result.append((reference, test, float(target)))
    return result
