"""The lens sweep (docs/design.md, "Lens sweep"): lens strength up to fisheye, and three ways to
treat the lens: ignore it (the paper), undistort the detected points, or rectify the image first;
and when a gimbal pays off against the best passive camera (docs/design.md, "When does a gimbal
pay off?").

Lenses (:data:`LENSES`): Brown–Conrady with the study's default coefficients scaled by 0, 0.5, 1
and 1.5 at 60° horizontal field, and equidistant Kannala–Brandt fisheyes (all k = 0, the stated
choice: the ideal fisheye, whose focal length follows from the field alone) of 120°, 150° and
185°, every one 640 × 480. Strategies (:data:`STRATEGIES`): :class:`gimbal_lab.config.Estimator`
``lens_strategy``; the undistorted pinhole has no lens, so it runs "ignore" only.

The target moves at 3 m from the home camera on a cone about the home axis, 0.7 of the half field
off it (:data:`gimbal_lab.config.CONE_FIELD_FRACTION`; the "field" cone), one revolution per
period. Its size is scaled by f_60°/f so that its image on the axis matches the paper study's
(sphere 0.10 m, marker 0.30 m at f = 554 px). The body hovers still at :data:`ALTITUDE_M` instead
of 2 m: the widest cone (185°: 2.71 m off the axis) would otherwise pass under the ground. The
fisheyes also run an "in-limit" cone (:data:`CONES`) of half-angle :data:`IN_LIMIT_HALF_ANGLE_RAD`
(40°), "ignore" strategy, passive and active: the 150° and 185° field cones ask for more yaw rate
than the loop's 3 rad/s and rise past the pitch stop (:func:`demand_table`).

Grid: {sphere, ArUco} × 7 lenses × strategies × {passive, active} on the field cones (76 cells)
plus {sphere, ArUco} × 3 fisheyes × {passive, active} on the in-limit cones (12 cells), each
``replicates`` times; replicate s draws the start phase and the sensor noise from seed s, shared
by every cell (paired). Each replicate runs ``revolutions`` periods; the first is acquisition.

Tables (measured revolutions): :func:`replicate_table`, one row per run (detection rate, the
distance error on the run's own detections and on the frames every strategy of the same lens,
target, mode, cone and seed detected, for the sphere also with the exact cone fit, the ``alt_*``
columns; frames at a joint stop); :func:`pipeline_table`, the compared pipelines of BP1 and BP2
on the frames both detected; :func:`measure_costs`, the CPU time per frame of each pipeline
(detection and localisation, rectification included) measured apart from the runs on the same
frames for every pipeline, the minimum of :data:`COST_REPEATS` repeats.

Hypotheses (fixed in docs/design.md before any result): **H1** (the paper's, §4.1.2 end and §5)
rectifying first worsens tracking at high distortion: error on common frames and detection rate,
for the Brown–Conrady ×1.5 lens and the fisheyes, the sphere judged with the exact cone fit (the
paper's circle method beside it, "H1 circle"); **H2** active's advantage over passive (paper
pipeline) grows with distortion, within each lens family: pinhole to ×1.5, and 120° to 185° on the
in-limit cones (the field cones "H2 over limit", reported apart with their demand); **H3**
undistorting points is at least as accurate as rectifying (non-inferiority, margin δ) at a
fraction of the CPU cost (sphere: exact cone fit; "H3 circle" beside); **BP1** "active (paper) <
best passive" and **BP2** "active (best) < best passive", per target and lens. Every verdict of
the report is one family held to 5 % by Holm (:func:`gimbal_lab.stats.holm`).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..camera import BrownConrady, Intrinsics, KannalaBrandt
from ..config import Camera, Estimator, Platform, Pointing, Target, TrackingConfig, _choice, _number
from . import _params
from . import report as _report
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "LensSweepStudy", "Study", "Lens", "LENSES", "STRATEGIES", "MODES", "TARGETS", "CONES", "FISHEYES",
    "HIGH_DISTORTION", "IN_LIMIT_HALF_ANGLE_RAD", "RATE_FLOOR_PCT", "COST_FLOOR_MS", "COST_REPEATS", "PIPELINES",
    "LENSES_ENV", "grid", "replicate_table", "pipeline_table", "measure_costs", "cost_summary", "summary_table",
    "check_hypotheses", "hypotheses_markdown", "make_report", "run_study", "cone_pointing_demand", "demand_table",
    "example_view", "lens_name", "cone_name", "strategies_for", "methods_for", "lenses_from_env",
]

NAME = "lens-sweep"
DESCRIPTION = ("lens sweep: Brown–Conrady up to fisheye; ignore the lens, undistort the points or rectify "
               "the image first; the best passive camera (88 cells)")

TARGETS = ("sphere", "aruco")
MODES = ("passive", "active")
STRATEGIES = ("ignore", "undistort", "rectify")
#: The target's cones: "field", 0.7 of the half field off the home axis (the sweep's own); "in-limit",
#: :data:`IN_LIMIT_HALF_ANGLE_RAD` (the fisheyes only, "ignore" strategy).
CONES = ("field", "in-limit")
#: The in-limit cone's half-angle (docs/design.md, "When does a gimbal pay off?", Repairs): at the
#: 2 s period the yaw rate peaks at ω·tan 40° = 2.6 rad/s, under the loop's 3 rad/s, and the
#: target rises 40°, inside the pitch joint's +45°.
IN_LIMIT_HALF_ANGLE_RAD = math.radians(40.0)

#: The paper study's camera, whose on-axis target images the sweep keeps: 60° across 640 px.
REFERENCE_FOCAL_PX = Intrinsics.default().fx
#: Height of the hovering body, m: the widest cone's lowest target point stays 0.7 m above ground.
ALTITUDE_M = 4.0
#: δ floors: a detection rate differing by under one percentage point, or a cost by under 0.05 ms
#: per frame, is no difference worth the name.
RATE_FLOOR_PCT = 1.0
COST_FLOOR_MS = 0.05
#: Repeats of each pipeline's timing; the cost is the fastest (docs/design.md: the minimum of 5).
COST_REPEATS = 5
#: Environment variable naming the lenses a notebook runs, comma-separated (all when unset).
LENSES_ENV = "GIMBAL_LAB_LENSES"


@dataclass(frozen=True)
class Lens:
    """One lens of the sweep: its name, family, strength (the x axis of the figures) and model."""

    name: str
    family: str  # "brown-conrady" or "fisheye"
    strength: float  # coefficient scale, or horizontal field in degrees
    hfov_deg: float

    @property
    def model(self) -> BrownConrady | KannalaBrandt:
        if self.family == "fisheye":
            return KannalaBrandt()
        d = BrownConrady.default()
        return BrownConrady(**{k: self.strength * getattr(d, k) for k in ("k1", "k2", "k3", "p1", "p2")})

    @property
    def focal_px(self) -> float:
        """Focal length at 640 px across: the equidistant rule for a fisheye, the pinhole's otherwise."""
        hfov = math.radians(self.hfov_deg)
        if self.family == "fisheye":
            return KannalaBrandt.equidistant_for_fov(640, hfov)[1]
        return Intrinsics.from_fov(640, 480, hfov).fx

    def camera_fields(self) -> dict:
        """The :class:`~gimbal_lab.config.Camera` fields of this lens."""
        return {"lens": self.model, "hfov_rad": math.radians(self.hfov_deg)}


LENSES = (
    Lens("pinhole", "brown-conrady", 0.0, 60.0),
    Lens("BC ×0.5", "brown-conrady", 0.5, 60.0),
    Lens("BC ×1", "brown-conrady", 1.0, 60.0),
    Lens("BC ×1.5", "brown-conrady", 1.5, 60.0),
    Lens("fisheye 120°", "fisheye", 120.0, 120.0),
    Lens("fisheye 150°", "fisheye", 150.0, 150.0),
    Lens("fisheye 185°", "fisheye", 185.0, 185.0),
)
_LENS = {lens.name: lens for lens in LENSES}
FISHEYES = tuple(lens.name for lens in LENSES if lens.family == "fisheye")
#: The lenses H1 calls high distortion: the strongest Brown–Conrady and every fisheye.
HIGH_DISTORTION = ("BC ×1.5", "fisheye 120°", "fisheye 150°", "fisheye 185°")
#: H2's weakest and strongest lens of each family, and the cone each family's H2 is judged on.
FAMILY_ENDS = {"brown-conrady": ("pinhole", "BC ×1.5"), "fisheye": ("fisheye 120°", "fisheye 185°")}
_H2_CONE = {"brown-conrady": "field", "fisheye": "in-limit"}
#: The sphere's localisers as a pipeline names them: the paper's circle method and the exact cone
#: fit (the ``alt_*`` columns of a run whose estimator uses the circle); the marker's PnP.
_METHODS = {"sphere": ("circle", "exact"), "aruco": ("PnP",)}
_SPHERE_METHOD = {"circle": "circle", "exact": "ellipse", "PnP": "circle"}
#: The pipelines compared against the passive camera (docs/design.md, "When does a gimbal pay
#: off?"): name → (mode, strategy with a lens, method per target). "best" knows the lens
#: ("undistort"; nothing to undistort on the pinhole, which runs "ignore") and uses the best estimator.
PIPELINES = {
    "active (paper)": ("active", "ignore", {"sphere": "circle", "aruco": "PnP"}),
    "active (best)": ("active", "undistort", {"sphere": "exact", "aruco": "PnP"}),
    "best passive": ("passive", "undistort", {"sphere": "exact", "aruco": "PnP"}),
}
#: BP1 and BP2: (a, b) of "a < b".
BP_CLAIMS = {"BP1": ("active (paper)", "best passive"), "BP2": ("active (best)", "best passive")}


def strategies_for(lens: str) -> tuple[str, ...]:
    """The strategies a lens runs: all three, or "ignore" alone for the ideal pinhole."""
    return ("ignore",) if _LENS[lens].strength == 0.0 else STRATEGIES


def methods_for(target: str) -> tuple[str, ...]:
    """The localisers a target's pipelines use: ("circle", "exact") for the sphere, ("PnP",) for the marker."""
    return _METHODS[_choice("target", target, TARGETS)]


def lenses_from_env(default=None) -> tuple[str, ...]:
    """The lenses named in :data:`LENSES_ENV` (comma-separated :data:`LENSES` names, in the sweep's
    order), or ``default`` (every lens) when it is unset; ValueError naming an unknown lens."""
    text = os.environ.get(LENSES_ENV, "").strip()
    if not text:
        return tuple(_LENS) if default is None else tuple(default)
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in _LENS]
    if unknown:
        raise ValueError(f"{LENSES_ENV} names unknown lens(es) {unknown}; the sweep's are {list(_LENS)}")
    return tuple(name for name in _LENS if name in names)


@dataclass(frozen=True)
class LensSweepStudy(StudyParams):
    """Parameters of the lens sweep (defaults: docs/design.md; ``data/studies/lens-sweep.toml``).

    Parameters
    ----------
    replicates, first_seed, revolutions, period_s, fps, latency_frames, noise_std :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`); a revolution is
        one turn of the target's cone.
    aruco_refinement : {"none", "subpix", "contour", "apriltag"}
        Corner refinement (sub-pixel, as in the paper's study).
    """

    aruco_refinement: str = "subpix"

    _TABLE = NAME

    def __post_init__(self):
        self._check_replicates()
        object.__setattr__(self, "period_s", _number("period_s", self.period_s, low=0.0, low_open=True))
        # the rest is validated by the config's parts, naming part and field
        self.config("aruco", "fisheye 185°", "rectify", "active", self.first_seed)

    def config(self, target: str, lens: str, strategy: str, mode: str, seed: int, cone: str = "field") -> TrackingConfig:
        """The run of one cell and replicate (``cone`` "in-limit": a fisheye, "ignore" only)."""
        _choice("target", target, TARGETS)
        _choice("lens", lens, tuple(_LENS))
        _choice("strategy", strategy, strategies_for(lens))
        _choice("mode", mode, MODES)
        _choice("cone", cone, CONES)
        if cone == "in-limit" and (lens not in FISHEYES or strategy != "ignore"):
            raise ValueError(f"cone 'in-limit' runs on the fisheyes {FISHEYES} with strategy 'ignore' only, got "
                             f"{lens!r} and {strategy!r}")
        scale = REFERENCE_FOCAL_PX / _LENS[lens].focal_px
        return TrackingConfig(
            camera=Camera(**_LENS[lens].camera_fields(), fps=self.fps, latency_frames=self.latency_frames,
                          noise_std=self.noise_std),
            platform=Platform(altitude_m=ALTITUDE_M),
            target=Target(kind=target, trajectory="cone", period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s), sphere_radius_m=0.10 * scale,
                          marker_length_m=0.30 * scale,
                          cone_half_angle_rad=IN_LIMIT_HALF_ANGLE_RAD if cone == "in-limit" else None),
            pointing=Pointing(_POINTING[mode]),
            estimator=Estimator(lens_strategy=strategy, aruco_refinement=self.aruco_refinement),
            revolutions=self.revolutions, seed=seed)


#: The pointing kind of each mode: passive holds the stabilised gimbal at home, active runs the
#: paper's image loop.
_POINTING = {"passive": "stabilised", "active": "paper"}

#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = LensSweepStudy


def grid(study: LensSweepStudy | None = None, targets=TARGETS, lenses=None) -> list[TrackingConfig]:
    """Every (cell, replicate) config: target, lens, strategy, mode, then replicates innermost (the
    runs of one renderer are adjacent); the in-limit cones follow their fisheye's field cone."""
    study = study or LensSweepStudy()
    lenses = tuple(_LENS) if lenses is None else tuple(lenses)
    for lens in lenses:
        _choice("lens", lens, tuple(_LENS))
    configs = []
    for target in targets:
        for lens in lenses:
            configs += [study.config(target, lens, strategy, mode, seed)
                        for strategy in strategies_for(lens) for mode in MODES for seed in study.seeds]
            if lens in FISHEYES:
                configs += [study.config(target, lens, "ignore", mode, seed, cone="in-limit")
                            for mode in MODES for seed in study.seeds]
    return configs


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def lens_name(config: TrackingConfig) -> str:
    """The :data:`LENSES` name of a config's lens (ValueError for a lens outside the sweep)."""
    camera = config.camera
    field_rad = camera.horizontal_field_rad
    for lens in LENSES:
        fields = lens.camera_fields()
        # the pinhole's model is Brown–Conrady with zero coefficients, which a camera holds as no lens
        if (camera.lens_model or BrownConrady()) == fields["lens"] and math.isclose(field_rad, fields["hfov_rad"]):
            return lens.name
    raise ValueError(f"the config's lens {camera.lens_model!r} at {math.degrees(field_rad):.1f}° is not one of the "
                     "sweep's")


def cone_name(config: TrackingConfig) -> str:
    """"in-limit" for a config whose cone has its own half-angle, "field" otherwise."""
    return "field" if config.target.cone_half_angle_rad is None else "in-limit"


def _mean(values) -> float:
    values = np.asarray(values, float)
    return float(values.mean()) if values.size else math.nan


def _measured(result) -> pd.DataFrame:
    """A run's frames of the measured revolutions (the first revolution is acquisition)."""
    return result.frames[result.frames["frame"] >= round(result.config.frames_per_revolution)]


def _column(frames: pd.DataFrame, name: str, fill, dtype=float) -> np.ndarray:
    return frames[name].to_numpy(dtype) if name in frames else np.full(len(frames), fill, dtype=dtype)


def _located(frames: pd.DataFrame, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(localised, |d_est − d_true|) per frame for a pipeline's method: the ``alt_*`` columns for
    the exact cone fit (the runs' estimators use the circle), the run's own otherwise."""
    if method == "exact":
        return _column(frames, "alt_detected", False, bool), _column(frames, "alt_abs_error_m", math.nan)
    return frames["detected"].to_numpy(bool), frames["abs_error_m"].to_numpy(float)


def replicate_table(results) -> pd.DataFrame:
    """One row per run: its means over the measured revolutions.

    Columns: target, lens, family, strength, strategy, mode, cone, seed, frames,
    detection_rate_pct, mean_abs_error_m (its own detections), common_rate_pct and
    common_abs_error_m (the frames where every strategy of the same target, lens, mode, cone and
    seed among ``results`` detected the target; NaN when there is none), mean_true_offset_px,
    alt_detection_rate_pct and alt_abs_error_m (the sphere's other localiser, the exact cone fit
    beside the paper's circle, on its own localisations; NaN for the marker),
    common_alt_rate_pct and common_alt_abs_error_m (the same on the frames every strategy's exact
    fit localised), stop_pct (frames with a joint at its stop, ``at_limit_*``), peak_joint_rate_rad_s
    (largest |joint rate| at a frame's start), estimate_ms (detection and localisation per frame,
    rectification included, wall time inside the run: informative only; the study's cost is
    :func:`measure_costs`) and render_ms.
    """
    groups: dict[tuple, list] = {}
    for r in results:
        c = r.config
        groups.setdefault((c.target.kind, lens_name(c), c.pointing.mode, cone_name(c), c.seed), []).append(r)
    rows = []
    for (target, lens, mode, cone, seed), members in groups.items():
        measured = {id(r): _measured(r) for r in members}
        if len({len(f) for f in measured.values()}) != 1:
            raise ValueError("runs of one target, lens, mode, cone and seed must have the same frames")
        common = np.logical_and.reduce([f["detected"].to_numpy(bool) for f in measured.values()])
        common_alt = np.logical_and.reduce([_located(f, "exact")[0] for f in measured.values()])
        for r in members:
            c, f = r.config, measured[id(r)]
            detected = f["detected"].to_numpy(bool)
            error = f["abs_error_m"].to_numpy(float)
            alt_ok, alt_error = _located(f, "exact")
            sphere = target == "sphere" and "alt_detected" in f
            at_stop = np.logical_or.reduce([_column(f, f"at_limit_{j}", False, bool) for j in ("yaw", "roll", "pitch")])
            rates = np.abs(np.column_stack([_column(f, f"qd_{j}_rad_s", math.nan) for j in ("yaw", "roll", "pitch")]))
            rows.append({
                "target": target, "lens": lens, "family": _LENS[lens].family, "strength": _LENS[lens].strength,
                "strategy": c.estimator.lens_strategy, "mode": mode, "cone": cone, "seed": seed, "frames": len(f),
                "detection_rate_pct": 100.0 * _mean(detected),
                "mean_abs_error_m": _mean(error[detected]),
                "common_rate_pct": 100.0 * _mean(common),
                "common_abs_error_m": _mean(error[common]),
                "mean_true_offset_px": _mean(f["true_offset_px"]),
                "alt_detection_rate_pct": 100.0 * _mean(alt_ok) if sphere else math.nan,
                "alt_abs_error_m": _mean(alt_error[alt_ok]) if sphere else math.nan,
                "common_alt_rate_pct": 100.0 * _mean(common_alt) if sphere else math.nan,
                "common_alt_abs_error_m": _mean(alt_error[common_alt]) if sphere else math.nan,
                "stop_pct": 100.0 * _mean(at_stop),
                "peak_joint_rate_rad_s": float(np.nanmax(rates)) if np.isfinite(rates).any() else math.nan,
                "estimate_ms": 1000.0 * r.timing.get("detect_s", math.nan) / max(len(r.frames), 1),
                "render_ms": 1000.0 * r.timing.get("render_s", math.nan) / max(len(r.frames), 1),
            })
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(["target", "lens", "cone", "strategy", "mode", "seed"], key=_sort_key, ignore_index=True)


_ORDER = {name: i for i, name in enumerate(TARGETS + tuple(_LENS) + CONES + STRATEGIES + MODES + tuple(PIPELINES)
                                            + tuple(BP_CLAIMS) + ("circle", "exact", "PnP"))}


def _sort_key(column: pd.Series) -> pd.Series:
    return column if column.name == "seed" else column.map(_ORDER)


def _pipeline_run(runs: dict, target: str, lens: str, pipeline: str):
    """The run and method of a pipeline among ``runs`` keyed (mode, strategy), or (None, method)."""
    mode, strategy, methods = PIPELINES[pipeline]
    if strategy not in strategies_for(lens):
        strategy = "ignore"  # the pinhole: no lens to know
    return runs.get((mode, strategy)), methods[target]


def pipeline_table(results) -> pd.DataFrame:
    """BP1 and BP2's pipelines per target, lens (field cones) and seed, on the frames both detected.

    One row per (target, lens, seed, claim): a and b (pipeline names, :data:`BP_CLAIMS`),
    a_error_m and b_error_m (mean |d_est − d_true| over the measured frames both pipelines
    localised; NaN when there is none), common_rate_pct (those frames' share), and a_rate_pct,
    b_rate_pct (each pipeline's own localisation rate). A pipeline's frames: its run's (mode,
    strategy) and method (:data:`PIPELINES`), the exact cone fit from the ``alt_*`` columns.
    Claims whose runs are not all in ``results`` are left out.
    """
    groups: dict[tuple, dict] = {}
    for r in results:
        c = r.config
        if cone_name(c) == "field":
            groups.setdefault((c.target.kind, lens_name(c), c.seed), {})[(c.pointing.mode,
                                                                         c.estimator.lens_strategy)] = r
    rows = []
    for (target, lens, seed), runs in groups.items():
        for claim, (a, b) in BP_CLAIMS.items():
            (run_a, method_a), (run_b, method_b) = (_pipeline_run(runs, target, lens, p) for p in (a, b))
            if run_a is None or run_b is None:
                continue
            (ok_a, err_a), (ok_b, err_b) = _located(_measured(run_a), method_a), _located(_measured(run_b), method_b)
            if ok_a.shape != ok_b.shape:
                raise ValueError(f"{target}/{lens} seed {seed}: the runs of {a} and {b} have different frames")
            both = ok_a & ok_b
            rows.append({"target": target, "lens": lens, "family": _LENS[lens].family, "seed": seed, "claim": claim,
                         "a": a, "b": b, "method_a": method_a, "method_b": method_b,
                         "a_error_m": _mean(err_a[both]), "b_error_m": _mean(err_b[both]),
                         "common_rate_pct": 100.0 * _mean(both), "a_rate_pct": 100.0 * _mean(ok_a),
                         "b_rate_pct": 100.0 * _mean(ok_b)})
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(["target", "lens", "claim", "seed"], key=_sort_key, ignore_index=True)


# ----------------------------------------------------------------------------------------------
# CPU cost of each pipeline, measured apart from the runs
# ----------------------------------------------------------------------------------------------
def _cpu_seconds(estimate, images) -> float:
    """CPU time of this process spent running ``estimate`` on every image, s."""
    start = time.process_time()
    for image in images:
        estimate(image)
    return time.process_time() - start


def _cost_job(result, repeats: int = COST_REPEATS, every: int = 1) -> list[dict]:
    """What a worker does for one run: replay its measured frames (every ``every``-th; bit-identical
    to the run's, :func:`gimbal_lab.show.replay`), then time every pipeline of its lens on them,
    ``repeats`` rounds of each pipeline in turn (module-level, so an executor can pickle it)."""
    from ..runner import _prepare_process, _renderer_for
    from ..show import replay

    _prepare_process()
    c = result.config
    images = [image for _, image in replay(result, renderer=_renderer_for(c), every=every,
                                            start=round(c.frames_per_revolution))]
    if not images:
        raise ValueError(f"{c.label} seed {c.seed}: no measured frames to time")
    target, lens = c.target.kind, lens_name(c)
    pipelines = {(strategy, method): c.estimator.replace(lens_strategy=strategy, sphere_method=_SPHERE_METHOD[method])
                 .build(c.camera, c.target, alt=False)
                 for strategy in strategies_for(lens) for method in methods_for(target)}
    seconds = {key: math.inf for key in pipelines}
    for _ in range(repeats):  # rounds, so that a slow spell of the machine falls on every pipeline alike
        for key, estimate in pipelines.items():
            seconds[key] = min(seconds[key], _cpu_seconds(estimate, images))
    return [{"target": target, "lens": lens, "mode": c.pointing.mode, "seed": c.seed, "strategy": strategy,
             "method": method, "frames": len(images), "cpu_ms": 1000.0 * s / len(images)}
            for (strategy, method), s in seconds.items()]


def measure_costs(results, *, jobs: int | None = None, executor=None, progress: bool = True,
                  repeats: int = COST_REPEATS, every: int = 1) -> pd.DataFrame:
    """CPU time per frame of every pipeline, measured apart from the runs (docs/design.md).

    For each target, lens (field cones), mode and seed, the "ignore" run's measured frames are
    rendered again exactly (:func:`gimbal_lab.show.replay`) and every strategy × method of the
    lens detects and localises them (:meth:`gimbal_lab.config.Estimator.build` with ``alt=False``:
    the pipeline alone, rectification included); a pipeline's cost is the least CPU time
    (:func:`time.process_time`) of ``repeats`` passes over the same frames, per frame.

    Parameters
    ----------
    results : sequence of TrackingResult
        The sweep's runs (those of other cones and strategies are skipped).
    jobs : int, optional
        Local worker processes (default: the CPU count); 1 measures in this process, which then
        holds a GL context.
    executor : concurrent.futures.Executor, optional
        Where the measurements go instead (a Dask cluster's executor).
    repeats : int
        Passes per pipeline, >= 1 (:data:`COST_REPEATS`).
    every : int
        Time every ``every``-th measured frame (the study times them all: 1).

    Returns
    -------
    DataFrame
        target, lens, mode, seed, strategy, method, frames (timed), cpu_ms.
    """
    from concurrent.futures import as_completed

    from ..runner import _local_pool, _single_threaded_children, _stop_pool

    repeats = _number("repeats", repeats, low=1, high=1000, integer=True)
    every = _number("every", every, low=1, high=10_000, integer=True)
    runs = [r for r in results if r.config.estimator.lens_strategy == "ignore" and cone_name(r.config) == "field"]
    if jobs is None:
        jobs = os.cpu_count() or 1
    rows: list[dict] = []
    bar = None
    if progress and runs:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(runs), desc="CPU cost of each pipeline", unit="run", dynamic_ncols=True)
    try:
        if executor is None and jobs == 1:
            for r in runs:
                rows += _cost_job(r, repeats, every)
                if bar is not None:
                    bar.update()
        elif runs:
            with _single_threaded_children() if executor is None else _nothing():
                pool = executor if executor is not None else _local_pool(min(jobs, len(runs)))
                try:
                    for future in as_completed([pool.submit(_cost_job, r, repeats, every) for r in runs]):
                        rows += future.result()
                        if bar is not None:
                            bar.update()
                except BaseException:
                    if executor is None:
                        _stop_pool(pool)
                    raise
                else:
                    if executor is None:
                        pool.shutdown(wait=True)
    finally:
        if bar is not None:
            bar.close()
    table = pd.DataFrame(rows, columns=["target", "lens", "mode", "seed", "strategy", "method", "frames", "cpu_ms"])
    return table.sort_values(["target", "lens", "mode", "strategy", "method", "seed"], key=_sort_key,
                             ignore_index=True)


class _nothing:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def cost_summary(costs: pd.DataFrame) -> pd.DataFrame:
    """Per target, lens, mode, strategy and method: replicates and the mean CPU ms per frame with
    its 95 % t-interval."""
    rows = []
    for key, g in costs.groupby(["target", "lens", "mode", "strategy", "method"], sort=False):
        mean, low, high = stats.mean_interval(g["cpu_ms"])
        rows.append(dict(zip(["target", "lens", "mode", "strategy", "method"], key), replicates=len(g), cpu_ms=mean,
                         cpu_ci_low_ms=low, cpu_ci_high_ms=high))
    return pd.DataFrame(rows)


_CELL = ["target", "lens", "cone", "strategy", "mode"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell: replicates, the mean of each replicate quantity and 95 % t-intervals of the error
    on the run's own detections (``ci_low_m``, ``ci_high_m``; the exact cone fit's
    ``alt_ci_low_m``, ``alt_ci_high_m``) and of the in-run cost per frame."""
    rows = []
    for key, g in replicates.groupby(_CELL, sort=False):
        row = dict(zip(_CELL, key))
        row.update(family=g["family"].iloc[0], strength=float(g["strength"].iloc[0]), replicates=len(g))
        mean, low, high = stats.mean_interval(g["mean_abs_error_m"].dropna())
        row.update(mean_abs_error_m=mean, ci_low_m=low, ci_high_m=high)
        _, low, high = stats.mean_interval(g["alt_abs_error_m"].dropna())
        row.update(alt_ci_low_m=low, alt_ci_high_m=high)
        mean, low, high = stats.mean_interval(g["estimate_ms"])
        row.update(estimate_ms=mean, estimate_ci_low_ms=low, estimate_ci_high_ms=high)
        for col in ("detection_rate_pct", "common_rate_pct", "common_abs_error_m", "mean_true_offset_px",
                    "alt_detection_rate_pct", "alt_abs_error_m", "common_alt_abs_error_m", "stop_pct",
                    "peak_joint_rate_rad_s", "render_ms"):
            row[col] = float(g[col].mean()) if col in g and g[col].notna().any() else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# what centring a cone asks of the gimbal
# ----------------------------------------------------------------------------------------------
def cone_pointing_demand(config: TrackingConfig) -> dict:
    """What centring the cone's target asks of a yaw–pitch pointing law (roll held at 0).

    The target's direction from the home camera is d = (cos β, sin β cos φ, sin β sin φ), φ = ωt,
    ω = 2π/T, β the cone's half-angle. Yaw ψ = atan(tan β cos φ) turns fastest where the target
    crosses the horizontal plane (φ = 90°): |dψ/dt| ≤ ω tan β; pitch asin(sin β sin φ) turns
    fastest at φ = 0: |dθ/dt| ≤ ω sin β; the target rises β above the horizon.

    Returns
    -------
    dict
        ``half_angle_deg``, ``peak_yaw_rate_rad_s``, ``peak_pitch_rate_rad_s`` and
        ``peak_elevation_deg`` (the centre of rotation's small offsets from the camera ignored).
    """
    if config.target.trajectory != "cone":
        raise ValueError(f"the config's target.trajectory is {config.target.trajectory!r}, not the cone")
    beta = config.target.cone_half_angle(config.camera.horizontal_field_rad)
    omega = 2.0 * math.pi / config.target.period_s
    return {"half_angle_deg": math.degrees(beta), "peak_yaw_rate_rad_s": omega * math.tan(beta),
            "peak_pitch_rate_rad_s": omega * math.sin(beta), "peak_elevation_deg": math.degrees(beta)}


def demand_table(replicates: pd.DataFrame | None = None, study: LensSweepStudy | None = None,
                 lenses=FISHEYES) -> pd.DataFrame:
    """The demand each cone makes against the gimbal's limits, and what the active runs met.

    One row per lens and cone (the fisheyes' field and in-limit cones by default): the cone's
    half-angle, its peak yaw and pitch rates against the image loop's joint-rate limit
    (``gimbal.max_joint_rate_rad_s``), its elevation against the pitch joint's upper stop, whether
    it keeps within all of them (``in_limits``), and, from ``replicates`` (active, "ignore"), per
    target: the mean share of measured frames with a joint at its stop (``stop_pct_<target>``) and
    the mean largest joint rate (``peak_joint_rate_<target>``).
    """
    study = study or LensSweepStudy()
    rows = []
    for lens in lenses:
        for cone in CONES if lens in FISHEYES else ("field",):
            config = study.config("sphere", lens, "ignore", "active", study.first_seed, cone)
            demand = cone_pointing_demand(config)
            limit = config.gimbal.max_joint_rate_rad_s
            pitch_stop_deg = math.degrees(config.gimbal.joint_limits_rad[2][1])
            row = {"lens": lens, "cone": cone, **demand, "rate_limit_rad_s": limit, "pitch_stop_deg": pitch_stop_deg,
                   "in_limits": bool(max(demand["peak_yaw_rate_rad_s"], demand["peak_pitch_rate_rad_s"]) <= limit
                                     and demand["peak_elevation_deg"] <= pitch_stop_deg)}
            if replicates is not None and len(replicates):
                for target in TARGETS:
                    sel = replicates[(replicates.target == target) & (replicates.lens == lens)
                                     & (replicates.cone == cone) & (replicates["mode"] == "active")
                                     & (replicates.strategy == "ignore")]
                    row[f"stop_pct_{target}"] = float(sel["stop_pct"].mean()) if len(sel) else math.nan
                    row[f"peak_joint_rate_{target}"] = (float(sel["peak_joint_rate_rad_s"].mean()) if len(sel)
                                                        else math.nan)
            rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _cell(replicates: pd.DataFrame, target, lens, strategy, mode, column, cone="field") -> pd.Series:
    r = replicates
    cones = r["cone"] if "cone" in r else pd.Series("field", index=r.index)
    sel = r[(r.target == target) & (r.lens == lens) & (r.strategy == strategy) & (r["mode"] == mode) & (cones == cone)]
    if sel.empty:
        raise ValueError(f"the replicate table has no rows for {target}/{lens}/{strategy}/{mode} ({cone} cone)")
    if sel["seed"].duplicated().any():
        raise ValueError(f"{target}/{lens}/{strategy}/{mode} ({cone} cone) holds a seed twice")
    return sel.set_index("seed")[column].sort_index()


_FLOORS = {"m": stats.MIN_EFFECT_M, "%": RATE_FLOOR_PCT, "ms": COST_FLOOR_MS}


def check_hypotheses(replicates: pd.DataFrame, pipelines: pd.DataFrame | None = None,
                     costs: pd.DataFrame | None = None) -> pd.DataFrame:
    """H1–H3 and BP1, BP2 per condition, with three-way verdicts, their p-values and Holm's
    family-level verdicts (every row one family).

    Parameters
    ----------
    replicates : DataFrame
        :func:`replicate_table` (H1, H2, H3's error rows).
    pipelines : DataFrame, optional
        :func:`pipeline_table` (BP1, BP2); without it those claims are left out.
    costs : DataFrame, optional
        :func:`measure_costs` (H3's cost rows); without it those rows are left out.

    Returns
    -------
    DataFrame
        :func:`gimbal_lab.stats.holm` of the verdict table: id, statement, condition, a, b, unit
        ("m": errors, common frames for strategies and pipelines, each run's own detections for
        H2; "%": detection rate; "ms": CPU time per frame), method ("exact", "circle", "PnP"),
        the verdict's numbers, ``p_value``, ``p_holm`` and ``verdict_holm``. A pair with a missing
        value (no common detections) drops out; fewer than two pairs is "inconclusive". Lenses,
        targets and cones absent from the tables are skipped.
    """
    rows = []
    present = lambda col, values: [v for v in values if (replicates[col] == v).any()]  # noqa: E731
    targets, lenses = present("target", TARGETS), present("lens", tuple(_LENS))
    if not targets or not lenses:
        raise ValueError("the replicate table holds no runs of the study's targets and lenses")
    cones = replicates["cone"] if "cone" in replicates else pd.Series("field", index=replicates.index)

    def has(target, lens, cone="field"):
        return bool(((replicates.target == target) & (replicates.lens == lens) & (cones == cone)).any())

    def add(cid, statement, condition, a_label, b_label, a, b, unit, method, test=stats.less_than):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         method=method, result=test(a.to_numpy(), b.to_numpy(), floor=_FLOORS[unit],
                                                    drop_missing=True)))

    value = lambda *cell, cone="field": _cell(replicates, *cell, cone=cone)  # noqa: E731
    # the sphere's claims with the exact cone fit, then the paper's circle beside them; the marker's PnP
    versions = {"sphere": (("", "exact", "common_alt_abs_error_m", "alt_detection_rate_pct"),
                           (" circle", "circle", "common_abs_error_m", "detection_rate_pct")),
                "aruco": (("", "PnP", "common_abs_error_m", "detection_rate_pct"),)}
    for t in targets:
        for suffix, method, error, rate in versions[t]:
            for lens in (x for x in HIGH_DISTORTION if x in lenses and has(t, x)):
                for m in MODES:
                    add(f"H1{suffix}", "rectifying first worsens tracking (error)", f"{t}, {lens}, {m}", "ignore",
                        "rectify", value(t, lens, "ignore", m, error), value(t, lens, "rectify", m, error), "m", method)
                    add(f"H1{suffix}", "rectifying first worsens tracking (detection rate)", f"{t}, {lens}, {m}",
                        "rectify", "ignore", value(t, lens, "rectify", m, rate), value(t, lens, "ignore", m, rate),
                        "%", method)
    for t in targets:
        for family, (weak, strong) in FAMILY_ENDS.items():
            for cid, cone in (("H2", _H2_CONE[family]),) + ((("H2 over limit", "field"),) if family == "fisheye" else ()):
                if not (has(t, weak, cone) and has(t, strong, cone)):
                    continue
                advantage = {lens: value(t, lens, "ignore", "passive", "mean_abs_error_m", cone=cone)
                             - value(t, lens, "ignore", "active", "mean_abs_error_m", cone=cone) for lens in (weak, strong)}
                where = {"field": "" if family != "fisheye" else " (the sweep's own cones)",
                         "in-limit": f" (in-limit {math.degrees(IN_LIMIT_HALF_ANGLE_RAD):.0f}° cones)"}[cone]
                add(cid, "active's advantage (passive − active error) grows with distortion", f"{t}, {family}{where}",
                    f"advantage {weak}", f"advantage {strong}", advantage[weak], advantage[strong], "m",
                    "circle" if t == "sphere" else "PnP")
    for t in targets:
        for suffix, method, error, _ in versions[t]:
            for lens in (x for x in lenses if "undistort" in strategies_for(x) and has(t, x)):
                for m in MODES:
                    add(f"H3{suffix}", "undistorting points is at least as accurate as rectifying (error)",
                        f"{t}, {lens}, {m}", "undistort", "rectify", value(t, lens, "undistort", m, error),
                        value(t, lens, "rectify", m, error), "m", method, test=stats.non_inferior)
                    if costs is None or costs.empty:
                        continue
                    cpu = {s: _cost(costs, t, lens, m, s, method) for s in ("undistort", "rectify")}
                    if cpu["undistort"] is not None and cpu["rectify"] is not None:
                        add(f"H3{suffix}", "undistorting points costs less than rectifying (CPU time per frame)",
                            f"{t}, {lens}, {m}", "undistort", "rectify", cpu["undistort"], cpu["rectify"], "ms", method)
    if pipelines is not None and not pipelines.empty:
        for t in targets:
            for lens in lenses:
                for claim, (a, b) in BP_CLAIMS.items():
                    sel = pipelines[(pipelines.target == t) & (pipelines.lens == lens) & (pipelines.claim == claim)]
                    if sel.empty:
                        continue
                    sel = sel.set_index("seed").sort_index()
                    add(claim, f"{a} < {b} (error on the frames both localised)", f"{t}, {lens}", a, b,
                        sel["a_error_m"], sel["b_error_m"], "m", f"{sel['method_a'].iloc[0]} vs {sel['method_b'].iloc[0]}")
    return stats.holm(stats.verdict_table(rows))


def _cost(costs: pd.DataFrame, target, lens, mode, strategy, method) -> pd.Series | None:
    sel = costs[(costs.target == target) & (costs.lens == lens) & (costs["mode"] == mode)
                & (costs.strategy == strategy) & (costs.method == method)]
    return None if sel.empty else sel.set_index("seed")["cpu_ms"].sort_index()


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds)."""
    if getattr(row, "kind", "less") == "non-inferior":
        return non_inferiority_reason(row, "have a value on both sides")
    return _params.verdict_reason(row, "have a value on both sides (a strategy that never detects the target "
                                       "leaves no common frames)")


def non_inferiority_reason(row, no_pairs: str) -> str:
    """Why a non-inferiority verdict ("a is at least as good as b") did not hold, in numbers
    (empty when it holds); ``no_pairs`` follows "only N replicate(s) " for a row without an interval."""
    u, f = _params.unit_name(row.unit), lambda x: _params.amount(x, row.unit)  # noqa: E731
    if row.verdict == stats.HOLDS:
        return ""
    if not math.isfinite(row.low):
        return f"only {row.n} replicate(s) {no_pairs}: nothing to compare"
    if row.verdict == stats.DOES_NOT_HOLD:
        return (f"{row.a} is worse than {row.b} by more than the margin: the one-sided 95 % bound {f(row.low)} {u} "
                f"lies above +δ = {f(row.delta)} {u}")
    return (f"the one-sided 95 % bounds [{f(row.low)}, {f(row.high)}] {u} hold the margin +δ = {f(row.delta)} {u}: "
            f"neither as good nor worse by more than δ")




def family_counts(verdicts: pd.DataFrame) -> pd.DataFrame:
    """Per hypothesis id: how many conditions hold, do not hold or are inconclusive, as computed
    (95 %) and at the family level after Holm (``… (Holm)``)."""
    rows = []
    for cid, g in verdicts.groupby("id", sort=False):
        row = {"id": cid, "conditions": len(g)}
        for level, column in (("", "verdict"), (" (Holm)", "verdict_holm")):
            if column in g:
                counts = g[column].value_counts()
                row.update({f"{v}{level}": int(counts.get(v, 0)) for v in stats.VERDICTS})
        rows.append(row)
    return pd.DataFrame(rows)


def _markdown_table(frame: pd.DataFrame, formats: dict | None = None) -> list[str]:
    formats = formats or {}
    lines = ["| " + " | ".join(map(str, frame.columns)) + " |", "|" + "---|" * len(frame.columns)]
    for row in frame.itertuples(index=False):
        cells = [formats.get(col, "{}").format(v) if not (isinstance(v, float) and math.isnan(v)) else "–"
                 for col, v in zip(frame.columns, row)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: LensSweepStudy | None = None, demand: pd.DataFrame | None = None,
                        pipelines: pd.DataFrame | None = None, costs: pd.DataFrame | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval, δ and
    p-values, the count per hypothesis at both levels, a measured reason for each condition that
    does not hold, the cones' demand against the gimbal's limits, the pipelines' localisation rates,
    the CPU cost of each pipeline, and the table of error and detection rate per cell."""
    study = study or LensSweepStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    lines = [
        "# Lens sweep: hypotheses H1–H3 and the best passive camera (BP1, BP2), measured",
        "",
        "Lenses: Brown–Conrady (the study's coefficients ×0, 0.5, 1, 1.5; 60°) and equidistant fisheyes of 120°, "
        "150° and 185°, 640 × 480. The target circles the home axis at 3 m, 0.7 of the half field off it (the "
        f"field cones); the fisheyes also run an in-limit cone of {math.degrees(IN_LIMIT_HALF_ANGLE_RAD):.0f}° "
        "(ignore strategy). Its size gives the paper study's image on the axis. Strategies: **ignore** the lens (the "
        "paper), **undistort** the detected points, **rectify** the image first (same K for Brown–Conrady, a 90° "
        f"pinhole for the fisheyes). Up to {n} replicates per cell of {study.revolutions:g} revolutions (the first "
        "is acquisition), paired by replicate. Strategy comparisons of error use the frames where every strategy "
        "localised the target; the sphere's H1 and H3 use the exact cone fit (the paper's circle method beside them "
        "as “H1 circle”, “H3 circle”). Pipelines (BP1, BP2): active (paper) = active, ignore, circle method or PnP; "
        "active (best) = active, undistort, exact cone fit or PnP on undistorted corners; best passive = passive, "
        "undistort, the same (the pinhole: ignore), on the frames both localised. H3's costs are CPU time per frame "
        f"measured apart from the runs on the same frames for every pipeline, the least of {COST_REPEATS} passes.",
        "",
        _params.verdict_rule(
            f"max(floor, 10 % of the smaller mean), floors 1 mm, {RATE_FLOOR_PCT:g} % of detection rate and "
            f"{COST_FLOOR_MS:g} ms per frame",
            "H3's error rows are non-inferiority (“at least as accurate”): **holds** when the upper one-sided 95 % "
            "bound of undistort − rectify lies below +δ, **does not hold** when the lower one lies above +δ; their "
            "interval is the 90 % one. Every verdict carries the p-value of its deciding test; all verdicts of this "
            "report are one family, and Holm's step-down correction at 5 % gives the family-level verdict (a "
            "decisive verdict whose adjusted p is not below 0.05 becomes inconclusive)."),
        "",
    ]
    lines += _params.verdict_lines(verdicts, verdict_reason, unit_in_list=True)
    lines += ["", "## Verdicts per hypothesis, as computed and after Holm", ""]
    lines += _markdown_table(family_counts(verdicts))
    if "p_holm" in verdicts:
        lines += ["", "## p-values and the family-level verdict of every condition", ""]
        show = verdicts[["id", "condition", "a", "b", "verdict", "p_value", "p_holm", "verdict_holm"]]
        lines += _markdown_table(show, {"p_value": "{:.2g}", "p_holm": "{:.2g}"})
    if demand is not None and len(demand):
        lines += ["", "## What each fisheye cone asks of the gimbal (H2 is judged on the in-limit cones)", ""]
        columns = ["lens", "cone", "half_angle_deg", "peak_yaw_rate_rad_s", "rate_limit_rad_s", "peak_elevation_deg",
                   "pitch_stop_deg", "in_limits"] + [c for c in demand.columns if c.startswith(("stop_pct", "peak_joint"))]
        lines += _markdown_table(demand[columns], {c: "{:.2f}" for c in columns[2:7]} |
                                 {c: "{:.1f}" for c in columns[8:]})
    if pipelines is not None and len(pipelines):
        lines += ["", "## The pipelines of BP1 and BP2: localisation rates and errors (means over replicates)", ""]
        means = pipelines.groupby(["target", "lens", "claim", "a", "b"], sort=False)[
            ["a_rate_pct", "b_rate_pct", "common_rate_pct", "a_error_m", "b_error_m"]].mean().reset_index()
        means[["a_error_m", "b_error_m"]] *= 1000.0
        means = means.rename(columns={"a_error_m": "a error mm", "b_error_m": "b error mm"})
        lines += _markdown_table(means, {c: "{:.1f}" for c in means.columns[5:]})
    if costs is not None and len(costs):
        lines += ["", "## CPU time per frame of each pipeline (measured apart from the runs, means over replicates)",
                  ""]
        table = cost_summary(costs)[["target", "lens", "mode", "strategy", "method", "replicates", "cpu_ms"]]
        lines += _markdown_table(table, {"cpu_ms": "{:.3f}"})
    if summary is not None and len(summary):
        lines += ["", "## Error and detection rate per cell (measured revolutions)", "",
                  "| target | lens | cone | strategy | mode | error mm [95 % CI] | exact fit mm | detected % | "
                  "frames at a stop % |", "|---|---|---|---|---|---|---|---|---|"]
        for row in summary.itertuples():
            lines.append(f"| {row.target} | {row.lens} | {row.cone} | {row.strategy} | {row.mode} | "
                         f"{1000 * row.mean_abs_error_m:.1f} [{1000 * row.ci_low_m:.1f}, {1000 * row.ci_high_m:.1f}] | "
                         f"{1000 * row.alt_abs_error_m:.1f} | {row.detection_rate_pct:.0f} | {row.stop_pct:.0f} |")
    return "\n".join(lines).replace("| nan", "| –") + "\n"


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def example_view(study: LensSweepStudy, target: str, lens: str, phase: float = 0.125):
    """The passive camera's frame of one lens with the target ``phase`` of a period into its cone
    (no noise), and its rectified view (None for the pinhole): ``(image, rectified, config)``."""
    from ..detection import Rectifier
    from ..simulation import make_renderer
    from ..trajectories import target_pose

    strategy = "rectify" if "rectify" in strategies_for(lens) else "ignore"
    config = study.config(target, lens, strategy, "passive", study.first_seed).with_(target__start_phase_s=0.0)
    T_world_cam = np.eye(4)  # the home pose: the body's axes are the world's
    T_world_cam[:3, :3] = config.gimbal.kinematics.T_body_cam(np.zeros(3))[:3, :3]
    T_world_cam[:3, 3] = config.home_camera_m
    renderer = make_renderer(config)
    try:
        image = renderer.render(T_world_cam, target_pose(config.path, phase * config.target.period_s))
    finally:
        renderer.close()
    camera = config.camera
    rectified = Rectifier(camera.intrinsics, camera.lens_model).rectify(image) if camera.lens_model is not None else None
    return image, rectified, config


def make_report(results, study: LensSweepStudy, *, costs: pd.DataFrame | None = None, store=None, jobs=None,
                executor=None, progress: bool = False) -> _report.Report:
    """The study's report (:class:`gimbal_lab.studies.report.Report`): its tables, hypotheses and figures.

    The CPU costs are measured here (:func:`measure_costs`, on ``jobs`` local processes or
    ``executor``) unless ``costs`` is given, once per set of runs when ``store`` is given
    (:func:`gimbal_lab.studies.report.measured_once`). Files: ``summary.csv``,
    ``replicates.parquet`` and ``.csv``, ``pipelines.csv``, ``costs.csv``, ``demand.csv``,
    ``verdicts.csv``, ``claims.md``, ``study.json`` and ``figures/`` (error and detection rate
    against lens strength per strategy, error against CPU cost per pipeline, the in-limit and
    over-limit H2 picture, the example frames and rectified views, the forest plot), PNG and SVG.
    """
    from .. import plotting

    replicates = replicate_table(results)
    pipelines = pipeline_table(results)
    if costs is None:
        costs = _report.measured_once(
            store, results, f"CPU time per frame of the lens sweep's pipelines (least of {_params.COST_REPEATS} passes)",
            lambda: measure_costs(results, jobs=jobs, executor=executor, progress=progress,
                                  repeats=_params.COST_REPEATS), progress)
    summary = summary_table(replicates)
    verdicts = check_hypotheses(replicates, pipelines, costs)
    demand = demand_table(replicates, study)
    figures = [("lens_sweep_error", lambda: plotting.study.plot_lens_sweep(summary, "mean_abs_error_m")),
               ("lens_sweep_detection", lambda: plotting.study.plot_lens_sweep(summary, "detection_rate_pct")),
               ("lens_sweep_error_vs_cost", lambda: plotting.study.plot_lens_error_cost(summary, cost_summary(costs))),
               ("lens_sweep_h2_limits", lambda: plotting.study.plot_lens_h2_limits(replicates, demand))]
    for target in sorted({r.config.target.kind for r in results}, key=TARGETS.index):
        figures.append((f"example_views_{target}", lambda target=target: plotting.study.plot_lens_views(
            {lens: example_view(study, target, lens)[:2] for lens in _LENS})))
    return _report.Report(NAME, study, len(results), [
        ("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
        ("pipelines.csv", pipelines), ("costs.csv", costs), ("demand.csv", demand), ("verdicts.csv", verdicts),
        ("claims.md", hypotheses_markdown(verdicts, summary, study, demand, pipelines, costs)),
    ], figures, verdicts)


def run_study(study: LensSweepStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``), measure the pipelines' CPU costs (once per set of runs)
    and write the report to ``out/lens-sweep`` (:func:`gimbal_lab.studies.report.run_and_report`).

    ``clips`` is accepted for the command line's sake; this study writes example frames, not clips.
    Returns a dict with the results, the verdicts, the folder and the paths written.
    """
    def report(results, study):
        return make_report(results, study, store=store, jobs=jobs, executor=executor, progress=progress)

    return _report.run_and_report(NAME, "lens sweep", grid(study), report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
