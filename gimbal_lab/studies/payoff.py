"""The payoff map: where the active camera beats the strongest passive one over the scene's choices.

The studies before it answer "does a gimbal pay off?" in a few scenes whose numbers are arbitrary.
The map (docs/design.md, "The payoff map") samples eight of those choices with a Latin hypercube
(SALib's ``latin.sample``): the sphere's apparent size, the range, how far off axis its path goes,
the lens (k1 from barrel to pincushion), the frame rate, the latency, the sensor noise and the
exposure. At every point and replicate three runs share the replicate's seed: **active (paper)**
(the paper's loop, the lens ignored, the circle method), **active (best)** (the same loop with the
lens known and the exact cone fit) and **best passive** (stabilised at home with that estimator).
The response is Δ = error(active) − error(best passive) on the measured frames all three detected.

Per point, claims BP1 "active (paper) < best passive" and BP2 "active (best) < best passive" get
the three-way verdict of :mod:`gimbal_lab.stats`; the 2N verdicts are one family (Holm). The
factors are ranked by SALib's ``rbd_fast`` (first-order variance share, bootstrap intervals) on the
per-point mean Δ, and the break-even boundary is the zero contour of a least-squares surface of the
mean Δ on the two factors ranked first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..camera import BrownConrady
from ..config import Camera, Estimator, Pointing, Target, TrackingConfig
from . import report as _report
from ._params import StudyParams, format_p, md_cell, verdict_counts
from .paper import PIPELINES, replicate_phase_s

__all__ = ["Factor", "FACTORS", "PIPELINES", "CLAIMS", "PayoffStudy", "unit_design", "design_table", "design", "point_config",
           "grid", "all_configs", "run_index", "common_frame_errors", "response_table", "point_verdicts",
           "rank_factors", "Surface", "fit_surface", "make_report", "run_study"]

NAME = "payoff"
DESCRIPTION = ("the payoff map: where active beats the best passive camera over 8 scene choices "
               "(Latin hypercube, sphere)")


@dataclass(frozen=True)
class Factor:
    """One of the scene's choices a map samples (this one and :mod:`gimbal_lab.studies.light`):
    its name, range and unit.

    A point's value is ``low + (high − low)·u`` for its unit coordinate u ∈ [0, 1); an integer
    factor takes ``low + ⌊(high − low + 1)·u⌋``, every level an equal share of the interval; a
    log-uniform one ``low·(high/low)^u``.
    """

    name: str
    low: float
    high: float
    unit: str
    label: str
    integer: bool = False
    log: bool = False

    def __post_init__(self):
        if self.integer and self.log:
            raise ValueError(f"{self.name}: a factor is integer or log-uniform, not both")
        if self.log and not 0.0 < self.low < self.high:
            raise ValueError(f"{self.name}: a log-uniform factor needs 0 < low < high, got {self.low!r}, {self.high!r}")

    def value(self, u):
        """The factor's value(s) at unit coordinate(s) ``u`` (array_like in [0, 1])."""
        u = np.asarray(u, float)
        if np.any((u < 0.0) | (u > 1.0)) or not np.all(np.isfinite(u)):
            raise ValueError(f"{self.name}: unit coordinates must lie in [0, 1], got {u!r}")
        if self.integer:
            levels = int(self.high - self.low) + 1
            return self.low + np.minimum(np.floor(levels * u), levels - 1)
        if self.log:
            return self.low * (self.high / self.low) ** u
        return self.low + (self.high - self.low) * u


#: The eight factors and their ranges (docs/design.md, "The payoff map": fixed before its runs).
FACTORS = (
    Factor("diameter_px", 12.0, 60.0, "px", "sphere's apparent diameter on axis"),
    Factor("range_m", 1.5, 4.5, "m", "range, camera to path"),
    Factor("off_axis_deg", 2.0, 20.0, "°", "path's off-axis extent"),
    Factor("k1", -0.25, 0.25, "", "lens k1 (barrel < 0 < pincushion)"),
    Factor("fps", 15.0, 60.0, "frames/s", "frame rate"),
    Factor("latency_frames", 1.0, 3.0, "frames", "latency", integer=True),
    Factor("noise_std", 0.0, 8.0, "grey levels", "sensor noise"),
    Factor("exposure_ms", 0.0, 16.0, "ms", "exposure"),
)
FACTOR_NAMES = tuple(f.name for f in FACTORS)

#: The fewest points the map accepts: SALib's rbd_fast bootstraps on half the points, and with
#: N/2 <= 2M + 1 (M = 2) a resample's periodogram has no bin beyond the harmonics, so its interval
#: collapses to zero width (and below 10 points it divides by zero).
MIN_POINTS = 12

#: The two claims judged at every point: (id, the active pipeline compared with the best passive).
CLAIMS = (("BP1", "active (paper)"), ("BP2", "active (best)"))

#: What each pipeline runs (docs/design.md, "Pipelines compared"): its pointing and estimator.
_PIPELINE_PARTS = {
    "active (paper)": (Pointing("paper"), Estimator()),
    "active (best)": (Pointing("paper"), Estimator(sphere_method="ellipse", lens_strategy="undistort")),
    "best passive": (Pointing("stabilised"), Estimator(sphere_method="ellipse", lens_strategy="undistort")),
}


@dataclass(frozen=True)
class PayoffStudy(StudyParams):
    """Parameters of the payoff map (docs/design.md, "The payoff map").

    Parameters
    ----------
    replicates : int
        Replicates per point, >= 2 (5 at full size).
    first_seed, period_s :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`). The inherited
        ``fps``, ``latency_frames`` and ``noise_std`` are not used (the map samples them) and are
        refused when set.
    points : int
        Points of the Latin hypercube, >= :data:`MIN_POINTS` (12: ``rbd_fast``'s bootstrap interval
        collapses below); 64 at full size.
    design_seed : int
        Seed of the Latin hypercube and of the ranking's bootstrap (28).
    harmonics : int
        ``rbd_fast``'s M, the harmonics of each factor's effect it sums (2).
    bootstrap : int
        Bootstrap resamples of the ranking's intervals (1000).
    revolutions : float
        Periods of the target's motion per run (2: the first acquisition); unlike most studies the
        map accepts down to half a revolution, notebook 15's size under pytest (a run inside its
        first revolution measures its second half: :func:`measured_frames`).
    """

    replicates: int = 5
    points: int = 64
    design_seed: int = 28
    harmonics: int = 2
    bootstrap: int = 1000

    _TABLE = NAME
    MIN_REVOLUTIONS = 0.5

    def __post_init__(self):
        from ..config import _number

        self._check_replicates()
        self._refuse_unused(("fps", "latency_frames", "noise_std"), "the map samples them at each point")
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("points", _number("points", self.points, low=MIN_POINTS, high=100_000, integer=True))
        set_("design_seed", _number("design_seed", self.design_seed, low=0, high=2**32 - 1, integer=True))
        set_("harmonics", _number("harmonics", self.harmonics, low=1, high=50, integer=True))
        set_("bootstrap", _number("bootstrap", self.bootstrap, low=10, high=100_000, integer=True))
        if self.points < 2 * (2 * self.harmonics + 2):
            raise ValueError(f"points must be at least 4 × harmonics + 4 = {4 * self.harmonics + 4} (rbd_fast's "
                             f"bootstrap resamples half of them), got {self.points}")
        set_("period_s", _number("period_s", self.period_s, low=0.0, high=1000.0, low_open=True))


#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = PayoffStudy


def _problem(k: int = len(FACTORS)) -> dict:
    return {"num_vars": k, "names": list(FACTOR_NAMES[:k]), "bounds": [[0.0, 1.0]] * k}


def unit_design(points: int, seed: int, k: int = len(FACTORS)) -> np.ndarray:
    """The Latin hypercube on the unit cube, shape (points, k): SALib's ``latin.sample`` with
    ``seed`` (each column hits each of its ``points`` strata [i/N, (i+1)/N) once)."""
    from SALib.sample import latin

    return np.asarray(latin.sample(_problem(k), int(points), seed=int(seed)), float)


def design_table(factors, points: int, seed: int) -> pd.DataFrame:
    """A map's points from :func:`unit_design`: ``point``, each factor's unit coordinate ``u_NAME``
    and its value ``NAME`` (every ``u_`` column first)."""
    u = unit_design(points, seed, k=len(factors))
    table = pd.DataFrame({"point": np.arange(points)})
    for j, f in enumerate(factors):
        table[f"u_{f.name}"] = u[:, j]
    for j, f in enumerate(factors):
        table[f.name] = f.value(u[:, j])
    return table


def design(study: PayoffStudy | None = None) -> pd.DataFrame:
    """The map's points: ``point``, each factor's unit coordinate ``u_NAME`` and its value ``NAME``."""
    study = study or PayoffStudy()
    return design_table(FACTORS, study.points, study.design_seed)


def point_config(values, pipeline: str, seed: int, study: PayoffStudy | None = None) -> TrackingConfig:
    """The run of one point, pipeline and replicate seed.

    Parameters
    ----------
    values : mapping
        The factors' values (a row of :func:`design`).
    pipeline : str
        One of :data:`PIPELINES`.
    seed : int
        The replicate's seed: its start phase (:func:`gimbal_lab.studies.paper.replicate_phase_s`)
        and every stream of the run; the three pipelines of a point and seed share them.
    """
    study = study or PayoffStudy()
    if pipeline not in _PIPELINE_PARTS:
        raise ValueError(f"pipeline must be one of {PIPELINES}, got {pipeline!r}")
    pointing, estimator = _PIPELINE_PARTS[pipeline]
    camera = Camera(lens=BrownConrady(k1=float(values["k1"])), fps=float(values["fps"]),
                    latency_frames=int(values["latency_frames"]), noise_std=float(values["noise_std"]),
                    exposure_s=1e-3 * float(values["exposure_ms"]))
    range_m = float(values["range_m"])
    # the sphere whose outline on the optical axis at range_m is diameter_px across: its image
    # radius is f·tan(asin(r / D)), so r = D·sin(atan(d / 2f))
    radius_m = range_m * math.sin(math.atan(0.5 * float(values["diameter_px"]) / camera.intrinsics.fx))
    target = Target(kind="sphere", trajectory="cone", period_s=study.period_s,
                    start_phase_s=replicate_phase_s(seed, study.period_s), sphere_radius_m=radius_m,
                    cone_half_angle_rad=math.radians(float(values["off_axis_deg"])), cone_range_m=range_m)
    return TrackingConfig(camera=camera, target=target, pointing=pointing, estimator=estimator,
                          revolutions=study.revolutions, seed=int(seed))


def run_index(study: PayoffStudy | None = None) -> pd.DataFrame:
    """What each run of :func:`grid` is, in its order: point, seed, pipeline (points outer,
    seeds, then the three pipelines)."""
    study = study or PayoffStudy()
    rows = [(p, s, pipe) for p in range(study.points) for s in study.seeds for pipe in PIPELINES]
    return pd.DataFrame(rows, columns=["point", "seed", "pipeline"])


def grid(study: PayoffStudy | None = None) -> list[TrackingConfig]:
    """Every run of the map, in :func:`run_index`'s order."""
    study = study or PayoffStudy()
    points = design(study).set_index("point")
    return [point_config(points.loc[r.point], r.pipeline, r.seed, study) for r in run_index(study).itertuples()]


def all_configs(study: PayoffStudy | None = None) -> list[TrackingConfig]:
    """Every run the map makes (its grid)."""
    return grid(study)


# ----------------------------------------------------------------------------------------------
# responses
# ----------------------------------------------------------------------------------------------
def measured_frames(frames: pd.DataFrame) -> pd.DataFrame:
    """The frames a map measures: every revolution after the first (the acquisition). A run that
    never leaves its first revolution (a notebook's short run under pytest) measures the second half
    of its frames instead; at two revolutions the two rules are the same frames."""
    if len(frames) and frames["revolution"].max() >= 1:
        return frames[frames["revolution"] >= 1]
    return frames.iloc[len(frames) // 2:]


def common_frame_errors(frames: dict) -> dict:
    """Each pipeline's mean distance error on the measured frames all of them detected.

    Parameters
    ----------
    frames : dict
        pipeline → its run's frame table (``frame``, ``revolution``, ``detected``,
        ``abs_error_m``); the runs share their frames.

    Returns
    -------
    dict
        pipeline → (mean abs error on the common frames, m, NaN when none; the common frames'
        share of the measured frames). Measured: :func:`measured_frames`.
    """
    measured = {p: measured_frames(f) for p, f in frames.items()}
    if len({tuple(f["frame"]) for f in measured.values()}) != 1:
        raise ValueError("the pipelines' runs have different measured frames")
    common = np.logical_and.reduce([f["detected"].to_numpy(bool) for f in measured.values()])
    rate = float(common.mean()) if common.size else math.nan
    return {p: (float(f["abs_error_m"].to_numpy(float)[common].mean()) if common.any() else math.nan, rate)
            for p, f in measured.items()}


def response_table(results, study: PayoffStudy | None = None) -> pd.DataFrame:
    """One row per point and replicate: the factors, each pipeline's common-frame error
    (``error_m[PIPELINE]`` as columns named by pipeline), the common frames' share, and
    ``delta_paper_m`` = active (paper) − best passive, ``delta_best_m`` = active (best) − best
    passive. ``results`` are :func:`grid`'s runs in its order."""
    study = study or PayoffStudy()
    index = run_index(study)
    results = list(results)
    if len(results) != len(index):
        raise ValueError(f"expected {len(index)} runs (the map's grid), got {len(results)}")
    points = design(study).set_index("point")
    rows = []
    for (point, seed), g in index.groupby(["point", "seed"], sort=True):
        errors = common_frame_errors({r.pipeline: results[i].frames for i, r in zip(g.index, g.itertuples())})
        row = {"point": point, "seed": seed, **points.loc[point, list(FACTOR_NAMES)].to_dict()}
        row.update({p: errors[p][0] for p in PIPELINES})
        row["common_rate"] = errors[PIPELINES[0]][1]
        row["delta_paper_m"] = row["active (paper)"] - row["best passive"]
        row["delta_best_m"] = row["active (best)"] - row["best passive"]
        rows.append(row)
    return pd.DataFrame(rows)


def point_verdicts(responses: pd.DataFrame) -> pd.DataFrame:
    """BP1 and BP2 at every point (three-way rule, δ = max(1 mm, 10 % of the smaller mean)), the
    2N verdicts held to the family's 5 % error by Holm (:func:`gimbal_lab.stats.holm`).

    Returns
    -------
    DataFrame
        One row per point and claim: id, point, statement, condition, a, b, the factors, the
        Verdict's fields (``difference`` is the mean Δ over the replicates with common frames,
        ``low``/``high`` its 95 % interval), p_holm and verdict_holm.
    """
    rows = []
    for point, g in responses.groupby("point", sort=True):
        g = g.sort_values("seed")
        factors = g.iloc[0][list(FACTOR_NAMES)].to_dict()
        for cid, active in CLAIMS:
            rows.append(dict(id=cid, point=int(point), statement=f"{active} error < best passive error",
                             condition=f"point {int(point)}", a=active, b="best passive", **factors,
                             result=stats.less_than(g[active].to_numpy(float), g["best passive"].to_numpy(float),
                                                    drop_missing=True)))
    table = stats.holm(stats.verdict_table(rows))
    table["unit"] = "m"
    return table


# ----------------------------------------------------------------------------------------------
# ranking and boundary
# ----------------------------------------------------------------------------------------------
def rank_factors(u, y, names=FACTOR_NAMES, harmonics: int = 2, bootstrap: int = 1000, seed: int = 28) -> pd.DataFrame:
    """The factors ranked by SALib's ``rbd_fast`` first-order index of ``y`` on the sample ``u``.

    Parameters
    ----------
    u : ndarray, shape (N, k)
        The design's unit coordinates (a Latin hypercube).
    y : ndarray, shape (N,)
        The response per point; non-finite points are left out.
    names : sequence of str
        The k factors' names.
    harmonics, bootstrap, seed :
        ``rbd_fast``'s M, its bootstrap resamples and their seed.

    Returns
    -------
    DataFrame
        factor, s1 (the share of y's variance the factor explains alone), s1_low, s1_high (95 %
        bootstrap interval, s1 ± SALib's half-width), rank (1 = most influential); rows in rank
        order. ``points`` says how many points entered.
    """
    from SALib.analyze import rbd_fast

    u, y = np.asarray(u, float), np.asarray(y, float)
    names = list(names)
    if u.ndim != 2 or u.shape[1] != len(names) or len(y) != len(u):
        raise ValueError(f"u must be (N, {len(names)}) and y (N,), got {u.shape} and {y.shape}")
    keep = np.isfinite(y)
    need = max(MIN_POINTS, 2 * (2 * harmonics + 2))  # half of them, a resample, must exceed 2M + 1
    if keep.sum() < need:
        raise ValueError(f"rbd_fast with M = {harmonics} needs at least {need} points with a response (its "
                         f"bootstrap resamples half of them), got {int(keep.sum())}")
    problem = {"num_vars": len(names), "names": names, "bounds": [[0.0, 1.0]] * len(names)}
    with np.errstate(all="ignore"):
        out = rbd_fast.analyze(problem, u[keep], y[keep], M=int(harmonics), num_resamples=int(bootstrap),
                               conf_level=0.95, seed=int(seed))
    s1, half = np.asarray(out["S1"], float), np.asarray(out["S1_conf"], float)
    table = pd.DataFrame({"factor": names, "s1": s1, "s1_low": s1 - half, "s1_high": s1 + half})
    table = table.sort_values("s1", ascending=False, ignore_index=True, na_position="last")
    table["rank"] = np.arange(1, len(table) + 1)
    table["points"] = int(keep.sum())
    return table


@dataclass(frozen=True)
class Surface:
    """The least-squares surface Δ ≈ β₀ + β₁a + β₂b + β₃ab over two factors' unit coordinates.

    ``a`` and ``b`` name the factors; ``coef`` holds (β₀, β₁, β₂, β₃); ``r2`` and
    ``residual_sd`` (the response's unit) say how well it fits; ``points`` how many points entered.
    """

    a: str
    b: str
    coef: tuple
    r2: float
    residual_sd: float
    points: int

    def __call__(self, ua, ub):
        """The surface at unit coordinates ``ua``, ``ub`` (broadcast)."""
        ua, ub = np.asarray(ua, float), np.asarray(ub, float)
        b0, b1, b2, b3 = self.coef
        return b0 + b1 * ua + b2 * ub + b3 * ua * ub

    def grid(self, n: int = 101):
        """(ua, ub, Δ) on an n × n grid of the unit square; Δ[i, j] at (ua[j], ub[i])."""
        ua = ub = np.linspace(0.0, 1.0, n)
        A, B = np.meshgrid(ua, ub)
        return ua, ub, self(A, B)

    @property
    def crosses_zero(self) -> bool:
        """Whether the surface changes sign inside the unit square: a break-even inside the ranges.
        A bilinear surface takes its extremes at the corners, so the corners decide."""
        corners = self(np.array([0.0, 1.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0]))
        return bool(corners.min() < 0.0 < corners.max())

    def break_even_ub(self, ua):
        """The unit coordinate of ``b`` where the surface is zero for each ``ua`` (NaN where the
        line b ↦ Δ has no zero, or it lies outside [0, 1])."""
        ua = np.asarray(ua, float)
        b0, b1, b2, b3 = self.coef
        slope = b2 + b3 * ua
        with np.errstate(divide="ignore", invalid="ignore"):
            ub = -(b0 + b1 * ua) / slope
        return np.where((slope != 0) & (ub >= 0.0) & (ub <= 1.0), ub, np.nan)


def fit_surface(ua, ub, y, a: str = "a", b: str = "b") -> Surface:
    """Fit :class:`Surface` to the response ``y`` at unit coordinates ``ua``, ``ub`` by ordinary
    least squares (``numpy.linalg.lstsq``); non-finite responses are left out; needs >= 5 points."""
    ua, ub, y = (np.asarray(v, float) for v in (ua, ub, y))
    keep = np.isfinite(y) & np.isfinite(ua) & np.isfinite(ub)
    if keep.sum() < 5:
        raise ValueError(f"the surface has four coefficients and needs at least 5 points with a response, "
                         f"got {int(keep.sum())}")
    ua, ub, y = ua[keep], ub[keep], y[keep]
    X = np.column_stack([np.ones_like(ua), ua, ub, ua * ub])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    residual = y - X @ coef
    total = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - float((residual**2).sum()) / total if total > 0 else math.nan
    sd = float(np.sqrt((residual**2).sum() / (len(y) - 4))) if len(y) > 4 else math.nan
    return Surface(a, b, tuple(float(c) for c in coef), r2, sd, int(len(y)))


def _factor(name: str) -> Factor:
    return FACTORS[FACTOR_NAMES.index(name)]


def _surface_for(points: pd.DataFrame, ranking: pd.DataFrame, column: str) -> Surface:
    a, b = ranking["factor"].iloc[0], ranking["factor"].iloc[1]
    return fit_surface(points[f"u_{a}"], points[f"u_{b}"], points[column], a, b)


def point_table(verdicts: pd.DataFrame, design_table: pd.DataFrame) -> pd.DataFrame:
    """One row per point: its unit coordinates and factors, and per claim the mean Δ with its
    interval and both verdicts (``delta_paper_m``, ``delta_paper_low_m`` … ``verdict_BP1``,
    ``verdict_holm_BP1``), and ``class``: "pays off" (BP2 holds in the family), "does not" (BP2
    does not hold in the family) or "open"."""
    out = design_table.copy()
    for cid, col in (("BP1", "delta_paper"), ("BP2", "delta_best")):
        v = verdicts[verdicts["id"] == cid].set_index("point")
        out[f"{col}_m"] = out["point"].map(v["difference"])
        out[f"{col}_low_m"] = out["point"].map(v["low"])
        out[f"{col}_high_m"] = out["point"].map(v["high"])
        out[f"pairs_{cid}"] = out["point"].map(v["n"])
        out[f"verdict_{cid}"] = out["point"].map(v["verdict"])
        out[f"verdict_holm_{cid}"] = out["point"].map(v["verdict_holm"])
    out["class"] = out["verdict_holm_BP2"].map({stats.HOLDS: "pays off", stats.DOES_NOT_HOLD: "does not"}).fillna("open")
    return out


def analyse(results, study: PayoffStudy) -> dict:
    """Every table of the report from the runs: responses, verdicts, points, rankings, surfaces."""
    responses = response_table(results, study)
    verdicts = point_verdicts(responses)
    points = point_table(verdicts, design(study))
    u = points[[f"u_{n}" for n in FACTOR_NAMES]].to_numpy(float)
    out = {"responses": responses, "verdicts": verdicts, "points": points}
    for col in ("delta_best", "delta_paper"):
        ranking = rank_factors(u, points[f"{col}_m"], harmonics=study.harmonics, bootstrap=study.bootstrap,
                               seed=study.design_seed)
        out[f"ranking_{col}"] = ranking
        out[f"surface_{col}"] = _surface_for(points, ranking, f"{col}_m")
    return out


def surface_table(surfaces: dict) -> pd.DataFrame:
    """The fitted surfaces as rows: response, a, b, β₀…β₃ (m), r2, residual_sd_m, points, crosses_zero."""
    rows = []
    for response, s in surfaces.items():
        rows.append({"response": response, "a": s.a, "b": s.b, **{f"beta{i}_m": c for i, c in enumerate(s.coef)},
                     "r2": s.r2, "residual_sd_m": s.residual_sd, "points": s.points, "crosses_zero": s.crosses_zero})
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def _mm(x) -> str:
    return f"{1000 * x:.2f}" if x is not None and math.isfinite(x) else "–"


def _boundary_sentence(s: Surface) -> str:
    fa, fb = _factor(s.a), _factor(s.b)
    fit = f"R² = {s.r2:.2f}, residual spread {_mm(s.residual_sd)} mm over {s.points} points"
    if not s.crosses_zero:
        sign = "above" if s(0.5, 0.5) > 0 else "below"
        return (f"the surface over {fa.label} and {fb.label} stays {sign} zero: no break-even inside the ranges "
                f"({fit}).")
    ua = np.linspace(0.0, 1.0, 5)
    ub = s.break_even_ub(ua)
    pairs = [f"{fa.value(a):.3g} {fa.unit} → {fb.value(b):.3g} {fb.unit}" for a, b in zip(ua, ub) if np.isfinite(b)]
    return (f"Δ = 0 along {fa.label} → {fb.label}: {'; '.join(pairs) if pairs else 'a curve that leaves the box'} "
            f"({fit}).")


def claims_markdown(tables: dict, study: PayoffStudy) -> str:
    """claims.md: the design, the points' verdicts at both levels, the ranking and the boundary."""
    v, points = tables["verdicts"], tables["points"]
    lines = [f"# The payoff map ({study.points} points × {study.replicates} replicates × 3 pipelines)", "",
             "Sphere on a cone about the home axis; eight factors sampled by a Latin hypercube "
             f"(SALib, seed {study.design_seed}); docs/design.md, “The payoff map”. Δ = error(active) − error(best "
             "passive) on the measured frames all three pipelines detected: below zero the gimbal pays off.", "",
             "| factor | range |", "|---|---|"]
    lines += [f"| {f.label} | {f.low:g}–{f.high:g} {f.unit} |" for f in FACTORS]
    lines += ["", "## Verdicts per point", "",
              "BP1 “active (paper) < best passive”, BP2 “active (best) < best passive”, three-way rule, "
              "δ = max(1 mm, 10 % of the smaller mean); one family of "
              f"{len(v)} verdicts (Holm, 5 % family-wise).", ""]
    for cid, active in CLAIMS:
        lines.append(f"- **{cid}** ({active}): " + verdict_counts(v[v["id"] == cid]))
    n_pay = (points["class"] == "pays off").sum()
    n_not = (points["class"] == "does not").sum()
    lines += ["", f"At the family level the gimbal (active, best) **pays off at {n_pay}** of {len(points)} points, "
              f"**does not at {n_not}**, and {len(points) - n_pay - n_not} stay open.", "",
              "| point | " + " | ".join(f.name for f in FACTORS) + " | Δ best [95 % CI] mm | BP2 | BP2 (Holm) "
              "| Δ paper [95 % CI] mm | BP1 | BP1 (Holm) |", "|" + "---|" * (len(FACTORS) + 7)]
    for r in points.itertuples():
        vals = " | ".join(f"{getattr(r, f.name):.3g}" for f in FACTORS)
        lines.append(
            f"| {r.point} | {vals} | {_mm(r.delta_best_m)} [{_mm(r.delta_best_low_m)}, {_mm(r.delta_best_high_m)}] "
            f"| {r.verdict_BP2} | **{r.verdict_holm_BP2}** | {_mm(r.delta_paper_m)} [{_mm(r.delta_paper_low_m)}, "
            f"{_mm(r.delta_paper_high_m)}] | {r.verdict_BP1} | **{r.verdict_holm_BP1}** |")
    for col, title in (("delta_best", "Δ best (active (best) − best passive)"),
                       ("delta_paper", "Δ paper (active (paper) − best passive)")):
        ranking, surface = tables[f"ranking_{col}"], tables[f"surface_{col}"]
        lines += ["", f"## What decides {title}", "",
                  f"rbd_fast first-order index (M = {study.harmonics}, 95 % bootstrap interval, "
                  f"{study.bootstrap} resamples) on {int(ranking['points'].iloc[0])} points' mean Δ.", "",
                  "| rank | factor | S1 [95 % CI] |", "|---|---|---|"]
        lines += [f"| {r.rank} | {md_cell(_factor(r.factor).label)} | {r.s1:.2f} [{r.s1_low:.2f}, {r.s1_high:.2f}] |"
                  for r in ranking.itertuples()]
        lines += ["", "Break-even: " + _boundary_sentence(surface)]
    p_min = v["p_holm"].min()
    lines += ["", f"Smallest Holm-adjusted p in the family: {format_p(p_min)}."]
    return "\n".join(lines) + "\n"


def make_report(results, study: PayoffStudy) -> _report.Report:
    """The map's report (:class:`gimbal_lab.studies.report.Report`): design.csv, responses.csv,
    points.csv, verdicts.csv, ranking.csv, surfaces.csv, claims.md, study.json and the figures
    (PNG): Δ against each factor, the ranking, the map with its boundary."""
    tables = analyse(results, study)
    ranking = pd.concat([tables[f"ranking_{c}"].assign(response=c) for c in ("delta_best", "delta_paper")])
    surfaces = surface_table({c: tables[f"surface_{c}"] for c in ("delta_best", "delta_paper")})
    return _report.Report(NAME, study, len(results), [
        ("design.csv", design(study)), ("responses.csv", tables["responses"]), ("points.csv", tables["points"]),
        ("verdicts.csv", tables["verdicts"]), ("ranking.csv", ranking), ("surfaces.csv", surfaces),
        ("claims.md", claims_markdown(tables, study)),
    ], figures(tables), tables["verdicts"], forest=None, formats=("png",))


def factor_axes() -> list[dict]:
    """Each factor as the plots take it: name, label with unit, low, high, integer."""
    return [{"name": f.name, "label": f"{f.label}" + (f" ({f.unit})" if f.unit else ""), "low": f.low, "high": f.high,
             "integer": f.integer} for f in FACTORS]


def figures(tables: dict) -> list:
    """The report's figures as (name, draw): Δ against each factor, the ranking, the map."""
    from ..plotting import payoff as pp

    points = tables["points"]

    def payoff_map():
        s = tables["surface_delta_best"]
        fa, fb = _factor(s.a), _factor(s.b)
        ua, ub, z = s.grid()
        return pp.plot_payoff_map(points, fa.name, fb.name, fa.value(ua), fb.value(ub), z,
                                  xlabel=f"{fa.label} ({fa.unit})", ylabel=f"{fb.label} ({fb.unit})")

    return [("delta_vs_factors", lambda: pp.plot_delta_vs_factors(points, factor_axes())),
            ("ranking", lambda: pp.plot_ranking({"Δ best": tables["ranking_delta_best"],
                                                 "Δ paper": tables["ranking_delta_paper"]},
                                                {f.name: f.label for f in FACTORS})),
            ("map", payoff_map)]


def run_study(study: PayoffStudy, out, *, store=None, executor=None, jobs=None, progress=True, clips=True) -> dict:
    """``gimbal-lab run payoff``: run the map (reusing ``store``) and write its report to
    ``out/payoff``. ``clips`` is accepted for the command's uniformity; the map writes none."""
    return _report.run_and_report(NAME, "payoff map", grid(study), make_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
