"""The paper's study (§4.1): the 16-cell grid with replicates, its tables, claims and report.

Grid: {sphere, ArUco} × {undistorted, distorted} × {circular, diagonal} × {passive, active}, each
cell run ``replicates`` times (seeds ``first_seed`` …). Replicate s draws its start phase
φ ~ U(0, T) and its sensor noise from seed s, and cells share those draws, so every comparison
between cells is paired. Each replicate runs ``revolutions`` periods: the first is **acquisition**
(reported on its own: time to centre the target, error while acquiring), the rest are
**measured**; the unit of evidence is one replicate's mean over its measured revolutions.

Claims (paper §4.1.1–4.1.2; docs/design.md) are checked with the three-way verdicts of
:mod:`gimbal_lab.stats`. "Active" is the paper's PI image loop with Ziegler–Nichols gains unless
``outer_loop`` says otherwise; "passive" is the stabilised gimbal at its home pose.

Beside the paper's pipeline the study compares the strongest passive one (docs/design.md, "When
does a gimbal pay off?"): **active (paper)** (the loop, the lens ignored, the circle method or PnP
on the sub-pixel corners), **active (best)** (the same loop with the lens known and the best
estimator: the exact cone fit for the sphere, PnP on undistorted corners for the marker) and
**best passive** (the passive camera with the lens known and the best estimator). The distorted
camera's known-lens pipelines are runs of their own (:func:`pipeline_grid`); the undistorted
camera's are the study's runs (the sphere's exact fit is recorded in every run's ``alt_*``
columns). Claims BP1 "active (paper) < best passive", BP2 "active (best) < best passive" per
target × distortion × trajectory, on the frames all three pipelines detected
(:func:`pipeline_table`), and A7 (§4.1.2) join the paper's; every verdict is also given at the
family level (Holm's correction across the report's claims, :func:`gimbal_lab.stats.holm`). Each
pipeline's CPU cost per frame is measured apart from the runs (:func:`pipeline_costs`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..config import Camera, Estimator, Pointing, Target, TrackingConfig, _number, seed_stream
from . import report as _report
from ._params import StudyParams, format_p, holm_change_lines, md_cell, verdict_counts, verdict_rule

__all__ = [
    "PaperStudy",
    "grid",
    "pipeline_grid",
    "all_configs",
    "pipeline_table",
    "pipeline_summary",
    "pipeline_costs",
    "PIPELINES",
    "is_study_run",
    "replicate_phase_s",
    "replicate_table",
    "summary_table",
    "frames_table",
    "check_claims",
    "claims_markdown",
    "CENTRED_FRACTION",
    "DISTORTIONS",
    "TRAJECTORIES",
    "MODES",
]

NAME = "paper"
DESCRIPTION = "paper §4.1: sphere and ArUco, passive vs active, with and without distortion (16 cells)"

DISTORTIONS = ("undistorted", "distorted")
TRAJECTORIES = ("circular", "diagonal")
MODES = ("passive", "active")
#: The camera's lens of each distortion condition.
_LENS = {"undistorted": "none", "distorted": "default"}

#: The pipelines compared by claims BP1 and BP2 (docs/design.md, "Pipelines compared").
PIPELINES = ("active (paper)", "active (best)", "best passive")

#: The target counts as centred once its detected centre comes within this fraction of the image
#: width of the image centre (32 px at 640 px).
CENTRED_FRACTION = 0.05

@dataclass(frozen=True)
class PaperStudy(StudyParams):
    """Parameters of the paper's study (defaults: docs/design.md; ``data/studies/paper.toml``).

    Parameters
    ----------
    replicates, first_seed, revolutions, period_s, fps, latency_frames, noise_std :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`).
    outer_loop : {"paper", "predictive"}
        What "active" means (the paper's ZN PI image loop by default): the active cells'
        :class:`~gimbal_lab.config.Pointing` kind.
    aruco_refinement : {"none", "subpix", "contour", "apriltag"}
        The study's corner refinement (sub-pixel).
    """

    outer_loop: str = "paper"
    aruco_refinement: str = "subpix"

    _TABLE = NAME

    def __post_init__(self):
        self._check_replicates()
        if self.outer_loop not in ("paper", "predictive"):
            raise ValueError(f"outer_loop must be one of ('paper', 'predictive'), got {self.outer_loop!r}")
        # the rest is validated by the config's parts, naming part and field
        self.config("aruco", "distorted", "diagonal", "active", self.first_seed)

    def config(self, target: str, distortion: str, trajectory: str, mode: str, seed: int,
               best: bool = False) -> TrackingConfig:
        """The run of one cell and replicate.

        With ``best``, the run of the known-lens pipeline on the distorted camera ("active (best)"
        or "best passive" by ``mode``): the estimator undistorts the outline or the corners
        (``lens_strategy="undistort"``; the loop measures through the lens too) and the sphere's
        primary localiser is the exact cone fit. The undistorted camera has no such run: its
        best pipelines are the study's own runs (the sphere's exact fit in their ``alt_*`` columns).
        """
        if target not in ("sphere", "aruco"):
            raise ValueError(f"targets must be 'sphere' or 'aruco', got {target!r}")
        if distortion not in DISTORTIONS:
            raise ValueError(f"distortion must be one of {DISTORTIONS}, got {distortion!r}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if best and distortion != "distorted":
            raise ValueError("best=True is a run of the distorted camera only: the undistorted camera's best "
                             "pipelines are the study's own runs (the exact fit in their alt_* columns)")
        estimator = (Estimator(sphere_method="ellipse", lens_strategy="undistort", aruco_refinement=self.aruco_refinement)
                     if best else Estimator(aruco_refinement=self.aruco_refinement))
        return TrackingConfig(
            camera=Camera(lens=_LENS[distortion], fps=self.fps, latency_frames=self.latency_frames,
                          noise_std=self.noise_std),
            target=Target(kind=target, trajectory=trajectory, period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s)),
            pointing=Pointing(self.outer_loop if mode == "active" else "stabilised"),
            estimator=estimator, revolutions=self.revolutions, seed=seed)


#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = PaperStudy


def replicate_phase_s(seed: int, period_s: float) -> float:
    """The start phase of replicate ``seed``: φ ~ U(0, period_s), drawn from the seed's "phase"
    stream (:func:`gimbal_lab.config.seed_stream`)."""
    return float(np.random.default_rng(seed_stream(seed, "phase")).uniform(0.0, period_s))


def grid(study: PaperStudy | None = None, targets=("sphere", "aruco"), **changes) -> list[TrackingConfig]:
    """Every (cell, replicate) config of the study, cells in the paper's order, replicates inner.

    ``changes`` override the study's parameters for these cells (e.g. ``outer_loop="predictive"``,
    ``aruco_refinement="none"`` for the extensions run beside the study).
    """
    study = dataclasses.replace(study or PaperStudy(), **changes)
    for target in targets:
        if target not in ("sphere", "aruco"):
            raise ValueError(f"targets must be 'sphere' or 'aruco', got {target!r}")
    return [study.config(target, dist, traj, mode, seed)
            for target in targets for dist in DISTORTIONS for traj in TRAJECTORIES for mode in MODES
            for seed in study.seeds]


def pipeline_grid(study: PaperStudy | None = None, targets=("sphere", "aruco")) -> list[TrackingConfig]:
    """The runs the known-lens pipelines add: the distorted camera, each target, trajectory and
    mode, with the lens known and the best estimator (:meth:`PaperStudy.config` with ``best``);
    8 cells × replicates for both targets. Replicates share the study's draws (same seeds)."""
    study = study or PaperStudy()
    for target in targets:
        if target not in ("sphere", "aruco"):
            raise ValueError(f"targets must be 'sphere' or 'aruco', got {target!r}")
    return [study.config(target, "distorted", traj, mode, seed, best=True)
            for target in targets for traj in TRAJECTORIES for mode in MODES for seed in study.seeds]


def all_configs(study: PaperStudy | None = None) -> list[TrackingConfig]:
    """Every run of the study: the 16-cell grid and the known-lens pipelines' runs."""
    return grid(study) + pipeline_grid(study)


def is_study_run(config: TrackingConfig) -> bool:
    """Whether a run belongs to the paper's 16-cell grid (the lens ignored), not to a known-lens
    pipeline of :func:`pipeline_grid`."""
    return config.estimator.lens_strategy == "ignore"


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _identity(c: TrackingConfig) -> dict:
    return {"target": c.target.kind, "distortion": c.camera.lens_label, "trajectory": c.target.trajectory,
            "mode": c.pointing.mode, "outer_loop": c.pointing.kind if c.pointing.active else "none",
            "lens_strategy": c.estimator.lens_strategy}


def _methods(c: TrackingConfig) -> list[tuple[str, str]]:
    method = c.estimator.sphere_method
    if c.target.kind == "sphere":
        other = "ellipse" if method == "circle" else "circle"
        return [(method, ""), (other, "alt_")]
    return [(f"aruco-{c.estimator.aruco_refinement}", "")]


def _measured(frames: pd.DataFrame) -> pd.DataFrame:
    """The measured frames of a run: every revolution after the first (acquisition, reported apart)."""
    return frames[frames["revolution"] >= 1]


def _time_to_centre(f: pd.DataFrame, threshold_px: float) -> float:
    inside = f.index[f["offset_px"] < threshold_px]
    return float(f.loc[inside[0], "t_mid_s"]) if len(inside) else math.nan


def _replicate_rows(result) -> list[dict]:
    c = result.config
    f = result.frames
    measured, acquiring = _measured(f), f[f["revolution"] == 0]
    threshold = CENTRED_FRACTION * c.camera.width
    rows = []
    for method, p in _methods(c):
        det = measured[measured[f"{p}detected"]]
        acq = acquiring[acquiring[f"{p}detected"]]
        row = {**_identity(c), "method": method, "seed": c.seed, "start_phase_s": c.target.start_phase_s,
               "frames": len(measured),
               "detection_rate": float(measured[f"{p}detected"].mean()) if len(measured) else math.nan,
               "mean_abs_error_m": float(det[f"{p}abs_error_m"].mean()) if len(det) else math.nan,
               "mean_error_m": float(det[f"{p}error_m"].mean()) if len(det) else math.nan,
               "std_error_m": float(det[f"{p}abs_error_m"].std(ddof=1)) if len(det) > 1 else math.nan,
               "mean_offset_px": float(det["offset_px"].mean()) if len(det) else math.nan}
        for axis in "xyz":
            row[f"mean_abs_err_{axis}_m"] = float((det[f"{p}est_{axis}_m"] - det[f"true_{axis}_m"]).abs().mean())
        for axis in "xyz":
            row[f"mean_abs_err_cam_{axis}_m"] = float(
                (det[f"{p}est_cam_{axis}_m"] - det[f"true_cam_{axis}_m"]).abs().mean())
        row["acq_mean_abs_error_m"] = float(acq[f"{p}abs_error_m"].mean()) if len(acq) else math.nan
        row["acq_detection_rate"] = float(acquiring[f"{p}detected"].mean()) if len(acquiring) else math.nan
        row["time_to_centre_s"] = _time_to_centre(acquiring, threshold) if c.pointing.active else math.nan
        rows.append(row)
    return rows


def replicate_table(results) -> pd.DataFrame:
    """One row per run and localiser: the replicate's means over its measured revolutions.

    Columns: target, distortion, trajectory, mode, outer_loop, lens_strategy, method, seed, start_phase_s,
    frames, detection_rate, mean_abs_error_m, mean_error_m (signed bias), std_error_m,
    mean_offset_px, mean_abs_err_{x,y,z}_m (world), mean_abs_err_cam_{x,y,z}_m (camera; z is
    depth), and the acquisition revolution's acq_mean_abs_error_m, acq_detection_rate and
    time_to_centre_s (active runs: first instant the target is within :data:`CENTRED_FRACTION`
    of the image width of the centre).

    A sphere run gives a row per localiser (circle and the exact ellipse on the same frames).
    """
    return pd.DataFrame([row for r in results for row in _replicate_rows(r)])


_CELL = ["target", "distortion", "trajectory", "mode", "outer_loop", "lens_strategy", "method"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell and localiser: replicate count, the mean of each replicate quantity and the 95 %
    t-interval of the mean error (``mean_abs_error_m``, ``ci_low_m``, ``ci_high_m``)."""
    rows = []
    cell = [c for c in _CELL if c in replicates]
    for key, g in replicates.groupby(cell, sort=False):
        mean, low, high = stats.mean_interval(g["mean_abs_error_m"])
        row = dict(zip(cell, key))
        row.update(replicates=len(g), mean_abs_error_m=mean, ci_low_m=low, ci_high_m=high)
        for col in ("mean_error_m", "std_error_m", "detection_rate", "mean_offset_px",
                    "mean_abs_err_x_m", "mean_abs_err_y_m", "mean_abs_err_z_m",
                    "mean_abs_err_cam_x_m", "mean_abs_err_cam_y_m", "mean_abs_err_cam_z_m",
                    "acq_mean_abs_error_m", "time_to_centre_s"):
            row[col] = float(g[col].mean())
        row["between_replicate_std_m"] = float(g["mean_abs_error_m"].std(ddof=1)) if len(g) > 1 else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def frames_table(results) -> pd.DataFrame:
    """Every frame of every run, with the run's identifying columns in front."""
    parts = []
    for r in results:
        f = r.frames.copy()
        ident = {**_identity(r.config), "method": _methods(r.config)[0][0], "seed": r.config.seed,
                 "start_phase_s": r.config.target.start_phase_s}
        for i, (k, v) in enumerate(ident.items()):
            f.insert(i, k, v)
        parts.append(f)
    return pd.concat(parts, ignore_index=True)


# ----------------------------------------------------------------------------------------------
# pipelines: the paper's active, the best active and the best passive
# ----------------------------------------------------------------------------------------------
def _exact_prefix(c: TrackingConfig) -> str:
    """The columns holding a run's best estimate: the sphere's exact cone fit ("alt_" beside the
    circle method), otherwise the run's own."""
    return "alt_" if c.target.kind == "sphere" and c.estimator.sphere_method == "circle" else ""


def _pipelines_of(c: TrackingConfig) -> list[tuple[str, str]]:
    """(pipeline, column prefix) of each pipeline a run provides (docs/design.md, "Pipelines compared")."""
    if c.pointing.active and c.pointing.kind != "paper":
        return []  # the pipelines compare the paper's loop (an extension's loop is no pipeline of them)
    active = c.pointing.active
    if is_study_run(c):
        paper_estimator = c.target.kind == "aruco" or c.estimator.sphere_method == "circle"
        out = [("active (paper)", "")] if active and paper_estimator else []
        if c.camera.lens_model is None:  # no lens: "lens known" changes nothing, the best estimator alone differs
            out.append(("active (best)" if active else "best passive", _exact_prefix(c)))
        return out
    known = c.estimator.lens_strategy == "undistort"
    best = known and (c.target.kind == "aruco" or c.estimator.sphere_method == "ellipse")
    return [("active (best)" if active else "best passive", "")] if best else []


def pipeline_table(results) -> pd.DataFrame:
    """The three pipelines per target, distortion, trajectory and replicate, on common frames.

    Each pipeline is read from the run that has it (:func:`pipeline_grid`'s runs for the distorted
    camera's known-lens pipelines; the study's runs, with the sphere's exact fit in ``alt_*``,
    for the rest). A condition and replicate enter the table only when all three pipelines of it
    are among ``results``.

    Returns
    -------
    DataFrame
        One row per condition, pipeline and seed: target, distortion, trajectory, pipeline
        (:data:`PIPELINES`), seed, frames (measured), detection_rate and mean_abs_error_m (its own
        detections), common_rate and common_abs_error_m (the measured frames where all three
        pipelines of the condition and seed detected and localised the target; NaN when there is
        none), mean_offset_px. Means over the measured revolutions only: the acquisition
        revolution never counts.
    """
    groups: dict[tuple, dict] = {}
    for r in results:
        c = r.config
        key = (c.target.kind, c.camera.lens_label, c.target.trajectory, c.seed)
        for pipeline, prefix in _pipelines_of(c):
            if pipeline in groups.setdefault(key, {}):
                raise ValueError(f"{'/'.join(map(str, key))} has two runs for pipeline {pipeline!r} "
                                 "(outer loops mixed?)")
            groups[key][pipeline] = (r, prefix)
    rows = []
    for (target, distortion, trajectory, seed), members in groups.items():
        if set(members) != set(PIPELINES):
            continue
        measured = {p: _measured(r.frames) for p, (r, _) in members.items()}
        if len({tuple(f["frame"]) for f in measured.values()}) != 1:
            raise ValueError(f"{target}/{distortion}/{trajectory}, seed {seed}: the pipelines' runs have different "
                             "measured frames")
        detected = {p: measured[p][f"{members[p][1]}detected"].to_numpy(bool) for p in PIPELINES}
        common = np.logical_and.reduce([detected[p] for p in PIPELINES])
        for p in PIPELINES:
            f, prefix = measured[p], members[p][1]
            error = f[f"{prefix}abs_error_m"].to_numpy(float)
            own = detected[p]
            rows.append({"target": target, "distortion": distortion, "trajectory": trajectory, "pipeline": p,
                         "seed": seed, "frames": len(f),
                         "detection_rate": float(own.mean()) if len(f) else math.nan,
                         "mean_abs_error_m": float(error[own].mean()) if own.any() else math.nan,
                         "common_rate": float(common.mean()) if len(f) else math.nan,
                         "common_abs_error_m": float(error[common].mean()) if common.any() else math.nan,
                         "mean_offset_px": float(f["offset_px"].to_numpy(float)[own].mean()) if own.any() else math.nan})
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    order = {name: i for i, name in enumerate(("sphere", "aruco") + DISTORTIONS + TRAJECTORIES + PIPELINES)}
    return table.sort_values(["target", "distortion", "trajectory", "pipeline", "seed"],
                             key=lambda s: s.map(order) if s.name != "seed" else s, ignore_index=True)


_PIPELINE_CONDITION = ["target", "distortion", "trajectory", "pipeline"]


def pipeline_summary(pipelines: pd.DataFrame, costs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per condition and pipeline: replicates, the mean common-frame error with its 95 % t-interval
    (``common_abs_error_m``, ``ci_low_m``, ``ci_high_m``), the rates, and the CPU cost per frame
    (``cost_ms``, from :func:`pipeline_costs`) when ``costs`` are given."""
    rows = []
    for key, g in pipelines.groupby(_PIPELINE_CONDITION, sort=False):
        mean, low, high = stats.mean_interval(g["common_abs_error_m"])
        row = dict(zip(_PIPELINE_CONDITION, key))
        row.update(replicates=len(g), common_abs_error_m=mean, ci_low_m=low, ci_high_m=high,
                   common_rate=float(g["common_rate"].mean()), detection_rate=float(g["detection_rate"].mean()),
                   mean_abs_error_m=float(g["mean_abs_error_m"].mean()))
        rows.append(row)
    out = pd.DataFrame(rows)
    if costs is not None and len(out):
        out = out.merge(costs[_PIPELINE_CONDITION + ["cost_ms"]], on=_PIPELINE_CONDITION, how="left")
    return out


def _pipeline_estimator(c: TrackingConfig, pipeline: str) -> Estimator:
    """The estimator of ``pipeline`` for the camera and target of the study's run ``c``."""
    if pipeline == "active (paper)":
        return Estimator(sphere_method="circle", lens_strategy="ignore", aruco_refinement=c.estimator.aruco_refinement)
    return Estimator(sphere_method="ellipse", lens_strategy="undistort" if c.camera.lens_model is not None else "ignore",
                     aruco_refinement=c.estimator.aruco_refinement)


def pipeline_costs(results, repeats: int | None = None, every: int = 1, progress: bool = False) -> pd.DataFrame:
    """CPU cost per frame of each pipeline's detection and localisation, measured apart from the runs.

    Per target, distortion and trajectory, the frames are the measured revolution of the first
    replicate's passive and active runs of the paper's grid (every ``every``-th frame of it; the
    study times them all), rendered again exactly as the runs saw them
    (:func:`gimbal_lab.studies._params.run_frames`); every pipeline's estimator (the detector and
    its one localiser, :meth:`gimbal_lab.config.Estimator.build` without the alternative) is timed
    on those same frames with :func:`time.process_time`, the least of ``repeats`` passes
    (:func:`gimbal_lab.studies._params.cpu_seconds_per_frame`; 5 by default). "active (best)" and
    "best passive" run the same estimator, so one measurement gives both. ``progress``: a bar over
    the conditions.

    Returns
    -------
    DataFrame
        target, distortion, trajectory, pipeline, estimator (what it runs), frames (timed), cost_ms.
    """
    from ..simulation import make_renderer
    from ._params import COST_REPEATS, cpu_seconds_per_frame, run_frames

    repeats = COST_REPEATS if repeats is None else repeats
    every = _number("every", every, low=1, high=10_000, integer=True)
    first: dict[tuple, dict] = {}
    for r in sorted((r for r in results if is_study_run(r.config)), key=lambda r: r.config.seed):
        c = r.config
        runs = first.setdefault((c.target.kind, c.camera.lens_label, c.target.trajectory), {})
        if not runs or next(iter(runs.values())).config.seed == c.seed:
            runs.setdefault(c.pointing.mode, r)
    order = {name: i for i, name in enumerate(("sphere", "aruco") + DISTORTIONS + TRAJECTORIES)}
    rows = []
    keys = sorted(first, key=lambda k: [order[x] for x in k])
    if progress:
        from tqdm.auto import tqdm

        keys = tqdm(keys, desc="CPU cost per frame", unit="condition", dynamic_ncols=True)
    for key in keys:
        runs = [first[key][m] for m in MODES if m in first[key]]
        c = runs[0].config
        renderer = make_renderer(c)
        try:
            images = [image for r in runs
                      for image in run_frames(r, int(round(r.config.frames_per_revolution)), r.config.n_frames,
                                              renderer=renderer, every=every)]
        finally:
            renderer.close()
        seconds: dict = {}
        for pipeline in PIPELINES:
            est = _pipeline_estimator(c, pipeline)
            if est not in seconds:
                seconds[est] = cpu_seconds_per_frame(est.build(c.camera, c.target, alt=False), images, repeats)
            what = (("circle method" if est.sphere_method == "circle" else "exact cone fit") if c.target.kind == "sphere"
                    else f"PnP on {est.aruco_refinement} corners")
            lens = "lens undistorted" if est.lens_strategy == "undistort" else "no lens model"
            rows.append({"target": key[0], "distortion": key[1], "trajectory": key[2], "pipeline": pipeline,
                         "estimator": f"{what}, {lens}", "frames": len(images), "cost_ms": 1000.0 * seconds[est]})
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# claims
# ----------------------------------------------------------------------------------------------
class _Cells:
    """Per-replicate values of one column for one cell, aligned on seed."""

    def __init__(self, replicates: pd.DataFrame, sphere_method: str, aruco_method: str):
        self.r = replicates
        self.methods = {"sphere": sphere_method, "aruco": aruco_method}
        self.seeds = None

    def __call__(self, target, dist, traj, mode, column="mean_abs_error_m") -> pd.Series:
        r = self.r
        sel = r[(r["target"] == target) & (r["distortion"] == dist) & (r["trajectory"] == traj)
                & (r["mode"] == mode) & (r["method"] == self.methods[target])]
        if "lens_strategy" in sel:  # the paper's grid ignores the lens; a known-lens pipeline is no cell of it
            sel = sel[sel["lens_strategy"] == "ignore"]
        if sel.empty:
            raise ValueError(f"the replicate table has no rows for {target}/{dist}/{traj}/{mode} "
                             f"({self.methods[target]})")
        if sel["seed"].duplicated().any():
            raise ValueError(f"{target}/{dist}/{traj}/{mode} holds a seed twice: mix of runs (outer loops?)")
        s = sel.set_index("seed")[column].sort_index()
        if self.seeds is None:
            self.seeds = list(s.index)
        elif list(s.index) != self.seeds:
            raise ValueError(f"{target}/{dist}/{traj}/{mode} has seeds {list(s.index)}, other cells {self.seeds}: "
                             "claims pair replicates by seed")
        return s


def check_claims(replicates: pd.DataFrame, pipelines: pd.DataFrame | None = None, sphere_method: str = "circle",
                 aruco_method: str = "aruco-subpix") -> pd.DataFrame:
    """Every claim of paper §4.1.1–4.1.2, and the strongest passive baseline's, with its three-way
    verdict at 95 % and at the family level, and the numbers behind it.

    Parameters
    ----------
    replicates : DataFrame
        :func:`replicate_table` of the grid (one outer loop), or of one target's half (the claims
        of a target without rows are skipped; A1 compares the two targets and needs both). Rows
        of known-lens pipelines (``lens_strategy`` other than "ignore") are no cells of the grid
        and are left aside.
    pipelines : DataFrame or None
        :func:`pipeline_table`: adds BP1 "active (paper) < best passive" and BP2 "active (best)
        < best passive" for each of its conditions (target, distortion, trajectory), on the
        common-frame errors; a replicate without common frames leaves its pair out.
    sphere_method, aruco_method : str
        The localiser whose rows the claims use (the paper's: circle; the study's refinement).

    Returns
    -------
    DataFrame
        One row per checked condition: id, section, statement, condition, a, b (what is compared,
        claim "a < b" or "a ≈ b"), the :class:`gimbal_lab.stats.Verdict` fields (verdict, kind,
        mean_a, mean_b, difference, low, high, delta, n, confidence, p_value) and, from
        :func:`gimbal_lab.stats.holm` over the whole table (one family, docs/design.md
        "Multiplicity"), p_holm and verdict_holm. Metres.
    """
    targets = set(replicates["target"])
    if not targets & {"sphere", "aruco"}:
        raise ValueError("the replicate table holds no sphere or aruco runs")
    m = _Cells(replicates, sphere_method, aruco_method)
    rows = []

    def add(cid, section, statement, condition, a_label, b_label, a, b, kind="less", drop_missing=False):
        a, b = np.asarray(a, float), np.asarray(b, float)
        result = (stats.less_than(a, b, drop_missing=drop_missing) if kind == "less" else stats.equivalent(a, b))
        rows.append(dict(id=cid, section=section, statement=statement, condition=condition, a=a_label, b=b_label,
                         result=result))

    if "sphere" in targets:
        _sphere_claims(m, add)
    if "aruco" in targets:
        _aruco_claims(m, add, with_sphere="sphere" in targets)
    if pipelines is not None and len(pipelines):
        _baseline_claims(pipelines, add)
    return stats.holm(stats.verdict_table(rows))


def _sphere_claims(m, add):
    for d in DISTORTIONS:
        for t in TRAJECTORIES:
            add("S1", "4.1.1", "sphere: active error < passive error", f"{d}, {t}", "active", "passive",
                m("sphere", d, t, "active"), m("sphere", d, t, "passive"))
    for d in DISTORTIONS:
        gap = {t: (m("sphere", d, t, "passive") - m("sphere", d, t, "active")).abs() for t in TRAJECTORIES}
        add("S2", "4.1.1", "sphere: the passive−active gap is smaller on the diagonal", d,
            "|gap| diagonal", "|gap| circular", gap["diagonal"], gap["circular"])
    for t in TRAJECTORIES:
        for mode in MODES:
            add("S3", "4.1.1", "sphere: distortion raises the error", f"{t}, {mode}", "undistorted", "distorted",
                m("sphere", "undistorted", t, mode), m("sphere", "distorted", t, mode))
    for mode in MODES:
        add("S4", "4.1.1", "sphere: distorted diagonal error < distorted circular error", mode,
            "diagonal", "circular", m("sphere", "distorted", "diagonal", mode), m("sphere", "distorted", "circular", mode))
    for mode in MODES:
        ex, ey, ez = (m("sphere", "undistorted", "circular", mode, f"mean_abs_err_cam_{a}_m") for a in "xyz")
        add("S5", "4.1.1", "sphere: the error lies mostly in depth (camera z)", f"undistorted, circular, {mode}",
            "max(|err x|, |err y|)", "|err depth|", np.maximum(ex, ey), ez)


def _aruco_claims(m, add, with_sphere):
    if with_sphere:
        und = [m("aruco", "undistorted", t, md) for t in TRAJECTORIES for md in MODES]
        others = [m(g, d, t, md) for g in ("sphere", "aruco") for d in DISTORTIONS for t in TRAJECTORIES
                  for md in MODES if not (g == "aruco" and d == "undistorted")]
        add("A1", "4.1.2", "ArUco undistorted is the most accurate of all runs", "all 16 cells",
            "worst ArUco undistorted", "best other cell", np.max(und, axis=0), np.min(others, axis=0))
    for t in TRAJECTORIES:
        add("A2", "4.1.2", "ArUco undistorted: active ≈ passive", t, "active", "passive",
            m("aruco", "undistorted", t, "active"), m("aruco", "undistorted", t, "passive"), kind="equivalent")
    for t in TRAJECTORIES:
        for mode in MODES:
            add("A3", "4.1.2", "ArUco: distortion raises the error", f"{t}, {mode}", "undistorted", "distorted",
                m("aruco", "undistorted", t, mode), m("aruco", "distorted", t, mode))
    for t in TRAJECTORIES:
        add("A4", "4.1.2", "ArUco distorted: active error < passive error", t, "active", "passive",
            m("aruco", "distorted", t, "active"), m("aruco", "distorted", t, "passive"))
    for mode in MODES:
        add("A5", "4.1.2", "ArUco: distorted diagonal error < distorted circular error", mode, "diagonal", "circular",
            m("aruco", "distorted", "diagonal", mode), m("aruco", "distorted", "circular", mode))
    # The paper's Fig. 14 "x and y" are the coordinates across the line of sight; in this lab's
    # world the home optical axis is +x, so the lateral coordinates are world y and z.
    for axis in "yz":
        add("A6", "4.1.2", f"ArUco: active tracking adds lateral error (world {axis})",
            f"distorted, diagonal, world {axis}", f"passive, world {axis}", f"active, world {axis}",
            m("aruco", "distorted", "diagonal", "passive", f"mean_abs_err_{axis}_m"),
            m("aruco", "distorted", "diagonal", "active", f"mean_abs_err_{axis}_m"))
    for mode in MODES:
        add("A7", "4.1.2", "ArUco undistorted: circular error < diagonal error", mode, "circular", "diagonal",
            m("aruco", "undistorted", "circular", mode), m("aruco", "undistorted", "diagonal", mode))


def _baseline_claims(pipelines: pd.DataFrame, add):
    """BP1 and BP2 per condition of ``pipelines`` (docs/design.md, "New claims")."""
    missing = set(PIPELINES) - set(pipelines["pipeline"])
    if missing:
        raise ValueError(f"the pipeline table lacks pipeline(s) {sorted(missing)}")
    conditions = pipelines[["target", "distortion", "trajectory"]].drop_duplicates().itertuples(index=False)
    for target, distortion, trajectory in conditions:
        sel = pipelines[(pipelines["target"] == target) & (pipelines["distortion"] == distortion)
                        & (pipelines["trajectory"] == trajectory)]
        value = {}
        for p in PIPELINES:
            rows = sel[sel["pipeline"] == p]
            if rows["seed"].duplicated().any():
                raise ValueError(f"{target}/{distortion}/{trajectory}/{p} holds a seed twice")
            value[p] = rows.set_index("seed")["common_abs_error_m"]
        seeds = sorted(set().union(*(v.index for v in value.values())))
        value = {p: v.reindex(seeds).to_numpy(float) for p, v in value.items()}
        condition = f"{target}, {distortion}, {trajectory}"
        for cid, active in (("BP1", "active (paper)"), ("BP2", "active (best)")):
            add(cid, "new", f"{active} error < best passive error", condition, active, "best passive",
                value[active], value["best passive"], drop_missing=True)


def _mm(x: float) -> str:
    return f"{1000 * x:.2f}"


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a claim that holds)."""
    if row.verdict == stats.HOLDS:
        return ""
    if not math.isfinite(row.low):
        return (f"only {row.n} replicate(s) have frames that every compared pipeline detected: nothing to "
                "compare")
    if row.kind == "equivalent":
        if row.verdict == stats.DOES_NOT_HOLD:
            return (f"the difference {_mm(row.difference)} mm lies outside the ±{_mm(row.delta)} mm margin "
                    f"(95 % interval entirely beyond it)")
        return (f"the 90 % interval [{_mm(row.low)}, {_mm(row.high)}] mm is not inside the ±{_mm(row.delta)} mm "
                f"margin: the replicates cannot show equivalence")
    if row.verdict == stats.DOES_NOT_HOLD and row.low > 0:
        return (f"the opposite is measured: {row.a} exceeds {row.b} by {_mm(row.difference)} mm "
                f"(95 % interval [{_mm(row.low)}, {_mm(row.high)}] mm, all above 0)")
    if row.verdict == stats.DOES_NOT_HOLD:
        return (f"no effect worth the name: the whole interval [{_mm(row.low)}, {_mm(row.high)}] mm lies within "
                f"±δ = {_mm(row.delta)} mm")
    if row.high < 0:
        return (f"the difference {_mm(row.difference)} mm is real (interval below 0) but smaller than "
                f"δ = {_mm(row.delta)} mm")
    return (f"the interval [{_mm(row.low)}, {_mm(row.high)}] mm straddles 0 and reaches beyond ±δ = "
            f"{_mm(row.delta)} mm: more replicates could decide")


#: Measured mechanisms behind claims that fail in this lab, stated with the numbers they need
#: (filled from the replicate table by :func:`claims_markdown`).
def _context(claim_id: str, replicates: pd.DataFrame) -> str:
    r = replicates

    if "lens_strategy" in r:
        r = r[r["lens_strategy"] == "ignore"]

    def cell(target, dist, traj, mode, method):
        sel = r[(r.target == target) & (r.distortion == dist) & (r.trajectory == traj) & (r["mode"] == mode)
                & (r.method == method)]
        return 1000 * float(sel["mean_abs_error_m"].mean()) if len(sel) else math.nan

    if claim_id == "S3" and (r.method == "ellipse").any():
        return ("The circle method's geometric over-size off the axis (passive undistorted circular: circle "
                f"{cell('sphere', 'undistorted', 'circular', 'passive', 'circle'):.1f} mm, exact ellipse "
                f"{cell('sphere', 'undistorted', 'circular', 'passive', 'ellipse'):.1f} mm) is partly cancelled by "
                "the barrel lens shrinking the peripheral image; the exact method on the same distorted frames "
                f"shows the lens alone: {cell('sphere', 'distorted', 'circular', 'passive', 'ellipse'):.1f} mm.")
    if claim_id == "A1" and (r.target == "sphere").any():
        best = min(cell("sphere", d, t, "active", "circle") for d in DISTORTIONS for t in TRAJECTORIES)
        und = max(cell("aruco", "undistorted", t, md, "aruco-subpix") for t in TRAJECTORIES for md in MODES)
        return (f"The centred sphere ({best:.1f} mm at best) is localised better than the ~50 px marker "
                f"({und:.1f} mm at worst undistorted), whose range moves by millimetres per 0.1 px of corner error.")
    return ""


def claims_markdown(verdicts: pd.DataFrame, replicates: pd.DataFrame | None = None, study: PaperStudy | None = None,
                    pipelines: pd.DataFrame | None = None) -> str:
    """claims.md: what "active" means, each claim's verdict with interval, δ and p at 95 % and at the
    family level (Holm), a measured reason for every claim that does not hold or is inconclusive,
    and, with ``pipelines`` (:func:`pipeline_summary` with costs), each pipeline's error and CPU
    cost per frame. Table cells are escaped (:func:`gimbal_lab.studies._params.md_cell`)."""
    study = study or PaperStudy()
    loop = ("the paper's PI image loop with Ziegler–Nichols gains from the outer loop's own plant "
            "(integrator + vision delay)" if study.outer_loop == "paper"
            else "the predictive line-of-sight loop (an extension, not the paper's)")
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    has_holm = "verdict_holm" in verdicts
    lines = [
        "# Claims of paper §4.1, measured",
        "",
        f"**Active** means {loop}; **passive** holds the gimbal at its home pose. Each cell ran {n} replicates "
        f"of {study.revolutions:g} revolutions (the first is acquisition, reported apart); a replicate's mean "
        "error over its measured revolution(s) is one observation, and cells are compared pairwise by replicate.",
        "",
        "Beside the paper's pipeline, the strongest passive one (docs/design.md, \u201cWhen does a gimbal pay "
        "off?\u201d): **active (paper)** is the paper's loop with the lens ignored and the circle method (sphere) or "
        "PnP on the sub-pixel corners (marker); **active (best)** the same loop with the lens known and the best "
        "estimator (the exact cone fit; PnP on undistorted corners); **best passive** the passive camera with the "
        "lens known and the best estimator. BP1 and BP2 compare them on the measured frames all three detected.",
        "",
        verdict_rule("max(1 mm, 10 % of the smaller mean)", "For “a ≈ b”, two one-sided tests with a ±20 % "
                     "margin of the two means' average. Differences in mm. p: the p-value of the test that decides "
                     "the verdict; the family is every claim below, held to 5 % family-wise error by Holm's "
                     "step-down method (p (Holm), verdict (Holm))."),
        "",
    ]
    head = ["id", "§", "claim", "condition", "a", "b", "mean a", "mean b", "a − b [95 % CI]", "δ", "p", "verdict"]
    head += ["p (Holm)", "verdict (Holm)"] * has_holm
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in verdicts.itertuples():
        cells = [row.id, row.section, row.statement, row.condition, row.a, row.b, _mm(row.mean_a), _mm(row.mean_b),
                 f"{_mm(row.difference)} [{_mm(row.low)}, {_mm(row.high)}]", _mm(row.delta), format_p(row.p_value),
                 f"**{row.verdict}**"]
        if has_holm:
            cells += [format_p(row.p_holm), f"**{row.verdict_holm}**"]
        lines.append("| " + " | ".join(md_cell(c) for c in cells) + " |")
    lines += ["", verdict_counts(verdicts), "", "## Why the others do not hold", ""]
    failing = verdicts[verdicts["verdict"] != stats.HOLDS]
    if failing.empty:
        lines.append("Every checked condition holds.")
    for row in failing.itertuples():
        lines.append(f"- **{row.id}** ({row.condition}), {row.verdict}: {verdict_reason(row)}.")
    if replicates is not None:
        notes = [(cid, _context(cid, replicates)) for cid in dict.fromkeys(failing["id"])]
        notes = [(cid, text) for cid, text in notes if text]
        if notes:
            lines += ["", "Mechanisms measured in the same runs:", ""]
            lines += [f"- **{cid}**: {text}" for cid, text in notes]
    if has_holm:
        lines += holm_change_lines(verdicts)
    if pipelines is not None and len(pipelines):
        lines += ["", "## Each pipeline's error and cost", "",
                  "Error: the mean over replicates of each replicate's mean |d_est − d_true| on the measured frames "
                  "all three pipelines detected (95 % interval). Cost: CPU time of detection and localisation per "
                  "frame (`time.process_time`, one OpenCV thread), the least of 5 passes over the same re-rendered "
                  "frames for every pipeline (the first replicate's passive and active runs, measured revolution), "
                  "measured apart from the runs. active (best) and best passive run the same estimator.", ""]
        head = ["target", "distortion", "trajectory", "pipeline", "error [mm] [95 % CI]", "frames all detected",
                "CPU per frame [ms]"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for row in pipelines.itertuples():
            cost = f"{row.cost_ms:.3f}" if "cost_ms" in pipelines and math.isfinite(row.cost_ms) else "–"
            cells = [row.target, row.distortion, row.trajectory, row.pipeline,
                     f"{_mm(row.common_abs_error_m)} [{_mm(row.ci_low_m)}, {_mm(row.ci_high_m)}]",
                     f"{row.common_rate:.2f}", cost]
            lines.append("| " + " | ".join(md_cell(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# the whole study: run, tables, figures
# ----------------------------------------------------------------------------------------------
def make_report(results, study: PaperStudy, costs: pd.DataFrame | None = None, store=None,
                progress: bool = False) -> _report.Report:
    """The study's report (:class:`gimbal_lab.studies.report.Report`): its tables, claims and figures.

    ``results`` are the grid's runs and the known-lens pipelines' (:func:`pipeline_grid`); the
    paper's tables and claims use the grid's, the pipeline table all of them. ``costs``: the
    pipelines' CPU costs (:func:`pipeline_costs`), measured here when not given, once per set of
    runs when ``store`` is given (:func:`gimbal_lab.studies.report.measured_once`).

    Files: ``summary.csv`` (per cell), ``replicates.parquet`` and ``.csv`` (per replicate),
    ``frames.parquet`` (every frame), ``pipelines.csv`` (per pipeline and replicate),
    ``pipeline_summary.csv`` (per pipeline, with its cost), ``verdicts.csv``, ``claims.md``,
    ``study.json`` and ``figures/`` (Figs. 10–14, the pipelines' error against their cost, and the
    forest plot of the claims, as PNG and SVG).
    """
    from .. import plotting
    from ._params import COST_REPEATS

    study_results = [r for r in results if is_study_run(r.config)]
    replicates = replicate_table(study_results)
    summary = summary_table(replicates)
    pipelines = pipeline_table(results)
    if costs is None:
        costs = _report.measured_once(store, study_results, f"CPU time per frame of the paper's pipelines (least of "
                                      f"{COST_REPEATS} passes)", lambda: pipeline_costs(study_results, progress=progress),
                                      progress)
    pipelines_summary = pipeline_summary(pipelines, costs) if len(pipelines) else pd.DataFrame()
    verdicts = check_claims(replicates, pipelines)
    figures = [("fig10_trajectories", lambda: plotting.study.plot_trajectories(study.period_s))]
    for target, name in (("sphere", "fig11_sphere_error"), ("aruco", "fig13_aruco_error")):
        if (summary["target"] == target).any():
            figures.append((name, lambda target=target: plotting.study.plot_error_bars(summary, target)))
    first = study.seeds[0]
    for (target, dist, traj), name in ((("sphere", "undistorted", "circular"), "fig12_sphere_xyz"),
                                       (("aruco", "distorted", "diagonal"), "fig14_aruco_xyz")):
        for r in study_results:
            c = r.config
            if (c.target.kind, c.camera.lens_label, c.target.trajectory, c.seed) == (target, dist, traj, first):
                figures.append((f"{name}_{c.pointing.mode}", lambda r=r: plotting.study.plot_xyz(r, revolution=1)))
    if len(pipelines_summary):
        figures.append(("pipelines_error_vs_cost", lambda: plotting.study.plot_pipeline_costs(pipelines_summary)))
    return _report.Report(NAME, study, len(results), [
        ("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
        ("frames.parquet", frames_table(results)), ("pipelines.csv", pipelines),
        ("pipeline_summary.csv", pipelines_summary), ("verdicts.csv", verdicts),
        ("claims.md", claims_markdown(verdicts, replicates, study, pipelines_summary)),
    ], figures, verdicts, forest="claims_forest")


#: The cell each target's clip shows (the first replicate): the lens and the circle, where the
#: passive camera sees the target wander furthest off-centre.
CLIP_CELL = ("distorted", "circular")


def write_clips(folder, results, study: PaperStudy, progress: bool = False, previous=None) -> list[Path]:
    """Write ``folder/clips/<target>.mp4``: the :data:`CLIP_CELL` runs of the first replicate,
    passive left and active right, as :func:`gimbal_lab.show.side_by_side` draws them, each with
    a ``<target>.json`` naming its runs. A clip of the report in ``previous`` (an earlier
    ``folder``) whose runs are unchanged is copied, not rendered again
    (:func:`gimbal_lab.studies._clips.write_or_reuse_clip`)."""
    from ..show import side_by_side
    from ._clips import write_or_reuse_clip

    written = []
    first = study.seeds[0]
    for target in ("sphere", "aruco"):
        pair = {r.config.pointing.mode: r for r in results if is_study_run(r.config)
                and (r.config.target.kind, r.config.camera.lens_label, r.config.target.trajectory, r.config.seed)
                == (target, *CLIP_CELL, first)}
        if set(pair) != {"passive", "active"}:
            continue

        def frames(pair=pair, target=target):
            frames = side_by_side(pair["passive"], pair["active"])
            if progress:
                from tqdm.auto import tqdm

                frames = tqdm(frames, total=pair["passive"].config.n_frames, desc=f"{target} clip", unit="frame")
            return frames

        name = Path("clips") / f"{target}.mp4"
        written += write_or_reuse_clip(Path(folder) / name, (pair["passive"], pair["active"]),
                                       pair["passive"].config.camera.fps, frames,
                                       previous=None if previous is None else Path(previous) / name,
                                       progress=progress)
    return written


def run_study(study: PaperStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid and the known-lens pipelines' runs (reusing ``store``) and write the report to
    ``out/paper`` (:func:`gimbal_lab.studies.report.run_and_report`: only the report's own files
    are replaced).

    With ``clips``, also one MP4 per target of a cell's passive and active runs side by side
    (:func:`write_clips`). Returns a dict with the results, the folder, the paths written and
    the files of an earlier report kept (``kept``: the clips after ``clips=False``).
    """
    def report(results, study):
        return make_report(results, study, store=store, progress=progress)

    def add_clips(folder, results, study):  # a clip of the report there whose runs are unchanged is reused
        write_clips(folder, results, study, progress=progress, previous=Path(out) / NAME)

    return _report.run_and_report(NAME, "paper study", all_configs(study), report, study, out,
                                  store=store, executor=executor, jobs=jobs, progress=progress,
                                  extra=add_clips if clips else None)
