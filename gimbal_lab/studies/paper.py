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
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..config import Camera, Estimator, Pointing, Target, TrackingConfig, seed_stream
from ._params import StudyParams, report_pyplot, verdict_rule, write_report_files

__all__ = [
    "PaperStudy",
    "grid",
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

    def config(self, target: str, distortion: str, trajectory: str, mode: str, seed: int) -> TrackingConfig:
        """The run of one cell and replicate."""
        if target not in ("sphere", "aruco"):
            raise ValueError(f"targets must be 'sphere' or 'aruco', got {target!r}")
        return TrackingConfig(
            camera=Camera(lens=_LENS[distortion], fps=self.fps, latency_frames=self.latency_frames,
                          noise_std=self.noise_std),
            target=Target(kind=target, trajectory=trajectory, period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s)),
            pointing=Pointing(self.outer_loop if mode == "active" else "stabilised"),
            estimator=Estimator(aruco_refinement=self.aruco_refinement),
            revolutions=self.revolutions, seed=seed)


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


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _identity(c: TrackingConfig) -> dict:
    return {"target": c.target.kind, "distortion": c.camera.lens_label, "trajectory": c.target.trajectory,
            "mode": c.pointing.mode, "outer_loop": c.pointing.kind if c.pointing.active else "none"}


def _methods(c: TrackingConfig) -> list[tuple[str, str]]:
    method = c.estimator.sphere_method
    if c.target.kind == "sphere":
        other = "ellipse" if method == "circle" else "circle"
        return [(method, ""), (other, "alt_")]
    return [(f"aruco-{c.estimator.aruco_refinement}", "")]


def _time_to_centre(f: pd.DataFrame, threshold_px: float) -> float:
    inside = f.index[f["offset_px"] < threshold_px]
    return float(f.loc[inside[0], "t_mid_s"]) if len(inside) else math.nan


def _replicate_rows(result) -> list[dict]:
    c = result.config
    f = result.frames
    measured, acquiring = f[f["revolution"] >= 1], f[f["revolution"] == 0]
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

    Columns: target, distortion, trajectory, mode, outer_loop, method, seed, start_phase_s,
    frames, detection_rate, mean_abs_error_m, mean_error_m (signed bias), std_error_m,
    mean_offset_px, mean_abs_err_{x,y,z}_m (world), mean_abs_err_cam_{x,y,z}_m (camera; z is
    depth), and the acquisition revolution's acq_mean_abs_error_m, acq_detection_rate and
    time_to_centre_s (active runs: first instant the target is within :data:`CENTRED_FRACTION`
    of the image width of the centre).

    A sphere run gives a row per localiser (circle and the exact ellipse on the same frames).
    """
    return pd.DataFrame([row for r in results for row in _replicate_rows(r)])


_CELL = ["target", "distortion", "trajectory", "mode", "outer_loop", "method"]


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell and localiser: replicate count, the mean of each replicate quantity and the 95 %
    t-interval of the mean error (``mean_abs_error_m``, ``ci_low_m``, ``ci_high_m``)."""
    rows = []
    for key, g in replicates.groupby(_CELL, sort=False):
        mean, low, high = stats.mean_interval(g["mean_abs_error_m"])
        row = dict(zip(_CELL, key))
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


def check_claims(replicates: pd.DataFrame, sphere_method: str = "circle", aruco_method: str = "aruco-subpix"
                 ) -> pd.DataFrame:
    """Every claim of paper §4.1.1–4.1.2 with its three-way verdict and the numbers behind it.

    Parameters
    ----------
    replicates : DataFrame
        :func:`replicate_table` of the grid (one outer loop), or of one target's half (the claims
        of a target without rows are skipped; A1 compares the two targets and needs both).
    sphere_method, aruco_method : str
        The localiser whose rows the claims use (the paper's: circle; the study's refinement).

    Returns
    -------
    DataFrame
        One row per checked condition: id, section, statement, condition, a, b (what is compared,
        claim "a < b" or "a ≈ b"), and the :class:`gimbal_lab.stats.Verdict` fields (verdict,
        kind, mean_a, mean_b, difference, low, high, delta, n, confidence). Metres.
    """
    targets = set(replicates["target"])
    if not targets & {"sphere", "aruco"}:
        raise ValueError("the replicate table holds no sphere or aruco runs")
    m = _Cells(replicates, sphere_method, aruco_method)
    rows = []

    def add(cid, section, statement, condition, a_label, b_label, a, b, kind="less"):
        a, b = np.asarray(a, float), np.asarray(b, float)
        result = stats.less_than(a, b) if kind == "less" else stats.equivalent(a, b)
        rows.append(dict(id=cid, section=section, statement=statement, condition=condition, a=a_label, b=b_label,
                         result=result))

    if "sphere" in targets:
        _sphere_claims(m, add)
    if "aruco" in targets:
        _aruco_claims(m, add, with_sphere="sphere" in targets)
    return stats.verdict_table(rows)


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
        add("A6", "4.1.2", f"ArUco: active tracking adds lateral error (world {axis})", "distorted, diagonal",
            "passive", "active", m("aruco", "distorted", "diagonal", "passive", f"mean_abs_err_{axis}_m"),
            m("aruco", "distorted", "diagonal", "active", f"mean_abs_err_{axis}_m"))


def _mm(x: float) -> str:
    return f"{1000 * x:.2f}"


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a claim that holds)."""
    if row.verdict == stats.HOLDS:
        return ""
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


def claims_markdown(verdicts: pd.DataFrame, replicates: pd.DataFrame | None = None, study: PaperStudy | None = None
                    ) -> str:
    """claims.md: what "active" means, each claim's verdict with interval and δ, and a measured
    reason for every claim that does not hold or is inconclusive."""
    study = study or PaperStudy()
    loop = ("the paper's PI image loop with Ziegler–Nichols gains from the outer loop's own plant "
            "(integrator + vision delay)" if study.outer_loop == "paper"
            else "the predictive line-of-sight loop (an extension, not the paper's)")
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    lines = [
        "# Claims of paper §4.1, measured",
        "",
        f"**Active** means {loop}; **passive** holds the gimbal at its home pose. Each cell ran {n} replicates "
        f"of {study.revolutions:g} revolutions (the first is acquisition, reported apart); a replicate's mean "
        "error over its measured revolution(s) is one observation, and cells are compared pairwise by replicate.",
        "",
        verdict_rule("max(1 mm, 10 % of the smaller mean)", "For “a ≈ b”, two one-sided tests with a ±20 % "
                     "margin of the two means' average. Differences in mm."),
        "",
        "| id | § | claim | condition | a | b | mean a | mean b | a − b [95 % CI] | δ | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in verdicts.itertuples():
        ci = f"{_mm(row.difference)} [{_mm(row.low)}, {_mm(row.high)}]"
        lines.append(f"| {row.id} | {row.section} | {row.statement} | {row.condition} | {row.a} | {row.b} | "
                     f"{_mm(row.mean_a)} | {_mm(row.mean_b)} | {ci} | {_mm(row.delta)} | **{row.verdict}** |")
    counts = verdicts["verdict"].value_counts()
    lines += ["", ", ".join(f"{counts.get(v, 0)} {v}" for v in stats.VERDICTS) + f" of {len(verdicts)} conditions.",
              "", "## Why the others do not hold", ""]
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
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# the whole study: run, tables, figures
# ----------------------------------------------------------------------------------------------
def write_report(folder, results, study: PaperStudy) -> list[Path]:
    """Write the study's tables, claims and figures into ``folder``; return the paths written.

    Files: ``summary.csv`` (per cell), ``replicates.parquet`` and ``.csv`` (per replicate),
    ``frames.parquet`` (every frame), ``verdicts.csv``, ``claims.md``, ``study.json`` and
    ``figures/`` (Figs. 10–14 and the forest plot of the claims, as PNG and SVG).
    """
    from .. import plotting

    plt = report_pyplot()
    folder = Path(folder)
    replicates = replicate_table(results)
    summary = summary_table(replicates)
    verdicts = check_claims(replicates)
    written = write_report_files(folder, (
        ("summary.csv", lambda p: summary.to_csv(p, index=False)),
        ("replicates.parquet", lambda p: replicates.to_parquet(p, index=False)),
        ("replicates.csv", lambda p: replicates.to_csv(p, index=False)),
        ("frames.parquet", lambda p: frames_table(results).to_parquet(p, index=False)),
        ("verdicts.csv", lambda p: verdicts.to_csv(p, index=False)),
        ("claims.md", lambda p: p.write_text(claims_markdown(verdicts, replicates, study))),
    ), NAME, study, len(results))

    figures = folder / "figures"
    save = lambda fig, name: written.extend(plotting.save_figure(fig, name, figures, formats=("png", "svg")))
    save(plotting.study.plot_trajectories(study.period_s).figure, "fig10_trajectories")
    for target, name in (("sphere", "fig11_sphere_error"), ("aruco", "fig13_aruco_error")):
        save(plotting.study.plot_error_bars(summary, target).figure, name)
    first = study.seeds[0]
    for (target, dist, traj), name in ((("sphere", "undistorted", "circular"), "fig12_sphere_xyz"),
                                       (("aruco", "distorted", "diagonal"), "fig14_aruco_xyz")):
        for r in results:
            c = r.config
            if (c.target.kind, c.camera.lens_label, c.target.trajectory, c.seed) == (target, dist, traj, first):
                save(plotting.study.plot_xyz(r, revolution=1), f"{name}_{c.pointing.mode}")
    save(plotting.study.plot_forest(verdicts).figure, "claims_forest")
    plt.close("all")
    return written


#: The cell each target's clip shows (the first replicate): the lens and the circle, where the
#: passive camera sees the target wander furthest off-centre.
CLIP_CELL = ("distorted", "circular")


def write_clips(folder, results, study: PaperStudy, progress: bool = False) -> list[Path]:
    """Write ``folder/clips/<target>.mp4``: the :data:`CLIP_CELL` runs of the first replicate,
    passive left and active right, as :func:`gimbal_lab.show.side_by_side` draws them."""
    from ..show import side_by_side, write_clip

    written = []
    first = study.seeds[0]
    for target in ("sphere", "aruco"):
        pair = {r.config.pointing.mode: r for r in results
                if (r.config.target.kind, r.config.camera.lens_label, r.config.target.trajectory, r.config.seed)
                == (target, *CLIP_CELL, first)}
        if set(pair) != {"passive", "active"}:
            continue
        frames = side_by_side(pair["passive"], pair["active"])
        if progress:
            from tqdm.auto import tqdm

            frames = tqdm(frames, total=pair["passive"].config.n_frames, desc=f"{target} clip", unit="frame")
        written.append(write_clip(Path(folder) / "clips" / f"{target}.mp4", frames,
                                  fps=pair["passive"].config.camera.fps))
    return written


def run_study(study: PaperStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/paper``
    (:func:`gimbal_lab.studies._params.run_and_report`: only the report's own files are replaced).

    With ``clips``, also one MP4 per target of a cell's passive and active runs side by side
    (:func:`write_clips`). Returns a dict with the results, the folder, the paths written and
    the files of an earlier report kept (``kept``: the clips after ``clips=False``).
    """
    from ._params import run_and_report

    def add_clips(folder, results, study):
        write_clips(folder, results, study, progress=progress)

    return run_and_report(NAME, "paper study", grid(study), write_report, study, out, store=store,
                          executor=executor, jobs=jobs, progress=progress, extra=add_clips if clips else None)
