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
  (transforms, strengths) over few clusters (images or pairs; their views correlated): a t interval with a
  cluster-robust (linearised) SE, a design-effect Wilson interval for every rate, a paired t over clusters
  (coverage simulated at 6, 12 and 25 clusters: tests/test_coverage.py);
- :func:`holm`: Holm's step-down adjustment; :func:`spent_alpha`: Lan-DeMets Pocock-type alpha spending;
- :func:`correlation_difference`: does one quantity rank with another more closely than a third does;
- :func:`verdict`: *holds*, *fails* or *inconclusive* for a single directional comparison at level ``alpha``
  (the survey's findings use :mod:`gtsweep.evaluation.verdicts`).

Seeds make every interval bit-identical from run to run, on any backend (they run in the driver).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

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
    se: float = math.nan  # standard error of the difference (a t-based comparison)
    centre: float = math.nan  # the centre its test and interval use, where an adjustment moves it
    p_greater: float = math.nan  # exact one-sided p of "A - B > 0" (and "< 0"), where an exact test exists
    p_less: float = math.nan
    df: int = 0  # its degrees of freedom

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


def _mean_of_strata(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # strata that are all empty: NaN
        return np.nanmean(np.where(count > 0, total / np.where(count > 0, count, 1), np.nan), axis=-1)


def clustered_mean(sums, counts) -> float:
    """The statistic of a table cell averaged over strata (e.g. transforms): per stratum Σ sums / Σ counts over the
    clusters (images or pairs), then the mean over strata with any count. ``sums``, ``counts``: (clusters, strata).

    A mean metric has the sum of a cluster's finite values and their number; a rate the same with 0/1 values; a
    pooled ratio the numerator's and the denominator's sums."""
    sums, counts = np.asarray(sums, dtype=np.float64), np.asarray(counts, dtype=np.float64)
    return float(_mean_of_strata(sums.sum(axis=0), counts.sum(axis=0)))


def influence(sums, counts) -> np.ndarray:
    """Each cluster's linearised contribution to :func:`clustered_mean` (Taylor / delta method): per stratum s
    with pooled ratio R_s = Σ y / Σ c, z_i = (1/S) Σ_s (y_is - R_s c_is) / C_s over the S strata with counts.
    Σ z_i = 0; the estimate's cluster-robust variance is n / (n - 1) Σ z_i² (clusters independent, anything
    inside a cluster correlated)."""
    sums, counts = np.asarray(sums, dtype=np.float64), np.asarray(counts, dtype=np.float64)
    total, count = sums.sum(axis=0), counts.sum(axis=0)
    active = count > 0
    if not active.any():
        return np.full(len(sums), np.nan)
    ratio = total[active] / count[active]
    return ((sums[:, active] - ratio * counts[:, active]) / count[active]).sum(axis=1) / active.sum()


@dataclass(frozen=True)
class Estimate:
    """A clustered estimate: value, cluster-robust standard error, degrees of freedom (clusters - 1), clusters."""

    value: float
    se: float
    df: int
    n: int


def clustered_estimate(sums, counts) -> Estimate:
    """:func:`clustered_mean` with its cluster-robust (linearised) standard error over the clusters with views."""
    sums, counts = np.asarray(sums, dtype=np.float64), np.asarray(counts, dtype=np.float64)
    seen = counts.sum(axis=1) > 0
    sums, counts = sums[seen], counts[seen]
    n = len(sums)
    value = clustered_mean(sums, counts) if n else math.nan
    if n < 2 or not math.isfinite(value):
        return Estimate(value, math.nan, max(n - 1, 0), n)
    z = influence(sums, counts)
    return Estimate(value, float(math.sqrt(n / (n - 1) * np.sum(z * z))), n - 1, n)


def _binomial_trials(counts: np.ndarray) -> float:
    """Trials a simple random sample would need for the variance of a mean over strata of rates: 1 / (Σ 1/C_s)
    * S² over the strata with counts C_s (C for one stratum)."""
    count = np.asarray(counts, dtype=np.float64).sum(axis=0)
    count = count[count > 0]
    return float(len(count) ** 2 / np.sum(1.0 / count))


def clustered_interval(sums, counts, confidence: float = CONFIDENCE, rate: bool = False) -> tuple[float, float]:
    """Interval of :func:`clustered_mean` over few clusters (images or pairs; views within one correlated).

    - a mean or pooled ratio: t interval, value ± t(n-1) · cluster-robust SE (:func:`clustered_estimate`);
    - a rate (0/1 views): Wilson's score interval on the effective number of trials n_eff = p(1 - p) / SE², with
      t(n-1) in place of z (Korn & Graubard 1998's design-effect adjustment). n_eff lies between the number of
      clusters (every view of a cluster alike: design effect at its bound) and the binomial count (views
      independent); where the SE cannot estimate it (every cluster alike, e.g. a rate of exactly 0 or 1) it takes
      the cautious bound, the number of clusters. One formula for every rate, 0 and 1 included; with one view
      per cluster (independent trials: nothing estimated) it is Wilson's interval itself, with z.

    Coverage checked by simulation at 6, 12 and 25 clusters (tests/test_coverage.py). Fewer than 2 clusters:
    (nan, nan)."""
    estimate = clustered_estimate(sums, counts)
    if estimate.n < 2 or not math.isfinite(estimate.value):
        return math.nan, math.nan
    quantile = float(stats.t.ppf(0.5 + confidence / 2, estimate.df))
    if not rate:
        return estimate.value - quantile * estimate.se, estimate.value + quantile * estimate.se
    p = min(max(estimate.value, 0.0), 1.0)
    trials = _binomial_trials(np.asarray(counts, dtype=np.float64)[np.asarray(counts).sum(axis=1) > 0])
    if trials <= estimate.n:  # one view per cluster: independent trials, nothing estimated: Wilson's own z
        return wilson_score(p, estimate.n, float(stats.norm.ppf(0.5 + confidence / 2)))
    n_eff = p * (1 - p) / estimate.se ** 2 if estimate.se > 0 and 0 < p < 1 else estimate.n
    return wilson_score(p, min(max(n_eff, estimate.n), max(trials, estimate.n)), quantile)


def wilson_score(p: float, n: float, z: float) -> tuple[float, float]:
    """Wilson's score interval of a proportion ``p`` observed on ``n`` (possibly effective, fractional) trials."""
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(centre - half, 0.0), min(centre + half, 1.0)


def clustered_difference(a_sums, a_counts, b_sums, b_counts, confidence: float = CONFIDENCE,
                         rate: bool = False) -> Comparison:
    """Paired comparison of two methods' :func:`clustered_mean` on the SAME clusters (rows and strata aligned):
    the difference A - B, its cluster-robust SE from the clusters' paired influence differences, a two-sided
    t test (n - 1 degrees of freedom) and its t interval at ``confidence``. For a ``rate``, half a cluster won by
    A alone and half a cluster won by B alone are added first (the cluster form of Agresti & Min 2005's
    adjustment): without it a paired t on 0/1 outcomes with few discordant pairs is far too sure of itself. For
    0/1 outcomes with one view per pair, the tests against 0 are the exact McNemar test (``p_value``, and
    ``p_greater`` / ``p_less`` one-sided); the margins use the t. The
    coverage of this method is checked by simulation at 6, 12 and 25 clusters (tests/test_coverage.py)."""
    a_s, a_c, b_s, b_c = (np.asarray(v, dtype=np.float64) for v in (a_sums, a_counts, b_sums, b_counts))
    seen = (a_c.sum(axis=1) > 0) & (b_c.sum(axis=1) > 0)
    a_s, a_c, b_s, b_c = a_s[seen], a_c[seen], b_s[seen], b_c[seen]
    n = len(a_s)
    difference = clustered_mean(a_s, a_c) - clustered_mean(b_s, b_c) if n else math.nan
    if n < 2 or not math.isfinite(difference):
        return Comparison(PAIRED_T, difference, math.nan, n=n)
    if rate:  # Agresti & Min (2005)-type: half a cluster won by A alone and half won by B alone
        half = (a_c.mean(axis=0) + b_c.mean(axis=0)) / 4
        a_s, b_s = np.vstack([a_s, half, 0 * half]), np.vstack([b_s, 0 * half, half])
        a_c, b_c = np.vstack([a_c, half, half]), np.vstack([b_c, half, half])
    centre = clustered_mean(a_s, a_c) - clustered_mean(b_s, b_c)
    z = influence(a_s, a_c) - influence(b_s, b_c)
    se = float(math.sqrt(n / (n - 1) * np.sum(z * z)))
    result = replace(from_estimate(PAIRED_T, centre, se, n - 1, n, confidence), difference=float(difference),
                     centre=float(centre))
    if rate and a_s.shape[1] == 1 and max(a_c.max(), b_c.max()) <= 1:  # 0/1 pairs: exact McNemar for "vs 0"
        won_a = int(np.sum((a_s[:n, 0] > 0.5) & (b_s[:n, 0] < 0.5)))
        won_b = int(np.sum((a_s[:n, 0] < 0.5) & (b_s[:n, 0] > 0.5)))
        exact = mcnemar_exact(np.r_[np.ones(won_a), np.zeros(won_b)], np.r_[np.zeros(won_a), np.ones(won_b)])
        m = won_a + won_b
        result = replace(result, test=f"{PAIRED_T}; exact McNemar vs 0", p_value=exact.p_value,
                         p_greater=float(stats.binom.sf(won_a - 1, m, 0.5)) if m else 1.0,
                         p_less=float(stats.binom.cdf(won_a, m, 0.5)) if m else 1.0)
    return result


PAIRED_T = "paired t over images"


def from_estimate(test: str, difference: float, se: float, df: int, n: int,
                  confidence: float = CONFIDENCE, target: float = 0.0) -> Comparison:
    """A :class:`Comparison` of ``difference`` (minus ``target``) with standard error ``se`` on ``df`` degrees of
    freedom: two-sided t p-value and t interval; a zero SE is certainty (p 0 for a non-zero difference, else 1)."""
    centred = difference - target
    quantile = float(stats.t.ppf(0.5 + confidence / 2, df))
    if se > 0:
        p = float(2 * stats.t.sf(abs(centred) / se, df))
    else:
        p = 1.0 if centred == 0 else 0.0
    return Comparison(test, float(centred), p, float(centred - quantile * se), float(centred + quantile * se), n=n,
                      se=float(se), df=int(df))


def holm(p_values) -> np.ndarray:
    """Holm's (1979) step-down adjusted p-values: the family-wise error rate of the rejections {p_adj < alpha}
    is at most alpha for any dependence between the tests."""
    p = np.asarray(p_values, dtype=np.float64)
    if p.size == 0:
        return p
    order = np.argsort(p, kind="stable")
    stepped = np.maximum.accumulate((len(p) - np.arange(len(p))) * p[order])
    adjusted = np.empty_like(p)
    adjusted[order] = np.minimum(stepped, 1.0)
    return adjusted


def spent_alpha(alpha: float, fraction: float) -> float:
    """Lan & DeMets (1983) Pocock-type spending function alpha · ln(1 + (e - 1) t): the error probability a
    group-sequential design may have spent by information fraction ``t`` (0 at 0, alpha at 1)."""
    t = min(max(float(fraction), 0.0), 1.0)
    return alpha * math.log(1 + (math.e - 1) * t)


def correlation_difference(x1, x2, y, confidence: float = CONFIDENCE, seed: int = 0,
                           resamples: int = RESAMPLES) -> Comparison:
    """Does ``x1`` rank with ``y`` more closely than ``x2`` does? Spearman rho(x1, y) - rho(x2, y) over the same
    items (pairings), with a seeded paired bootstrap interval; no p-value (judge it by the interval). The
    resamples grow with the confidence so that each tail holds at least 50 of them (a sequential look at level
    0.001: 50 000), never fewer than ``resamples``."""
    x1, x2, y = (np.asarray(v, dtype=np.float64) for v in (x1, x2, y))
    keep = np.isfinite(x1) & np.isfinite(x2) & np.isfinite(y)
    x1, x2, y = x1[keep], x2[keep], y[keep]
    if len(y) < 3 or not math.isfinite(difference := float(_spearman(x1, y) - _spearman(x2, y))):
        return Comparison("Spearman difference, bootstrap over pairings", math.nan, math.nan, n=len(y))
    resamples = max(resamples, math.ceil(50 / ((1 - confidence) / 2)))
    index = np.random.default_rng(seed).integers(0, len(y), size=(resamples, len(y)))
    values = _spearman(x1[index], y[index]) - _spearman(x2[index], y[index])
    if np.isfinite(values).sum() < resamples / 2:  # resamples whose values all tie have no rank correlation
        low, high = math.nan, math.nan
    else:
        tail = 50 * (1 - confidence)
        low, high = (float(v) for v in np.nanpercentile(values, [tail, 100 - tail]))
    return Comparison("Spearman difference, bootstrap over pairings", difference, math.nan, low, high, n=len(y))


def _spearman(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Spearman's rho of ``u`` and ``v`` along their last axis: Pearson's r of their average ranks (as
    scipy.stats.spearmanr), every bootstrap resample at once (one row each); NaN where either is constant."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stats.ConstantInputWarning)  # a constant row's NaN is the answer
        return stats.pearsonr(stats.rankdata(u, axis=-1), stats.rankdata(v, axis=-1), axis=-1).statistic
