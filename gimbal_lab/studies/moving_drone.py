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

The strongest passive baseline and the gain decomposed (docs/design.md, "When does a gimbal pay
off?"): **BP1** "active (paper) < best passive" and **BP2** "active (best) < best passive" per
target × motion × shutter, where active (paper) is the active mount's circle method (sphere) or
PnP on the sub-pixel corners, active (best) the active mount's exact estimator (the sphere's cone
fit, recorded in every run's ``alt_*`` columns; the marker's PnP), best passive the stabilised
mount's exact estimator, on the frames all three detected (:func:`pipeline_table`). Two arms
beside the grid (:func:`arm_grid`), global shutter, stabilised and active mounts, the study's
draws: **sharp** (exposure 0) and **static** (the target held still at the circle's centre,
1/60 s exposure). With G = stabilised − active error (exact estimator, frames both mounts
detected) per replicate (:func:`gain_table`): **D1** "G_sharp < G_full", **D2** "G_static <
G_full", and the shares G_full − G_sharp, G_sharp, G_static with intervals
(:func:`gain_summary`). Against every passive pipeline at once (the decision recorded after the
first full run: under blur the exact estimator is not the strongest passive one): **SP1** "active
(paper) < every passive pipeline" and **SP2** "active (best) < every passive pipeline", the fixed
and stabilised mounts each with its own and (sphere) its exact estimator, an intersection–union
test (:func:`every_pipeline_table`, :func:`gimbal_lab.stats.against_every`). Every verdict is
also given at the family level: Holm's correction over the report's whole table
(:func:`gimbal_lab.stats.holm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..mount import GYRO_NOISE_RAD_S_RTHZ
from ..platform import WaypointFlight
from ..config import Camera, Estimator, Gimbal, Platform, Pointing, Target, TrackingConfig, _choice, _number, seed_stream
from . import _params
from . import report as _report
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "MovingDroneStudy",
    "Study",
    "TARGETS",
    "MOTIONS",
    "MOUNTS",
    "SHUTTERS",
    "shutter_of",
    "STREAK_FLOOR_PX",
    "flight_phase_s",
    "grid",
    "ARMS",
    "arm_grid",
    "all_configs",
    "arm_of",
    "PIPELINES",
    "pipeline_table",
    "every_pipeline_table",
    "PASSIVE_PIPELINES",
    "gain_table",
    "gain_summary",
    "replicate_table",
    "summary_table",
    "check_hypotheses",
    "hypotheses_markdown",
    "make_report",
    "run_study",
]

NAME = "moving-drone"
DESCRIPTION = ("moving drone: fixed vs stabilised vs active camera under sway, vibration and flight, "
               "with motion blur and rolling shutter (36 cells)")

TARGETS = ("sphere", "aruco")
MOTIONS = ("hover", "vibration", "flight")
MOUNTS = ("fixed", "stabilised", "active")
SHUTTERS = ("global", "rolling")

#: The study's runs and the two arms of the gain's decomposition (docs/design.md, "The moving
#: drone's gain, decomposed"): no exposure blur, and the target held still.
ARMS = ("full", "sharp", "static")

#: The pipelines compared by BP1 and BP2 (docs/design.md, "Pipelines compared").
PIPELINES = ("active (paper)", "active (best)", "best passive")
#: The passive pipelines SP1 and SP2 compare with (docs/design.md, "When does a gimbal pay off?",
#: the decision on the moving drone): each passive mount with its own and, for the sphere, its exact
#: estimator (the marker's exact estimator is its own PnP).
PASSIVE_PIPELINES = {"sphere": ("fixed (paper)", "stabilised (paper)", "fixed (best)", "stabilised (best)"),
                     "aruco": ("fixed (paper)", "stabilised (paper)")}

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

    def config(self, target: str, motion: str, mount: str, shutter: str, seed: int, arm: str = "full"
               ) -> TrackingConfig:
        """The run of one cell and replicate; ``arm`` "sharp" sets the exposure to 0 (no blur),
        "static" holds the target still at the circle's centre (trajectory "stationary")."""
        _choice("target", target, TARGETS)
        _choice("motion", motion, MOTIONS)
        _choice("mount", mount, MOUNTS)
        _choice("shutter", shutter, SHUTTERS)
        _choice("arm", arm, ARMS)
        return TrackingConfig(
            camera=Camera(fps=self.fps, latency_frames=self.latency_frames, noise_std=self.noise_std,
                          exposure_s=0.0 if arm == "sharp" else self.exposure_s, blur="fast",
                          readout_s=self.readout_s if shutter == "rolling" else 0.0),
            gimbal=Gimbal(gyro_noise_rad_s_rthz=math.radians(self.gyro_noise_deg_s_rthz)),
            platform=Platform(motion=motion, motion_phase_s=flight_phase_s(seed) if motion == "flight" else 0.0),
            target=Target(kind=target, trajectory="stationary" if arm == "static" else "circular",
                          period_s=self.period_s,
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


def arm_grid(study: MovingDroneStudy | None = None, targets=TARGETS, motions=MOTIONS) -> list[TrackingConfig]:
    """The runs of the two arms beside the grid: sharp and static, each target and motion, the
    stabilised and active mounts, global shutter, the study's replicates (same seeds, so the
    same draws); 2 × 2 × 3 × 2 cells × replicates for both targets and every motion."""
    study = study or MovingDroneStudy()
    return [study.config(target, motion, mount, "global", seed, arm=arm)
            for arm in ARMS[1:] for target in targets for motion in motions for mount in ("stabilised", "active")
            for seed in study.seeds]


def all_configs(study: MovingDroneStudy | None = None) -> list[TrackingConfig]:
    """Every run of the study: the grid and the two arms of the gain's decomposition."""
    return grid(study) + arm_grid(study)


def arm_of(config: TrackingConfig) -> str:
    """Which arm a run belongs to: "static" (target still), "sharp" (no exposure) or "full"."""
    if config.target.trajectory == "stationary":
        return "static"
    return "sharp" if config.camera.exposure_s == 0 else "full"


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def shutter_of(config: TrackingConfig) -> str:
    """The shutter a run's camera has: "rolling" when its rows have a readout time, else "global"."""
    return "rolling" if config.camera.readout_s > 0 else "global"


def _identity(config: TrackingConfig) -> dict:
    return {"arm": arm_of(config), "target": config.target.kind, "motion": config.platform.motion,
            "mount": config.pointing.mount, "shutter": shutter_of(config), "seed": config.seed}


def _exact(result) -> tuple[np.ndarray, np.ndarray] | None:
    """(detected, |error|) of the run's exact estimator on its measured frames: the sphere's cone
    fit (``alt_*`` beside the circle method) or the marker's own PnP; None when the run's frames
    lack those columns."""
    from .paper import _exact_prefix

    prefix = _exact_prefix(result.config)
    f = _measured(result)
    if f"{prefix}detected" not in f or f"{prefix}abs_error_m" not in f:
        return None
    return f[f"{prefix}detected"].to_numpy(bool), f[f"{prefix}abs_error_m"].to_numpy(float)


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
        groups.setdefault((arm_of(c), c.target.kind, c.platform.motion, shutter_of(c), c.seed), []).append(r)
    rows = []
    for members in groups.values():
        measured = {id(r): _measured(r) for r in members}
        lengths = {len(f) for f in measured.values()}
        if len(lengths) != 1:
            raise ValueError("runs of one target, motion, shutter and seed must have the same frames")
        common = np.logical_and.reduce([f["detected"].to_numpy() for f in measured.values()])
        by_mount = {r.config.pointing.mount: r for r in members}
        exact = {m: _exact(r) for m, r in by_mount.items()}
        # the frames the gain compares: both the stabilised and the active mount's exact estimator detected
        pair = (exact["stabilised"][0] & exact["active"][0]
                if all(exact.get(m) is not None for m in ("stabilised", "active")) else None)
        # BP's frames: the active mount's own and exact estimators and the stabilised mount's exact one
        bp = (pair & measured[id(by_mount["active"])]["detected"].to_numpy(bool)) if pair is not None else None
        # SP's frames: every mount's own and exact estimators
        sp = (np.logical_and.reduce([common] + [exact[m][0] for m in MOUNTS])
              if all(exact.get(m) is not None for m in MOUNTS) else None)
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
                **_pipeline_columns(f, exact.get(c.pointing.mount), pair, bp, sp),
            })
    order = {name: i for i, name in enumerate(ARMS + TARGETS + MOTIONS + MOUNTS + SHUTTERS)}
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(["arm", "target", "motion", "mount", "shutter", "seed"],
                             key=lambda s: s.map(order) if s.name != "seed" else s, ignore_index=True)


def _pipeline_columns(f: pd.DataFrame, exact, pair, bp, sp) -> dict:
    """A run's errors on the frames the pipelines compare (NaN where they do not apply):
    ``pair_abs_error_m`` (exact estimator, frames the stabilised and active mounts' exact
    estimators both detected: the gain), ``bp_rate``, ``bp_paper_abs_error_m`` (own estimator)
    and ``bp_best_abs_error_m`` (exact estimator) on BP's frames (:func:`pipeline_table`), and
    ``sp_rate``, ``sp_paper_abs_error_m``, ``sp_best_abs_error_m`` on SP's frames, where every
    mount's own and exact estimators detected (:func:`every_pipeline_table`)."""
    nan = dict(pair_rate=math.nan, pair_abs_error_m=math.nan, bp_rate=math.nan, bp_paper_abs_error_m=math.nan,
               bp_best_abs_error_m=math.nan, sp_rate=math.nan, sp_paper_abs_error_m=math.nan,
               sp_best_abs_error_m=math.nan)
    if exact is None:
        return nan
    own = f["abs_error_m"].to_numpy(float)
    out = dict(nan)
    if pair is not None:
        out.update(pair_rate=_mean(pair), pair_abs_error_m=_mean(exact[1][pair]), bp_rate=_mean(bp),
                   bp_paper_abs_error_m=_mean(own[bp]), bp_best_abs_error_m=_mean(exact[1][bp]))
    if sp is not None:
        out.update(sp_rate=_mean(sp), sp_paper_abs_error_m=_mean(own[sp]), sp_best_abs_error_m=_mean(exact[1][sp]))
    return out


def pipeline_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """The three pipelines per target, motion, shutter and replicate, from the study's runs.

    active (paper): the active mount's own estimator (the paper's circle method or PnP on the
    sub-pixel corners); active (best): the active mount's exact estimator (the sphere's cone fit
    in its ``alt_*`` columns); best passive: the stabilised mount's exact estimator. All on the
    measured frames where the three detected (``bp_*`` columns of :func:`replicate_table`).

    Returns
    -------
    DataFrame
        target, motion, shutter, pipeline, seed, rate (of those frames) and abs_error_m (m).
    """
    r = replicates[replicates["arm"] == "full"] if "arm" in replicates else replicates
    rows = []
    for (t, m, s, seed), g in r.groupby(["target", "motion", "shutter", "seed"], sort=False):
        mounts = g.set_index("mount")
        if not {"active", "stabilised"} <= set(mounts.index):
            continue
        values = {"active (paper)": mounts.loc["active", "bp_paper_abs_error_m"],
                  "active (best)": mounts.loc["active", "bp_best_abs_error_m"],
                  "best passive": mounts.loc["stabilised", "bp_best_abs_error_m"]}
        for p in PIPELINES:
            rows.append(dict(target=t, motion=m, shutter=s, pipeline=p, seed=seed,
                             rate=float(mounts.loc["active", "bp_rate"]), abs_error_m=float(values[p])))
    return pd.DataFrame(rows)


def every_pipeline_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Every pipeline SP1 and SP2 compare, per target, motion, shutter and replicate, on SP's frames
    (the measured frames where every mount's own and exact estimators detected; ``sp_*`` columns of
    :func:`replicate_table`): active (paper), active (best) and the target's
    :data:`PASSIVE_PIPELINES` ("fixed (paper)": the fixed mount's own estimator, "fixed (best)":
    its exact one; the same for the stabilised mount).

    Returns
    -------
    DataFrame
        target, motion, shutter, pipeline, seed, rate (of those frames) and abs_error_m (m); empty
        when the table has no ``sp_*`` columns.
    """
    r = replicates[replicates["arm"] == "full"] if "arm" in replicates else replicates
    rows = []
    if "sp_paper_abs_error_m" not in r:
        return pd.DataFrame(rows, columns=["target", "motion", "shutter", "pipeline", "seed", "rate", "abs_error_m"])
    for (t, m, s, seed), g in r.groupby(["target", "motion", "shutter", "seed"], sort=False):
        mounts = g.set_index("mount")
        if not set(MOUNTS) <= set(mounts.index):
            continue
        for p in ("active (paper)", "active (best)") + PASSIVE_PIPELINES[t]:
            mount, estimator = p.rstrip(")").split(" (")  # "fixed (best)" -> fixed, best
            column = f"sp_{estimator}_abs_error_m"
            rows.append(dict(target=t, motion=m, shutter=s, pipeline=p, seed=seed,
                             rate=float(mounts.loc["active", "sp_rate"]), abs_error_m=float(mounts.loc[mount, column])))
    return pd.DataFrame(rows)


def gain_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """G = stabilised − active error per arm, target, motion and replicate (global shutter; the
    exact estimator on the frames both mounts detected, ``pair_abs_error_m``), m. NaN where a
    replicate has no such frame.

    Returns
    -------
    DataFrame
        arm, target, motion, seed, gain (``G_full``, ``G_sharp``, ``G_static``), G_m.
    """
    if "arm" not in replicates:
        return pd.DataFrame(columns=["arm", "target", "motion", "seed", "gain", "G_m"])
    r = replicates[(replicates["shutter"] == "global") & replicates["mount"].isin(["stabilised", "active"])]
    rows = []
    for (arm, t, m, seed), g in r.groupby(["arm", "target", "motion", "seed"], sort=False):
        e = g.set_index("mount")["pair_abs_error_m"]
        if set(e.index) != {"stabilised", "active"}:
            continue
        rows.append(dict(arm=arm, target=t, motion=m, seed=seed, gain=f"G_{arm}",
                         G_m=float(e["stabilised"] - e["active"])))
    return pd.DataFrame(rows, columns=["arm", "target", "motion", "seed", "gain", "G_m"])


def _gains_of(gains: pd.DataFrame, target, motion) -> dict[str, pd.Series]:
    sel = gains[(gains["target"] == target) & (gains["motion"] == motion)]
    return {arm: sel[sel["arm"] == arm].set_index("seed")["G_m"].sort_index() for arm in ARMS}


def gain_summary(gains: pd.DataFrame) -> pd.DataFrame:
    """The shares of the gain per target and motion, with 95 % t-intervals over replicates
    (docs/design.md: no verdict on them): G_full, G_sharp, G_static, and the target's own blur
    G_full − G_sharp (paired by replicate; a replicate lacking either leaves its pair out).

    Returns
    -------
    DataFrame
        target, motion, gain, n, mean_m, low_m, high_m.
    """
    rows = []
    if gains.empty:
        return pd.DataFrame(columns=["target", "motion", "gain", "n", "mean_m", "low_m", "high_m"])
    for (t, m), _ in gains.groupby(["target", "motion"], sort=False):
        g = _gains_of(gains, t, m)
        series = {f"G_{arm}": g[arm].dropna() for arm in ARMS if len(g[arm])}
        if "G_full" in series and "G_sharp" in series:
            series["G_full − G_sharp"] = (g["full"] - g["sharp"]).dropna()
        for name, values in series.items():
            mean, low, high = stats.mean_interval(values.to_numpy()) if len(values) else (math.nan,) * 3
            rows.append(dict(target=t, motion=m, gain=name, n=len(values), mean_m=mean, low_m=low, high_m=high))
    return pd.DataFrame(rows)


_CELL = ["target", "motion", "mount", "shutter"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell: replicates, the mean of each replicate quantity, and 95 % t-intervals of the
    common-frame error (``ci_low_m``, ``ci_high_m``) and of the streak (``streak_ci_low_px``, ...).
    The study's own runs only (``arm`` "full"; the arms are summarised by :func:`gain_summary`)."""
    rows = []
    if "arm" in replicates:
        replicates = replicates[replicates["arm"] == "full"]
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
    r = replicates[replicates["arm"] == "full"] if "arm" in replicates else replicates
    sel = r[(r.target == target) & (r.motion == motion) & (r["mount"] == mount) & (r.shutter == shutter)]
    if sel.empty:
        raise ValueError(f"the replicate table has no rows for {target}/{motion}/{mount}/{shutter}")
    if sel["seed"].duplicated().any():
        raise ValueError(f"{target}/{motion}/{mount}/{shutter} holds a seed twice")
    return sel.set_index("seed")[column].sort_index()


def check_hypotheses(replicates: pd.DataFrame) -> pd.DataFrame:
    """H1–H4, BP1, BP2, D1 and D2 per condition, with three-way verdicts at 95 % and at the
    family level, and the numbers behind them.

    Errors (H1, H2, H4) are the common-frame errors, metres; H4's quantity is the rolling
    shutter's cost, common-frame error with the rolling minus with the global shutter, per
    replicate. Streaks (H3) are pixels, with δ's floor :data:`STREAK_FLOOR_PX`. A replicate
    without common frames leaves its pair out; fewer than two pairs is "inconclusive".
    H1–H4 use the study's own runs (``arm`` "full"). Where the table has the pipelines' columns
    (:func:`replicate_table` of real runs), BP1 "active (paper) < best passive" and BP2 "active
    (best) < best passive" per target × motion × shutter (:func:`pipeline_table`); where it has
    the sharp or static arm, D1 "G_sharp < G_full" and D2 "G_static < G_full" per target × motion
    (:func:`gain_table`); where it has SP's columns, SP1 "active (paper) < every passive pipeline"
    and SP2 "active (best) < every passive pipeline" per target × motion × shutter
    (:func:`every_pipeline_table`, :func:`gimbal_lab.stats.against_every`; ``b`` names the passive
    pipeline that decides, ``passive_pipelines`` counts them). Errors in m. A target–motion cell the table does not hold (a smaller
    run of the grid, such as notebook 09's test size) is left out, and so is a shutter a cell did
    not run (H4, which compares the shutters, needs both); a cell and shutter it holds must have
    every mount.

    Returns
    -------
    DataFrame
        One row per condition: id, statement, condition, a, b, unit ("m" or "px"), the
        :class:`gimbal_lab.stats.Verdict` fields and, from :func:`gimbal_lab.stats.holm` over the
        whole table (one family, docs/design.md "Multiplicity"), p_holm and verdict_holm.
    """
    rows = []
    targets = [t for t in TARGETS if (replicates["target"] == t).any()]
    motions = [m for m in MOTIONS if (replicates["motion"] == m).any()]
    if not targets or not motions:
        raise ValueError("the replicate table holds no runs of the study's targets and motions")
    full = replicates[replicates["arm"] == "full"] if "arm" in replicates else replicates
    # the (target, motion) cells the table ran (a smaller run may leave some out), each with the shutters it ran
    cells = [(t, m) for t in targets for m in motions if ((full.target == t) & (full.motion == m)).any()]
    shutters = {(t, m): [s for s in SHUTTERS if ((full.target == t) & (full.motion == m) & (full.shutter == s)).any()]
                for t, m in cells}

    def value(target, motion, mount, shutter, column="common_abs_error_m"):
        return _cell(replicates, target, motion, mount, shutter, column)

    def add(cid, statement, condition, a_label, b_label, a, b, unit="m"):
        a, b = a.align(b, join="outer")
        floor = STREAK_FLOOR_PX if unit == "px" else stats.MIN_EFFECT_M
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         result=stats.less_than(a.to_numpy(), b.to_numpy(), floor=floor, drop_missing=True)))

    for t, m in cells:
        for s in shutters[t, m]:
            for mount in ("stabilised", "active"):
                add("H1", "stabilised and active beat fixed (error)", f"{t}, {m}, {s}", mount, "fixed",
                    value(t, m, mount, s), value(t, m, "fixed", s))
    for t in (t for t, m in cells if m == "flight"):
        for s in shutters[t, "flight"]:
            add("H2", "active beats stabilised in flight (error)", f"{t}, flight, {s}", "active", "stabilised",
                value(t, "flight", "active", s), value(t, "flight", "stabilised", s))
    for t, m in cells:
        for s in shutters[t, m]:
            for a_mount, b_mount in (("active", "stabilised"), ("stabilised", "fixed")):
                add("H3", "blur streak: active < stabilised < fixed", f"{t}, {m}, {s}", a_mount, b_mount,
                    value(t, m, a_mount, s, "mean_streak_px"), value(t, m, b_mount, s, "mean_streak_px"),
                    unit="px")
    for t, m in (cell for cell in cells if len(shutters[cell]) == len(SHUTTERS)):
        cost = {mount: value(t, m, mount, "rolling") - value(t, m, mount, "global") for mount in MOUNTS}
        for mount in ("stabilised", "active"):
            add("H4", "the rolling shutter costs fixed more (error: rolling − global)", f"{t}, {m}",
                f"cost {mount}", "cost fixed", cost[mount], cost["fixed"])
    if "bp_paper_abs_error_m" in replicates:
        pipes = pipeline_table(replicates)
        for (t, m, s), g in (pipes.groupby(["target", "motion", "shutter"], sort=False) if len(pipes) else ()):
            value = {p: g[g["pipeline"] == p].set_index("seed")["abs_error_m"].sort_index() for p in PIPELINES}
            for cid, active in (("BP1", "active (paper)"), ("BP2", "active (best)")):
                add(cid, f"{active} error < best passive error", f"{t}, {m}, {s}", active, "best passive",
                    value[active], value["best passive"])
    every = every_pipeline_table(replicates)
    for (t, m, s), g in (every.groupby(["target", "motion", "shutter"], sort=False) if len(every) else ()):
        value = {p: g[g["pipeline"] == p].set_index("seed")["abs_error_m"].sort_index() for p in set(g["pipeline"])}
        passive = PASSIVE_PIPELINES[t]
        for cid, active in (("SP1", "active (paper)"), ("SP2", "active (best)")):
            pairs = [value[active].align(value[p], join="outer") for p in passive]
            j, result = stats.against_every([stats.less_than(x.to_numpy(), y.to_numpy(), drop_missing=True)
                                             for x, y in pairs])
            rows.append(dict(id=cid, statement=f"{active} error < every passive pipeline's", condition=f"{t}, {m}, {s}",
                             a=active, b=passive[j], unit="m", passive_pipelines=len(passive), result=result))
    gains = gain_table(replicates)
    for t, m in cells:
        g = _gains_of(gains, t, m)
        if not len(g["full"]):
            continue
        for cid, arm, what in (("D1", "sharp", "removing the target's own blur lowers the gain"),
                               ("D2", "static", "the body's sway alone gives less gain than a moving target")):
            if len(g[arm]):
                add(cid, f"{what} (G_{arm} < G_full)", f"{t}, {m}", f"G_{arm}", "G_full", g[arm], g["full"])
    return stats.holm(stats.verdict_table(rows))


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds). SP1 and
    SP2 name the passive pipeline that decides them; an SP comparison that does not hold at 95 %
    but not at the Bonferroni level over the passive pipelines says so."""
    reason = _params.verdict_reason(row, "have frames where every mount detected the target")
    if str(row.id).startswith("SP") and reason:
        k = int(row.passive_pipelines)
        bonferroni_only = (row.verdict == stats.INCONCLUSIVE and math.isfinite(row.low)
                           and (row.low > 0 or (-row.delta < row.low and row.high < row.delta)))
        if bonferroni_only:
            reason = (f"against {row.b} it does not hold at 95 % but not at the Bonferroni level over the {k} "
                      f"passive pipelines ({k} × p = {_params.format_p(row.p_value)})")
        return f"decided against {row.b} of {k} passive pipelines: {reason}"
    return reason


def _mm_interval(mean: float, low: float, high: float) -> str:
    """"12.34 [10.00, 14.00]" in mm from metres; "–" for what is not defined (one replicate)."""
    f = lambda x: f"{1000 * x:.2f}" if math.isfinite(x) else "–"  # noqa: E731
    return f"{f(mean)} [{f(low)}, {f(high)}]"


def _pipeline_error_lines(table: pd.DataFrame, title: str, note: str = "") -> list[str]:
    """A claims.md section: each pipeline's mean error over replicates with its 95 % interval, per
    target, motion and shutter (a :func:`pipeline_table` or :func:`every_pipeline_table`)."""
    lines = ["", f"## {title}", "",
             " ".join(["Mean over replicates of each replicate's mean |d_est − d_true|, with its 95 % interval.", note]).strip(),
             "", "| target | motion | shutter | pipeline | n | error [mm] [95 % CI] | frames all detected |",
             "|---|---|---|---|---|---|---|"]
    for (t, m, s, p), g in table.groupby(["target", "motion", "shutter", "pipeline"], sort=False):
        values = g["abs_error_m"].dropna().to_numpy()
        mean, low, high = stats.mean_interval(values) if len(values) else (math.nan,) * 3
        lines.append(f"| {t} | {m} | {s} | {p} | {len(values)} | {_mm_interval(mean, low, high)} | "
                     f"{g['rate'].mean():.2f} |")
    return lines


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: MovingDroneStudy | None = None, pipelines: pd.DataFrame | None = None,
                        gains: pd.DataFrame | None = None, every: pd.DataFrame | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval, δ, p and
    Holm p at both levels, a per-hypothesis count, a measured reason for each condition that
    does not hold, and with ``pipelines`` (:func:`pipeline_table`), ``every``
    (:func:`every_pipeline_table`) and ``gains`` (:func:`gain_summary`) each pipeline's error and
    the gain's shares with their intervals."""
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
        "The strongest passive baseline (docs/design.md, \u201cWhen does a gimbal pay off?\u201d): **active (paper)** "
        "is the active mount with the paper's estimator (circle method; PnP on the sub-pixel corners), **active "
        "(best)** the active mount with the exact estimator (the sphere's cone fit; the marker's PnP), **best "
        "passive** the stabilised mount with the exact estimator; BP1 and BP2 compare them on the frames all three "
        "detected. The gain G = stabilised − active error (exact estimator, frames both mounts detected) is "
        "decomposed with two arms (global shutter, the same draws): **sharp** (exposure 0) and **static** (the "
        "target held still at the circle's centre); D1 \u201cG_sharp < G_full\u201d, D2 \u201cG_static < "
        "G_full\u201d. SP1 and SP2 compare active (paper) and active (best) with every passive pipeline at once "
        "(the fixed and the stabilised mount, each with its own and, for the sphere, its exact estimator), on the "
        "frames all of them detected: a claim holds when it holds against each passive pipeline, does not hold when "
        "it does not hold against one at the Bonferroni level over them, and names the one that decides it. "
        "Every verdict is given at 95 % and after Holm's step-down correction over all the verdicts "
        "below (5 % family-wise error).",
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
    if pipelines is not None and len(pipelines):
        lines += _pipeline_error_lines(pipelines, "Each pipeline's error (frames all three detected)")
    if every is not None and len(every):
        lines += _pipeline_error_lines(every, "Every pipeline's error (SP's frames: every mount's estimators detected)",
                                       "(paper): the mount's own estimator, (best): the exact one.")
    if gains is not None and len(gains):
        lines += ["", "## The gain, decomposed", "",
                  "G = stabilised − active error, mm (exact estimator, frames both mounts detected, global shutter); "
                  "mean over replicates and 95 % interval. The target's own blur: G_full − G_sharp; centring on a "
                  "moving target without blur: G_sharp; sway alone: G_static. No verdict on the shares.", "",
                  "| target | motion | share | n | G [mm] [95 % CI] |", "|---|---|---|---|---|"]
        for row in gains.itertuples():
            lines.append(f"| {row.target} | {row.motion} | {row.gain} | {row.n} | "
                         f"{_mm_interval(row.mean_m, row.low_m, row.high_m)} |")
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
            if (r.config.target.kind, r.config.platform.motion, shutter_of(r.config), r.config.seed)
            == (target, motion, shutter, seed)}
    missing = [m for m in MOUNTS if m not in runs]
    if missing:
        raise ValueError(f"no {', '.join(missing)} run of {target}/{motion}/{shutter}, seed {seed}")
    return [runs[m] for m in MOUNTS]


def make_report(results, study: MovingDroneStudy) -> _report.Report:
    """The study's report (:class:`gimbal_lab.studies.report.Report`): its tables, hypotheses and figures.

    ``results``: the grid's runs and, when run, the arms' (:func:`arm_grid`). Files:
    ``summary.csv``, ``replicates.parquet`` and ``.csv`` (every run, with its ``arm``),
    ``pipelines.csv``, ``every_pipeline.csv`` (SP's pipelines), ``gains.csv`` (per replicate) and
    ``gain_summary.csv``, ``verdicts.csv``,
    ``claims.md``, ``study.json`` and ``figures/`` (bars of error, detection rate and streak; the
    example frames of each target; the three gains per motion and target when the arms ran; the
    forest plot of the verdicts), PNG and SVG.
    """
    from .. import plotting

    replicates = replicate_table(results)
    summary = summary_table(replicates)
    verdicts = check_hypotheses(replicates)
    pipelines = pipeline_table(replicates)
    every = every_pipeline_table(replicates)
    gains = gain_table(replicates)
    shares = gain_summary(gains)
    full = [r for r in results if arm_of(r.config) == "full"]

    def example_frames(target):
        runs = example_runs(full, target)
        return plotting.study.plot_mount_frames(runs, int(round(runs[0].config.frames_per_revolution * 1.25)))

    figures = [("mount_bars", lambda: plotting.study.plot_mount_bars(summary))]
    figures += [(f"example_frames_{target}", lambda target=target: example_frames(target))
                for target in sorted({r.config.target.kind for r in full}, key=TARGETS.index)]
    if (shares["gain"] != "G_full").any() if len(shares) else False:
        figures.append(("gains", lambda: plotting.study.plot_gains(
            shares[shares["gain"].isin(["G_full", "G_sharp", "G_static"])])))
    return _report.Report(NAME, study, len(results), [
        ("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
        ("pipelines.csv", pipelines), ("every_pipeline.csv", every), ("gains.csv", gains),
        ("gain_summary.csv", shares), ("verdicts.csv", verdicts),
        ("claims.md", hypotheses_markdown(verdicts, summary, study, pipelines, shares, every)),
    ], figures, verdicts)


def run_study(study: MovingDroneStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid and the arms of the gain's decomposition (reusing ``store``) and write the
    report to ``out/moving-drone`` (:func:`gimbal_lab.studies.report.run_and_report`).

    ``clips`` is accepted for the command line's sake; this study writes example frames, not clips.
    Returns a dict with the results, the verdicts, the folder and the paths written.
    """
    return _report.run_and_report(NAME, "moving drone", all_configs(study), make_report, study, out,
                                  store=store, executor=executor, jobs=jobs, progress=progress)
