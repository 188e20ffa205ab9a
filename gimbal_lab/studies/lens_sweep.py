"""The lens sweep (docs/design.md, "Lens sweep"): lens strength up to fisheye, and three ways to
treat the lens: ignore it (the paper), undistort the detected points, or rectify the image first.

Lenses (:data:`LENSES`): Brown–Conrady with the study's default coefficients scaled by 0, 0.5, 1
and 1.5 at 60° horizontal field, and equidistant Kannala–Brandt fisheyes (all k = 0, the stated
choice: the ideal fisheye, whose focal length follows from the field alone) of 120°, 150° and
185°, every one 640 × 480. Strategies (:data:`STRATEGIES`): :class:`gimbal_lab.config.Estimator`
``lens_strategy``; the undistorted pinhole has no lens, so it runs "ignore" only.

The target moves at 3 m from the home camera on a cone about the home axis, 0.7 of the half field
off it (:data:`gimbal_lab.config.CONE_FIELD_FRACTION`), one revolution per period. Its size is
scaled by f_60°/f so that its image on the axis matches the paper study's (sphere 0.10 m, marker
0.30 m at f = 554 px). The body hovers still at :data:`ALTITUDE_M` instead of 2 m: the widest
cone (185°: 2.71 m off the axis) would otherwise pass under the ground.

Grid: {sphere, ArUco} × 7 lenses × strategies × {passive, active} (76 cells), each cell
``replicates`` times; replicate s draws the start phase and the sensor noise from seed s, shared
by every cell (paired). Each replicate runs ``revolutions`` periods; the first is acquisition.
Metrics per replicate (measured revolutions): detection rate, the distance error on the frames
where every strategy of the same lens, target, mode and seed detected the target ("common"
frames) and on the run's own detections, and the cost per frame of detection and localisation,
rectification included, measured in the run (:attr:`gimbal_lab.simulation.TrackingResult.timing`).

Hypotheses (fixed in docs/design.md before any result): **H1** (the paper's, §4.1.2 end and §5)
rectifying first worsens tracking at high distortion, against the paper's "ignore": error on
common frames and detection rate, for the Brown–Conrady ×1.5 lens and the fisheyes; **H2**
active's advantage over passive (paper pipeline) grows with distortion, within each lens family;
**H3** undistorting points is at least as accurate as rectifying, at a fraction of the cost.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..camera import BrownConrady, Intrinsics, KannalaBrandt
from ..config import Camera, Estimator, Platform, Pointing, Target, TrackingConfig, _choice, _number
from . import _params
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "LensSweepStudy", "Study", "Lens", "LENSES", "STRATEGIES", "MODES", "TARGETS", "HIGH_DISTORTION",
    "RATE_FLOOR_PCT", "COST_FLOOR_MS", "grid", "replicate_table", "summary_table", "check_hypotheses",
    "hypotheses_markdown", "write_report", "run_study", "cone_pointing_demand", "example_view", "lens_name",
    "strategies_for",
]

NAME = "lens-sweep"
DESCRIPTION = ("lens sweep: Brown–Conrady up to fisheye; ignore the lens, undistort the points or rectify "
               "the image first (76 cells)")

TARGETS = ("sphere", "aruco")
MODES = ("passive", "active")
STRATEGIES = ("ignore", "undistort", "rectify")

#: The paper study's camera, whose on-axis target images the sweep keeps: 60° across 640 px.
REFERENCE_FOCAL_PX = Intrinsics.default().fx
#: Height of the hovering body, m: the widest cone's lowest target point stays 0.7 m above ground.
ALTITUDE_M = 4.0
#: δ floors: a detection rate differing by under one percentage point, or a cost by under 0.05 ms
#: per frame, is no difference worth the name.
RATE_FLOOR_PCT = 1.0
COST_FLOOR_MS = 0.05


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
#: The lenses H1 calls high distortion: the strongest Brown–Conrady and every fisheye.
HIGH_DISTORTION = ("BC ×1.5", "fisheye 120°", "fisheye 150°", "fisheye 185°")
#: H2's weakest and strongest lens of each family.
FAMILY_ENDS = {"brown-conrady": ("pinhole", "BC ×1.5"), "fisheye": ("fisheye 120°", "fisheye 185°")}


def strategies_for(lens: str) -> tuple[str, ...]:
    """The strategies a lens runs: all three, or "ignore" alone for the ideal pinhole."""
    return ("ignore",) if _LENS[lens].strength == 0.0 else STRATEGIES


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

    def config(self, target: str, lens: str, strategy: str, mode: str, seed: int) -> TrackingConfig:
        """The run of one cell and replicate."""
        _choice("target", target, TARGETS)
        _choice("lens", lens, tuple(_LENS))
        _choice("strategy", strategy, strategies_for(lens))
        _choice("mode", mode, MODES)
        scale = REFERENCE_FOCAL_PX / _LENS[lens].focal_px
        return TrackingConfig(
            camera=Camera(**_LENS[lens].camera_fields(), fps=self.fps, latency_frames=self.latency_frames,
                          noise_std=self.noise_std),
            platform=Platform(altitude_m=ALTITUDE_M),
            target=Target(kind=target, trajectory="cone", period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s), sphere_radius_m=0.10 * scale,
                          marker_length_m=0.30 * scale),
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
    runs of one renderer are adjacent)."""
    study = study or LensSweepStudy()
    lenses = tuple(_LENS) if lenses is None else tuple(lenses)
    return [study.config(target, lens, strategy, mode, seed)
            for target in targets for lens in lenses for strategy in strategies_for(lens) for mode in MODES
            for seed in study.seeds]


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


def _mean(values) -> float:
    values = np.asarray(values, float)
    return float(values.mean()) if values.size else math.nan


def replicate_table(results) -> pd.DataFrame:
    """One row per run: its means over the measured revolutions.

    Columns: target, lens, family, strength, strategy, mode, seed, frames, detection_rate_pct,
    mean_abs_error_m (its own detections), common_rate_pct and common_abs_error_m (the frames where
    every strategy of the same target, lens, mode and seed among ``results`` detected the target;
    NaN when there is none), mean_true_offset_px, alt_abs_error_m (the sphere's other localiser,
    the exact cone fit beside the paper's circle, on its own detections; NaN for the marker),
    estimate_ms (detection and localisation per frame, rectification included, wall time of the
    run) and render_ms.
    """
    groups: dict[tuple, list] = {}
    for r in results:
        c = r.config
        groups.setdefault((c.target.kind, lens_name(c), c.pointing.mode, c.seed), []).append(r)
    rows = []
    for (target, lens, mode, seed), members in groups.items():
        measured = {id(r): r.frames[r.frames["frame"] >= round(r.config.frames_per_revolution)] for r in members}
        if len({len(f) for f in measured.values()}) != 1:
            raise ValueError("runs of one target, lens, mode and seed must have the same frames")
        common = np.logical_and.reduce([f["detected"].to_numpy() for f in measured.values()])
        for r in members:
            c, f = r.config, measured[id(r)]
            detected = f["detected"].to_numpy()
            rows.append({
                "target": target, "lens": lens, "family": _LENS[lens].family, "strength": _LENS[lens].strength,
                "strategy": c.estimator.lens_strategy, "mode": mode, "seed": seed, "frames": len(f),
                "detection_rate_pct": 100.0 * _mean(detected),
                "mean_abs_error_m": _mean(f["abs_error_m"].to_numpy()[detected]),
                "common_rate_pct": 100.0 * _mean(common),
                "common_abs_error_m": _mean(f["abs_error_m"].to_numpy()[common]),
                "mean_true_offset_px": _mean(f["true_offset_px"]),
                "alt_abs_error_m": (_mean(f["alt_abs_error_m"].to_numpy()[f["alt_detected"].to_numpy(bool)])
                                    if "alt_detected" in f else math.nan),
                "estimate_ms": 1000.0 * r.timing.get("detect_s", math.nan) / max(len(r.frames), 1),
                "render_ms": 1000.0 * r.timing.get("render_s", math.nan) / max(len(r.frames), 1),
            })
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    order = {name: i for i, name in enumerate(TARGETS + tuple(_LENS) + STRATEGIES + MODES)}
    return table.sort_values(["target", "lens", "strategy", "mode", "seed"],
                             key=lambda s: s.map(order) if s.name != "seed" else s, ignore_index=True)


_CELL = ["target", "lens", "strategy", "mode"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell: replicates, the mean of each replicate quantity and 95 % t-intervals of the error
    on the run's own detections (``ci_low_m``, ``ci_high_m``) and of the cost per frame."""
    rows = []
    for key, g in replicates.groupby(_CELL, sort=False):
        row = dict(zip(_CELL, key))
        row.update(family=g["family"].iloc[0], strength=float(g["strength"].iloc[0]), replicates=len(g))
        mean, low, high = stats.mean_interval(g["mean_abs_error_m"].dropna())
        row.update(mean_abs_error_m=mean, ci_low_m=low, ci_high_m=high)
        mean, low, high = stats.mean_interval(g["estimate_ms"])
        row.update(estimate_ms=mean, estimate_ci_low_ms=low, estimate_ci_high_ms=high)
        for col in ("detection_rate_pct", "common_rate_pct", "common_abs_error_m", "mean_true_offset_px",
                    "alt_abs_error_m", "render_ms"):
            row[col] = float(g[col].mean()) if g[col].notna().any() else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _cell(replicates: pd.DataFrame, target, lens, strategy, mode, column) -> pd.Series:
    r = replicates
    sel = r[(r.target == target) & (r.lens == lens) & (r.strategy == strategy) & (r["mode"] == mode)]
    if sel.empty:
        raise ValueError(f"the replicate table has no rows for {target}/{lens}/{strategy}/{mode}")
    if sel["seed"].duplicated().any():
        raise ValueError(f"{target}/{lens}/{strategy}/{mode} holds a seed twice")
    return sel.set_index("seed")[column].sort_index()


_FLOORS = {"m": stats.MIN_EFFECT_M, "%": RATE_FLOOR_PCT, "ms": COST_FLOOR_MS}


def check_hypotheses(replicates: pd.DataFrame) -> pd.DataFrame:
    """H1–H3 per condition, with three-way verdicts and the numbers behind them.

    Units: "m" (errors; common-frame errors for strategy comparisons, each run's own detections
    for H2's passive − active advantage), "%" (detection rate) and "ms" (cost per frame). A pair
    with a missing value (no common detections) drops out; fewer than two pairs is
    "inconclusive". Lenses or targets absent from ``replicates`` are skipped.
    """
    rows = []
    present = lambda col, values: [v for v in values if (replicates[col] == v).any()]  # noqa: E731
    targets, lenses = present("target", TARGETS), present("lens", tuple(_LENS))
    if not targets or not lenses:
        raise ValueError("the replicate table holds no runs of the study's targets and lenses")

    def add(cid, statement, condition, a_label, b_label, a, b, unit):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         result=stats.less_than(a.to_numpy(), b.to_numpy(), floor=_FLOORS[unit], drop_missing=True)))

    value = lambda *cell: _cell(replicates, *cell)  # noqa: E731
    for t in targets:
        for lens in (x for x in HIGH_DISTORTION if x in lenses):
            for m in MODES:
                add("H1", "rectifying first worsens tracking (error)", f"{t}, {lens}, {m}", "ignore", "rectify",
                    value(t, lens, "ignore", m, "common_abs_error_m"), value(t, lens, "rectify", m, "common_abs_error_m"),
                    "m")
                add("H1", "rectifying first worsens tracking (detection rate)", f"{t}, {lens}, {m}", "rectify",
                    "ignore", value(t, lens, "rectify", m, "detection_rate_pct"),
                    value(t, lens, "ignore", m, "detection_rate_pct"), "%")
    for t in targets:
        for family, (weak, strong) in FAMILY_ENDS.items():
            if weak in lenses and strong in lenses:
                advantage = {lens: value(t, lens, "ignore", "passive", "mean_abs_error_m")
                             - value(t, lens, "ignore", "active", "mean_abs_error_m") for lens in (weak, strong)}
                add("H2", "active's advantage (passive − active error) grows with distortion", f"{t}, {family}",
                    f"advantage {weak}", f"advantage {strong}", advantage[weak], advantage[strong], "m")
    for t in targets:
        for lens in (x for x in lenses if "undistort" in strategies_for(x)):
            for m in MODES:
                add("H3", "undistorting points is as accurate as rectifying (error)", f"{t}, {lens}, {m}", "undistort",
                    "rectify", value(t, lens, "undistort", m, "common_abs_error_m"),
                    value(t, lens, "rectify", m, "common_abs_error_m"), "m")
                add("H3", "undistorting points costs less than rectifying", f"{t}, {lens}, {m}", "undistort",
                    "rectify", value(t, lens, "undistort", m, "estimate_ms"),
                    value(t, lens, "rectify", m, "estimate_ms"), "ms")
    return stats.verdict_table(rows)


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds)."""
    return _params.verdict_reason(row, "have a value on both sides (a strategy that never detects the target "
                                       "leaves no common frames)")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: LensSweepStudy | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval and δ, a count
    per hypothesis, a measured reason for each condition that does not hold, and the table of
    error, detection rate and cost per lens and strategy."""
    study = study or LensSweepStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    lines = [
        "# Lens sweep: hypotheses H1–H3, measured",
        "",
        "Lenses: Brown–Conrady (the study's coefficients ×0, 0.5, 1, 1.5; 60°) and equidistant fisheyes of 120°, "
        "150° and 185°, 640 × 480. The target circles the home axis at 3 m, 0.7 of the half field off it; its size "
        "gives the paper study's image on the axis. Strategies: **ignore** the lens (the paper), **undistort** the "
        "detected points, **rectify** the image first (same K for Brown–Conrady, a 90° pinhole for the fisheyes). "
        f"Up to {n} replicates per cell of {study.revolutions:g} revolutions (the first is acquisition), paired by "
        "replicate. Strategy comparisons of error use the frames where every strategy detected the target.",
        "",
        _params.verdict_rule(f"max(floor, 10 % of the smaller mean), floors 1 mm, {RATE_FLOOR_PCT:g} % of detection "
                             f"rate and {COST_FLOOR_MS:g} ms per frame", "H3's error rows test “undistort < rectify”: "
                             "an interval within ±δ (does not hold, no effect) means the two are equally accurate, "
                             "which meets the design's “at least as accurate”; only an interval above 0 contradicts it."),
        "",
    ]
    lines += _params.verdict_lines(verdicts, verdict_reason, unit_in_list=True)
    if summary is not None and len(summary):
        lines += ["", "## Error, detection rate and cost per lens and strategy (measured revolutions)", "",
                  "| target | lens | strategy | mode | error mm [95 % CI] | detected % | estimate ms/frame | "
                  "render ms/frame |", "|---|---|---|---|---|---|---|---|"]
        for row in summary.itertuples():
            lines.append(f"| {row.target} | {row.lens} | {row.strategy} | {row.mode} | {1000 * row.mean_abs_error_m:.1f} "
                         f"[{1000 * row.ci_low_m:.1f}, {1000 * row.ci_high_m:.1f}] | {row.detection_rate_pct:.0f} | "
                         f"{row.estimate_ms:.2f} | {row.render_ms:.1f} |")
    return "\n".join(lines) + "\n"


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


def write_report(folder, results, study: LensSweepStudy) -> list[Path]:
    """Write the tables, hypotheses and figures into ``folder``; return the paths written.

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``verdicts.csv``, ``claims.md``,
    ``study.json`` and ``figures/`` (error and detection rate against lens strength per strategy,
    the cost per frame, the example frames and rectified views, the forest plot), PNG and SVG.
    """
    from .. import plotting

    def figures(save, results, summary):
        save(plotting.study.plot_lens_sweep(summary, "mean_abs_error_m"), "lens_sweep_error")
        save(plotting.study.plot_lens_sweep(summary, "detection_rate_pct"), "lens_sweep_detection")
        save(plotting.study.plot_lens_costs(summary), "lens_sweep_cost")
        for target in sorted({r.config.target.kind for r in results}, key=TARGETS.index):
            views = {lens: example_view(study, target, lens)[:2] for lens in _LENS}
            save(plotting.study.plot_lens_views(views), f"example_views_{target}")

    return _params.write_study_report(folder, results, study, sys.modules[__name__], figures)


def run_study(study: LensSweepStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/lens-sweep`` atomically.

    ``clips`` is accepted for the command line's sake; this study writes example frames, not clips.
    Returns a dict with the results, the folder and the paths written.
    """
    return _params.run_and_report(NAME, "lens sweep", grid(study), write_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)


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
    from ..config import CONE_FIELD_FRACTION

    beta = CONE_FIELD_FRACTION * 0.5 * config.camera.horizontal_field_rad
    omega = 2.0 * math.pi / config.target.period_s
    return {"half_angle_deg": math.degrees(beta), "peak_yaw_rate_rad_s": omega * math.tan(beta),
            "peak_pitch_rate_rad_s": omega * math.sin(beta), "peak_elevation_deg": math.degrees(beta)}
