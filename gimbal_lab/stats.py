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

Intervals come from :func:`scipy.stats.t`; nothing here looks at individual frames.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from scipy import stats as _st

__all__ = [
    "HOLDS",
    "DOES_NOT_HOLD",
    "INCONCLUSIVE",
    "VERDICTS",
    "MIN_EFFECT_M",
    "RELATIVE_EFFECT",
    "EQUIVALENCE_MARGIN",
    "Verdict",
    "t_interval",
    "smallest_effect",
    "less_than",
    "equivalent",
    "mean_interval",
]

HOLDS, DOES_NOT_HOLD, INCONCLUSIVE = "holds", "does not hold", "inconclusive"
VERDICTS = (HOLDS, DOES_NOT_HOLD, INCONCLUSIVE)

#: Absolute floor of the smallest effect of interest, metres.
MIN_EFFECT_M = 1e-3
#: Relative part of the smallest effect of interest: a fraction of the smaller mean.
RELATIVE_EFFECT = 0.10
#: Equivalence margin: a fraction of the two means' average.
EQUIVALENCE_MARGIN = 0.20


@dataclass(frozen=True)
class Verdict:
    """A claim's verdict with the numbers it rests on (all in the claim's unit, metres here).

    Attributes
    ----------
    verdict : {"holds", "does not hold", "inconclusive"}
    kind : {"less", "equivalent"}
    mean_a, mean_b : float
        Means of the two compared quantities over the replicates.
    difference : float
        Mean paired difference A − B.
    low, high : float
        Interval of the mean difference: 95 % for "less"; for "equivalent" the 90 % interval
        used by the two one-sided tests.
    delta : float
        Smallest effect of interest ("less") or the equivalence margin ("equivalent"), > 0.
    n : int
        Number of replicates (pairs).
    confidence : float
        Confidence level of ``low``, ``high``.
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
        two complete pairs give "inconclusive" with a NaN interval and ``n`` the pairs left.

    Examples
    --------
    >>> less_than([1.0, 1.1, 0.9], [2.0, 2.1, 1.9]).verdict
    'holds'
    """
    if drop_missing:
        a, b = _complete_pairs(a, b)
        if a.size < 2:
            mean_a = float(a.mean()) if a.size else math.nan
            mean_b = float(b.mean()) if b.size else math.nan
            return Verdict(INCONCLUSIVE, "less", mean_a, mean_b, mean_a - mean_b, math.nan, math.nan,
                           smallest_effect(mean_a, mean_b, floor) if a.size else float(floor), int(a.size), confidence)
    a, b = _pairs(a, b)
    d = a - b
    mean, low, high = t_interval(d, confidence)
    delta = smallest_effect(a.mean(), b.mean(), floor)
    if high < 0.0 and abs(mean) >= delta:
        verdict = HOLDS
    elif low > 0.0 or (-delta < low and high < delta):
        verdict = DOES_NOT_HOLD
    else:
        verdict = INCONCLUSIVE
    return Verdict(verdict, "less", float(a.mean()), float(b.mean()), mean, low, high, delta, int(a.size), confidence)


def equivalent(a, b, margin: float = EQUIVALENCE_MARGIN, alpha: float = 0.05) -> Verdict:
    """Verdict on "A ≈ B" by two one-sided tests (TOST) on paired replicate values.

    The margin is m = ``margin`` × (mean A + mean B)/2. Holds when the (1 − 2α) interval of the
    mean difference lies inside (−m, m) (both one-sided tests reject at α); does not hold when
    the (1 − α) interval lies entirely outside [−m, m]; otherwise inconclusive.

    Returns
    -------
    Verdict
        ``low``, ``high`` are the (1 − 2α) interval, ``delta`` the margin m.
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
    if -m < low90 and high90 < m:
        verdict = HOLDS
    elif low95 > m or high95 < -m:
        verdict = DOES_NOT_HOLD
    else:
        verdict = INCONCLUSIVE
    return Verdict(verdict, "equivalent", float(a.mean()), float(b.mean()), mean, low90, high90, m, int(a.size),
                   1.0 - 2.0 * alpha)


def verdict_table(rows) -> pd.DataFrame:
    """A DataFrame of claim rows: each a dict of identifying fields merged with a Verdict."""
    out = []
    for row in rows:
        row = dict(row)
        v = row.pop("result")
        out.append({**row, **v.to_dict()})
    return pd.DataFrame(out)
