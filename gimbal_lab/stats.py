"""Replicate statistics and three-way verdicts (docs/design.md, "Verdicts").

One deterministic run is not evidence: the unit of evidence is one replicate's mean over its
measured revolution(s). A claim compares two quantities measured on the same replicates (same
start phase, same sensor-noise seed), so the comparison is paired:

* **"A < B"** (:func:`less_than`): the paired differences dᵢ = Aᵢ − Bᵢ give a 95 % Student-t
  interval for their mean. The smallest effect of interest is δ = max(1 mm, 10 % of the smaller of
  the two means). The claim **holds** when the interval lies below 0 and |mean d| ≥ δ; it **does
  not hold** when the interval lies above 0, or lies inside (−δ, δ) (no effect worth the name);
  otherwise it is **inconclusive**.
* **"A ≈ B"** (:func:`equivalent`): two one-sided tests at 5 % with the margin m = 20 % of the
  average of the two means. **Holds** when the 90 % interval of the mean difference lies inside
  (−m, m); **does not hold** when the 95 % interval lies entirely outside [−m, m]; otherwise
  **inconclusive**.
* **"A is at least as good as B"** (:func:`non_inferior`, lower is better): a one-sided test at
  5 % against a margin M > 0 (by default δ). **Holds** when the upper one-sided 95 % bound of
  mean(A − B) lies below M; **does not hold** when the lower one-sided 95 % bound lies above M;
  otherwise **inconclusive**.
* **"mean X is x₀"** (:func:`mean_equals`, one quantity over independent replicates, not a
  pair; a filter's mean NEES against its dimension): **does not hold** when the 95 % interval of
  the mean excludes x₀ (the one-sample t-test); **holds** when it contains x₀ and the 90 %
  interval lies inside x₀ ± a margin (two one-sided tests); otherwise **inconclusive**.

Every verdict carries the p-value of the test that decides it, on one scale: a verdict is
decisive at 95 % only if its p < 0.05 (see :class:`Verdict` for each rule's test). Many verdicts
in one report are a family: :func:`holm` adds the Holm-adjusted p within each family and the
verdict that survives it (a decisive verdict whose adjusted p is not below 5 % becomes
inconclusive), beside the unadjusted one.

Intervals come from :func:`scipy.stats.t`, p-values from :mod:`scipy.stats` and statsmodels'
``ttost_paired``, Holm's adjustment from statsmodels' ``multipletests``; nothing here looks at
individual frames.
"""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace

import numpy as np
import pandas as pd
from scipy import stats as _st
from statsmodels.stats.multitest import multipletests
from statsmodels.stats.weightstats import ttost_paired

__all__ = [
    "HOLDS",
    "DOES_NOT_HOLD",
    "INCONCLUSIVE",
    "VERDICTS",
    "MIN_EFFECT_M",
    "RELATIVE_EFFECT",
    "EQUIVALENCE_MARGIN",
    "FAMILY_ALPHA",
    "Verdict",
    "t_interval",
    "smallest_effect",
    "less_than",
    "equivalent",
    "non_inferior",
    "mean_equals",
    "against_every",
    "mean_interval",
    "verdict_table",
    "holm",
]

HOLDS, DOES_NOT_HOLD, INCONCLUSIVE = "holds", "does not hold", "inconclusive"
VERDICTS = (HOLDS, DOES_NOT_HOLD, INCONCLUSIVE)

#: Absolute floor of the smallest effect of interest, metres.
MIN_EFFECT_M = 1e-3
#: Relative part of the smallest effect of interest: a fraction of the smaller mean.
RELATIVE_EFFECT = 0.10
#: Equivalence margin: a fraction of the two means' average.
EQUIVALENCE_MARGIN = 0.20
#: Family-wise error rate of :func:`holm`: the chance of one or more false decisive verdicts in a family.
FAMILY_ALPHA = 0.05


@dataclass(frozen=True)
class Verdict:
    """A claim's verdict with the numbers it rests on (all in the claim's unit, metres here).

    Attributes
    ----------
    verdict : {"holds", "does not hold", "inconclusive"}
    kind : {"less", "equivalent", "non-inferior", "equals"}
    mean_a, mean_b : float
        Means of the two compared quantities over the replicates.
    difference : float
        Mean paired difference A − B.
    low, high : float
        Interval of the mean difference: 95 % for "less"; for "equivalent" and "non-inferior"
        the 90 % interval, whose ends are the one-sided 95 % bounds their tests use; for
        "equals" the 95 % interval of the mean of A (one quantity, ``mean_b`` the stated value).
    delta : float
        Smallest effect of interest ("less"), the equivalence margin ("equivalent", "equals")
        or the non-inferiority margin ("non-inferior"), > 0.
    n : int
        Number of replicates (pairs).
    confidence : float
        Confidence level of ``low``, ``high``.
    p_value : float
        p-value of the test that decides the verdict, scaled so that a verdict decisive at the
        95 % level has p < 0.05 (``FAMILY_ALPHA`` is the level :func:`holm` holds it to):

        * "less", holds, or does not hold because the interval lies above 0: the two-sided
          paired t-test of mean(A − B) = 0 (the 95 % interval's own test: it excludes 0 ⇔ p < 0.05);
        * "less", does not hold because the interval lies inside (−δ, δ) (and not above 0):
          twice the TOST p-value against (−δ, δ), capped at 1. The 95 % interval lies inside
          (−δ, δ) ⇔ both one-sided tests have p < 0.025 ⇔ this p < 0.05;
        * "equivalent", holds: the TOST p-value against (−m, m) (the larger one-sided p; the
          90 % interval lies inside ⇔ both one-sided p < 0.05); does not hold: twice the
          one-sided p of "mean(A − B) > m" (or "< −m"), the 95 % interval's test of lying beyond
          the margin;
        * "non-inferior", holds: the one-sided t-test of H0 mean(A − B) ≥ M; does not hold: the
          one-sided t-test of H0 mean(A − B) ≤ M;
        * "equals", does not hold: the two-sided one-sample t-test of mean A = the stated value
          (the 95 % interval excludes it ⇔ p < 0.05); holds: the TOST p against the margin;
        * inconclusive: the smallest p among the tests that could have decided it (for "less"
          it can lie below 0.05 when the interval excludes 0 but the effect is smaller than δ).

        NaN when no test statistic exists: fewer than 2 pairs, or differences without spread
        lying exactly on a test's boundary (zero spread elsewhere gives p = 0 or 1).
    """

    verdict: str
    kind: str
    mean_a: float
    mean_b: float
    difference: float
    low: float
    high: float
    delta: float
    n: int
    confidence: float
    p_value: float

    def to_dict(self) -> dict:
        return asdict(self)


def _same_length(a, b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    if a.shape != b.shape:
        raise ValueError(f"paired samples must have the same length, got {a.size} and {b.size}")
    return a, b


def _pairs(a, b) -> tuple[np.ndarray, np.ndarray]:
    a, b = _same_length(a, b)
    if a.size < 2:
        raise ValueError(f"a paired comparison needs at least 2 replicates, got {a.size}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("replicate values must be finite (a replicate without detections has no mean)")
    return a, b


def _complete_pairs(a, b) -> tuple[np.ndarray, np.ndarray]:
    a, b = _same_length(a, b)
    keep = np.isfinite(a) & np.isfinite(b)
    return a[keep], b[keep]


def t_interval(values, confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean of ``values`` and its two-sided Student-t confidence interval.

    Parameters
    ----------
    values : array_like, shape (n,), n >= 2
    confidence : float
        In (0, 1).

    Returns
    -------
    (mean, low, high) : floats
        A sample with zero spread gives low = high = mean.
    """
    if not (0.0 < confidence < 1.0):
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    x = np.asarray(values, dtype=float).ravel()
    if x.size < 2:
        raise ValueError(f"an interval needs at least 2 values, got {x.size}")
    mean = float(x.mean())
    sem = float(x.std(ddof=1)) / math.sqrt(x.size)
    if sem == 0.0:
        return mean, mean, mean
    half = float(_st.t.ppf(0.5 + confidence / 2.0, df=x.size - 1)) * sem
    return mean, mean - half, mean + half


def mean_interval(values, confidence: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high) of replicate values; a single value gives (v, nan, nan)."""
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan, math.nan
    if x.size == 1:
        return float(x[0]), math.nan, math.nan
    return t_interval(x, confidence)


def smallest_effect(mean_a: float, mean_b: float, floor: float = MIN_EFFECT_M) -> float:
    """δ = max(floor, 10 % of the smaller of the two means' magnitudes)."""
    return max(float(floor), RELATIVE_EFFECT * min(abs(float(mean_a)), abs(float(mean_b))))


@contextmanager
def _spread_at_rounding_level(d: np.ndarray):
    """Silences the t-tests' warnings about differences without spread, or with a spread at the
    level of rounding (scipy: "Precision loss ..."; statsmodels: division by zero).

    Such differences make the t statistic ±inf or huge (p = 0 or 1, as the interval, a point in all
    but name, says) or 0/0 (p NaN); the verdict rests on the interval from the same mean and spread,
    so the warning would add nothing to it. Replicate tables built from one repeated value (tests,
    fixed-start runs) give them by the hundred.
    """
    constant = bool(np.ptp(d) == 0.0)
    with warnings.catch_warnings(), np.errstate(**({"divide": "ignore", "invalid": "ignore"} if constant else {})):
        warnings.filterwarnings("ignore", message="Precision loss occurred in moment calculation",
                                category=RuntimeWarning)
        if constant:
            warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _smallest_p(*p: float) -> float:
    """The smallest of the p-values that exist (NaN when none does)."""
    return float(np.fmin.reduce(np.asarray(p, dtype=float)))


def _doubled(p: float) -> float:
    """A one-sided p whose test the verdict runs at half its level, put on the verdict's scale."""
    return min(1.0, 2.0 * float(p))


def _one_sided_p(d: np.ndarray, value: float, alternative: str) -> float:
    """p of the one-sided t-test of mean(d) against ``value`` ("greater": H1 mean > value)."""
    with _spread_at_rounding_level(d):
        return float(_st.ttest_1samp(d, value, alternative=alternative).pvalue)


def _too_few_pairs(kind: str, a: np.ndarray, b: np.ndarray, delta: float, confidence: float) -> Verdict:
    """The inconclusive verdict of fewer than two complete pairs: no interval, no test."""
    mean_a = float(a.mean()) if a.size else math.nan
    mean_b = float(b.mean()) if b.size else math.nan
    return Verdict(INCONCLUSIVE, kind, mean_a, mean_b, mean_a - mean_b, math.nan, math.nan, delta, int(a.size),
                   confidence, math.nan)


def less_than(a, b, confidence: float = 0.95, floor: float = MIN_EFFECT_M, drop_missing: bool = False) -> Verdict:
    """Verdict on "A < B" from paired replicate values.

    Parameters
    ----------
    a, b : array_like, shape (n,)
        The two quantities, replicate i of ``a`` paired with replicate i of ``b``.
    confidence : float
        Level of the interval (0.95 by the project's rule).
    floor : float
        Absolute floor of δ, in the values' unit (1 mm for errors in metres).
    drop_missing : bool
        False: a non-finite value is an error. True: pairs with a non-finite member (a replicate
        in which the quantity was never measured, e.g. no detection) are left out, and fewer than
        two complete pairs give "inconclusive" with a NaN interval and p-value and ``n`` the
        pairs left.

    Returns
    -------
    Verdict
        ``p_value``: the two-sided paired t-test's p when the interval excludes 0; twice the TOST
        p against (−δ, δ) when "does not hold" comes from the interval lying inside (−δ, δ); the
        smaller of the two when inconclusive. A decisive verdict has p < 1 − ``confidence``.

    Examples
    --------
    >>> less_than([1.0, 1.1, 0.9], [2.0, 2.1, 1.9]).verdict
    'holds'
    """
    if drop_missing:
        a, b = _complete_pairs(a, b)
        if a.size < 2:
            delta = smallest_effect(a.mean(), b.mean(), floor) if a.size else float(floor)
            return _too_few_pairs("less", a, b, delta, confidence)
    a, b = _pairs(a, b)
    d = a - b
    mean, low, high = t_interval(d, confidence)
    delta = smallest_effect(a.mean(), b.mean(), floor)
    with _spread_at_rounding_level(d):
        p_zero = float(_st.ttest_rel(a, b).pvalue)  # H0 mean(d) = 0: the interval's own test
        p_inside = _doubled(ttost_paired(a, b, -delta, delta)[0])  # H0 |mean(d)| >= δ
    if high < 0.0 and abs(mean) >= delta:
        verdict, p = HOLDS, p_zero
    elif low > 0.0:
        verdict, p = DOES_NOT_HOLD, p_zero
    elif -delta < low and high < delta:
        verdict, p = DOES_NOT_HOLD, p_inside
    else:
        verdict, p = INCONCLUSIVE, _smallest_p(p_zero, p_inside)
    return Verdict(verdict, "less", float(a.mean()), float(b.mean()), mean, low, high, delta, int(a.size), confidence,
                   p)


def equivalent(a, b, margin: float = EQUIVALENCE_MARGIN, alpha: float = 0.05) -> Verdict:
    """Verdict on "A ≈ B" by two one-sided tests (TOST) on paired replicate values.

    The margin is m = ``margin`` × (mean A + mean B)/2. Holds when the (1 − 2α) interval of the
    mean difference lies inside (−m, m) (both one-sided tests reject at α); does not hold when
    the (1 − α) interval lies entirely outside [−m, m]; otherwise inconclusive.

    Returns
    -------
    Verdict
        ``low``, ``high`` are the (1 − 2α) interval, ``delta`` the margin m. ``p_value``: the
        TOST p (the larger one-sided p) when it holds; twice the one-sided p of lying beyond the
        margin (mean > m or mean < −m, the side giving the smaller p) when it does not hold; the
        smaller of the two when inconclusive. A decisive verdict has p < α.
    """
    if not (0.0 < margin):
        raise ValueError(f"margin must be > 0, got {margin!r}")
    if not (0.0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    a, b = _pairs(a, b)
    d = a - b
    m = margin * 0.5 * (abs(a.mean()) + abs(b.mean()))
    mean, low90, high90 = t_interval(d, 1.0 - 2.0 * alpha)
    _, low95, high95 = t_interval(d, 1.0 - alpha)
    with _spread_at_rounding_level(d):
        p_inside = float(ttost_paired(a, b, -m, m)[0])
    p_beyond = _doubled(min(_one_sided_p(d, m, "greater"), _one_sided_p(d, -m, "less")))
    if -m < low90 and high90 < m:
        verdict, p = HOLDS, p_inside
    elif low95 > m or high95 < -m:
        verdict, p = DOES_NOT_HOLD, p_beyond
    else:
        verdict, p = INCONCLUSIVE, _smallest_p(p_inside, p_beyond)
    return Verdict(verdict, "equivalent", float(a.mean()), float(b.mean()), mean, low90, high90, m, int(a.size),
                   1.0 - 2.0 * alpha, p)


def non_inferior(a, b, margin: float | None = None, alpha: float = 0.05, floor: float = MIN_EFFECT_M,
                 drop_missing: bool = False) -> Verdict:
    """Verdict on "A is at least as good as B" (lower is better) by a one-sided test against a margin.

    With d = A − B paired by replicate and M the margin (the most by which A may be worse than B
    and still count as "as good"):

    * **holds** when the upper one-sided (1 − α) bound of mean d (the upper end of the
      two-sided (1 − 2α) interval) lies below M: the t-test rejects H0 mean d ≥ M at α;
    * **does not hold** when the lower one-sided (1 − α) bound lies above M: A is worse than B
      by more than the margin (the t-test rejects H0 mean d ≤ M at α);
    * **inconclusive** otherwise.

    Parameters
    ----------
    a, b : array_like, shape (n,)
        The two quantities, replicate i of ``a`` paired with replicate i of ``b``.
    margin : float or None
        M > 0, in the values' unit. None: δ = :func:`smallest_effect` of the two means with
        ``floor``, the smallest effect the studies report.
    alpha : float
        Level of each one-sided test, in (0, 0.5).
    floor : float
        Absolute floor of the default margin δ (ignored when ``margin`` is given).
    drop_missing : bool
        As in :func:`less_than`: pairs with a non-finite member are left out, and fewer than two
        complete pairs give "inconclusive" with a NaN interval and p-value.

    Returns
    -------
    Verdict
        kind "non-inferior"; ``low``, ``high`` the (1 − 2α) interval; ``delta`` the margin M;
        ``p_value`` the p of H0 mean d ≥ M when it holds, of H0 mean d ≤ M when it does not hold,
        the smaller of the two when inconclusive. A decisive verdict has p < α.

    Examples
    --------
    >>> non_inferior([1.0, 1.2, 1.1], [1.0, 1.1, 1.1], margin=0.5).verdict
    'holds'
    """
    if margin is not None and not (math.isfinite(margin) and margin > 0.0):
        raise ValueError(f"margin must be a finite number > 0 or None (δ), got {margin!r}")
    if not (0.0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    confidence = 1.0 - 2.0 * alpha
    if drop_missing:
        a, b = _complete_pairs(a, b)
        if a.size < 2:
            if margin is None:
                margin = smallest_effect(a.mean(), b.mean(), floor) if a.size else float(floor)
            return _too_few_pairs("non-inferior", a, b, float(margin), confidence)
    a, b = _pairs(a, b)
    d = a - b
    if margin is None:
        margin = smallest_effect(a.mean(), b.mean(), floor)
    margin = float(margin)
    mean, low, high = t_interval(d, confidence)
    p_as_good = _one_sided_p(d, margin, "less")  # H0 mean d >= M
    p_worse = _one_sided_p(d, margin, "greater")  # H0 mean d <= M
    if high < margin:
        verdict, p = HOLDS, p_as_good
    elif low > margin:
        verdict, p = DOES_NOT_HOLD, p_worse
    else:
        verdict, p = INCONCLUSIVE, _smallest_p(p_as_good, p_worse)
    return Verdict(verdict, "non-inferior", float(a.mean()), float(b.mean()), mean, low, high, margin, int(a.size),
                   confidence, p)


def mean_equals(values, expected: float, margin: float, alpha: float = 0.05) -> Verdict:
    """Verdict on "the mean of X is ``expected``" from independent replicate values of X.

    With the replicates' mean x̄ and Student-t intervals on n − 1 degrees of freedom:

    * **does not hold** when the two-sided (1 − α) interval of the mean excludes ``expected``
      (the one-sample t-test rejects mean = expected at α);
    * **holds** when that interval contains ``expected`` and the (1 − 2α) interval lies inside
      (expected − margin, expected + margin) (two one-sided tests at α bound the mean within the
      margin);
    * **inconclusive** otherwise: the data neither reject ``expected`` nor bound the mean.

    The level is right for n independent replicates whatever the correlation inside each one (a
    replicate's mean of correlated frames is one value), as long as the replicate means are near
    normal: a mean of many frames is.

    Parameters
    ----------
    values : array_like, shape (n,), n >= 2
        One value per replicate (not pairs), finite.
    expected : float
        The mean the claim states (3 for the NEES of a 3-D position), finite.
    margin : float
        Half-width of the band within which "holds" bounds the mean, > 0, finite.
    alpha : float
        Level of the tests, in (0, 0.5).

    Returns
    -------
    Verdict
        kind "equals"; ``mean_a`` the mean, ``mean_b`` ``expected``, ``difference`` their
        difference, ``low``, ``high`` the (1 − α) interval of the mean (of X, not of the
        difference), ``delta`` the margin. ``p_value`` on the scale of the other verdicts
        (decisive ⇔ p < α): does not hold, the two-sided t-test of mean = expected; holds, the
        TOST p against the margin (the larger one-sided p); inconclusive, the smaller of the two.

    Notes
    -----
    docs/design.md, "When does a gimbal pay off?", Repairs, "Filter consistency as a verdict": a
    filter's NEES is consistent with χ²(3) when its replicates' mean NEES is 3.

    Examples
    --------
    >>> mean_equals([2.9, 3.1, 3.0, 3.2], 3.0, 0.6).verdict
    'holds'
    >>> mean_equals([4.4, 4.6, 4.5], 3.0, 0.6).verdict
    'does not hold'
    """
    if not (0.0 < alpha < 0.5):
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha!r}")
    expected, margin = float(expected), float(margin)
    if not math.isfinite(expected):
        raise ValueError(f"expected must be finite, got {expected!r}")
    if not (math.isfinite(margin) and margin > 0.0):
        raise ValueError(f"margin must be a finite number > 0, got {margin!r}")
    x = np.asarray(values, dtype=float).ravel()
    if x.size < 2:
        raise ValueError(f"an interval needs at least 2 values, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise ValueError("values must be finite (a replicate without a value has no mean)")
    mean, low, high = t_interval(x, 1.0 - alpha)
    _, low_tost, high_tost = t_interval(x, 1.0 - 2.0 * alpha)
    with _spread_at_rounding_level(x):
        p_differs = float(_st.ttest_1samp(x, expected).pvalue)  # the (1 − α) interval's own test
    p_within = max(_one_sided_p(x, expected - margin, "greater"),  # H0 mean <= expected − margin
                   _one_sided_p(x, expected + margin, "less"))  # H0 mean >= expected + margin
    if not (low <= expected <= high):
        verdict, p = DOES_NOT_HOLD, p_differs
    elif expected - margin < low_tost and high_tost < expected + margin:
        verdict, p = HOLDS, p_within
    else:
        verdict, p = INCONCLUSIVE, _smallest_p(p_differs, p_within)
    return Verdict(verdict, "equals", mean, expected, mean - expected, low, high, margin, int(x.size), 1.0 - alpha,
                   p)


def against_every(verdicts, alpha: float = FAMILY_ALPHA) -> tuple[int, Verdict]:
    """Intersection–union verdict on "A < every B_j" from the k verdicts of "A < B_j"
    (:func:`less_than`, one per B_j; docs/design.md, the moving drone's SP1 and SP2).

    * **holds** when every comparison holds; p-value: the largest of theirs (the claim is the
      intersection, so it is rejected at the level of its weakest part, with no correction);
    * **does not hold** when some comparison does not hold at the Bonferroni level, k × p <
      ``alpha``; p-value: k × the smallest such p, capped at 1 (k chances to fail);
    * **inconclusive** otherwise.

    Returns
    -------
    (int, Verdict)
        The index of the comparison that decides (holds: the one with the largest p; does not
        hold: the smallest p; inconclusive: among those that do not hold, the one whose interval
        reaches highest, a NaN interval first) and its Verdict with the combined ``verdict`` and
        ``p_value`` (its interval, δ and means unchanged).

    Examples
    --------
    >>> a = [1.0, 1.1, 0.9]
    >>> j, v = against_every([less_than(a, [2.0, 2.1, 1.9]), less_than(a, [1.0, 1.12, 0.88])])
    >>> j, v.verdict
    (1, 'does not hold')
    """
    vs = list(verdicts)
    if not vs or not all(isinstance(v, Verdict) for v in vs):
        raise ValueError("against_every needs one or more Verdicts")
    k = len(vs)
    if all(v.verdict == HOLDS for v in vs):
        j = max(range(k), key=lambda i: vs[i].p_value)
        return j, vs[j]
    scaled = [min(1.0, k * v.p_value) if math.isfinite(v.p_value) else math.nan for v in vs]
    failing = [i for i in range(k) if vs[i].verdict == DOES_NOT_HOLD and scaled[i] < alpha]
    if failing:
        j = min(failing, key=lambda i: scaled[i])
        return j, replace(vs[j], p_value=scaled[j])
    open_ = [i for i in range(k) if vs[i].verdict != HOLDS]
    j = max(open_, key=lambda i: vs[i].high if math.isfinite(vs[i].high) else math.inf)
    p = scaled[j] if vs[j].verdict == DOES_NOT_HOLD else vs[j].p_value
    return j, replace(vs[j], verdict=INCONCLUSIVE, p_value=p)


def verdict_table(rows) -> pd.DataFrame:
    """A DataFrame of claim rows: each a dict of identifying fields merged with a Verdict."""
    out = []
    for row in rows:
        row = dict(row)
        v = row.pop("result")
        out.append({**row, **v.to_dict()})
    return pd.DataFrame(out)


def holm(table: pd.DataFrame, family_column=None, alpha: float = FAMILY_ALPHA) -> pd.DataFrame:
    """The verdicts of ``table`` held to a family-wise error rate ``alpha`` by Holm's step-down method.

    Parameters
    ----------
    table : DataFrame
        A :func:`verdict_table` (any table with ``verdict`` and ``p_value`` columns).
    family_column : str, list of str or None
        Column(s) whose values name the families; None: the whole table is one family (the
        project's rule: all the hypothesis verdicts of one study report).
    alpha : float
        Family-wise error rate, in (0, 1).

    Returns
    -------
    DataFrame
        A copy of ``table`` with two columns added:

        * ``p_holm``: Holm-adjusted p within the row's family (statsmodels ``multipletests``,
          method "holm"). A row whose ``p_value`` is NaN (no test: fewer than two pairs) still
          counts in its family's size, as p = 1, and gets NaN;
        * ``verdict_holm``: the verdict at the family level: "holds" or "does not hold" stays
          so when ``p_holm`` < ``alpha`` and becomes "inconclusive" otherwise; "inconclusive"
          stays "inconclusive".

        ``verdict``, ``p_value``, the interval and δ are kept unchanged beside them.

    Examples
    --------
    >>> t = pd.DataFrame({"verdict": ["holds"] * 4, "p_value": [0.01, 0.02, 0.03, 0.04]})
    >>> holm(t)["verdict_holm"].tolist()
    ['holds', 'inconclusive', 'inconclusive', 'inconclusive']
    """
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"table must be a pandas DataFrame (a verdict_table), got {type(table).__name__}")
    missing = {"verdict", "p_value"} - set(table.columns)
    if missing:
        raise ValueError(f"table lacks the column(s) {sorted(missing)}: holm needs a verdict_table")
    if not (0.0 < alpha < 1.0):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    unknown = set(table["verdict"]) - set(VERDICTS)
    if unknown:
        raise ValueError(f"verdict column holds {sorted(unknown)}; allowed: {list(VERDICTS)}")
    p = pd.to_numeric(table["p_value"], errors="raise").astype(float)
    if ((p < 0.0) | (p > 1.0)).any():
        raise ValueError("p_value must lie in [0, 1] (or be NaN for a verdict without a test)")
    keys = [] if family_column is None else [family_column] if isinstance(family_column, str) else list(family_column)
    absent = [k for k in keys if k not in table.columns]
    if absent:
        raise ValueError(f"family_column {absent} is not a column of the table; columns: {list(table.columns)}")

    tested = p.fillna(1.0).to_numpy()  # an untested claim is still one of the family's hypotheses
    family = (table.groupby(keys, dropna=False, sort=False).ngroup().to_numpy() if keys
              else np.zeros(len(table), dtype=int))
    adjusted = np.full(len(table), math.nan)
    for f in np.unique(family):
        rows = family == f
        adjusted[rows] = multipletests(tested[rows], alpha=alpha, method="holm")[1]
    out = table.copy()
    out["p_holm"] = np.where(p.notna(), adjusted, math.nan)
    # a decisive verdict needs its adjusted p below alpha; an inconclusive one stays as it is
    out["verdict_holm"] = out["verdict"].where(out["p_holm"] < alpha, INCONCLUSIVE)
    return out
