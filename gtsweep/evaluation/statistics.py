"""Uncertainty of the survey's numbers and paired tests between methods, from SciPy.

Every number of a table is a mean over a few dozen views or pairs; these functions say how sure it is:

- :func:`wilson_interval`: a success rate's 95 % interval (Wilson 1927), from ``scipy.stats.binomtest``;
- :func:`bootstrap_interval`: a mean's seeded percentile bootstrap interval over views, ``scipy.stats.bootstrap``;
- :func:`mcnemar_exact`: two methods' success on the SAME pairs (exact McNemar test: a binomial test on the
  discordant pairs);
- :func:`paired_difference`: two methods' per-view values on the same views (a paired sign-flip permutation test
  of the mean difference, ``scipy.stats.permutation_test``, with a bootstrap interval of the difference);
- :func:`correlation_interval`: Spearman's rho with a paired bootstrap interval;
- :func:`clustered_interval`, :func:`clustered_difference`: the same for a table cell that averages over strata
  (transforms, strengths), resampling or swapping whole images (clusters) so correlated views stay together;
- :func:`correlation_difference`: does one quantity rank with another more closely than a third does;
- :func:`verdict`: *holds*, *fails* or *inconclusive* for a directional claim at significance level ``alpha``.

Seeds make every interval bit-identical from run to run, on any backend (they run in the driver).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 2000


def _finite(values) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64).ravel()
    return array[np.isfinite(array)]


def wilson_interval(successes: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a success rate ``successes / n``; (nan, nan) for n = 0."""
    if n == 0:
        return math.nan, math.nan
    interval = stats.binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return float(interval.low), float(interval.high)


def bootstrap_interval(values, confidence: float = CONFIDENCE, seed: int = 0,
                       resamples: int = RESAMPLES) -> tuple[float, float]:
    """Seeded percentile bootstrap interval of the mean of the finite ``values`` (2000 resamples).

    One value, or values that are all equal, have no spread to resample: the interval is that value. None at all:
    (nan, nan).
    """
    data = _finite(values)
    if len(data) == 0:
        return math.nan, math.nan
    if np.all(data == data[0]):
        return float(data[0]), float(data[0])
    result = stats.bootstrap((data,), np.mean, confidence_level=confidence, n_resamples=resamples,
                             method="percentile", rng=np.random.default_rng(seed))
    low, high = result.confidence_interval
    return float(low), float(high)


def ratio_interval(numerators, denominators, confidence: float = CONFIDENCE, seed: int = 0,
                   resamples: int = RESAMPLES) -> tuple[float, float]:
    """Seeded percentile bootstrap interval of a pooled ratio Σ num / Σ den, resampling (num, den) pairs."""
    num, den = np.asarray(numerators, dtype=np.float64), np.asarray(denominators, dtype=np.float64)
    if len(num) == 0 or den.sum() == 0:
        return math.nan, math.nan
    if len(num) == 1 or np.all(num * den.sum() == den * num.sum()):  # every view has the pooled ratio
        value = float(num.sum() / den.sum())
        return value, value

    def pooled(n, d, axis=-1):
        total = d.sum(axis=axis)
        return np.where(total > 0, n.sum(axis=axis) / np.where(total > 0, total, 1), np.nan)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = stats.bootstrap((num, den), pooled, paired=True, vectorized=True, confidence_level=confidence,
                                 n_resamples=resamples, method="percentile", rng=np.random.default_rng(seed))
    low, high = result.confidence_interval
    return float(low), float(high)


@dataclass(frozen=True)
class Comparison:
    """A paired comparison of method A with method B on the same items."""

    test: str  # which test
    difference: float  # A - B (rate or mean difference)
    p_value: float  # two-sided
    low: float = math.nan  # interval of the difference, where the test gives one
    high: float = math.nan
    n: int = 0  # items compared

    def describe(self) -> str:
        interval = f", CI [{self.low:+.3f}, {self.high:+.3f}]" if math.isfinite(self.low) else ""
        p = f", p = {self.p_value:.3g}" if math.isfinite(self.p_value) else ""
        return f"{self.test}: A - B = {self.difference:+.3f}{interval}{p}, n = {self.n}"


def mcnemar_exact(a_success, b_success) -> Comparison:
    """Exact McNemar test of two methods' 0/1 outcomes on the same pairs (NaN pairs left out).

    Only the discordant pairs tell the methods apart: with ``b`` pairs won by A alone and ``c`` by B alone, the
    two-sided p-value is that of ``b`` successes in ``b + c`` fair coin tosses (1 when there is none).
    """
    a, b_ = np.asarray(a_success, dtype=np.float64), np.asarray(b_success, dtype=np.float64)
    keep = np.isfinite(a) & np.isfinite(b_)
    a, b_ = a[keep] > 0.5, b_[keep] > 0.5
    only_a, only_b = int(np.sum(a & ~b_)), int(np.sum(~a & b_))
    p = 1.0 if only_a + only_b == 0 else float(stats.binomtest(only_a, only_a + only_b, 0.5).pvalue)
    n = len(a)
    return Comparison("exact McNemar", (only_a - only_b) / n if n else math.nan, p, n=n)


def paired_difference(a_values, b_values, confidence: float = CONFIDENCE, seed: int = 0,
                      resamples: int = RESAMPLES) -> Comparison:
    """Paired comparison of two methods' per-view values (views where either is NaN left out): a sign-flip
    permutation test of the mean difference and a bootstrap interval of it."""
    a, b = np.asarray(a_values, dtype=np.float64), np.asarray(b_values, dtype=np.float64)
    keep = np.isfinite(a) & np.isfinite(b)
    diff = a[keep] - b[keep]
    if len(diff) == 0:
        return Comparison("paired permutation", math.nan, math.nan)
    if np.all(diff == 0):
        return Comparison("paired permutation", 0.0, 1.0, 0.0, 0.0, n=len(diff))
    test = stats.permutation_test((a[keep], b[keep]), lambda x, y: np.mean(x - y), permutation_type="samples",
                                  n_resamples=resamples, rng=np.random.default_rng(seed))
    low, high = bootstrap_interval(diff, confidence, seed, resamples)
    return Comparison("paired permutation", float(diff.mean()), float(test.pvalue), low, high, n=len(diff))


def correlation_interval(x, y, confidence: float = CONFIDENCE, seed: int = 0,
                         resamples: int = RESAMPLES) -> tuple[float, float, float]:
    """Spearman's rho of paired ``x``, ``y`` with a seeded paired percentile bootstrap interval."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if len(x) < 3 or np.all(x == x[0]) or np.all(y == y[0]):
        return math.nan, math.nan, math.nan
    rho = float(stats.spearmanr(x, y).statistic)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # resamples where one side is constant have no rho
        result = stats.bootstrap((x, y), lambda u, v: stats.spearmanr(u, v).statistic, paired=True,
                                 vectorized=False, confidence_level=confidence, n_resamples=resamples,
                                 method="percentile", rng=np.random.default_rng(seed))
    low, high = result.confidence_interval
    return rho, float(low), float(high)


HOLDS, FAILS, INCONCLUSIVE = "holds", "fails", "inconclusive"


def verdict(comparison: Comparison, alpha: float = 0.05, claim: str = "greater") -> str:
    """The verdict on the claim "A is ``greater`` (or ``less``) than B": *holds* when the difference is significant
    at ``alpha`` in the claimed direction, *fails* when it is significant the other way, else *inconclusive*.
    A comparison with only an interval (no p-value; its confidence 1 - ``alpha``) is significant when the interval
    excludes 0."""
    if math.isfinite(comparison.p_value):
        significant = comparison.p_value < alpha and comparison.difference != 0
    else:
        significant = math.isfinite(comparison.low) and (comparison.low > 0 or comparison.high < 0)
    if not significant:
        return INCONCLUSIVE
    agrees = comparison.difference > 0 if claim == "greater" else comparison.difference < 0
    return HOLDS if agrees else FAILS


def _pooled_mean(sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Mean over strata (last axis) of Σ sums / Σ counts over clusters (axis -2); strata without counts skipped."""
    return _mean_of_strata(sums.sum(axis=-2), counts.sum(axis=-2))


def _resampled(index, sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """:func:`_pooled_mean` of the clusters (rows) that each row of ``index`` (..., n) picks, as a weighted sum: a
    matrix product with how often each row is picked, instead of gathering a (..., n, strata) copy."""
    index = np.asarray(index).astype(int)
    flat = index.reshape(-1, index.shape[-1])
    rows = len(sums)
    picks = np.bincount((np.arange(len(flat))[:, None] * rows + flat).ravel(), minlength=len(flat) * rows)
    weights = picks.reshape(len(flat), rows).astype(np.float64)
    return _mean_of_strata(weights @ sums, weights @ counts).reshape(index.shape[:-1])


def _mean_of_strata(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a resample whose strata are all empty: NaN
        return np.nanmean(np.where(count > 0, total / np.where(count > 0, count, 1), np.nan), axis=-1)


def clustered_mean(sums, counts) -> float:
    """The statistic of a table cell averaged over strata (e.g. transforms): per stratum Σ sums / Σ counts over the
    clusters (images or pairs), then the mean over strata with any count. ``sums``, ``counts``: (clusters, strata).

    A mean metric has the sum of a cluster's finite values and their number; a rate the same with 0/1 values; a
    pooled ratio the numerator's and the denominator's sums."""
    return float(_pooled_mean(np.asarray(sums, dtype=np.float64), np.asarray(counts, dtype=np.float64)))


def clustered_interval(sums, counts, confidence: float = CONFIDENCE, seed: int = 0,
                       resamples: int = RESAMPLES) -> tuple[float, float]:
    """Seeded percentile bootstrap interval of :func:`clustered_mean`, resampling whole clusters (an image's
    views at every strength and transform stay together, so their correlation widens the interval honestly)."""
    sums, counts = np.asarray(sums, dtype=np.float64), np.asarray(counts, dtype=np.float64)
    value = clustered_mean(sums, counts)
    if not math.isfinite(value):
        return math.nan, math.nan
    if len(sums) < 2:
        return value, value

    def statistic(index, axis=-1):
        return _resampled(index, sums, counts)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # constant resamples (e.g. every pose found) are not an error here
        result = stats.bootstrap((np.arange(len(sums)),), statistic, vectorized=True, confidence_level=confidence,
                                 n_resamples=resamples, method="percentile", batch=250,
                                 rng=np.random.default_rng(seed))
    low, high = result.confidence_interval
    return (float(low), float(high)) if math.isfinite(low) else (value, value)


def clustered_difference(a_sums, a_counts, b_sums, b_counts, confidence: float = CONFIDENCE, seed: int = 0,
                         resamples: int = RESAMPLES) -> Comparison:
    """Paired comparison of two methods' :func:`clustered_mean` on the SAME clusters (rows aligned; strata aligned):
    a permutation test that swaps the two methods within clusters (``scipy.stats.permutation_test``, exact when
    2^clusters <= ``resamples``) and a paired cluster bootstrap interval of the difference A - B."""
    a_s, a_c, b_s, b_c = (np.asarray(v, dtype=np.float64) for v in (a_sums, a_counts, b_sums, b_counts))
    n = len(a_s)
    difference = clustered_mean(a_s, a_c) - clustered_mean(b_s, b_c)
    if n == 0 or not math.isfinite(difference):
        return Comparison("paired permutation over images", math.nan, math.nan, n=n)
    if difference == 0 and np.array_equal(a_s, b_s) and np.array_equal(a_c, b_c):
        return Comparison("paired permutation over images", 0.0, 1.0, 0.0, 0.0, n=n)
    step_s, step_c = b_s - a_s, b_c - a_c

    def swapped(x, y, axis=-1):
        """A - B after the swaps: position i of ``x`` holds i (A's cluster kept) or i + n (swapped with B's)."""
        flips = (np.asarray(x) >= n).astype(np.float64)
        moved_s, moved_c = flips @ step_s, flips @ step_c
        return (_mean_of_strata(a_s.sum(axis=0) + moved_s, a_c.sum(axis=0) + moved_c)
                - _mean_of_strata(b_s.sum(axis=0) - moved_s, b_c.sum(axis=0) - moved_c))

    index = np.arange(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        test = stats.permutation_test((index, index + n), swapped, permutation_type="samples", vectorized=True,
                                      n_resamples=resamples, rng=np.random.default_rng(seed))
        low, high = (difference, difference) if n < 2 else stats.bootstrap(
            (index,), lambda i, axis=-1: _resampled(i, a_s, a_c) - _resampled(i, b_s, b_c), vectorized=True,
            confidence_level=confidence, n_resamples=resamples, method="percentile", batch=250,
            rng=np.random.default_rng(seed)).confidence_interval
    return Comparison("paired permutation over images", float(difference), float(test.pvalue), float(low),
                      float(high), n=n)


def correlation_difference(x1, x2, y, confidence: float = CONFIDENCE, seed: int = 0,
                           resamples: int = RESAMPLES) -> Comparison:
    """Does ``x1`` rank with ``y`` more closely than ``x2`` does? Spearman rho(x1, y) - rho(x2, y) over the same
    items (pairings), with a seeded paired bootstrap interval; no p-value (judge it by the interval)."""
    x1, x2, y = (np.asarray(v, dtype=np.float64) for v in (x1, x2, y))
    keep = np.isfinite(x1) & np.isfinite(x2) & np.isfinite(y)
    x1, x2, y = x1[keep], x2[keep], y[keep]

    def rho(u, v):
        return math.nan if np.all(u == u[0]) or np.all(v == v[0]) else stats.spearmanr(u, v).statistic

    if len(y) < 3 or not math.isfinite(difference := rho(x1, y) - rho(x2, y)):
        return Comparison("Spearman difference, bootstrap over pairings", math.nan, math.nan, n=len(y))
    low, high = _paired_percentiles(lambda i: rho(x1[i], y[i]) - rho(x2[i], y[i]), len(y), confidence, seed,
                                    resamples)
    return Comparison("Spearman difference, bootstrap over pairings", float(difference), math.nan, low, high,
                      n=len(y))


def _paired_percentiles(statistic, n: int, confidence: float, seed: int, resamples: int) -> tuple[float, float]:
    """Percentile bootstrap of ``statistic(indices)`` over ``n`` paired items, leaving out the resamples where it
    is undefined (NaN: e.g. a rank correlation of a resample whose values all tie, common with success rates of
    1.0), which ``scipy.stats.bootstrap`` cannot do; (nan, nan) when under half of the resamples are defined."""
    index = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    values = np.array([statistic(i) for i in index], dtype=np.float64)
    if np.isfinite(values).sum() < resamples / 2:
        return math.nan, math.nan
    tail = 50 * (1 - confidence)
    low, high = np.nanpercentile(values, [tail, 100 - tail])
    return float(low), float(high)
