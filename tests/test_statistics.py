"""Intervals and paired tests (gtsweep.evaluation.statistics), each against an answer worked out by hand."""
import math

import numpy as np
import pytest
from scipy import stats

from gtsweep.evaluation.statistics import (FAILS, HOLDS, INCONCLUSIVE, bootstrap_interval, clustered_difference,
                                           clustered_interval, clustered_mean, correlation_difference,
                                           correlation_interval, holm, mcnemar_exact, paired_difference, spent_alpha,
                                           verdict, wilson_interval)


def test_wilson_interval_by_hand():
    # 8 of 10, z = 1.959964: centre (0.8 + z^2/20) / (1 + z^2/10) = 0.716738,
    # half width z * sqrt(0.8 * 0.2 / 10 + z^2 / 400) / (1 + z^2/10) = 0.226576
    low, high = wilson_interval(8, 10)
    assert low == pytest.approx(0.716738 - 0.226576, abs=1e-5) and high == pytest.approx(0.716738 + 0.226576, abs=1e-5)
    assert wilson_interval(0, 5)[0] == 0.0 and wilson_interval(5, 5)[1] == pytest.approx(1.0)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))


def test_exact_mcnemar_by_hand():
    # A alone succeeds on 6 pairs, B alone on 1, both on 3: p = 2 * P(X <= 1 | n = 7, 1/2) = 2 * 8 / 128 = 0.125
    a = [1] * 6 + [0] + [1] * 3
    b = [0] * 6 + [1] + [1] * 3
    result = mcnemar_exact(a, b)
    assert result.p_value == pytest.approx(0.125) and result.difference == pytest.approx(0.5) and result.n == 10
    assert verdict(result, alpha=0.05) == INCONCLUSIVE and verdict(result, alpha=0.2) == HOLDS
    assert verdict(result, alpha=0.2, claim="less") == FAILS
    # NaN pairs (not evaluated) are left out
    assert mcnemar_exact([1, np.nan, 1], [0, 1, 0]).n == 2


def test_a_finding_on_tied_data_is_inconclusive():
    same = [1, 0, 1, 1, 0, 1, 1, 1]
    assert verdict(mcnemar_exact(same, same)) == INCONCLUSIVE
    assert mcnemar_exact(same, same).p_value == 1.0
    tied = paired_difference([0.5, 0.7, 0.9], [0.5, 0.7, 0.9])
    assert tied.p_value == 1.0 and verdict(tied) == INCONCLUSIVE


def test_paired_difference_is_an_exact_sign_flip_test_on_few_views():
    # differences 0.1, 0, 0.2, 0, 0.3: of the 2^5 sign flips, those with |mean| >= 0.12 are the 8 that keep
    # 0.1, 0.2 and 0.3 on one side (x4 for the zeros): p = 8/32 = 0.25
    result = paired_difference([0.5, 0.7, 0.9, 0.6, 0.8], [0.4, 0.7, 0.7, 0.6, 0.5])
    assert result.difference == pytest.approx(0.12) and result.p_value == pytest.approx(0.25) and result.n == 5


def test_bootstrap_interval_is_seeded_and_brackets_the_mean():
    values = np.random.default_rng(3).normal(0.7, 0.1, 40)
    first, second = bootstrap_interval(values, seed=5), bootstrap_interval(values, seed=5)
    assert first == second and first[0] < values.mean() < first[1]
    assert bootstrap_interval([0.4, np.nan, 0.4]) == (0.4, 0.4)
    assert all(math.isnan(v) for v in bootstrap_interval([np.nan]))


def test_correlation_interval():
    rho, low, high = correlation_interval([1, 2, 3, 4, 5, 6], [2, 1, 4, 3, 6, 5])
    # Spearman: d = (-1, 1, -1, 1, -1, 1), 1 - 6 * 6 / (6 * 35) = 0.828571
    assert rho == pytest.approx(0.828571, abs=1e-6) and low <= rho <= high
    assert math.isnan(correlation_interval([1, 1, 1], [1, 2, 3])[0])


def test_clustered_mean_averages_strata_of_pooled_clusters():
    # two images (clusters) x two transforms (strata): rotation 1/1 and 1/1 -> 1.0; noise 1/2 and 0/2 -> 0.25:
    # the table's value is the mean over transforms, (1.0 + 0.25) / 2 = 0.625
    sums, counts = np.array([[1.0, 1.0], [1.0, 0.0]]), np.array([[1.0, 2.0], [1.0, 2.0]])
    assert clustered_mean(sums, counts) == pytest.approx(0.625)
    # influence: rotation contributes 0 (both 1/1), noise (1 - 0.25*2)/4 = +0.125 and (0 - 0.5)/4 = -0.125, halved
    # over the 2 strata: +-0.0625; SE = sqrt(2/1 * 2 * 0.0625^2) = 0.125; t(1) = 12.706: 0.625 +- 1.588
    low, high = clustered_interval(sums, counts)
    assert (low, high) == pytest.approx((0.625 - 12.7062 * 0.125, 0.625 + 12.7062 * 0.125), abs=1e-3)


def test_rate_interval_is_a_design_effect_wilson_for_every_rate():
    # 6 images x 10 views, every view succeeds: no spread to estimate a design effect, so its bound, 6 trials,
    # with t(5) = 2.571: Wilson(6/6) low = 1 / (1 + 2.571^2 / 6) = 0.476
    ones = np.full((6, 1), 10.0)
    assert clustered_interval(ones, ones, rate=True) == pytest.approx((0.4758, 1.0), abs=1e-3)
    assert clustered_interval(0 * ones, ones, rate=True) == pytest.approx((0.0, 1 - 0.4758), abs=1e-3)
    # one view per pair (independent trials): Wilson's own interval
    assert clustered_interval(np.array([[1.0]] * 8 + [[0.0]] * 2), np.ones((10, 1)), rate=True) == \
        pytest.approx(wilson_interval(8, 10))


def test_clustered_difference_is_a_paired_t_over_images():
    # one stratum, 5 images with one view each: the paired t of the differences 0.1, 0, 0.2, 0, 0.3
    a, b = np.array([[0.5], [0.7], [0.9], [0.6], [0.8]]), np.array([[0.4], [0.7], [0.7], [0.6], [0.5]])
    ones = np.ones((5, 1))
    result = clustered_difference(a, ones, b, ones)
    expected = stats.ttest_1samp([0.1, 0, 0.2, 0, 0.3], 0.0)
    assert result.difference == pytest.approx(0.12) and result.p_value == pytest.approx(expected.pvalue)
    assert result.n == 5 and result.df == 4
    tied = clustered_difference(a, ones, a, ones)
    assert tied.p_value == 1.0 and tied.difference == 0.0


def test_holm_by_hand():
    # p sorted 0.01, 0.02, 0.04: x3, x2, x1 = 0.03, 0.04, 0.04 (monotone), in the original order
    assert list(holm([0.04, 0.01, 0.02])) == pytest.approx([0.04, 0.03, 0.04])
    assert list(holm([0.5, 0.9])) == pytest.approx([1.0, 1.0])


def test_pocock_spending_spends_alpha_by_the_end():
    assert spent_alpha(0.05, 0.0) == 0.0 and spent_alpha(0.05, 1.0) == pytest.approx(0.05)
    assert spent_alpha(0.05, 0.06) == pytest.approx(0.05 * math.log(1 + (math.e - 1) * 0.06))


def test_correlation_difference_is_judged_by_its_interval():
    success = [0.9, 0.5, 0.7, 0.6, 0.4, 0.8, 0.3]
    precision = [0.95, 0.6, 0.8, 0.7, 0.5, 0.85, 0.4]  # ranks exactly with success: rho 1
    correct = [100, 300, 200, 150, 90, 50, 120]
    result = correlation_difference(precision, correct, success)
    assert result.difference == pytest.approx(1 - stats.spearmanr(correct, success).statistic)
    assert math.isnan(result.p_value) and result.low <= result.difference <= result.high
    assert verdict(result) == (HOLDS if result.low > 0 else INCONCLUSIVE)
    assert math.isnan(correlation_difference([1, 1, 1], [1, 2, 3], [1, 1, 1]).difference)


def test_spearman_of_every_resample_at_once_is_scipys():
    from gtsweep.evaluation.statistics import _spearman

    rng = np.random.default_rng(3)
    u, v = rng.integers(0, 5, size=(50, 9)).astype(float), rng.random((50, 9))  # ties in u
    u[0] = 2.0  # a constant row has no rank correlation
    expected = [np.nan] + [stats.spearmanr(a, b).statistic for a, b in zip(u[1:], v[1:])]
    np.testing.assert_allclose(_spearman(u, v), expected, rtol=0, atol=1e-12)


def test_correlation_difference_keeps_50_resamples_in_each_tail_at_a_sequential_level():
    """At a look's level 0.001 (interval 0.998) 2000 resamples leave 2 in each tail; 50 000 leave 50: the
    interval's ends are then the 50th resample from each end, and wider than at 0.95."""
    success = [0.9, 0.5, 0.7, 0.6, 0.4, 0.8, 0.3, 0.65, 0.55]
    precision = [0.95, 0.6, 0.8, 0.7, 0.5, 0.85, 0.4, 0.62, 0.66]
    correct = [100, 300, 200, 150, 90, 50, 120, 180, 60]
    narrow = correlation_difference(precision, correct, success, confidence=0.95)
    wide = correlation_difference(precision, correct, success, confidence=0.998)
    assert wide.low <= narrow.low <= narrow.high <= wide.high
    # at 0.95: the 2000 resamples of the loop it replaced (scipy's spearmanr per resample), the same ends
    index = np.random.default_rng(0).integers(0, 9, size=(2000, 9))
    x1, x2, y = (np.asarray(v, dtype=float) for v in (precision, correct, success))
    loop = [stats.spearmanr(x1[i], y[i]).statistic - stats.spearmanr(x2[i], y[i]).statistic for i in index]
    np.testing.assert_allclose((narrow.low, narrow.high), np.nanpercentile(loop, [2.5, 97.5]), atol=1e-12)
