"""experiment.budget_per_mpx: keypoint budgets per area (the survey's N = 1000 per 1288x964 view)."""
from __future__ import annotations

import pytest

from gtsweep.evaluation import budget


def test_off_by_default_keeps_the_budget():
    assert budget.scaled({"n": 1000}, 100, {}, (480, 640)) == ({"n": 1000}, 100)
    assert budget.scaled({"n": 1000}, 100, {"budget_per_mpx": None}, (480, 640)) == ({"n": 1000}, 100)


def test_survey_density_on_a_quarter_view():
    assert budget.SURVEY_PER_MPX == pytest.approx(805.4, abs=0.05)
    params, few = budget.scaled({"n": 1000, "other": 1}, 100, {"budget_per_mpx": budget.SURVEY_PER_MPX}, (964, 1288))
    assert params == {"n": 1000, "other": 1} and few == 100  # the survey's own view size: unchanged
    params, few = budget.scaled({"n": 1000}, 100, {"budget_per_mpx": budget.SURVEY_PER_MPX}, (480, 640))
    assert params == {"n": 247} and few == 25  # 640 x 480 = 0.307 Mpx x 805.4 = 247.4; 100 x 247 / 1000 = 24.7


def test_selector_without_n_scales_only_the_threshold():
    params, few = budget.scaled({}, 100, {"budget_per_mpx": 805.4}, (482, 644))
    assert params == {} and few == 25
