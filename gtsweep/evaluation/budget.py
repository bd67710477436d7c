"""Keypoint budgets per area: the survey's N = 1000 keypoints and its "< N KPs" threshold of 100 are per image of
1288x964 px at Micro-GPS's 6.25 px/mm (survey section 5), i.e. 805 keypoints per megapixel (31.5 per 1000 mm^2).
On a smaller view the same N means a higher density; ``experiment.budget_per_mpx`` (off by default) scales the
selector's ``n`` to the view's area and the "< N KPs" threshold in proportion, so a view keeps the survey's density.
"""
from __future__ import annotations

from typing import Mapping

#: The survey's images (Micro-GPS): 1288 x 964 px.
SURVEY_VIEW_PX = 1288 * 964
#: The survey's keypoint budget N per image.
SURVEY_N = 1000
#: The survey's density: N per megapixel of a 1288x964 view (805.4).
SURVEY_PER_MPX = SURVEY_N / (SURVEY_VIEW_PX / 1e6)


def scaled(selector_params: Mapping, min_keypoints: int, experiment: Mapping, shape) -> tuple[dict, int]:
    """(selector params, min_keypoints) for an image of ``shape`` (h, w): unchanged unless
    ``experiment["budget_per_mpx"]`` is set; then ``n = round(budget_per_mpx * h * w / 1e6)`` (at least 1) and
    ``min_keypoints`` scaled by the same factor against the configured ``n`` (the survey's 1000 without one)."""
    density = experiment.get("budget_per_mpx")
    if density is None:
        return dict(selector_params), int(min_keypoints)
    h, w = shape[:2]
    n = max(1, round(float(density) * h * w / 1e6))
    configured = selector_params.get("n", SURVEY_N)
    params = {**selector_params, "n": n} if "n" in selector_params else dict(selector_params)
    return params, max(1, round(min_keypoints * n / configured))
