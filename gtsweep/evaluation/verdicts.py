"""Verdicts of pre-stated hypotheses: each survey finding is a set of comparisons, each with a claim and a margin.

A comparison's ``difference`` is oriented so that a positive value is the survey's direction (the caller negates
"less" claims). Kinds of claim (``margin`` delta > 0, fixed from the survey's wording or numbers, never ours):

- :data:`BEATS` "A is better than B": *holds* when A - B > 0, *fails* when A - B < 0, *equivalent* when
  -delta < A - B < delta (two one-sided tests, TOST), each at level ``alpha``;
- :data:`AMONG` "A is among the best (lowest)", a rank claim against the best rival: *holds* when A is better,
  *equivalent* when tied within delta (which supports the claim: A ranks with the best), *fails* only when A is
  worse by more than delta;
- :data:`BELOW` "A - B stays below delta" (e.g. success stops growing): *holds* when A - B < delta, *fails*
  when A - B > delta (one-sided tests at the margin);
- :data:`ABOVE` "A - B exceeds delta" (e.g. success is low: it drops by more than "similar"): *holds* when
  A - B > delta, *fails* when A - B < delta (one-sided tests at the margin);
- :data:`WITHIN` "A is about x": *holds* when -delta < A - x < delta (TOST), *fails* when it lies outside.

The finding's verdict: *fails* when any comparison's failure test is significant after Holm's correction across
the finding's comparisons; *holds* when every comparison holds (intersection-union test: each at ``alpha``, no
correction needed, Berger 1982); *equivalent* when every comparison holds or is equivalent and at least one is
equivalent; else *undecided*. BELOW, ABOVE and WITHIN claims are tests at the margin: their *holds* already
says where the difference lies against it, they never read *equivalent*.

Comparisons with a standard error use t tests on its degrees of freedom; comparisons with only an interval
(a bootstrap over pairings, a rate's Wilson interval) are decided by their (1 - 2 alpha) interval, which is the
same one-sided level alpha (and, for one comparison, the same as Holm).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from gtsweep.evaluation.statistics import Comparison, holm

BEATS, AMONG, BELOW, ABOVE, WITHIN = "beats", "among", "below", "above", "within"
HOLDS, FAILS, EQUIVALENT, UNDECIDED = "holds", "fails", "equivalent", "undecided"
DECIDED = (HOLDS, FAILS, EQUIVALENT)


@dataclass(frozen=True)
class Claim:
    """One comparison of a finding: its label, the oriented comparison, the kind of claim and its margin."""

    label: str
    comparison: Comparison
    kind: str
    margin: float
    #: the share of the finding's clusters this comparison tests (0.5 when a rival picked on one half of the
    #: images is tested on the other): the images to decide it are counted over all of them
    share: float = 1.0
    #: False for an interval over the methods compared (a bootstrap over pairings): more images add none of them
    images_narrow: bool = True

    def p_values(self) -> tuple[float, float, float]:
        """(p of *holds*, p of *fails*, p of *equivalent*), each one-sided; 1.0 where not applicable."""
        c, delta = self.comparison, self.margin
        d = c.centre if math.isfinite(c.centre) else c.difference
        if not math.isfinite(d):
            return 1.0, 1.0, 1.0
        if math.isfinite(c.se):  # t tests; against 0 the exact test where the comparison has one
            above = lambda x: c.p_greater if x == 0 and math.isfinite(c.p_greater) else \
                _p_above(d, c.se, c.df, x)  # noqa: E731  p of "d > x"
            below = lambda x: c.p_less if x == 0 and math.isfinite(c.p_less) else \
                _p_above(-d, c.se, c.df, -x)  # noqa: E731  p of "d < x"
        elif math.isfinite(c.low) and math.isfinite(c.high):  # interval at 1 - 2 alpha: 0 when it excludes
            above = lambda x: 0.0 if c.low > x else 1.0  # noqa: E731
            below = lambda x: 0.0 if c.high < x else 1.0  # noqa: E731
        else:
            return 1.0, 1.0, 1.0
        inside = max(above(-delta), below(delta))
        if self.kind == BEATS:
            return above(0.0), below(0.0), inside
        if self.kind == AMONG:
            return above(0.0), below(-delta), inside
        if self.kind == BELOW:
            return below(delta), above(delta), 1.0
        if self.kind == ABOVE:
            return above(delta), below(delta), 1.0
        if self.kind == WITHIN:
            return inside, min(above(delta), below(-delta)), 1.0
        raise ValueError(f"unknown kind of claim {self.kind!r}")


def _p_above(d: float, se: float, df: int, x: float) -> float:
    """One-sided t p-value of "the difference exceeds x"; a zero SE is certainty."""
    if se > 0:
        return float(stats.t.sf((d - x) / se, max(df, 1)))
    return 0.0 if d > x else 1.0


@dataclass(frozen=True)
class Verdict:
    verdict: str
    tests: tuple[Claim, ...]
    adjusted_fail: tuple[float, ...]  # Holm-adjusted p of each comparison's failure
    alpha: float

    def parts(self) -> list[str]:
        """Per comparison: which of holds / equivalent / fails its own test reached."""
        out = []
        for test, p_fail in zip(self.tests, self.adjusted_fail):
            p_hold, _, p_equiv = test.p_values()
            out.append(FAILS if p_fail < self.alpha else HOLDS if p_hold < self.alpha else
                       EQUIVALENT if p_equiv < self.alpha else UNDECIDED)
        return out


def decide(tests: list[Claim], alpha: float) -> Verdict:
    """The finding's verdict from its comparisons (rules in the module docstring)."""
    if not tests:
        return Verdict(UNDECIDED, (), (), alpha)
    p = np.array([t.p_values() for t in tests], dtype=np.float64)
    adjusted = holm(p[:, 1])
    holds, equivalent = p[:, 0] < alpha, p[:, 2] < alpha
    if np.any(adjusted < alpha):
        verdict = FAILS
    elif holds.all():
        verdict = HOLDS
    elif (holds | equivalent).all():
        verdict = EQUIVALENT
    else:
        verdict = UNDECIDED
    return Verdict(verdict, tuple(tests), tuple(float(x) for x in adjusted), alpha)


def images_to_decide(test: Claim, alpha: float, power: float = 0.8) -> float:
    """How many clusters (images or pairs) this comparison would need to reach a verdict at the observed effect
    and SE (normal approximation, ``power``, SE shrinking as 1 / sqrt(n)): n (z_alpha + z_power)² / z_observed²,
    z_observed = distance / SE for the verdict reached soonest, the one whose decision boundary lies FARTHEST
    from the estimate on the side it already is (the largest distance needs the fewest clusters). Reachable
    verdicts at an estimate d with margin delta: BEATS: holds / fails beyond 0 (distance |d|), equivalent inside
    ±delta (delta - |d|); AMONG: holds above 0 (d), equivalent inside ±delta (delta - |d|), fails below -delta
    (-delta - d); BELOW, ABOVE: either side of delta; WITHIN: inside or outside ±delta. A WITHIN comparison decided by
    its interval alone (a rate against a band: intervals over clusters) reads its SE off the interval's end that
    must cross the boundary (its (1 - 2 alpha) half-width / z_(1-alpha)). A comparison over the methods compared
    (``images_narrow`` False: a bootstrap over pairings, to which images add no pairings) gives infinity: no
    number of images decides it; other interval-only comparisons and an estimate on a boundary give NaN. Counted over
    all the clusters the finding draws on (the tested ones / ``share``), as the rounds add images to both
    halves."""
    c = test.comparison
    d, delta = (c.centre if math.isfinite(c.centre) else c.difference), test.margin
    se = c.se
    if not math.isfinite(se) and test.kind == WITHIN and math.isfinite(c.low) and math.isfinite(c.high):
        upper = (abs(d) < delta) == (d >= 0)  # inside and above 0, or outside below -delta: the high end moves
        se = ((c.high - d) if upper else (d - c.low)) / stats.norm.ppf(1 - alpha)
    if not test.images_narrow:
        return math.inf
    if not (math.isfinite(se) and se > 0 and c.n > 1 and math.isfinite(d)):
        return math.nan
    if test.kind == BEATS:
        distance = max(abs(d), delta - abs(d))
    elif test.kind == AMONG:
        distance = max(d, delta - abs(d), -delta - d)
    elif test.kind in (BELOW, ABOVE):
        distance = abs(d - delta)
    else:
        distance = abs(delta - abs(d))
    if distance <= 0:
        return math.nan
    z = stats.norm.ppf(1 - alpha) + stats.norm.ppf(power)
    return float(c.n / test.share * (z * se / distance) ** 2)
