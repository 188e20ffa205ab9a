"""Occlusion and manoeuvres (docs/design.md): can a filter keep the gimbal pointing while the
target is hidden, and which filter for which motion? (paper §5: a Bayesian filter should keep
tracking through occlusion; its related work uses an IMM).

Occluders (:data:`OCCLUSIONS`): a vertical pole 0.15 m wide and a 0.6 m square panel, matte
grey boxes (:class:`gimbal_lab.scene.Occluder`). Each stands on the line from the home camera to
the lowest point of the paper's circle, its top edge level with the home camera's optical centre,
at the distance from the camera where the circle's target is hidden (the line of sight to its
centre blocked) for the stated time per revolution, seen from the home camera:
:func:`place_occluder` solves for that distance. A top edge at the camera's height can hide at
most the arc below that height, 0.97 s of the 2 s period, so the "1.0 s" panel hides that arc
and stands where it first does.

Targets (:data:`TARGETS`): the red sphere on the paper's circle, and on the manoeuvring path
(:class:`gimbal_lab.trajectories.ManoeuvringTarget`: 1 m/s legs joined by 5 m/s² coordinated
turns in a box around the circle's centre, its plan drawn from the replicate's seed). Outer loops
(:data:`LOOPS`): the paper's PI image loop, which holds the joints while the target is not
detected, and pointing driven by a constant-velocity, a constant-acceleration or an IMM filter on
the target's world position (:class:`gimbal_lab.tracking.FilterPointing`), coasting on the
filter's prediction through misses. Every run is active, sharp (no exposure) and undistorted.

Grid: 4 occlusions × 2 targets × 4 loops = 32 cells, each ``replicates`` times; replicate s draws
the circle's start phase, the manoeuvring plan and the sensor noise from seed s, shared by every
cell (paired). Each replicate runs ``revolutions`` periods; the first is acquisition.

Metrics per replicate (measured revolutions; an occlusion *episode* is a run of frames whose
target centre is hidden, wholly inside them, that ends before the run does):

* ``pointing_error_deg``: angle between the optical axis and the target's true direction, mean
  over every frame (hidden or not);
* ``hidden_pointing_deg``: the same while hidden;
* ``reappear_error_deg``: the angle on the first frame the target's centre is visible again;
* ``lost_pct``: episodes after which the target reappears outside the field of view (a track loss);
* ``reacquire_frames``: frames from the reappearance to the first detection (NaN if none before
  the next episode or the run's end);
* ``after_error_m``: distance error over the :data:`AFTER_FRAMES` frames after re-acquisition;
* ``visible_error_m``, ``visible_offset_px``: distance error and true image offset on frames where
  the whole outline is visible; ``detection_rate_pct``, ``partial_pct`` (detections with a cut
  silhouette), and ``filter_nees`` (mean NEES of the filter's prediction against the truth,
  χ²(3): 3 for a consistent filter) on visible and on hidden frames.

Hypotheses (docs/design.md, issue "Occlusion and manoeuvres"): **H1** a filter keeps the target in
view through a 1 s occlusion: on the 1.0 s panel, each filter's pointing error when the target
reappears is smaller than the paper loop's (which holds its last pose); **H2** the IMM beats CV
and CA on the manoeuvring target (pointing error over the run, per occlusion); **H2c** ... without
losing on the circle: the rows "CV < IMM" and "CA < IMM" on the circle, which the design's claim
needs *not* to hold.
"""

from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..evaluation import pointing_error_deg
from ..scene import Occluder, points_visible
from ..config import Camera, Pointing, Target, TrackingConfig, _choice, _number
from . import _params
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "OcclusionStudy", "Study", "OCCLUSIONS", "TARGETS", "LOOPS", "FILTERS", "AFTER_FRAMES", "ANGLE_FLOOR_DEG",
    "place_occluder", "hidden_time_s", "occluders_for", "grid", "episodes", "timeline_runs", "replicate_table", "summary_table",
    "check_hypotheses", "hypotheses_markdown", "write_report", "run_study", "example_view",
]

NAME = "occlusion"
DESCRIPTION = ("occlusion and manoeuvres: a pole and a panel hide the target 0.2–1 s per revolution; the paper's "
               "loop vs CV, CA and IMM filter-driven pointing on the circle and a manoeuvring target (32 cells)")

#: Occlusion conditions: name → (occluder, hidden time per revolution of the circle, s), or None.
OCCLUSIONS = {"none": None, "pole 0.2 s": ("pole", 0.2), "panel 0.5 s": ("panel", 0.5), "panel 1.0 s": ("panel", 1.0)}
#: Targets: name → the target's trajectory.
TARGETS = {"circle": "circular", "manoeuvring": "manoeuvring"}
#: Outer loops: name → the pointing.
LOOPS = {"paper": Pointing("paper"), "CV": Pointing("filter", "cv"), "CA": Pointing("filter", "ca"),
         "IMM": Pointing("filter", "imm")}
FILTERS = ("CV", "CA", "IMM")
#: Sizes of the occluders, m (docs/design.md): a square pole 0.15 m wide; a square panel 0.6 m
#: wide and high, 0.02 m thick.
POLE_WIDTH_M = 0.15
PANEL_SIZE_M = 0.6
PANEL_THICKNESS_M = 0.02
#: Frames after re-acquisition over which the distance error is averaged (0.5 s at 30 frames/s).
AFTER_FRAMES = 15
#: δ floor: a pointing difference under 0.2° (about 2 px at the study's 554 px focal length) is no
#: difference worth the name.
ANGLE_FLOOR_DEG = 0.2
#: Samples per period when measuring how long an occluder hides the circle's target.
_HIDDEN_SAMPLES = 4000


def _occluder(kind: str, distance_m: float, camera_m) -> Occluder:
    """The pole or panel ``distance_m`` ahead of the camera (along world x), top level with it."""
    top = float(camera_m[2])
    x = float(camera_m[0]) + distance_m
    if kind == "pole":
        return Occluder("pole", (x, 0.0, 0.5 * top), (POLE_WIDTH_M, POLE_WIDTH_M, top))
    return Occluder("panel", (x, 0.0, top - 0.5 * PANEL_SIZE_M), (PANEL_THICKNESS_M, PANEL_SIZE_M, PANEL_SIZE_M))


def hidden_time_s(occluder: Occluder, config: TrackingConfig | None = None) -> float:
    """How long per period the occluder hides the centre of the circle's target from the home camera, s."""
    config = config or TrackingConfig()
    period_s = config.target.period_s
    t = np.arange(_HIDDEN_SAMPLES) * (period_s / _HIDDEN_SAMPLES)
    hidden = ~points_visible([occluder], config.home_camera_m, config.path.position(t))
    return float(hidden.mean() * period_s)


@functools.lru_cache(maxsize=8)
def place_occluder(kind: str, hidden_s: float) -> Occluder:
    """The occluder of ``kind`` ("pole" or "panel") placed to hide the circle's target ``hidden_s``
    per revolution (the module's rule; at most what a top edge at the camera's height can hide).

    The hidden time falls as the occluder moves away from the camera; the distance is found by
    Brent's method between 0.3 m and 2.5 m (:func:`scipy.optimize.brentq`). When ``hidden_s``
    exceeds what the occluder can hide at 0.3 m, it is placed where it first hides that much,
    less 5 ms (the hidden time is flat nearer the camera).
    """
    from scipy.optimize import brentq

    _choice("kind", kind, ("pole", "panel"))
    hidden_s = _number("hidden_s", hidden_s, low=0.0, low_open=True)
    config = TrackingConfig()
    camera = config.home_camera_m
    hidden = lambda d: hidden_time_s(_occluder(kind, d, camera), config)  # noqa: E731
    near, far = 0.3, 2.5
    wanted = min(hidden_s, hidden(near) - 0.005)
    distance = brentq(lambda d: hidden(d) - wanted, near, far, xtol=1e-4)
    return _occluder(kind, distance, camera)


def occluders_for(occlusion: str) -> tuple[Occluder, ...]:
    """The occluders of one :data:`OCCLUSIONS` condition."""
    _choice("occlusion", occlusion, tuple(OCCLUSIONS))
    spec = OCCLUSIONS[occlusion]
    return () if spec is None else (place_occluder(*spec),)


@dataclass(frozen=True)
class OcclusionStudy(StudyParams):
    """Parameters of the occlusion study (defaults: docs/design.md; ``data/studies/occlusion.toml``).

    Parameters
    ----------
    replicates, first_seed, period_s, fps, latency_frames, noise_std :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`).
    revolutions : float
        Periods per replicate, >= 2 (the first is acquisition): 3, so that the circle's target is
        hidden twice in the measured part.
    """

    revolutions: float = 3.0  # the circle's target is hidden twice in the measured part

    _TABLE = NAME

    def __post_init__(self):
        self._check_replicates()
        object.__setattr__(self, "period_s", _number("period_s", self.period_s, low=0.0, low_open=True))
        self.config("panel 1.0 s", "manoeuvring", "IMM", self.first_seed)  # validates the rest, naming the field

    def config(self, occlusion: str, target: str, loop: str, seed: int) -> TrackingConfig:
        """The run of one cell and replicate."""
        _choice("target", target, tuple(TARGETS))
        _choice("loop", loop, tuple(LOOPS))
        return TrackingConfig(
            camera=Camera(fps=self.fps, latency_frames=self.latency_frames, noise_std=self.noise_std),
            target=Target(kind="sphere", trajectory=TARGETS[target], period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s), occluders=occluders_for(occlusion)),
            pointing=LOOPS[loop], revolutions=self.revolutions, seed=seed)


#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = OcclusionStudy


def grid(study: OcclusionStudy | None = None, occlusions=None, targets=None, loops=None) -> list[TrackingConfig]:
    """Every (cell, replicate) config: occlusion, target, loop, then replicates innermost."""
    study = study or OcclusionStudy()
    occlusions = tuple(OCCLUSIONS) if occlusions is None else tuple(occlusions)
    targets = tuple(TARGETS) if targets is None else tuple(targets)
    loops = tuple(LOOPS) if loops is None else tuple(loops)
    return [study.config(o, t, loop, seed) for o in occlusions for t in targets for loop in loops
            for seed in study.seeds]


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _names(config: TrackingConfig) -> tuple[str, str, str]:
    """(occlusion, target, loop) names of a config of the study."""
    occlusion = next((name for name in OCCLUSIONS if occluders_for(name) == config.target.occluders), None)
    target = next((name for name, traj in TARGETS.items() if traj == config.target.trajectory), None)
    loop = next((name for name, pointing in LOOPS.items() if pointing == config.pointing), None)
    if occlusion is None or target is None or loop is None:
        raise ValueError(f"the config {config.label} is not one of the occlusion study's")
    return occlusion, target, loop


def timeline_runs(results, target: str = "circle", occlusion: str = "panel 1.0 s", seed=None) -> dict:
    """Loop name → its run of one cell (``target``, ``occlusion``) and replicate (``seed``, default
    the lowest present): what :func:`gimbal_lab.plotting.occlusion.plot_occlusion_timelines` draws."""
    chosen = {}
    for r in results:
        o, t, loop = _names(r.config)
        if o == occlusion and t == target and (seed is None or r.config.seed == seed):
            if loop not in chosen or r.config.seed < chosen[loop].config.seed:
                chosen[loop] = r
    if not chosen:
        raise ValueError(f"no run of {target!r} with {occlusion!r}" + ("" if seed is None else f" and seed {seed}"))
    return chosen


def episodes(hidden, first: int = 0) -> list[tuple[int, int]]:
    """Occlusion episodes: (start, end) frame indices of each run of True in ``hidden`` that starts
    at or after ``first`` (after a visible frame) and ends before the sequence does; ``end`` is the
    first visible frame after it.

    Examples
    --------
    >>> episodes([False, True, True, False, False, True, False, True])
    [(1, 3), (5, 6)]
    """
    h = np.asarray(hidden, bool)
    edges = np.flatnonzero(np.diff(h.astype(np.int8)))
    starts = [i + 1 for i in edges if not h[i] and h[i + 1]]
    ends = [i + 1 for i in edges if h[i] and not h[i + 1]]
    return [(s, next(e for e in ends if e > s)) for s in starts if s >= first and any(e > s for e in ends)]


def _mean(values) -> float:
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(values.mean()) if values.size else math.nan


def _in_view(frames: pd.DataFrame, i: int, width: int, height: int) -> bool:
    row = frames.iloc[i]
    return bool(row["true_cam_z_m"] > 0 and 0 <= row["true_u_px"] <= width - 1 and 0 <= row["true_v_px"] <= height - 1)


def run_metrics(result) -> dict:
    """The metrics of one run (module docstring) over its measured revolutions."""
    c, f = result.config, result.frames
    first = int(round(c.frames_per_revolution))
    angle = pointing_error_deg(f)
    detected = f["detected"].to_numpy(bool)
    hidden = f["hidden"].to_numpy(bool)
    visible = f["visible_fraction"].to_numpy(float) >= 1.0
    measured = f["frame"].to_numpy() >= first
    found = episodes(hidden, first)
    starts = [s for s, _ in found] + [len(f)]
    hidden_angle, reappear, lost, reacquire, after = [], [], [], [], []
    for (s, e), next_start in zip(found, starts[1:]):
        hidden_angle.append(angle[s:e].mean())
        reappear.append(angle[e])
        lost.append(0.0 if _in_view(f, e, c.camera.width, c.camera.height) else 100.0)
        hits = np.flatnonzero(detected[e:next_start])
        if hits.size:
            k = e + int(hits[0])
            reacquire.append(float(hits[0]))
            window = slice(k, min(k + AFTER_FRAMES, len(f)))
            after.append(_mean(f["abs_error_m"].to_numpy(float)[window][detected[window]]))
        else:
            reacquire.append(math.nan)
    nees = f["filter_nees"].to_numpy(float)
    return {
        "episodes": len(found),
        "hidden_s": hidden[first:].sum() / c.camera.fps / ((len(f) - first) / c.frames_per_revolution),
        "pointing_error_deg": _mean(angle[measured]),
        "hidden_pointing_deg": _mean(hidden_angle),
        "reappear_error_deg": _mean(reappear),
        "lost_pct": _mean(lost),
        "reacquire_frames": _mean(reacquire),
        "after_error_m": _mean(after),
        "visible_error_m": _mean(f["abs_error_m"].to_numpy(float)[measured & visible & detected]),
        "visible_offset_px": _mean(f["true_offset_px"].to_numpy(float)[measured & visible]),
        "detection_rate_pct": 100.0 * _mean(detected[measured]),
        "partial_pct": 100.0 * _mean(f["partial"].to_numpy(bool)[measured & detected]) if detected[measured].any()
        else math.nan,
        "nees_visible": _mean(nees[measured & visible]),
        "nees_hidden": _mean(nees[measured & hidden]),
    }


_ORDER = {name: i for i, name in enumerate(tuple(OCCLUSIONS) + tuple(TARGETS) + tuple(LOOPS))}
_CELL = ["occlusion", "target", "loop"]


def replicate_table(results) -> pd.DataFrame:
    """One row per run: occlusion, target, loop, seed and :func:`run_metrics`."""
    rows = []
    for r in results:
        occlusion, target, loop = _names(r.config)
        rows.append({"occlusion": occlusion, "target": target, "loop": loop, "seed": r.config.seed, **run_metrics(r)})
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(_CELL + ["seed"], key=lambda s: s.map(_ORDER) if s.name != "seed" else s,
                             ignore_index=True)


_SUMMARY_COLUMNS = ("hidden_s", "hidden_pointing_deg", "reappear_error_deg", "lost_pct", "reacquire_frames",
                    "after_error_m", "visible_error_m", "visible_offset_px", "detection_rate_pct", "partial_pct",
                    "nees_visible", "nees_hidden")


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per cell: replicates, episodes, the mean of every replicate metric, and the 95 % t-interval of
    the pointing error (``ci_low_deg``, ``ci_high_deg``)."""
    rows = []
    for key, g in replicates.groupby(_CELL, sort=False):
        row = dict(zip(_CELL, key))
        row.update(replicates=len(g), episodes=int(g["episodes"].sum()))
        mean, low, high = stats.mean_interval(g["pointing_error_deg"].dropna())
        row.update(pointing_error_deg=mean, ci_low_deg=low, ci_high_deg=high)
        for col in _SUMMARY_COLUMNS:
            row[col] = _mean(g[col])
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _cell(replicates: pd.DataFrame, occlusion, target, loop, column) -> pd.Series:
    r = replicates
    sel = r[(r.occlusion == occlusion) & (r.target == target) & (r.loop == loop)]
    if sel.empty:
        raise ValueError(f"the replicate table has no rows for {occlusion}/{target}/{loop}")
    if sel["seed"].duplicated().any():
        raise ValueError(f"{occlusion}/{target}/{loop} holds a seed twice")
    return sel.set_index("seed")[column].sort_index()


_FLOORS = {"deg": ANGLE_FLOOR_DEG}


def check_hypotheses(replicates: pd.DataFrame) -> pd.DataFrame:
    """H1, H2 and H2c per condition, with three-way verdicts and the numbers behind them.

    Units: "deg" (pointing errors). A pair with a missing value (no episode measured) drops out;
    fewer than two pairs is "inconclusive". Cells absent from ``replicates`` are skipped.
    """
    rows = []
    has = lambda o, t, loop: bool(((replicates.occlusion == o) & (replicates.target == t)  # noqa: E731
                                   & (replicates.loop == loop)).any())

    def add(cid, statement, condition, a_label, b_label, a, b, unit):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         result=stats.less_than(a.to_numpy(), b.to_numpy(), floor=_FLOORS[unit], drop_missing=True)))

    value = lambda *cell: _cell(replicates, *cell)  # noqa: E731
    longest = "panel 1.0 s"
    for t in TARGETS:
        for loop in FILTERS:
            if has(longest, t, loop) and has(longest, t, "paper"):
                add("H1", "a filter keeps the target in view through a 1 s occlusion (error when it reappears)",
                    f"{t}, {longest}", loop, "paper", value(longest, t, loop, "reappear_error_deg"),
                    value(longest, t, "paper", "reappear_error_deg"), "deg")
    for o in OCCLUSIONS:
        for other in ("CV", "CA"):
            if has(o, "manoeuvring", "IMM") and has(o, "manoeuvring", other):
                add("H2", "the IMM beats CV and CA on the manoeuvring target (pointing error)", f"manoeuvring, {o}",
                    "IMM", other, value(o, "manoeuvring", "IMM", "pointing_error_deg"),
                    value(o, "manoeuvring", other, "pointing_error_deg"), "deg")
    for o in OCCLUSIONS:
        for other in ("CV", "CA"):
            if has(o, "circle", "IMM") and has(o, "circle", other):
                add("H2c", "the IMM loses to CV or CA on the circle (the design needs: does not hold)",
                    f"circle, {o}", other, "IMM", value(o, "circle", other, "pointing_error_deg"),
                    value(o, "circle", "IMM", "pointing_error_deg"), "deg")
    if not rows:
        raise ValueError("the replicate table holds none of the cells the hypotheses compare")
    return stats.verdict_table(rows)


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds)."""
    return _params.verdict_reason(row, "have an occlusion episode on both sides")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: OcclusionStudy | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval and δ, a count
    per hypothesis, a measured reason for each condition that does not hold, and the table per
    occlusion, target and loop."""
    study = study or OcclusionStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    hidden = ", ".join(f"{name} {hidden_time_s(occluders_for(name)[0]):.2f} s at "
                       f"{occluders_for(name)[0].centre_m[0] - TrackingConfig().home_camera_m[0]:.2f} m"
                       for name, spec in OCCLUSIONS.items() if spec is not None)
    lines = [
        "# Occlusion and manoeuvres: hypotheses H1, H2, H2c, measured",
        "",
        "A grey pole (0.15 m) or panel (0.6 m) stands between the home camera and the lowest point of the paper's "
        f"circle, hiding the circle's target per revolution as seen from the home camera: {hidden} ahead of the "
        "camera. Targets: the sphere on the circle and on a seeded manoeuvring path (1 m/s legs, 5 m/s² turns). "
        "Loops: the paper's PI image loop (holds while the target is lost) and pointing driven by a CV, CA or IMM "
        f"filter on the target's world position. Up to {n} replicates per cell of {study.revolutions:g} revolutions "
        "(the first is acquisition), paired by replicate.",
        "",
        _params.verdict_rule(f"max({ANGLE_FLOOR_DEG:g}°, 10 % of the smaller mean)", "H2c rows state the opposite of "
                             "the design's “without losing on the circle”: that part of the claim stands where they "
                             "do not hold."),
        "",
    ]
    lines += _params.verdict_lines(verdicts, verdict_reason, unit_in_list=True)
    if summary is not None and len(summary):
        lines += ["", "## Per occlusion, target and loop (measured revolutions, means over replicates)", "",
                  "| occlusion | target | loop | episodes | pointing ° [95 % CI] | hidden ° | reappear ° | lost % | "
                  "re-acquire frames | error after mm | visible error mm | detected % | NEES visible | NEES hidden |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in summary.itertuples():
            lines.append(
                f"| {row.occlusion} | {row.target} | {row.loop} | {row.episodes} | {row.pointing_error_deg:.2f} "
                f"[{row.ci_low_deg:.2f}, {row.ci_high_deg:.2f}] | {row.hidden_pointing_deg:.2f} | "
                f"{row.reappear_error_deg:.2f} | {row.lost_pct:.0f} | {row.reacquire_frames:.1f} | "
                f"{1000 * row.after_error_m:.1f} | {1000 * row.visible_error_m:.1f} | {row.detection_rate_pct:.0f} | "
                f"{row.nees_visible:.1f} | {row.nees_hidden:.1f} |")
    return "\n".join(lines).replace("| nan", "| –") + "\n"


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def example_view(occlusion: str, phase: float = 0.75, hfov_rad: float | None = None):
    """The home camera's frame (no noise) with the circle's target ``phase`` of a period in, behind
    the occlusion's occluder at its lowest point by default: ``(image, config)``."""
    from ..simulation import make_renderer
    from ..trajectories import target_pose

    config = OcclusionStudy(replicates=2).config(occlusion, "circle", "paper", 0)
    config = config.with_(target__start_phase_s=0.0, pointing=Pointing("stabilised"),
                          **({} if hfov_rad is None else {"camera__hfov_rad": hfov_rad}))
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = config.gimbal.kinematics.T_body_cam(np.zeros(3))[:3, :3]
    T_world_cam[:3, 3] = config.home_camera_m
    renderer = make_renderer(config)
    try:
        image = renderer.render(T_world_cam, target_pose(config.path, phase * config.target.period_s))
    finally:
        renderer.close()
    return image, config


def write_report(folder, results, study: OcclusionStudy) -> list[Path]:
    """Write the tables, hypotheses and figures into ``folder``; return the paths written.

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``verdicts.csv``, ``claims.md``,
    ``study.json`` and ``figures/`` (pointing error per loop and occlusion, the occlusion metrics,
    example timelines, the forest plot), PNG and SVG.
    """
    from .. import plotting

    def figures(save, results, summary):
        save(plotting.occlusion.plot_occlusion_metrics(summary), "occlusion_metrics")
        save(plotting.occlusion.plot_occlusion_timelines(timeline_runs(results)), "occlusion_timelines")

    return _params.write_study_report(folder, results, study, sys.modules[__name__], figures)


def run_study(study: OcclusionStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/occlusion`` atomically.

    ``clips`` is accepted for the command line's sake; this study writes figures, not clips.
    """
    return _params.run_and_report(NAME, "occlusion", grid(study), write_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
