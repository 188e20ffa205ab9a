"""Verdict rules on hand-built replicate values, one case per outcome, with intervals by hand.

Hand oracle: for paired differences d with n values, the 95 % interval is mean ± t·s/√n with
t = t_{0.975, n−1} from a printed table (4.3027 for n = 3, 2.2622 for n = 10) and s the sample
standard deviation (ddof = 1).
"""

import contextlib
import gc
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as hst
from hypothesis.extra import numpy as hnp
from scipy import stats as _sst
from statsmodels.stats.weightstats import ttost_paired

from gimbal_lab import stats

T975_DF2 = 4.302652729749464  # table value, 2 degrees of freedom
T975_DF9 = 2.262157162798205
T95_DF9 = 1.833112932656237


def test_t_interval_matches_the_hand_formula():
    d = np.array([1.0, 2.0, 4.0])
    mean, low, high = stats.t_interval(d)
    s = math.sqrt(((1 - 7 / 3) ** 2 + (2 - 7 / 3) ** 2 + (4 - 7 / 3) ** 2) / 2)
    half = T975_DF2 * s / math.sqrt(3)
    assert mean == pytest.approx(7 / 3, abs=1e-15)
    assert (low, high) == pytest.approx((7 / 3 - half, 7 / 3 + half), abs=1e-12)


def test_smallest_effect_is_one_mm_or_ten_percent_of_the_smaller_mean():
    assert stats.smallest_effect(0.005, 0.2) == 1e-3  # 10 % of 5 mm is below the floor
    assert stats.smallest_effect(0.030, 0.050) == pytest.approx(0.003, abs=1e-15)
    assert stats.smallest_effect(0.050, 0.030) == pytest.approx(0.003, abs=1e-15)


# Ten replicates: b = a + shift + noise with a known spread (each case worked out below).
A = np.linspace(0.010, 0.019, 10)  # 10–19 mm
NOISE = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1]) * 1e-4  # s = 1.054e-4 m, mean 0


def _half_width(n=10, t=T975_DF9):
    return t * float(np.std(NOISE, ddof=1)) / math.sqrt(n)  # 75.4 µm


def test_holds_interval_below_zero_and_effect_at_least_delta():
    b = A + 0.005 + NOISE  # a − b = −5 mm ± 0.08 mm; δ = max(1, 1.45) mm
    v = stats.less_than(A, b)
    assert v.verdict == stats.HOLDS
    assert v.difference == pytest.approx(-0.005, abs=1e-12)
    assert (v.low, v.high) == pytest.approx((-0.005 - _half_width(), -0.005 + _half_width()), abs=1e-12)
    assert v.delta == pytest.approx(0.1 * A.mean(), abs=1e-15) and v.n == 10


def test_does_not_hold_when_the_opposite_is_measured():
    v = stats.less_than(A + 0.005 + NOISE, A)
    assert v.verdict == stats.DOES_NOT_HOLD and v.low > 0


def test_does_not_hold_when_the_whole_interval_is_inside_plus_minus_delta():
    v = stats.less_than(A, A + 0.0005 + NOISE)  # −0.5 mm ± 0.08 mm; δ = 1.45 mm
    assert v.high < 0  # a real but negligible difference ...
    assert v.verdict == stats.DOES_NOT_HOLD  # ... is no effect worth the name


def test_inconclusive_when_the_interval_straddles_zero_and_reaches_past_delta():
    wide = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1]) * 0.004  # ±4 mm scatter, mean 0
    v = stats.less_than(A, A + wide)
    assert v.low < -v.delta and v.high > v.delta
    assert v.verdict == stats.INCONCLUSIVE


def test_inconclusive_when_below_zero_but_smaller_than_delta_and_not_inside_the_band():
    # mean −1.2 mm, interval about [−2.1, −0.3] mm, δ = 1.45 mm: below 0, |mean| < δ, low < −δ
    spread = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1]) * 0.0013
    v = stats.less_than(A, A + 0.0012 + spread)
    assert v.high < 0 and abs(v.difference) < v.delta and v.low < -v.delta
    assert v.verdict == stats.INCONCLUSIVE


def test_holds_boundary_is_the_effect_size_delta():
    """|mean| at δ holds; a tenth of a millimetre less does not (pins the formula of δ)."""
    a = np.full(10, 0.020)
    # δ = max(1 mm, 0.1 · min(20 mm, mean b)) = 2 mm; a − b = −δ (b = 22 mm), zero spread
    assert stats.less_than(a, a + 0.002 + 1e-12).verdict == stats.HOLDS
    just_less = stats.less_than(a, a + 0.0019)
    assert just_less.verdict == stats.DOES_NOT_HOLD  # zero spread: the interval is the point, inside ±δ


def test_equivalence_holds_inside_the_margin():
    b = A + 0.0002 + NOISE  # difference −0.2 mm; margin 20 % of ~14.6 mm = 2.9 mm
    v = stats.equivalent(A, b)
    m = 0.2 * 0.5 * (A.mean() + b.mean())
    assert v.delta == pytest.approx(m, abs=1e-15)
    half90 = T95_DF9 * float(np.std(NOISE, ddof=1)) / math.sqrt(10)
    assert (v.low, v.high) == pytest.approx((-0.0002 - half90, -0.0002 + half90), abs=1e-12)
    assert v.verdict == stats.HOLDS and v.confidence == pytest.approx(0.90)


def test_equivalence_does_not_hold_outside_the_margin():
    v = stats.equivalent(A, A * 1.5 + NOISE)  # differs by 50 % of the smaller mean
    assert v.verdict == stats.DOES_NOT_HOLD


def test_equivalence_inconclusive_when_the_interval_crosses_the_margin():
    wide = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1]) * 0.008  # 90 % half-width 4.9 mm > margin 2.9 mm
    v = stats.equivalent(A, A + wide)
    assert v.low < -v.delta < v.delta < v.high
    assert v.verdict == stats.INCONCLUSIVE


def test_equivalence_margin_boundary():
    """Zero spread: a difference just inside 20 % of the mean holds, just outside does not."""
    a = np.full(10, 0.010)
    inside = stats.equivalent(a, a * 1.2222)  # |d| = 2.222 mm < 0.2 · 11.11 mm = 2.2222 mm
    outside = stats.equivalent(a, a * 1.2223)  # 2.2230 mm > 2.2223 mm
    assert inside.verdict == stats.HOLDS and outside.verdict == stats.DOES_NOT_HOLD


@pytest.mark.parametrize(
    "a, b, match",
    [([1.0], [2.0], "at least 2"), ([1.0, 2.0], [1.0], "same length"), ([1.0, np.nan], [1.0, 2.0], "finite")],
)
def test_bad_replicates_are_rejected(a, b, match):
    with pytest.raises(ValueError, match=match):
        stats.less_than(a, b)


def test_drop_missing_leaves_out_incomplete_pairs_and_judges_the_rest():
    b = A + 0.005 + NOISE
    a_gaps, b_gaps = A.copy(), b.copy()
    a_gaps[2], b_gaps[7] = np.nan, np.inf  # replicates 2 and 7 measured nothing
    v = stats.less_than(a_gaps, b_gaps, drop_missing=True)
    keep = np.ones(10, bool)
    keep[[2, 7]] = False
    d = A[keep] - b[keep]  # 8 pairs: t_{0.975, 7} = 2.3646 (table)
    half = 2.364624251592785 * float(np.std(d, ddof=1)) / math.sqrt(8)
    assert v.verdict == stats.HOLDS and v.n == 8
    assert (v.low, v.high) == pytest.approx((d.mean() - half, d.mean() + half), abs=1e-12)
    assert v.mean_a == pytest.approx(A[keep].mean(), abs=1e-15)


@pytest.mark.parametrize("n_complete", [0, 1])
def test_drop_missing_with_fewer_than_two_pairs_is_inconclusive(n_complete):
    a = np.full(5, np.nan)
    b = np.linspace(0.01, 0.02, 5)
    a[:n_complete] = 0.001
    v = stats.less_than(a, b, drop_missing=True)
    assert v.verdict == stats.INCONCLUSIVE and v.n == n_complete
    assert math.isnan(v.low) and math.isnan(v.high)
    assert v.delta >= stats.MIN_EFFECT_M
    with pytest.raises(ValueError, match="finite"):
        stats.less_than(a, b)


# ----------------------------------------------------------------------------------------------
# p-values. Hand oracle: t = (mean d − μ0)/(s/√n) with s the sample standard deviation (ddof = 1),
# and its tail areas from scipy.stats.t directly (not from the t-tests the module calls). The
# module's p comes from the same t computed in another order, so the two agree to a few ulp of t;
# at the |t| < 40 used here that moves p by far less than the relative 1e-9 allowed.
P_REL = 1e-9
PM = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1])  # mean 0, sample s = 1.054 per unit


def _t(d, mu=0.0):
    d = np.asarray(d, dtype=float)
    return (d.mean() - mu) / (np.std(d, ddof=1) / math.sqrt(d.size)), d.size - 1


def _p_two_sided(d, mu=0.0):
    t, df = _t(d, mu)
    return 2.0 * _sst.t.sf(abs(t), df)


def _p_below(d, mu):
    """p of H0 mean d >= mu against H1 mean d < mu."""
    t, df = _t(d, mu)
    return _sst.t.cdf(t, df)


def _p_above(d, mu):
    """p of H0 mean d <= mu against H1 mean d > mu."""
    t, df = _t(d, mu)
    return _sst.t.sf(t, df)


def _p_inside(d, delta):
    """TOST p of H0 |mean d| >= delta: the larger of the two one-sided p."""
    return max(_p_above(d, -delta), _p_below(d, delta))


def test_p_of_holds_is_the_paired_t_test_of_zero():
    b = A + 0.003 + PM * 0.003  # a − b = −3 mm, t = −3.0, interval [−5.26, −0.74] mm
    v = stats.less_than(A, b)
    assert v.verdict == stats.HOLDS
    assert _t(A - b)[0] == pytest.approx(-3.0, rel=1e-12)
    assert v.p_value == pytest.approx(_p_two_sided(A - b), rel=P_REL)  # 0.0150
    assert 0.01 < v.p_value < 0.02


def test_p_of_the_opposite_measured_is_the_same_two_sided_test():
    b = A + 0.003 + PM * 0.003
    v = stats.less_than(b, A)
    assert v.verdict == stats.DOES_NOT_HOLD and v.low > 0
    assert v.p_value == pytest.approx(_p_two_sided(b - A), rel=P_REL)


def test_p_inside_the_band_is_twice_the_tost_p():
    # −0.2 mm ± 1.0 mm (95 %), δ = 1.45 mm: inside (−δ, δ), straddling 0
    b = A + 0.0002 + PM * 0.00133
    v = stats.less_than(A, b)
    assert v.verdict == stats.DOES_NOT_HOLD and v.low < 0 < v.high and -v.delta < v.low and v.high < v.delta
    assert v.p_value == pytest.approx(2 * _p_inside(A - b, v.delta), rel=P_REL)  # 2 × 0.0100
    # the convention: the 95 % interval inside (−δ, δ) ⇔ both one-sided p < 0.025 ⇔ reported p < 0.05
    assert _p_above(A - b, -v.delta) < 0.025 and _p_below(A - b, v.delta) < 0.025 and v.p_value < 0.05


def test_p_inside_the_band_wins_over_the_t_test_when_the_interval_is_also_below_zero():
    # −0.70 mm, interval [−1.30, −0.10] mm: below 0 but inside ±1.45 mm, so "does not hold" comes
    # from the band; its TOST p (2 × 0.0101) differs from the t-test's 0.0276
    b = A + 0.0007 + PM * 0.0008
    v = stats.less_than(A, b)
    assert v.verdict == stats.DOES_NOT_HOLD and v.high < 0 and v.low > -v.delta
    assert v.p_value == pytest.approx(2 * _p_inside(A - b, v.delta), rel=P_REL)
    assert _p_two_sided(A - b) == pytest.approx(0.0276, abs=1e-4) and v.p_value == pytest.approx(0.0203, abs=1e-4)


def test_p_of_inconclusive_is_the_smaller_of_the_two_deciding_tests():
    wide = PM * 0.004  # 0 ± 3.0 mm: t-test p = 1, doubled TOST p = 0.305
    v = stats.less_than(A, A + wide)
    d = -wide
    assert v.verdict == stats.INCONCLUSIVE
    assert _p_two_sided(d) == pytest.approx(1.0, abs=1e-12)
    assert v.p_value == pytest.approx(2 * _p_inside(d, v.delta), rel=P_REL)
    assert v.p_value >= 0.05
    # −1.2 mm, interval [−2.18, −0.22] mm reaching past −δ: the t-test rejects 0 (p = 0.022) but
    # the effect is smaller than δ; the verdict stays inconclusive with that p
    b = A + 0.0012 + PM * 0.0013
    small = stats.less_than(A, b)
    assert small.verdict == stats.INCONCLUSIVE
    assert small.p_value == pytest.approx(min(_p_two_sided(A - b), 2 * _p_inside(A - b, small.delta)), rel=P_REL)
    assert small.p_value == pytest.approx(_p_two_sided(A - b), rel=P_REL) and small.p_value < 0.05


def test_p_without_spread_is_exact_and_without_pairs_is_nan():
    a = np.full(10, 0.020)
    assert stats.less_than(a, a + 0.0025).p_value == 0.0  # t = −inf
    assert stats.less_than(a, a + 0.0019).p_value == 0.0  # inside the band, both one-sided t infinite
    v = stats.less_than(np.array([0.001, np.nan, np.nan]), np.array([0.01, 0.02, 0.03]), drop_missing=True)
    assert math.isnan(v.p_value)


def test_p_value_is_in_the_dict_and_the_table():
    v = stats.less_than(A, A + 0.003 + PM * 0.003)
    assert v.to_dict()["p_value"] == v.p_value
    table = stats.verdict_table([dict(id="X", result=v)])
    assert table.loc[0, "p_value"] == v.p_value and table.loc[0, "id"] == "X"


def test_equivalence_p_values_per_outcome():
    b = A + 0.0002 + PM * 0.0020  # −0.2 mm, 90 % interval [−1.42, 1.02] mm, margin 2.92 mm
    v = stats.equivalent(A, b)
    assert v.verdict == stats.HOLDS
    assert v.p_value == pytest.approx(_p_inside(A - b, v.delta), rel=P_REL)  # 0.0014, not doubled
    b = A * 1.5 + PM * 0.004  # −7.25 mm, 95 % interval [−9.99, −4.51] mm beyond −3.63 mm
    v = stats.equivalent(A, b)
    assert v.verdict == stats.DOES_NOT_HOLD
    assert v.p_value == pytest.approx(2 * _p_below(A - b, -v.delta), rel=P_REL)  # 0.038
    assert 0.03 < v.p_value < 0.05
    b = A + PM * 0.008
    v = stats.equivalent(A, b)
    assert v.verdict == stats.INCONCLUSIVE
    expected = min(_p_inside(A - b, v.delta), 2 * min(_p_above(A - b, v.delta), _p_below(A - b, -v.delta)))
    assert v.p_value == pytest.approx(expected, rel=P_REL) and v.p_value >= 0.05


# Every verdict is decisive at its level only with p below it: the p is the verdict's own test.
_replicates = hnp.arrays(float, 6, elements=hst.floats(0.0, 0.05))


@settings(max_examples=300, deadline=None)
@given(_replicates, _replicates)
def test_a_decisive_verdict_has_p_below_its_level(a, b):
    d = a - b
    assume(np.std(d, ddof=1) > 1e-6)  # the interval has a width, so no bound sits on a threshold
    v = stats.less_than(a, b, floor=1e-4)
    straddles = v.low < 0 < v.high and not (-v.delta < v.low and v.high < v.delta)
    assert (v.verdict != stats.INCONCLUSIVE) <= (v.p_value < 0.05)
    assert straddles <= (v.p_value >= 0.05)
    for w in (stats.equivalent(a + 0.01, b + 0.01), stats.non_inferior(a, b, margin=2e-3)):
        assert (w.verdict != stats.INCONCLUSIVE) == (w.p_value < 0.05), w


# ----------------------------------------------------------------------------------------------
# Non-inferiority: "A at least as good as B" (lower is better), the upper one-sided 95 % bound of
# mean(A − B) against the margin M. One-sided 95 % bound = mean ± t_{0.95, 9}·s/√10 (table 1.8331).
def test_non_inferiority_holds_where_the_superiority_test_fails():
    b = A + PM * 0.0008  # a − b = 0 ± 0.49 mm (one-sided 95 %); δ = 1.45 mm
    v = stats.non_inferior(A, b)
    half = T95_DF9 * float(np.std(A - b, ddof=1)) / math.sqrt(10)
    assert v.kind == "non-inferior" and v.verdict == stats.HOLDS
    assert v.delta == pytest.approx(0.1 * A.mean(), rel=1e-12)  # default margin: δ
    assert (v.low, v.high) == pytest.approx(((A - b).mean() - half, (A - b).mean() + half), abs=1e-12)
    assert v.confidence == pytest.approx(0.90)
    assert v.p_value == pytest.approx(_p_below(A - b, v.delta), rel=P_REL)
    assert stats.less_than(A, b).verdict == stats.DOES_NOT_HOLD  # "A < B" was never the claim


def test_non_inferiority_does_not_hold_when_a_is_worse_by_more_than_the_margin():
    a = A + 0.004 + PM * 0.002  # a − b = 4 mm, lower one-sided bound 2.78 mm > δ = 1.45 mm
    v = stats.non_inferior(a, A)
    assert v.verdict == stats.DOES_NOT_HOLD and v.low > v.delta
    assert v.p_value == pytest.approx(_p_above(a - A, v.delta), rel=P_REL)  # 0.0020
    assert v.p_value < 0.05


def test_non_inferiority_inconclusive_when_the_interval_holds_the_margin():
    a = A + 0.001 + PM * 0.0015  # 1 mm, one-sided bounds [0.08, 1.92] mm around δ = 1.45 mm
    v = stats.non_inferior(a, A)
    assert v.verdict == stats.INCONCLUSIVE and v.low < v.delta < v.high
    expected = min(_p_below(a - A, v.delta), _p_above(a - A, v.delta))
    assert v.p_value == pytest.approx(expected, rel=P_REL) and v.p_value >= 0.05


def test_non_inferiority_uses_the_one_sided_bound():
    """The margin between the one-sided (0.489 mm) and two-sided (0.603 mm) 95 % upper bounds."""
    b = A + PM * 0.0008
    assert stats.non_inferior(A, b, margin=0.00055).verdict == stats.HOLDS
    d = A - b
    upper = d.mean() + T95_DF9 * float(np.std(d, ddof=1)) / math.sqrt(10)  # the one-sided bound by hand
    just_above, just_below = upper * (1 + 1e-9), upper * (1 - 1e-9)
    at = stats.non_inferior(A, b, margin=just_above)
    assert at.verdict == stats.HOLDS and at.p_value == pytest.approx(0.05, rel=1e-6) and at.p_value < 0.05
    below = stats.non_inferior(A, b, margin=just_below)
    assert below.verdict == stats.INCONCLUSIVE and below.p_value == pytest.approx(0.05, rel=1e-6)
    assert below.p_value > 0.05


def test_non_inferiority_without_spread_and_the_default_margin_floor():
    a = np.full(10, 0.005)  # δ = max(1 mm, 0.5 mm) = 1 mm
    assert stats.non_inferior(a + 0.00099, a).verdict == stats.HOLDS
    assert stats.non_inferior(a + 0.00101, a).verdict == stats.DOES_NOT_HOLD
    assert stats.non_inferior(a + 0.00101, a).delta == stats.MIN_EFFECT_M
    assert stats.non_inferior(a + 0.00101, a, floor=2e-3).verdict == stats.HOLDS


def test_non_inferiority_drop_missing_as_less_than():
    a = A + PM * 0.0008
    a_gaps, b_gaps = a.copy(), A.copy()
    a_gaps[3], b_gaps[8] = np.nan, -np.inf
    v = stats.non_inferior(a_gaps, b_gaps, drop_missing=True)
    keep = np.ones(10, bool)
    keep[[3, 8]] = False
    d = a[keep] - A[keep]
    assert v.n == 8 and v.difference == pytest.approx(d.mean(), abs=1e-15)
    assert v.p_value == pytest.approx(_p_below(d, v.delta), rel=P_REL)
    with pytest.raises(ValueError, match="finite"):
        stats.non_inferior(a_gaps, b_gaps)
    few = stats.non_inferior(np.array([0.01, np.nan]), np.array([0.02, 0.03]), drop_missing=True)
    assert few.verdict == stats.INCONCLUSIVE and few.n == 1 and math.isnan(few.high) and math.isnan(few.p_value)
    assert few.delta == stats.MIN_EFFECT_M  # 10 % of 10 mm is the floor
    assert stats.non_inferior([np.nan] * 3, [1.0] * 3, margin=0.5, drop_missing=True).delta == 0.5


@pytest.mark.parametrize("kwargs, match", [
    (dict(margin=0.0), "margin"), (dict(margin=-1e-3), "margin"), (dict(margin=math.nan), "margin"),
    (dict(margin=math.inf), "margin"), (dict(alpha=0.5), "alpha"), (dict(alpha=0.0), "alpha"),
])
def test_non_inferiority_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        stats.non_inferior(A, A, **kwargs)


# ----------------------------------------------------------------------------------------------
# Holm. Hand oracle: sort the family's p ascending; the i-th (1-based) of m is compared with
# α/(m − i + 1) and the procedure stops at the first that fails; adjusted p_(i) =
# max_{j <= i} min(1, (m − j + 1)·p_(j)).
def _table(p, verdict=stats.HOLDS, **columns):
    return pd.DataFrame({"verdict": verdict, "p_value": p, **columns})


def test_holm_hand_example_stops_at_the_second_step():
    # m = 4: thresholds 0.0125, 0.0167, 0.025, 0.05; 0.01 passes, 0.02 fails, so do the rest
    # adjusted: 4·0.01 = 0.04, 3·0.02 = 0.06, max(0.06, 2·0.03) = 0.06, max(0.06, 1·0.04) = 0.06
    t = _table([0.03, 0.01, 0.04, 0.02])  # not sorted: the order of rows does not matter
    out = stats.holm(t)
    assert out["p_holm"].tolist() == pytest.approx([0.06, 0.04, 0.06, 0.06], abs=1e-15)
    assert out["verdict_holm"].tolist() == [stats.INCONCLUSIVE, stats.HOLDS, stats.INCONCLUSIVE, stats.INCONCLUSIVE]
    # the last p alone (1 · 0.04 < 0.05) would pass; step-down stops before it
    assert out.loc[2, "verdict_holm"] == stats.INCONCLUSIVE
    assert out["verdict"].tolist() == [stats.HOLDS] * 4 and out["p_value"].tolist() == [0.03, 0.01, 0.04, 0.02]


def test_holm_goes_further_than_bonferroni():
    # thresholds 0.0125, 0.0167, 0.025, 0.05: all four pass; Bonferroni (4·p) keeps only two
    t = _table([0.001, 0.01, 0.02, 0.04], verdict=[stats.HOLDS, stats.DOES_NOT_HOLD, stats.HOLDS, stats.DOES_NOT_HOLD])
    out = stats.holm(t)
    assert out["p_holm"].tolist() == pytest.approx([0.004, 0.03, 0.04, 0.04], abs=1e-15)
    assert out["verdict_holm"].tolist() == out["verdict"].tolist()
    assert (4 * t["p_value"] < 0.05).sum() == 2


def test_holm_keeps_inconclusive_and_counts_untested_claims():
    t = _table([0.02, 0.001, math.nan], verdict=[stats.HOLDS, stats.INCONCLUSIVE, stats.INCONCLUSIVE])
    out = stats.holm(t)
    # m = 3 (the claim without a test counts, as p = 1): 3·0.001, 2·0.02, max(0.04, 1·1) = 1 → NaN
    assert out["p_holm"].iloc[:2].tolist() == pytest.approx([0.04, 0.003], abs=1e-15)
    assert math.isnan(out["p_holm"].iloc[2])
    assert out["verdict_holm"].tolist() == [stats.HOLDS, stats.INCONCLUSIVE, stats.INCONCLUSIVE]


def test_holm_within_each_family():
    t = _table([0.01, 0.04, 0.02, 0.03], study=["one", "two", "one", "two"])
    out = stats.holm(t, family_column="study")
    # one: 2·0.01 = 0.02, max(0.02, 0.02) = 0.02; two: 2·0.03 = 0.06, max(0.06, 0.04) = 0.06
    assert out["p_holm"].tolist() == pytest.approx([0.02, 0.06, 0.02, 0.06], abs=1e-15)
    assert out["verdict_holm"].tolist() == [stats.HOLDS, stats.INCONCLUSIVE, stats.HOLDS, stats.INCONCLUSIVE]
    one_family = stats.holm(t)  # m = 4: 0.04, 0.06, 0.06, 0.06
    assert one_family["p_holm"].tolist() == pytest.approx([0.04, 0.06, 0.06, 0.06], abs=1e-15)
    two_keys = stats.holm(t.assign(part=["a", "a", "b", "b"]), family_column=["study", "part"])
    assert two_keys["p_holm"].tolist() == pytest.approx(t["p_value"].tolist(), abs=1e-15)  # families of one


@contextlib.contextmanager
def _objects_so_far_left_out_of_gc():
    """statsmodels' Holm runs gc.collect() on each call, which walks every object of the process:
    ~0.1 s with the renderer and matplotlib loaded, seconds in a worker that ran many tests. With
    the objects alive so far frozen (gc.freeze) it walks only the few the call makes; the values
    do not change (a collection frees garbage, nothing else)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(float, hst.integers(1, 30), elements=hst.floats(0.0, 1.0)))
def test_holm_lies_between_the_raw_p_and_bonferroni(p):
    with _objects_so_far_left_out_of_gc():
        out = stats.holm(_table(p))
    m, adj = p.size, out["p_holm"].to_numpy()
    bonferroni = np.minimum(1.0, m * p)
    assert np.all(adj >= p - 1e-15) and np.all(adj <= bonferroni + 1e-15)
    assert adj.min() == pytest.approx(bonferroni.min(), abs=1e-15)  # its first step is Bonferroni's
    order = np.argsort(p, kind="stable")
    assert np.all(np.diff(adj[order]) >= -1e-15)  # the adjusted p keep the raw p's order
    kept = out["verdict_holm"] == stats.HOLDS
    assert np.all(kept[bonferroni < 0.05])  # whatever Bonferroni keeps, Holm keeps


def test_holm_on_verdicts_from_replicates():
    """Three claims of one report: two decisive at 95 % turn inconclusive at the family level."""
    x = A + 0.0026 + PM * 0.0030  # X: holds, p = 0.0287
    y = A + 0.0025 + PM * 0.0032  # Y: the opposite is measured, p = 0.0438
    z = A + 0.005 + NOISE  # Z: holds, p ~ 1e-15
    rows = [dict(id="X", result=stats.less_than(A, x)), dict(id="Y", result=stats.less_than(y, A)),
            dict(id="Z", result=stats.less_than(A, z))]
    out = stats.holm(stats.verdict_table(rows))
    p = [_p_two_sided(A - x), _p_two_sided(y - A), _p_two_sided(A - z)]
    assert out["p_value"].tolist() == pytest.approx(p, rel=P_REL)
    assert out["verdict"].tolist() == [stats.HOLDS, stats.DOES_NOT_HOLD, stats.HOLDS]
    # sorted Z, X, Y: 3·p_Z, 2·p_X = 0.0575, max(0.0575, 1·p_Y)
    assert out["p_holm"].tolist() == pytest.approx([2 * p[0], 2 * p[0], 3 * p[2]], rel=P_REL)
    assert out["verdict_holm"].tolist() == [stats.INCONCLUSIVE, stats.INCONCLUSIVE, stats.HOLDS]
    assert out["low"].tolist() == [r["result"].low for r in rows]  # the interval is kept beside


def test_holm_leaves_its_input_alone():
    t = _table([0.01, 0.2])
    stats.holm(t)
    assert list(t.columns) == ["verdict", "p_value"]


@pytest.mark.parametrize("table, kwargs, error, match", [
    ([1, 2], {}, TypeError, "DataFrame"),
    (pd.DataFrame({"verdict": ["holds"]}), {}, ValueError, "p_value"),
    (pd.DataFrame({"verdict": ["true"], "p_value": [0.01]}), {}, ValueError, "allowed"),
    (pd.DataFrame({"verdict": ["holds"], "p_value": [1.5]}), {}, ValueError, r"\[0, 1\]"),
    (pd.DataFrame({"verdict": ["holds"], "p_value": [0.01]}), dict(alpha=0.0), ValueError, "alpha"),
    (pd.DataFrame({"verdict": ["holds"], "p_value": [0.01]}), dict(family_column="study"), ValueError, "study"),
])
def test_holm_rejects_bad_input(table, kwargs, error, match):
    with pytest.raises(error, match=match):
        stats.holm(table, **kwargs)


# ----------------------------------------------------------------------------------------------
# a mean inside a band (a filter's NEES against its χ² band)
# ----------------------------------------------------------------------------------------------
def _by_hand(x):
    """mean and the 95 % interval half-width of 10 values, with the printed t table value."""
    x = np.asarray(x, float)
    return x.mean(), T975_DF9 * x.std(ddof=1) / math.sqrt(x.size)


SPREAD = np.array([-1.5, -1.0, -0.5, -0.25, 0.0, 0.0, 0.25, 0.5, 1.0, 1.5]) * 0.2  # sd 0.158, half-width 0.113
NEES_DOF, NEES_MARGIN = 3.0, 0.6  # the occlusion study's NEES claim: mean 3, margin 20 % of 3


def _tost_p(x, expected, margin):
    """TOST p of "|mean − expected| < margin" by statsmodels' paired TOST against a constant
    sample (an implementation apart from the one-sample t-tests mean_equals runs)."""
    return ttost_paired(np.asarray(x, float), np.full(len(x), float(expected)), -margin, margin)[0]


def test_mean_equals_holds_when_the_interval_holds_the_value_inside_the_margin():
    x = 3.0 + SPREAD
    v = stats.mean_equals(x, NEES_DOF, NEES_MARGIN)
    mean, half = _by_hand(x)
    assert (v.verdict, v.kind, v.n, v.confidence) == (stats.HOLDS, "equals", 10, 0.95)
    assert (v.low, v.high) == pytest.approx((mean - half, mean + half), rel=1e-12)
    assert v.mean_a == pytest.approx(3.0) and v.mean_b == 3.0 and v.delta == NEES_MARGIN
    assert v.difference == pytest.approx(0.0, abs=1e-15)
    # the 90 % interval by hand lies inside (2.4, 3.6); p: the TOST p, from statsmodels
    half90 = T95_DF9 * x.std(ddof=1) / math.sqrt(10)
    assert 2.4 < mean - half90 and mean + half90 < 3.6
    assert v.p_value == pytest.approx(_tost_p(x, 3.0, 0.6), rel=1e-9) and v.p_value < 0.05


@pytest.mark.parametrize("centre", [4.5, 2.0, 3.3])
def test_mean_equals_does_not_hold_when_the_interval_excludes_the_value(centre):
    """4.5 and 2.0: a covariance off by ×1.5 either way; 3.3: inside the margin, yet the interval
    (±0.113) excludes 3, and a mean detectably off 3 is not χ²(3)'s."""
    x = centre + SPREAD
    v = stats.mean_equals(x, NEES_DOF, NEES_MARGIN)
    assert v.verdict == stats.DOES_NOT_HOLD
    assert v.p_value == pytest.approx(_sst.ttest_1samp(x, 3.0).pvalue, rel=1e-12) and v.p_value < 0.05


@pytest.mark.parametrize("centre", [3.0, 3.4, 2.7])
def test_mean_equals_inconclusive_when_the_interval_holds_the_value_but_reaches_past_the_margin(centre):
    x = centre + 8.0 * SPREAD  # sd 1.26: 95 % half-width 0.90, 90 % half-width 0.73 > 0.6
    v = stats.mean_equals(x, NEES_DOF, NEES_MARGIN)
    assert v.verdict == stats.INCONCLUSIVE and v.low <= 3.0 <= v.high
    p_differs = _sst.ttest_1samp(x, 3.0).pvalue
    assert v.p_value == pytest.approx(min(p_differs, _tost_p(x, 3.0, 0.6)), rel=1e-9)


def test_mean_equals_boundaries_and_bad_input():
    x = 3.0 + SPREAD
    _, low, high = stats.t_interval(x)
    # the value on an end of the 95 % interval is inside it; just beyond it is excluded
    assert stats.mean_equals(x, low, 10.0).verdict == stats.HOLDS
    assert stats.mean_equals(x, high, 10.0).verdict == stats.HOLDS
    assert stats.mean_equals(x, np.nextafter(low, -1.0), 10.0).verdict == stats.DOES_NOT_HOLD
    assert stats.mean_equals(x, np.nextafter(high, 9.0), 10.0).verdict == stats.DOES_NOT_HOLD
    # a 90 % interval ending exactly on the margin is not inside it
    _, low90, high90 = stats.t_interval(x, 0.90)
    reach = max(high90 - 3.0, 3.0 - low90)  # the end farther from 3 (the mean is 3 to rounding)
    assert stats.mean_equals(x, 3.0, reach).verdict == stats.INCONCLUSIVE
    assert stats.mean_equals(x, 3.0, reach * (1.0 + 1e-9)).verdict == stats.HOLDS
    assert stats.mean_equals([3.0, 3.0], 3.0, 0.6).verdict == stats.HOLDS  # no spread: the mean alone
    assert stats.mean_equals([3.2, 3.2], 3.0, 0.6).verdict == stats.DOES_NOT_HOLD
    for bad, match in (([3.0], "at least 2"), ([3.0, math.nan], "finite")):
        with pytest.raises(ValueError, match=match):
            stats.mean_equals(bad, 3.0, 0.6)
    for margin in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="margin"):
            stats.mean_equals(x, 3.0, margin)
    with pytest.raises(ValueError, match="expected"):
        stats.mean_equals(x, math.nan, 0.6)
    with pytest.raises(ValueError, match="alpha"):
        stats.mean_equals(x, 3.0, 0.6, alpha=0.5)
    t = stats.holm(stats.verdict_table([dict(id="NEES", result=stats.mean_equals(x, 3.0, 0.6))]))
    assert t["verdict_holm"].tolist() == [stats.HOLDS]


#: replicates and frames per replicate of the occlusion study at full size (two measured revolutions
#: at 30 frames/s)
MC_REPLICATES, MC_FRAMES = 10, 120


def _verdict_rates(scale: float, blocks: int) -> dict:
    """Share of each verdict over ``blocks`` blocks of MC_REPLICATES replicate means of NEES from a
    filter whose true error covariance is ``scale`` × the one it claims: each frame's NEES is then
    scale · χ²(3), and a replicate's mean of MC_FRAMES independent frames is scale · χ²(3·F)/F,
    drawn from scipy.stats.chi2 (the distribution, not the lab's code)."""
    rng = np.random.default_rng(20261207)
    draws = scale * _sst.chi2.rvs(3 * MC_FRAMES, size=(blocks, MC_REPLICATES), random_state=rng) / MC_FRAMES
    verdicts = [stats.mean_equals(block, NEES_DOF, NEES_MARGIN).verdict for block in draws]
    return {v: verdicts.count(v) / blocks for v in stats.VERDICTS}


def test_mean_equals_size_and_power_by_monte_carlo():
    """The test's size at the study's 10 replicates: a consistent filter is judged inconsistent in
    5 % of blocks (binomial σ 0.69 % over 1000 blocks; bound ±2.1 %, 3σ; measured 4.9 %). Its
    power: a covariance off by ×1.5 either way (mean 4.5 or 2) is judged inconsistent in every
    block of 100, and a consistent filter is judged consistent in every block it does not reject
    (the 90 % interval's half-width, about 0.13 here, is far inside the margin)."""
    consistent = _verdict_rates(1.0, 1000)
    assert abs(consistent[stats.DOES_NOT_HOLD] - 0.05) < 0.021, consistent
    assert consistent[stats.HOLDS] > 0.93, consistent
    for scale in (1.5, 1.0 / 1.5):
        assert _verdict_rates(scale, 100)[stats.DOES_NOT_HOLD] == 1.0, scale
