"""Verdict rules on hand-built replicate values, one case per outcome, with intervals by hand.

Hand oracle: for paired differences d with n values, the 95 % interval is mean ± t·s/√n with
t = t_{0.975, n−1} from a printed table (4.3027 for n = 3, 2.2622 for n = 10) and s the sample
standard deviation (ddof = 1).
"""

import math

import numpy as np
import pytest

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
