"""The buying-rule map: where a gimbal pays once every pipeline picks its own exposure for the light.

docs/design.md, "Exposure as a choice, and a buying rule". Five factors are sampled by a Latin
hypercube (SALib's ``latin.sample``): the scene's light (lux), the target's angular rate seen from
the body, the range, the sphere's apparent size and the body's vibration. The camera records its
frames with the EMVA 1288 sensor model (``Camera(noise="sensor")``), so a short exposure pays in
noise as the light says, and a long one in the target's own streak.

At every point each pipeline (two active, six passive) takes from the exposure set E the exposure
with its lowest mean error on the *calibration seeds* (:func:`choose_exposures`); the best active
and the best passive pipeline are then the lowest of each kind there (:func:`best_pipelines`).
Fresh *test seeds* run those two at their chosen exposures, and the response of a test replicate
is Δ = error(best active) − error(best passive) on the measured frames both detected. Per point the
claim BP2″ "best active < best passive" gets the three-way verdict of :mod:`gimbal_lab.stats`;
the N verdicts are one family (Holm). A point *pays* when BP2″ holds at the family level.

The rule is drawn on one covariate: s = ω·f·t_min, the streak in px the target would leave at the
shortest exposure in E that the light allows (:func:`shortest_exposure_s`); a logistic regression
of "pays" on log s gives the s where the gimbal starts to pay, with a bootstrap band
(:func:`fit_boundary`). The factors are ranked by SALib's ``rbd_fast`` on the ranks of the
per-point mean Δ, so one runaway point cannot zero the ranking (:func:`rank_factors`).

The camera has the paper's distorted lens (``lens="default"``). *Active (paper)* ignores it (the
circle method); *active (best)* and every passive pipeline know it (``lens_strategy="undistort"``).
A known lens also reaches the active outer loop, so the two active pipelines fly differently and
are two runs. On a passive mount the estimator steers nothing, so its three pipelines see the same
frames and one run records them all on the same detection: the blur-aware localiser as the run's
estimate, the cone fit beside it (``alt_*``) and the circle method in its own columns
(``circle_*``, ``Estimator(extra_methods=("circle",))``). Four runs per point, exposure and seed
(:data:`RUNS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..config import Camera, Estimator, Platform, Pointing, Target, TrackingConfig
from ..platform import Vibration
from ._params import StudyParams, format_p, md_cell, verdict_counts
from .paper import replicate_phase_s
from .payoff import Factor, design_table, measured_frames

__all__ = ["Factor", "FACTORS", "FACTOR_NAMES", "PIPELINES", "ACTIVE", "PASSIVE", "CLAIM", "ChoiceStudyParams", "LightStudy", "Study",
           "design", "cone_for_rate", "point_config", "calibration_index", "grid", "all_configs", "run_errors",
           "choice_table", "calibration_table", "choose_exposures", "best_pipelines", "test_index", "test_configs",
           "response_table", "point_verdicts", "shortest_exposure_s", "full_well_lux", "streak_covariate_px", "Boundary",
           "fit_logistic", "fit_boundary", "rank_factors", "analyse", "make_report", "run_study"]

NAME = "light"
DESCRIPTION = ("the buying rule: where a gimbal pays when every pipeline picks its exposure for the light "
               "(Latin hypercube over light, angular rate, range, size, vibration; sphere)")

#: The widest cone the map draws, rad: a faster target keeps it and circles with a shorter period.
MAX_HALF_ANGLE_RAD = math.radians(20.0)

#: The fewest revolutions per run the map accepts: a fifth of a revolution, notebook 16's size under
#: pytest (docs/design.md, "Exposure as a choice, and a buying rule", As built); the full size keeps two.
MIN_REVOLUTIONS = 0.2

#: The fewest points the map accepts (SALib's rbd_fast with M = 2 bootstraps on half of them; below
#: 12 its interval collapses: docs/design.md, "The payoff map").
MIN_POINTS = 12


#: The five factors (docs/design.md, "Exposure as a choice, and a buying rule": fixed before its runs).
FACTORS = (
    Factor("light_lux", 10.0, 100_000.0, "lx", "light", log=True),
    Factor("rate_rad_s", 0.05, 1.5, "rad/s", "target's angular rate seen from the body", log=True),
    Factor("range_m", 1.5, 6.0, "m", "range"),
    Factor("diameter_px", 12.0, 60.0, "px", "sphere's apparent diameter on axis"),
    Factor("vibration_deg", 0.0, 0.5, "° RMS", "body vibration per axis"),
)
FACTOR_NAMES = tuple(f.name for f in FACTORS)

#: The runs made at a point, exposure and seed: (run, pointing kind, sphere method, lens strategy,
#: the estimator's extra methods, the pipelines it records as (pipeline, column prefix)); "" is the
#: run's own estimate, "alt_" the one beside it and "circle_" the circle method's family
#: (``estimator.extra_methods``), all on the same detection and frame. The camera has the paper's
#: distorted lens: *active (paper)* ignores it; *active (best)* and every passive pipeline know it
#: ("undistort"), which also gives the active loop the lens, so the two active pipelines fly
#: differently and are two runs. A passive mount steers on nothing its estimator gives, so one run
#: per mount records its three pipelines.
RUNS = (
    ("active (paper)", "paper", "circle", "ignore", (), (("active (paper)", ""),)),
    ("active (best)", "paper", "ellipse", "undistort", (), (("active (best)", ""),)),
    ("fixed", "fixed", "streak", "undistort", ("circle",),
     (("fixed, circle", "circle_"), ("fixed, cone fit", "alt_"), ("fixed, streak", ""))),
    ("stabilised", "stabilised", "streak", "undistort", ("circle",),
     (("stabilised, circle", "circle_"), ("stabilised, cone fit", "alt_"), ("stabilised, streak", ""))),
)
_RUN_OF = {pipe: (run, prefix) for run, *_, pipes in RUNS for pipe, prefix in pipes}
_RUN_PARTS = {run: (kind, method, lens, extra) for run, kind, method, lens, extra, _ in RUNS}
#: Every pipeline, the active ones first.
PIPELINES = tuple(pipe for *_, pipes in RUNS for pipe, _ in pipes)
ACTIVE = ("active (paper)", "active (best)")
PASSIVE = tuple(p for p in PIPELINES if p not in ACTIVE)

#: The claim judged at every point.
CLAIM = ("BP2″", "best active error < best passive error")


def _float_tuple(name: str, value) -> tuple:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name} must be a list of numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{name} must hold finite numbers, got {v!r}")
        out.append(float(v))
    return tuple(out)


def check_choice_params(study) -> None:
    """Validate (and normalise) a study's ``calibration_seeds`` and ``exposures_ms``, the fields of
    every study whose pipelines choose their exposure (after its ``fps`` and ``replicates``)."""
    seeds = _float_tuple("calibration_seeds", study.calibration_seeds)
    if not seeds or any(s != int(s) or s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"calibration_seeds must be distinct integers >= 0, at least one, got "
                         f"{study.calibration_seeds!r}")
    seeds = tuple(int(s) for s in seeds)
    shared = sorted(set(seeds) & set(study.seeds))
    if shared:
        raise ValueError(f"calibration_seeds {shared} are also test seeds ({study.seeds[0]}–{study.seeds[-1]}): "
                         "nothing may be chosen on the seeds that test it")
    object.__setattr__(study, "calibration_seeds", seeds)
    exposures = _float_tuple("exposures_ms", study.exposures_ms)
    frame_ms = 1000.0 / study.fps
    if not exposures or any(not 0.0 < e <= frame_ms for e in exposures) or len(set(exposures)) != len(exposures):
        raise ValueError(f"exposures_ms must be distinct numbers in (0, {frame_ms:.4g}] ms (the frame period), "
                         f"at least one, got {study.exposures_ms!r}")
    object.__setattr__(study, "exposures_ms", tuple(sorted(exposures)))


@dataclass(frozen=True)
class ChoiceStudyParams(StudyParams):
    """What every study whose pipelines choose their exposure shares (:class:`LightStudy`,
    :class:`gimbal_lab.studies.exposure.ExposureStudy`): test seeds from 200, the calibration
    seeds (100, 101), the exposure set E, runs down to :data:`MIN_REVOLUTIONS`, the sensor model's
    noise instead of ``noise_std`` (refused when set). Each subclass documents its fields."""

    replicates: int = 5
    first_seed: int = 200
    calibration_seeds: tuple = (100, 101)
    exposures_ms: tuple = (0.5, 1.0, 2.0, 4.0, 8.0, 16.7)

    MIN_REVOLUTIONS = MIN_REVOLUTIONS

    def __post_init__(self):
        from ..config import _number

        self._check_replicates()
        self._refuse_unused(("noise_std",), "the sensor model sets the noise")
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("period_s", _number("period_s", self.period_s, low=0.0, high=1000.0, low_open=True))
        set_("fps", _number("fps", self.fps, low=1.0, high=1000.0))
        set_("latency_frames", _number("latency_frames", self.latency_frames, low=1, high=100, integer=True))
        check_choice_params(self)

    @property
    def exposures_s(self) -> tuple:
        """The exposure set E, s, shortest first."""
        return tuple(1e-3 * e for e in self.exposures_ms)


@dataclass(frozen=True)
class LightStudy(ChoiceStudyParams):
    """Parameters of the buying-rule map (docs/design.md, "Exposure as a choice, and a buying rule").

    Parameters
    ----------
    replicates : int
        Test replicates per point, >= 2 (5 at full size); seeds ``first_seed`` onwards.
    first_seed : int
        Seed of the first test replicate (200: disjoint from every earlier study's and from the
        calibration seeds).
    calibration_seeds : tuple of int
        The seeds on which every pipeline chooses its exposure ((100, 101)); none of them may be a
        test seed.
    exposures_ms : tuple of float
        The exposure set E, ms ((0.5, 1, 2, 4, 8, 16.7)); each > 0 and within the frame period.
    points : int
        Points of the Latin hypercube, >= :data:`MIN_POINTS` (40 at full size).
    design_seed : int
        Seed of the Latin hypercube and of every bootstrap (40).
    harmonics, bootstrap : int
        ``rbd_fast``'s M (2) and the bootstrap resamples of the ranking and the boundary (1000).
    revolutions : float
        Periods of the target's motion per run (2: the first acquisition); unlike every other study
        the map accepts down to :data:`MIN_REVOLUTIONS`, notebook 16's size under pytest.
    period_s, fps, latency_frames :
        As every study's: the cone's period before a fast
        target shortens it (2 s), 30 frames/s, one frame of latency. ``noise_std`` is not used
        (the sensor model sets the noise) and is refused when set.
    """

    points: int = 40
    design_seed: int = 40
    harmonics: int = 2
    bootstrap: int = 1000

    _TABLE = NAME

    def __post_init__(self):
        from ..config import _number

        super().__post_init__()
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("points", _number("points", self.points, low=MIN_POINTS, high=100_000, integer=True))
        set_("design_seed", _number("design_seed", self.design_seed, low=0, high=2**32 - 1, integer=True))
        set_("harmonics", _number("harmonics", self.harmonics, low=1, high=50, integer=True))
        set_("bootstrap", _number("bootstrap", self.bootstrap, low=10, high=100_000, integer=True))
        if self.points < 2 * (2 * self.harmonics + 2):
            raise ValueError(f"points must be at least 4 × harmonics + 4 = {4 * self.harmonics + 4} (rbd_fast's "
                             f"bootstrap resamples half of them), got {self.points}")


#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = LightStudy


# ----------------------------------------------------------------------------------------------
# design and runs
# ----------------------------------------------------------------------------------------------
def design(study: LightStudy | None = None) -> pd.DataFrame:
    """The map's points: ``point``, each factor's unit coordinate ``u_NAME`` and its value ``NAME``,
    and the cone the rate maps to (``half_angle_deg``, ``period_s``)."""
    study = study or LightStudy()
    table = design_table(FACTORS, study.points, study.design_seed)
    cones = [cone_for_rate(w, study.period_s) for w in table["rate_rad_s"]]
    table["half_angle_deg"] = [math.degrees(a) for a, _ in cones]
    table["period_s"] = [t for _, t in cones]
    return table


def cone_for_rate(rate_rad_s: float, period_s: float = 2.0, max_half_angle_rad: float = MAX_HALF_ANGLE_RAD):
    """The cone whose target the camera at its apex sees move at ``rate_rad_s``.

    A target circling the home axis at half-angle α with period T moves 2π·D·sin α / T along its
    circle at range D, so the line of sight turns at ω = 2π·sin α / T. At the period ``period_s``
    α = asin(ω·T / 2π); when that exceeds ``max_half_angle_rad`` the half-angle stays there and the
    period shortens to T = 2π·sin α_max / ω.

    Returns
    -------
    (half_angle_rad, period_s)
    """
    if not (math.isfinite(rate_rad_s) and rate_rad_s > 0):
        raise ValueError(f"rate_rad_s must be a finite number > 0, got {rate_rad_s!r}")
    x = rate_rad_s * period_s / (2.0 * math.pi)
    if x <= math.sin(max_half_angle_rad):
        return math.asin(x), float(period_s)
    return float(max_half_angle_rad), 2.0 * math.pi * math.sin(max_half_angle_rad) / rate_rad_s


def point_config(values, pipeline: str, exposure_s: float, seed: int, study: LightStudy | None = None,
                 light_lux: float | None = None) -> TrackingConfig:
    """The run that records ``pipeline`` at one point, exposure and seed.

    Parameters
    ----------
    values : mapping
        The factors' values (a row of :func:`design`).
    pipeline : str
        One of :data:`PIPELINES`; pipelines that one run records (:data:`RUNS`) get the same config.
    exposure_s : float
        The camera's exposure, s (> 0; the sensor model integrates it and the frame blurs over it).
    seed : int
        The run's seed: its start phase and every stream (the pipelines of a point and seed pair).
    light_lux : float, optional
        The scene's light instead of the point's (the notebook's look at one point).
    """
    study = study or LightStudy()
    if pipeline not in _RUN_OF:
        raise ValueError(f"pipeline must be one of {PIPELINES}, got {pipeline!r}")
    kind, method, lens_strategy, extra_methods = _RUN_PARTS[_RUN_OF[pipeline][0]]
    lux = float(values["light_lux"]) if light_lux is None else float(light_lux)
    camera = Camera(fps=study.fps, latency_frames=study.latency_frames, exposure_s=float(exposure_s),
                    noise="sensor", light_lux=lux, lens="default")
    range_m = float(values["range_m"])
    half_angle_rad, period_s = cone_for_rate(float(values["rate_rad_s"]), study.period_s)
    # the sphere whose outline on the optical axis at range_m is diameter_px across: r = D·sin(atan(d / 2f))
    radius_m = range_m * math.sin(math.atan(0.5 * float(values["diameter_px"]) / camera.intrinsics.fx))
    target = Target(kind="sphere", trajectory="cone", period_s=period_s,
                    start_phase_s=replicate_phase_s(seed, period_s), sphere_radius_m=radius_m,
                    cone_half_angle_rad=half_angle_rad, cone_range_m=range_m)
    platform = Platform(motion="vibration", vibration=Vibration(rms_rad=math.radians(float(values["vibration_deg"]))))
    return TrackingConfig(camera=camera, target=target, platform=platform, pointing=Pointing(kind),
                          estimator=Estimator(sphere_method=method, lens_strategy=lens_strategy,
                                              extra_methods=extra_methods), revolutions=study.revolutions, seed=int(seed))


def calibration_index(study: LightStudy | None = None) -> pd.DataFrame:
    """What each calibration run is, in :func:`grid`'s order: point, exposure_s, seed, run (points
    outer, then exposures, seeds and the runs of :data:`RUNS`)."""
    study = study or LightStudy()
    rows = [(p, e, s, run) for p in range(study.points) for e in study.exposures_s for s in study.calibration_seeds
            for run, *_ in RUNS]
    return pd.DataFrame(rows, columns=["point", "exposure_s", "seed", "run"])


def _run_pipeline(run: str) -> str:
    return next(pipes[0][0] for r, *_, pipes in RUNS if r == run)


def grid(study: LightStudy | None = None) -> list[TrackingConfig]:
    """The calibration runs, in :func:`calibration_index`'s order (the test runs follow from the
    choices they make: :func:`test_configs`)."""
    study = study or LightStudy()
    points = design(study).set_index("point")
    return [point_config(points.loc[r.point], _run_pipeline(r.run), r.exposure_s, r.seed, study)
            for r in calibration_index(study).itertuples()]


def all_configs(study: LightStudy | None = None) -> list[TrackingConfig]:
    """The runs known before any is made: the calibration runs. The test runs, two per point and
    test seed, depend on the choices and follow them."""
    return grid(study)


# ----------------------------------------------------------------------------------------------
# errors, exposure choice, best pipelines
# ----------------------------------------------------------------------------------------------
def run_errors(frames: pd.DataFrame, run: str) -> dict:
    """Each pipeline the run records: (mean |d_est − d_true| over the measured frames where it
    detected, m, NaN when none; how many such frames)."""
    measured = measured_frames(frames)
    out = {}
    for pipe, prefix in next(p for r, *_, p in RUNS if r == run):
        detected = measured[f"{prefix}detected"].to_numpy(bool)
        errors = measured[f"{prefix}abs_error_m"].to_numpy(float)[detected]
        out[pipe] = (float(errors.mean()) if errors.size else math.nan, int(errors.size))
    return out


def choice_table(index: pd.DataFrame, results, unit: str = "point") -> pd.DataFrame:
    """One row per calibration run of ``index`` and pipeline it records: point (the run's ``unit``
    column: a point of the map, a condition of :mod:`gimbal_lab.studies.exposure`), pipeline,
    exposure_s, seed, error_m (the run's mean error over the measured frames where the pipeline
    detected; NaN when none) and frames (how many): what :func:`choose_exposures` reads.
    ``results`` are the runs of ``index``'s rows, in its order."""
    results = list(results)
    if len(results) != len(index):
        raise ValueError(f"expected {len(index)} calibration runs (one per row of the calibration index), "
                         f"got {len(results)}")
    rows = []
    for r, result in zip(index.itertuples(), results):
        for pipe, (error, n) in run_errors(result.frames, r.run).items():
            rows.append({"point": getattr(r, unit), "pipeline": pipe, "exposure_s": r.exposure_s, "seed": r.seed,
                         "error_m": error, "frames": n})
    return pd.DataFrame(rows, columns=["point", "pipeline", "exposure_s", "seed", "error_m", "frames"])


def calibration_table(results, study: LightStudy | None = None) -> pd.DataFrame:
    """One row per point, pipeline, exposure and calibration seed (:func:`choice_table`).
    ``results`` are :func:`grid`'s runs in its order."""
    return choice_table(calibration_index(study or LightStudy()), results)


def choose_exposures(table: pd.DataFrame) -> pd.DataFrame:
    """Each pipeline's exposure: the one with its lowest mean error over the frames where it detected.

    Parameters
    ----------
    table : DataFrame
        Columns pipeline, exposure_s, error_m (a run's mean error, m) and frames (the frames it
        was taken over), one row per run (seed); optional ``point``: a choice per point.

    Returns
    -------
    DataFrame
        One row per (point and) pipeline: exposure_s (NaN when the pipeline detected at no
        exposure) and error_m, the frames' mean error there (the runs' means weighted by their
        frames). Ties go to the shorter exposure; an exposure at which the pipeline detected in no
        frame of any seed cannot be chosen.
    """
    keys = ["point", "pipeline"] if "point" in table else ["pipeline"]
    t = table.copy()
    t["frames"] = t["frames"].astype(int)
    t["weighted"] = np.where(t["frames"] > 0, t["error_m"].to_numpy(float) * t["frames"], 0.0)
    pooled = t.groupby(keys + ["exposure_s"], sort=True)[["weighted", "frames"]].sum().reset_index()
    pooled = pooled[pooled["frames"] > 0]
    pooled["error_m"] = pooled["weighted"] / pooled["frames"]
    chosen = (pooled.sort_values(keys + ["error_m", "exposure_s"], kind="mergesort")
              .groupby(keys, sort=True).head(1)[keys + ["exposure_s", "error_m"]])
    everyone = t[keys].drop_duplicates().sort_values(keys)
    return everyone.merge(chosen, on=keys, how="left").reset_index(drop=True)


def best_pipelines(choices: pd.DataFrame) -> pd.DataFrame:
    """Per point the best active and the best passive pipeline: each kind's lowest ``error_m`` at
    its chosen exposure (ties: the one listed first in :data:`PIPELINES`); a pipeline without a
    choice cannot be best. Columns point, best_active, exposure_active_s, error_active_m and the
    same for passive (missing, NaN, when no pipeline of a kind detected at all)."""
    order = {p: i for i, p in enumerate(PIPELINES)}
    rows = []
    for point, g in choices.groupby("point", sort=True):
        row = {"point": int(point)}
        for kind, names in (("active", ACTIVE), ("passive", PASSIVE)):
            c = g[g["pipeline"].isin(names) & np.isfinite(g["error_m"].to_numpy(float))]
            c = c.assign(order=c["pipeline"].map(order)).sort_values(["error_m", "order"], kind="mergesort")
            best = c.iloc[0] if len(c) else None
            row[f"best_{kind}"] = None if best is None else best["pipeline"]
            row[f"exposure_{kind}_s"] = math.nan if best is None else float(best["exposure_s"])
            row[f"error_{kind}_m"] = math.nan if best is None else float(best["error_m"])
        rows.append(row)
    return pd.DataFrame(rows)


def test_index(best: pd.DataFrame, study: LightStudy | None = None) -> pd.DataFrame:
    """The test runs: per point (with both a best active and a best passive) and test seed, the two
    pipelines at their chosen exposures. Columns point, seed, side ("active"/"passive"), pipeline,
    exposure_s."""
    study = study or LightStudy()
    rows = []
    for b in best.itertuples():
        if pd.isna(b.best_active) or pd.isna(b.best_passive):
            continue
        for seed in study.seeds:
            rows.append((b.point, seed, "active", b.best_active, b.exposure_active_s))
            rows.append((b.point, seed, "passive", b.best_passive, b.exposure_passive_s))
    return pd.DataFrame(rows, columns=["point", "seed", "side", "pipeline", "exposure_s"])


def test_configs(index: pd.DataFrame, study: LightStudy | None = None) -> list[TrackingConfig]:
    """The configs of :func:`test_index`'s rows, in its order."""
    study = study or LightStudy()
    points = design(study).set_index("point")
    return [point_config(points.loc[r.point], r.pipeline, r.exposure_s, r.seed, study) for r in index.itertuples()]


def _pipeline_frames(frames: pd.DataFrame, pipeline: str) -> pd.DataFrame:
    """The frames of ``pipeline`` (its column family) in the form
    :func:`gimbal_lab.studies.payoff.common_frame_errors` reads; it keeps the measured ones."""
    prefix = _RUN_OF[pipeline][1]
    return pd.DataFrame({"frame": frames["frame"], "revolution": frames["revolution"],
                         "detected": frames[f"{prefix}detected"], "abs_error_m": frames[f"{prefix}abs_error_m"]})


def response_table(index: pd.DataFrame, results) -> pd.DataFrame:
    """One row per point and test seed: the best active and best passive pipelines, their mean
    errors on the measured frames both detected (``active_m``, ``passive_m``), the share of such
    frames and Δ = active − passive (``delta_m``; NaN without common frames)."""
    from .payoff import common_frame_errors

    results = list(results)
    if len(results) != len(index):
        raise ValueError(f"expected {len(index)} test runs, got {len(results)}")
    rows = []
    for (point, seed), g in index.groupby(["point", "seed"], sort=True):
        runs = {r.side: (r.pipeline, results[i].frames) for i, r in zip(g.index, g.itertuples())}
        errors = common_frame_errors({side: _pipeline_frames(f, p) for side, (p, f) in runs.items()})
        rows.append({"point": int(point), "seed": int(seed), "best_active": runs["active"][0],
                     "best_passive": runs["passive"][0], "active_m": errors["active"][0],
                     "passive_m": errors["passive"][0], "common_rate": errors["active"][1],
                     "delta_m": errors["active"][0] - errors["passive"][0]})
    return pd.DataFrame(rows, columns=["point", "seed", "best_active", "best_passive", "active_m", "passive_m",
                                       "common_rate", "delta_m"])


def point_verdicts(responses: pd.DataFrame, design_table: pd.DataFrame) -> pd.DataFrame:
    """BP2″ at every point with test runs (three-way rule, δ = max(1 mm, 10 % of the smaller mean)),
    the N verdicts held to the family's 5 % error by Holm (:func:`gimbal_lab.stats.holm`)."""
    points = design_table.set_index("point")
    rows = []
    for point, g in responses.groupby("point", sort=True):
        g = g.sort_values("seed")
        rows.append(dict(id=CLAIM[0], point=int(point), statement=CLAIM[1], condition=f"point {int(point)}",
                         a=str(g["best_active"].iloc[0]), b=str(g["best_passive"].iloc[0]),
                         **points.loc[point, list(FACTOR_NAMES)].to_dict(),
                         result=stats.less_than(g["active_m"].to_numpy(float), g["passive_m"].to_numpy(float),
                                                drop_missing=True)))
    table = stats.holm(stats.verdict_table(rows))
    table["unit"] = "m"
    return table


# ----------------------------------------------------------------------------------------------
# the covariate: the streak at the shortest exposure the light allows
# ----------------------------------------------------------------------------------------------
def shortest_exposure_s(light_lux: float, exposures_s, sensor: str = "IMX273", f_number: float = 2.8) -> float:
    """The shortest exposure in ``exposures_s`` at which the auto-gain stays within its maximum.

    The auto-gain brings the frame's mean to the rendered mean, K = 255 / (η·μ_p at reflectance 1)
    whatever the image (:meth:`gimbal_lab.sensor.SensorModel.auto_gain`); the light allows an
    exposure when that K is at most K_max. NaN when no exposure of the set is long enough.
    """
    from ..sensor import SensorModel

    model = SensorModel(sensor, light_lux=float(light_lux), f_number=float(f_number))
    k_max = model.figures.max_gain_dn_per_e
    for t in sorted(float(e) for e in exposures_s):
        if 255.0 / model.electrons_at_full_reflectance(t) <= k_max:
            return t
    return math.nan


def full_well_lux(exposure_s: float, sensor: str = "IMX273", f_number: float = 2.8) -> float:
    """The light, lx, above which a pixel of reflectance 1 collects more than the full well over
    ``exposure_s`` (η·μ_p = μ_e.sat). Brighter, the auto-gain is at K_min and the frame is brighter
    than rendered: every pixel of reflectance above (this light / the scene's) clips
    (docs/design.md, "Sensor and light"). η·μ_p is linear in the light, so this is μ_e.sat over
    the electrons one lux gives."""
    from ..sensor import SensorModel

    model = SensorModel(sensor, light_lux=1.0, f_number=float(f_number))
    return float(model.figures.saturation_e / model.electrons_at_full_reflectance(float(exposure_s)))


def streak_covariate_px(design_table: pd.DataFrame, study: LightStudy | None = None) -> pd.DataFrame:
    """Per point t_min (:func:`shortest_exposure_s` over E, with the camera's sensor and f-number)
    and s = ω·f·t_min, px (``t_min_s``, ``s_px``)."""
    study = study or LightStudy()
    camera = Camera(noise="sensor", light_lux=1.0, exposure_s=study.exposures_s[0], fps=study.fps)
    t_min = [shortest_exposure_s(lux, study.exposures_s, camera.sensor, camera.f_number)
             for lux in design_table["light_lux"]]
    out = design_table[["point"]].copy()
    out["t_min_s"] = t_min
    out["s_px"] = design_table["rate_rad_s"].to_numpy(float) * camera.intrinsics.fx * np.asarray(t_min, float)
    return out


# ----------------------------------------------------------------------------------------------
# the boundary and the ranking
# ----------------------------------------------------------------------------------------------
def fit_logistic(x, y) -> tuple:
    """Maximum-likelihood logistic regression P(y = 1) = 1 / (1 + exp(−(b0 + b1·x))).

    Returns (b0, b1), or None when the classes do not overlap in x (the likelihood then has no
    maximum) or one class is missing. Fitted by Newton's method (scipy's ``expit``), from zero.
    """
    from scipy.special import expit

    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) != len(y) or not np.all(np.isin(y, (0.0, 1.0))):
        raise ValueError("x and y must have one length and y be 0 or 1")
    if y.min() == y.max():
        return None
    if x[y == 1].max() < x[y == 0].min() or x[y == 0].max() < x[y == 1].min():
        return None
    X = np.column_stack([np.ones_like(x), x])
    beta = np.zeros(2)
    for _ in range(100):
        p = expit(X @ beta)
        w = p * (1.0 - p)
        step = np.linalg.solve(X.T @ (X * w[:, None]) + 1e-12 * np.eye(2), X.T @ (y - p))
        beta += step
        if np.max(np.abs(step)) < 1e-10:
            break
    return float(beta[0]), float(beta[1])


def _crossing(x, y):
    """The x where the fitted probability is 0.5, and the slope; under complete separation the middle
    of the gap between the classes (every x there fits them perfectly), slope ±inf."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if y.min() == y.max():
        return math.nan, math.nan
    fit = fit_logistic(x, y)
    if fit is not None:
        b0, b1 = fit
        return (-b0 / b1 if b1 != 0 else math.nan), b1
    pays_high = x[y == 1].min() > x[y == 0].max()
    low, high = (x[y == 0].max(), x[y == 1].min()) if pays_high else (x[y == 1].max(), x[y == 0].min())
    return 0.5 * (low + high), (math.inf if pays_high else -math.inf)


@dataclass(frozen=True)
class Boundary:
    """The s (px) where the probability that the gimbal pays crosses 0.5, with its bootstrap band.

    ``s_px`` is NaN when the decided points fall on one side (``note`` says which); ``low_px`` and
    ``high_px`` bound the 95 % band from the resamples that had both classes (``resamples``);
    ``slope`` is the fit's slope per unit log s (> 0: the gimbal pays above s*); ``pays`` and
    ``does_not`` count the decided points that entered."""

    s_px: float
    low_px: float
    high_px: float
    slope: float
    pays: int
    does_not: int
    resamples: int
    note: str


def fit_boundary(s_px, pays, bootstrap: int = 1000, seed: int = 40) -> Boundary:
    """The logistic boundary of ``pays`` (True/False per decided point) on log ``s_px``.

    The rule is the s at which the fit crosses 0.5 (:func:`fit_logistic`; the gap's middle on log s
    under complete separation); its 95 % band the 2.5 and 97.5 percentiles of the crossings over
    ``bootstrap`` resamples of the points (numpy's default generator, ``seed``), those with both
    classes. Points with a non-finite s are left out.
    """
    s, y = np.asarray(s_px, float), np.asarray(pays, float)
    keep = np.isfinite(s) & (s > 0)
    x, y = np.log(s[keep]), y[keep]
    n_pay, n_not = int((y == 1).sum()), int((y == 0).sum())
    if n_pay == 0 or n_not == 0:
        side = "pays" if n_pay else "does not pay" if n_not else "is decided"
        note = f"every decided point {side}: no boundary inside the map" if (n_pay or n_not) else \
            "no decided point: no boundary"
        return Boundary(math.nan, math.nan, math.nan, math.nan, n_pay, n_not, 0, note)
    crossing, slope = _crossing(x, y)
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(int(bootstrap)):
        i = rng.integers(0, len(x), len(x))
        c, _ = _crossing(x[i], y[i])
        if math.isfinite(c):
            draws.append(c)
    low, high = (np.exp(np.percentile(draws, [2.5, 97.5])) if draws else (math.nan, math.nan))
    note = "the gimbal pays above s*" if slope > 0 else "the gimbal pays below s*"
    return Boundary(float(np.exp(crossing)), float(low), float(high), float(slope), n_pay, n_not, len(draws), note)


def rank_factors(u, y, harmonics: int = 2, bootstrap: int = 1000, seed: int = 40) -> pd.DataFrame:
    """The factors ranked by SALib's ``rbd_fast`` on the *ranks* of ``y`` (average ranks for ties;
    non-finite points left out): one runaway point moves its own rank by at most N − 1, so it
    cannot take the variance from the factor that drives the rest
    (:func:`gimbal_lab.studies.payoff.rank_factors` does the rest)."""
    from scipy.stats import rankdata

    from .payoff import rank_factors as _rank

    y = np.asarray(y, float)
    ranks = np.full(len(y), np.nan)
    keep = np.isfinite(y)
    ranks[keep] = rankdata(y[keep])
    return _rank(u, ranks, FACTOR_NAMES, harmonics=harmonics, bootstrap=bootstrap, seed=seed)


# ----------------------------------------------------------------------------------------------
# analysis and report
# ----------------------------------------------------------------------------------------------
def point_table(verdicts: pd.DataFrame, design_table: pd.DataFrame, best: pd.DataFrame,
                covariate: pd.DataFrame) -> pd.DataFrame:
    """One row per point: factors, cone, t_min and s, the best pipelines and their exposures, the
    mean Δ with its interval, both verdicts and ``class``: "pays" (BP2″ holds in the family),
    "does not" (it does not hold there) or "open"."""
    out = design_table.merge(covariate, on="point").merge(best, on="point", how="left")
    v = verdicts.set_index("point")
    out["delta_m"] = out["point"].map(v["difference"])
    out["delta_low_m"] = out["point"].map(v["low"])
    out["delta_high_m"] = out["point"].map(v["high"])
    out["pairs"] = out["point"].map(v["n"])
    out["verdict"] = out["point"].map(v["verdict"])
    out["verdict_holm"] = out["point"].map(v["verdict_holm"])
    out["class"] = out["verdict_holm"].map({stats.HOLDS: "pays", stats.DOES_NOT_HOLD: "does not"}).fillna("open")
    return out


def analyse(calibration_results, test_index_table, test_results, study: LightStudy) -> dict:
    """Every table of the report: calibration, choices, best, responses, verdicts, points, ranking,
    boundary."""
    table = design(study)
    calibration = calibration_table(calibration_results, study)
    choices = choose_exposures(calibration)
    best = best_pipelines(choices)
    responses = response_table(test_index_table, test_results)
    verdicts = point_verdicts(responses, table)
    points = point_table(verdicts, table, best, streak_covariate_px(table, study))
    u = points[[f"u_{n}" for n in FACTOR_NAMES]].to_numpy(float)
    try:
        ranking = rank_factors(u, points["delta_m"], harmonics=study.harmonics, bootstrap=study.bootstrap,
                               seed=study.design_seed)
    except ValueError:  # too few points with a response: the report says so rather than failing after the runs
        ranking = pd.DataFrame({"factor": list(FACTOR_NAMES), "s1": math.nan, "s1_low": math.nan,
                                "s1_high": math.nan, "rank": math.nan,
                                "points": int(np.isfinite(points["delta_m"].to_numpy(float)).sum())})
    decided = points[points["class"] != "open"]
    boundary = fit_boundary(decided["s_px"], decided["class"] == "pays", bootstrap=study.bootstrap,
                            seed=study.design_seed)
    return {"design": table, "calibration": calibration, "choices": choices, "best": best, "responses": responses,
            "verdicts": verdicts, "points": points, "ranking": ranking, "boundary": boundary}


def _mm(x) -> str:
    return f"{1000 * x:.2f}" if x is not None and math.isfinite(x) else "–"


def _ms(x) -> str:
    return f"{1000 * x:.3g}" if x is not None and math.isfinite(x) else "–"


def boundary_sentence(b: Boundary) -> str:
    """The rule in one sentence, or why the map gives none."""
    if not math.isfinite(b.s_px):
        return f"{b.note} ({b.pays} pay, {b.does_not} do not)."
    side = "more" if b.slope > 0 else "less"
    return (f"the gimbal pays when the target would streak {side} than s* = {b.s_px:.3g} px "
            f"[95 % band {b.low_px:.3g}–{b.high_px:.3g} px, {b.resamples} resamples] at the shortest exposure the "
            f"light allows ({b.pays} points pay, {b.does_not} do not).")


def claims_markdown(tables: dict, study: LightStudy) -> str:
    """claims.md: the design, every pipeline's chosen exposure per point, the verdicts at both
    levels, the boundary and the ranking."""
    v, points, choices = tables["verdicts"], tables["points"], tables["choices"]
    lines = [f"# The buying-rule map ({study.points} points; exposures chosen on seeds "
             f"{', '.join(map(str, study.calibration_seeds))}, tested on seeds {study.seeds[0]}–{study.seeds[-1]})", "",
             "Sphere on a cone about the home axis, hovering body with vibration, the IMX273 sensor model at f/2.8; "
             f"five factors sampled by a Latin hypercube (SALib, seed {study.design_seed}); docs/design.md, "
             "“Exposure as a choice, and a buying rule”. E = {" + ", ".join(f"{e:g}" for e in study.exposures_ms)
             + "} ms. Δ = error(best active) − error(best passive) on the measured frames both detected: below zero "
             "the gimbal pays.", "", "| factor | range |", "|---|---|"]
    lines += [f"| {f.label} | {f.low:g}–{f.high:g} {f.unit}{' (log-uniform)' if f.log else ''} |" for f in FACTORS]
    lines += ["", "## The exposure each pipeline chose (ms; – : it detected at no exposure)", "",
              "| point | " + " | ".join(PIPELINES) + " |", "|" + "---|" * (len(PIPELINES) + 1)]
    for point, g in choices.groupby("point", sort=True):
        chosen = g.set_index("pipeline")["exposure_s"]
        lines.append(f"| {point} | " + " | ".join(_ms(chosen.get(p, math.nan)) for p in PIPELINES) + " |")
    lines += ["", "## Verdicts per point", "",
              f"{CLAIM[0]} “{CLAIM[1]}”, three-way rule, δ = max(1 mm, 10 % of the smaller mean); one family of "
              f"{len(v)} verdicts (Holm, 5 % family-wise).", "", f"- **{CLAIM[0]}**: " + verdict_counts(v)]
    counts = points["class"].value_counts()
    lines += ["", f"At the family level the gimbal **pays at {counts.get('pays', 0)}** of {len(points)} points, "
              f"**does not at {counts.get('does not', 0)}**, and {counts.get('open', 0)} stay open.", "",
              "| point | " + " | ".join(f.name for f in FACTORS) + " | s (px) | best active @ ms | best passive @ ms "
              "| Δ [95 % CI] mm | BP2″ | BP2″ (Holm) |", "|" + "---|" * (len(FACTORS) + 7)]
    for r in points.itertuples():
        vals = " | ".join(f"{getattr(r, f.name):.3g}" for f in FACTORS)
        lines.append(f"| {r.point} | {vals} | {r.s_px:.3g} | {md_cell(r.best_active)} @ {_ms(r.exposure_active_s)} "
                     f"| {md_cell(r.best_passive)} @ {_ms(r.exposure_passive_s)} | {_mm(r.delta_m)} "
                     f"[{_mm(r.delta_low_m)}, {_mm(r.delta_high_m)}] | {r.verdict} | **{r.verdict_holm}** |")
    lines += ["", "## The rule", "", "Logistic regression of “pays” (pays vs does not; open points left out) on "
              "log s, s = ω·f·t_min the streak at the shortest exposure in E the light allows: "
              + boundary_sentence(tables["boundary"])]
    ranking = tables["ranking"]
    lines += ["", "## What decides Δ", "",
              f"rbd_fast first-order index on the ranks of the per-point mean Δ (M = {study.harmonics}, 95 % "
              f"bootstrap interval, {study.bootstrap} resamples, {int(ranking['points'].iloc[0])} points).", "",
              "| rank | factor | S1 [95 % CI] |", "|---|---|---|"]
    labels = {f.name: f.label for f in FACTORS}
    if ranking["s1"].isna().all():
        lines += ["", f"Not ranked: rbd_fast needs at least {MIN_POINTS} points with a response."]
    lines += [f"| {r.rank} | {md_cell(labels[r.factor])} | {r.s1:.2f} [{r.s1_low:.2f}, {r.s1_high:.2f}] |"
              for r in ranking.itertuples()]
    lines += ["", f"Smallest Holm-adjusted p in the family: {format_p(v['p_holm'].min())}."]
    return "\n".join(lines) + "\n"


def figures(tables: dict) -> list:
    """The report's figures as (name, draw): the map, Δ against s, the ranking."""
    from ..plotting import light as pl
    from ..plotting import payoff as pp

    points, boundary = tables["points"], tables["boundary"]
    return [("map", lambda: pl.plot_buying_map(points, boundary)),
            ("delta_vs_streak", lambda: pl.plot_delta_vs_streak(points, boundary)),
            ("ranking", lambda: pp.plot_ranking({"Δ (ranks)": tables["ranking"]},
                                                {f.name: f.label for f in FACTORS}))]


def make_report(calibration_results, test_index_table, test_results, study: LightStudy):
    """The map's report: design.csv, calibration.csv, choices.csv, best.csv, responses.csv,
    points.csv, verdicts.csv, ranking.csv, boundary.csv, claims.md, study.json and the figures
    (a :class:`gimbal_lab.studies.report.Report`)."""
    from . import report as _report

    tables = analyse(calibration_results, test_index_table, test_results, study)
    b = tables["boundary"]
    boundary = pd.DataFrame([{"s_px": b.s_px, "low_px": b.low_px, "high_px": b.high_px, "slope": b.slope,
                              "pays": b.pays, "does_not": b.does_not, "resamples": b.resamples, "note": b.note}])
    runs = len(calibration_results) + len(test_results)
    return _report.Report(NAME, study, runs, [
        ("design.csv", tables["design"]), ("calibration.csv", tables["calibration"]),
        ("choices.csv", tables["choices"]), ("best.csv", tables["best"]), ("responses.csv", tables["responses"]),
        ("points.csv", tables["points"]), ("verdicts.csv", tables["verdicts"]), ("ranking.csv", tables["ranking"]),
        ("boundary.csv", boundary), ("claims.md", claims_markdown(tables, study)),
    ], figures(tables), tables["verdicts"], forest=None, formats=("png",))


def run_map(study: LightStudy, *, store=None, executor=None, jobs=None, progress=True) -> dict:
    """Both stages of the map: the calibration runs, the choices, then the test runs. Returns
    ``calibration`` (results), ``test_index`` and ``test`` (results)."""
    from ..runner import run

    calibration = run(grid(study), store=store, executor=executor, jobs=jobs, progress=progress,
                      desc="light map: calibration")
    index = _plan_tests(calibration, study)
    test = run(test_configs(index, study), store=store, executor=executor, jobs=jobs, progress=progress,
               desc="light map: test")
    return {"calibration": calibration, "test_index": index, "test": test}


def _plan_tests(calibration, study: LightStudy) -> pd.DataFrame:
    """The test runs (:func:`test_index`) that the calibration runs' choices call for."""
    return test_index(best_pipelines(choose_exposures(calibration_table(calibration, study))), study)


def run_study(study: LightStudy, out, *, store=None, executor=None, jobs=None, progress=True, clips=True) -> dict:
    """``gimbal-lab run light``: the calibration runs, the choices, the test runs (reusing ``store``)
    and the report in ``out/light``. ``clips`` is accepted for the command's uniformity; the map
    writes none."""
    from . import report as _report

    def plan(calibration):
        index = _plan_tests(calibration, study)
        return index, test_configs(index, study)

    return _report.run_with_choices(NAME, "light map", grid(study), plan, make_report, study, out, store=store,
                                    executor=executor, jobs=jobs, progress=progress)
