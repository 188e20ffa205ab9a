"""The moving drone (docs/design.md, "Moving drone"): fixed vs stabilised vs active camera under
hover sway, blade-pass vibration and flight, with motion blur and a global or rolling shutter.

Grid: {sphere, ArUco} × {hover, vibration, flight} × {fixed, stabilised, active} × {global,
rolling}, each cell ``replicates`` times. Replicate s draws the target's start phase, the body's
sway and vibration, the flight's start point on its pass, the gyro noise and the sensor noise from
seed s; every cell shares those draws, so cells are compared pair by pair. Each replicate runs
``revolutions`` periods of the paper's circle; the first is acquisition, the rest are measured.

Every frame integrates a 1/60 s exposure of the true, continuous camera and target motion
(:meth:`gimbal_lab.scene.SceneRenderer.render_motion`); the rolling shutter reads its rows over
20 ms. Metrics per replicate (measured revolutions): detection rate; the distance error on the
frames where **every** mount of the same target, motion, shutter and seed detected the target
(so that a mount is not credited for frames it lost), and on its own detections; the target's
blur streak (px, from the true image motion over the exposure, detected or not); the pointing
jitter (the camera's largest rotation within an exposure, deg).

Hypotheses (fixed in docs/design.md before any result): **H1** stabilised and active beat fixed on
every motion; **H2** active beats stabilised in flight; **H3** the target's blur streak is smallest
for active, then stabilised, then fixed; **H4** the rolling shutter costs the fixed mount more
than the others. Verdicts: :mod:`gimbal_lab.stats`, with δ's floor 1 mm for errors and
:data:`STREAK_FLOOR_PX` for streaks.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..mount import GYRO_NOISE_RAD_S_RTHZ
from ..platform import WaypointFlight
from ..config import Camera, Estimator, Gimbal, Platform, Pointing, Target, TrackingConfig, _choice, _number, seed_stream
from . import _params
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "MovingDroneStudy",
    "Study",
    "TARGETS",
    "MOTIONS",
    "MOUNTS",
    "SHUTTERS",
    "STREAK_FLOOR_PX",
    "flight_phase_s",
    "grid",
    "replicate_table",
    "summary_table",
    "check_hypotheses",
    "hypotheses_markdown",
    "write_report",
    "run_study",
]

NAME = "moving-drone"
DESCRIPTION = ("moving drone: fixed vs stabilised vs active camera under sway, vibration and flight, "
               "with motion blur and rolling shutter (36 cells)")

TARGETS = ("sphere", "aruco")
MOTIONS = ("hover", "vibration", "flight")
MOUNTS = ("fixed", "stabilised", "active")
SHUTTERS = ("global", "rolling")

#: Absolute floor of δ for blur streaks: a difference under a pixel is no difference in blur.
STREAK_FLOOR_PX = 1.0

@dataclass(frozen=True)
class MovingDroneStudy(StudyParams):
    """Parameters of the moving-drone study (defaults: docs/design.md; ``data/studies/moving-drone.toml``).

    Parameters
    ----------
    replicates, first_seed, revolutions, period_s, fps, latency_frames, noise_std :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`).
    exposure_s : float
        Exposure of every frame, s (1/60), at most one frame period.
    readout_s : float
        Top-to-bottom readout of the rolling shutter, s (0.020); the global shutter reads at once.
    gyro_noise_deg_s_rthz : float
        White-noise density of the camera-platform gyro, °/s/√Hz (0.005).
    aruco_refinement : {"none", "subpix", "contour", "apriltag"}
        Corner refinement (sub-pixel, as in the paper's study).
    """

    exposure_s: float = 1.0 / 60.0
    readout_s: float = 0.020
    gyro_noise_deg_s_rthz: float = math.degrees(GYRO_NOISE_RAD_S_RTHZ)
    aruco_refinement: str = "subpix"

    _TABLE = NAME

    def __post_init__(self):
        self._check_replicates()
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("exposure_s", _number("exposure_s", self.exposure_s, low=0.0, low_open=True))
        set_("readout_s", _number("readout_s", self.readout_s, low=0.0, low_open=True))
        # the rest is validated by the config's parts, naming part and field
        for shutter in SHUTTERS:
            self.config("sphere", "flight", "active", shutter, self.first_seed)

    def config(self, target: str, motion: str, mount: str, shutter: str, seed: int) -> TrackingConfig:
        """The run of one cell and replicate."""
        _choice("target", target, TARGETS)
        _choice("motion", motion, MOTIONS)
        _choice("mount", mount, MOUNTS)
        _choice("shutter", shutter, SHUTTERS)
        return TrackingConfig(
            camera=Camera(fps=self.fps, latency_frames=self.latency_frames, noise_std=self.noise_std,
                          exposure_s=self.exposure_s, blur="fast",
                          readout_s=self.readout_s if shutter == "rolling" else 0.0),
            gimbal=Gimbal(gyro_noise_rad_s_rthz=math.radians(self.gyro_noise_deg_s_rthz)),
            platform=Platform(motion=motion, motion_phase_s=flight_phase_s(seed) if motion == "flight" else 0.0),
            target=Target(kind=target, trajectory="circular", period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s)),
            pointing=Pointing(_POINTING[mount]), estimator=Estimator(aruco_refinement=self.aruco_refinement),
            revolutions=self.revolutions, seed=seed)


#: The pointing kind of each mount: the active mount runs the paper's image loop.
_POINTING = {"fixed": "fixed", "stabilised": "stabilised", "active": "paper"}

#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = MovingDroneStudy


def flight_phase_s(seed: int) -> float:
    """Where replicate ``seed`` starts on the flight's round trip: U(0, its period), from the seed's
    "flight_phase" stream (:func:`gimbal_lab.config.seed_stream`)."""
    return float(np.random.default_rng(seed_stream(seed, "flight_phase")).uniform(0.0, WaypointFlight().period_s))


def grid(study: MovingDroneStudy | None = None, targets=TARGETS, motions=MOTIONS) -> list[TrackingConfig]:
    """Every (cell, replicate) config: target, motion, mount, shutter, then replicates innermost."""
    study = study or MovingDroneStudy()
    return [study.config(target, motion, mount, shutter, seed)
            for target in targets for motion in motions for mount in MOUNTS for shutter in SHUTTERS
            for seed in study.seeds]


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _shutter(config: TrackingConfig) -> str:
    return "rolling" if config.camera.readout_s > 0 else "global"


def _identity(config: TrackingConfig) -> dict:
    return {"target": config.target.kind, "motion": config.platform.motion, "mount": config.pointing.mount,
            "shutter": _shutter(config), "seed": config.seed}


def _measured(result) -> pd.DataFrame:
    """The frames after the acquisition revolution (by frame index, so every mount's are the same)."""
    f = result.frames
    return f[f["frame"] >= round(result.config.frames_per_revolution)]


def _mean(values) -> float:
    values = np.asarray(values, float)
    return float(values.mean()) if values.size else math.nan


def replicate_table(results) -> pd.DataFrame:
    """One row per run: its means over the measured revolutions.

    Columns: target, motion, mount, shutter, seed, frames, detection_rate, mean_abs_error_m (over
    its own detections), common_rate and common_abs_error_m (over the frames where every mount of
    the same target, motion, shutter and seed among ``results`` detected the target; NaN when there
    is none), mean_streak_px, max_streak_px, jitter_deg (mean largest camera rotation within an
    exposure), mean_true_offset_px (how far off the image centre the target truly was) and, for
    active runs, time_to_centre_s (acquisition: first instant the detection came within 5 % of the
    image width of the centre).
    """
    from .paper import CENTRED_FRACTION, _time_to_centre

    groups: dict[tuple, list] = {}
    for r in results:
        c = r.config
        groups.setdefault((c.target.kind, c.platform.motion, _shutter(c), c.seed), []).append(r)
    rows = []
    for members in groups.values():
        measured = {id(r): _measured(r) for r in members}
        lengths = {len(f) for f in measured.values()}
        if len(lengths) != 1:
            raise ValueError("runs of one target, motion, shutter and seed must have the same frames")
        common = np.logical_and.reduce([f["detected"].to_numpy() for f in measured.values()])
        for r in members:
            c, f = r.config, measured[id(r)]
            detected = f["detected"].to_numpy()
            acquiring = r.frames[r.frames["frame"] < round(c.frames_per_revolution)]
            rows.append({
                **_identity(c), "frames": len(f),
                "detection_rate": _mean(detected),
                "mean_abs_error_m": _mean(f["abs_error_m"].to_numpy()[detected]),
                "common_rate": _mean(common),
                "common_abs_error_m": _mean(f["abs_error_m"].to_numpy()[common]),
                "mean_streak_px": _mean(f["streak_px"]),
                "max_streak_px": float(f["streak_px"].max()) if len(f) else math.nan,
                "jitter_deg": _mean(f["cam_turn_deg"]),
                "mean_true_offset_px": _mean(f["true_offset_px"]),
                "time_to_centre_s": (_time_to_centre(acquiring, CENTRED_FRACTION * c.camera.width)
                                     if c.pointing.active else math.nan),
            })
    order = {name: i for i, name in enumerate(TARGETS + MOTIONS + MOUNTS + SHUTTERS)}
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(["target", "motion", "mount", "shutter", "seed"],
                             key=lambda s: s.map(order) if s.name != "seed" else s, ignore_index=True)


_CELL = ["target", "motion", "mount", "shutter"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell: replicates, the mean of each replicate quantity, and 95 % t-intervals of the
    common-frame error (``ci_low_m``, ``ci_high_m``) and of the streak (``streak_ci_low_px``, ...)."""
    rows = []
    for key, g in replicates.groupby(_CELL, sort=False):
        row = dict(zip(_CELL, key))
        mean, low, high = stats.mean_interval(g["common_abs_error_m"])
        row.update(replicates=len(g), common_abs_error_m=mean, ci_low_m=low, ci_high_m=high)
        mean, low, high = stats.mean_interval(g["mean_streak_px"])
        row.update(mean_streak_px=mean, streak_ci_low_px=low, streak_ci_high_px=high)
        for col in ("detection_rate", "common_rate", "mean_abs_error_m", "max_streak_px", "jitter_deg",
                    "mean_true_offset_px", "time_to_centre_s"):
            row[col] = float(g[col].mean()) if g[col].notna().any() else math.nan
        row["replicates_with_common_frames"] = int(g["common_abs_error_m"].notna().sum())
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _cell(replicates: pd.DataFrame, target, motion, mount, shutter, column) -> pd.Series:
    r = replicates
    sel = r[(r.target == target) & (r.motion == motion) & (r["mount"] == mount) & (r.shutter == shutter)]
    if sel.empty:
        raise ValueError(f"the replicate table has no rows for {target}/{motion}/{mount}/{shutter}")
    if sel["seed"].duplicated().any():
        raise ValueError(f"{target}/{motion}/{mount}/{shutter} holds a seed twice")
    return sel.set_index("seed")[column].sort_index()


def check_hypotheses(replicates: pd.DataFrame) -> pd.DataFrame:
    """H1–H4 per condition, with three-way verdicts and the numbers behind them.

    Errors (H1, H2, H4) are the common-frame errors, metres; H4's quantity is the rolling
    shutter's cost, common-frame error with the rolling minus with the global shutter, per
    replicate. Streaks (H3) are pixels, with δ's floor :data:`STREAK_FLOOR_PX`. A replicate
    without common frames leaves its pair out; fewer than two pairs is "inconclusive".

    Returns
    -------
    DataFrame
        One row per condition: id, statement, condition, a, b, unit ("m" or "px") and the
        :class:`gimbal_lab.stats.Verdict` fields.
    """
    rows = []
    targets = [t for t in TARGETS if (replicates["target"] == t).any()]
    motions = [m for m in MOTIONS if (replicates["motion"] == m).any()]
    if not targets or not motions:
        raise ValueError("the replicate table holds no runs of the study's targets and motions")

    def value(target, motion, mount, shutter, column="common_abs_error_m"):
        return _cell(replicates, target, motion, mount, shutter, column)

    def add(cid, statement, condition, a_label, b_label, a, b, unit="m"):
        a, b = a.align(b, join="outer")
        floor = STREAK_FLOOR_PX if unit == "px" else stats.MIN_EFFECT_M
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         result=stats.less_than(a.to_numpy(), b.to_numpy(), floor=floor, drop_missing=True)))

    for t in targets:
        for m in motions:
            for s in SHUTTERS:
                for mount in ("stabilised", "active"):
                    add("H1", "stabilised and active beat fixed (error)", f"{t}, {m}, {s}", mount, "fixed",
                        value(t, m, mount, s), value(t, m, "fixed", s))
    if "flight" in motions:
        for t in targets:
            for s in SHUTTERS:
                add("H2", "active beats stabilised in flight (error)", f"{t}, flight, {s}", "active", "stabilised",
                    value(t, "flight", "active", s), value(t, "flight", "stabilised", s))
    for t in targets:
        for m in motions:
            for s in SHUTTERS:
                for a_mount, b_mount in (("active", "stabilised"), ("stabilised", "fixed")):
                    add("H3", "blur streak: active < stabilised < fixed", f"{t}, {m}, {s}", a_mount, b_mount,
                        value(t, m, a_mount, s, "mean_streak_px"), value(t, m, b_mount, s, "mean_streak_px"),
                        unit="px")
    for t in targets:
        for m in motions:
            cost = {mount: value(t, m, mount, "rolling") - value(t, m, mount, "global") for mount in MOUNTS}
            for mount in ("stabilised", "active"):
                add("H4", "the rolling shutter costs fixed more (error: rolling − global)", f"{t}, {m}",
                    f"cost {mount}", "cost fixed", cost[mount], cost["fixed"])
    return stats.verdict_table(rows)


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds)."""
    return _params.verdict_reason(row, "have frames where every mount detected the target")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: MovingDroneStudy | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval and δ, a
    per-hypothesis count and a measured reason for each condition that does not hold."""
    study = study or MovingDroneStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    lines = [
        "# Moving drone: hypotheses H1–H4, measured",
        "",
        f"Every frame integrates a {1000 * study.exposure_s:.1f} ms exposure of the moving camera and target; the "
        f"rolling shutter reads its rows over {1000 * study.readout_s:.0f} ms. **Fixed**: the camera rigid on the "
        "body; **stabilised**: the gimbal holds its home orientation in the world from its own gyro; **active**: "
        f"the paper's PI image loop. Up to {n} replicates per cell of {study.revolutions:g} revolutions (the first "
        "is acquisition); cells are paired by replicate. Errors are over the frames where every mount detected "
        "the target.",
        "",
        _params.verdict_rule(f"max(floor, 10 % of the smaller mean), floor 1 mm for errors and {STREAK_FLOOR_PX:g} px "
                             "for streaks", "A replicate without common detections drops out of its pair."),
        "",
    ]
    lines += _params.verdict_lines(verdicts, verdict_reason)
    if summary is not None and len(summary):
        lines += ["", "## Detection rate per cell (measured revolutions)", "",
                  "| target | motion | shutter | " + " | ".join(MOUNTS) + " |", "|---|---|---|---|---|---|"]
        for (t, m, s), g in summary.groupby(["target", "motion", "shutter"], sort=False):
            rate = g.set_index("mount")["detection_rate"]
            lines.append(f"| {t} | {m} | {s} | " + " | ".join(f"{rate.get(x, math.nan):.2f}" for x in MOUNTS) + " |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
#: The cell and frame of the example figure: the three mounts at one instant of the measured
#: revolution, blurred.
EXAMPLE_MOTION, EXAMPLE_SHUTTER = "vibration", "rolling"


def example_runs(results, target: str, motion: str = EXAMPLE_MOTION, shutter: str = EXAMPLE_SHUTTER,
                 seed: int | None = None) -> list:
    """The fixed, stabilised and active runs of one cell and replicate (the first seed by default)."""
    seeds = sorted({r.config.seed for r in results})
    if not seeds:
        raise ValueError("no runs given")
    seed = seeds[0] if seed is None else seed
    runs = {r.config.pointing.mount: r for r in results
            if (r.config.target.kind, r.config.platform.motion, _shutter(r.config), r.config.seed)
            == (target, motion, shutter, seed)}
    missing = [m for m in MOUNTS if m not in runs]
    if missing:
        raise ValueError(f"no {', '.join(missing)} run of {target}/{motion}/{shutter}, seed {seed}")
    return [runs[m] for m in MOUNTS]


def write_report(folder, results, study: MovingDroneStudy) -> list[Path]:
    """Write the tables, hypotheses and figures into ``folder``; return the paths written.

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``verdicts.csv``, ``claims.md``,
    ``study.json`` and ``figures/`` (bars of error, detection rate and streak; the example frames
    of each target; the forest plot of the hypotheses), PNG and SVG.
    """
    from .. import plotting

    def figures(save, results, summary):
        save(plotting.study.plot_mount_bars(summary), "mount_bars")
        for target in sorted({r.config.target.kind for r in results}, key=TARGETS.index):
            runs = example_runs(results, target)
            frame = int(round(runs[0].config.frames_per_revolution * 1.25))
            save(plotting.study.plot_mount_frames(runs, frame), f"example_frames_{target}")

    return _params.write_study_report(folder, results, study, sys.modules[__name__], figures)


def run_study(study: MovingDroneStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/moving-drone`` atomically.

    ``clips`` is accepted for the command line's sake; this study writes example frames, not clips.
    Returns a dict with the results, the folder and the paths written.
    """
    return _params.run_and_report(NAME, "moving drone", grid(study), write_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
