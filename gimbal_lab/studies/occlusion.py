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
(:data:`LOOPS`): the paper's PI image loop, which repeats its last rate command while the target is
not detected for at most the filters' coasting time (:data:`gimbal_lab.tracking.FILTER_COAST_S`,
1.5 s), then holds the pose (docs/design.md, "When does a gimbal pay off?", Repairs: the blind
fallback); pointing driven by a constant-velocity, a constant-acceleration or an IMM filter on
the target's world position (:class:`gimbal_lab.tracking.FilterPointing`), coasting on the
filter's prediction through misses; and the best passive camera ("passive": the gimbal
stabilised at home, its distance from the exact cone fit, the ``alt_*`` columns). Every run is
sharp (no exposure) and undistorted.

Grid: 4 occlusions × 2 targets × 5 loops = 40 cells, each ``replicates`` times; replicate s draws
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
  χ²(3): 3 for a consistent filter) on visible and on hidden frames; ``nees_live`` and
  ``nees_live_frames``, its mean and count over the measured frames with a live track;
  ``exact_detection_rate_pct`` and ``exact_error_m``, the exact cone fit's rate and error on its
  own localisations.

Hypotheses (docs/design.md, issue "Occlusion and manoeuvres"): **H1** a filter keeps the target in
view through a 1 s occlusion: on the 1.0 s panel, each filter's pointing error when the target
reappears is smaller than the paper loop's (which coasts on its last command, then holds);
**H2** the IMM beats CV and CA on the manoeuvring target (pointing error over the run, per
occlusion); **H2c** ... and is at least as good as CV and CA on the circle (non-inferiority, margin
δ with the 0.2° floor); **NEES** each filter's NEES is consistent with χ²(3), per filter and target
(the 95 % interval of the replicates' means inside the band of an average of N χ²(3) values);
**BP1** "active (paper) < best passive" and **BP2** "active (best) < best passive" per occlusion
and target: the paper loop's circle method and its exact cone fit against the passive camera's
exact fit, distance error on the frames both localised (:func:`pipeline_table`). Every verdict of
the report is one family held to 5 % by Holm (:func:`gimbal_lab.stats.holm`).

The design's occlusion dose for the manoeuvring target (an occluder per seed on the line to the
target at the middle of the measured part, top edge at the camera's height) is not built: with the
target above the camera's height at that moment (seven of the ten seeds), no occluder whose top is
at the camera's height can stand on that line of sight. The manoeuvring target meets the circle's
occluders, and each run's realised hidden time is reported (``hidden_s``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..evaluation import pointing_error_deg
from ..config import Camera, Pointing, Target, TrackingConfig, _choice, _number
from ..scene import Occluder, points_visible
from ..tracking import FILTER_COAST_S
from . import _params
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "OcclusionStudy", "Study", "OCCLUSIONS", "TARGETS", "LOOPS", "FILTERS", "AFTER_FRAMES", "ANGLE_FLOOR_DEG",
    "PIPELINES", "BP_CLAIMS", "place_occluder", "hidden_time_s", "occluders_for", "grid", "episodes", "timeline_runs",
    "replicate_table", "pipeline_table", "summary_table", "nees_band", "check_hypotheses", "hypotheses_markdown",
    "write_report", "run_study", "example_view",
]

NAME = "occlusion"
DESCRIPTION = ("occlusion and manoeuvres: a pole and a panel hide the target 0.2–1 s per revolution; the paper's "
               "loop vs CV, CA and IMM filter-driven pointing and the best passive camera on the circle and a "
               "manoeuvring target (40 cells)")

#: Occlusion conditions: name → (occluder, hidden time per revolution of the circle, s), or None.
OCCLUSIONS = {"none": None, "pole 0.2 s": ("pole", 0.2), "panel 0.5 s": ("panel", 0.5), "panel 1.0 s": ("panel", 1.0)}
#: Targets: name → the target's trajectory.
TARGETS = {"circle": "circular", "manoeuvring": "manoeuvring"}
#: Outer loops: name → the pointing. The paper loop's blind fallback coasts on its last rate
#: command for the filters' coasting time; "passive" is the best passive camera (stabilised at home).
LOOPS = {"paper": Pointing("paper", coast_s=FILTER_COAST_S), "CV": Pointing("filter", "cv"),
         "CA": Pointing("filter", "ca"), "IMM": Pointing("filter", "imm"), "passive": Pointing("stabilised")}
FILTERS = ("CV", "CA", "IMM")
#: The pipelines compared with the passive camera (docs/design.md, "When does a gimbal pay off?"):
#: name → (loop, localiser). No lens here: "best" differs from "paper" by the exact cone fit alone,
#: which the paper loop's runs record beside the circle method (the ``alt_*`` columns).
PIPELINES = {"active (paper)": ("paper", "circle"), "active (best)": ("paper", "exact"),
             "best passive": ("passive", "exact")}
#: BP1 and BP2: (a, b) of "a < b".
BP_CLAIMS = {"BP1": ("active (paper)", "best passive"), "BP2": ("active (best)", "best passive")}
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
    live = measured & np.isfinite(nees)  # the frame table holds a prediction for a live track only
    exact_ok, exact_error = _located(f, "exact")
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
        "nees_live": _mean(nees[live]),
        "nees_live_frames": int(live.sum()),
        "exact_detection_rate_pct": 100.0 * _mean(exact_ok[measured]),
        "exact_error_m": _mean(exact_error[measured & exact_ok]),
    }


def _located(frames: pd.DataFrame, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(localised, |d_est − d_true|) per frame: the run's own (the circle method) or, for
    "exact", the exact cone fit recorded beside it (the ``alt_*`` columns)."""
    if method == "exact":
        if "alt_detected" not in frames:
            raise ValueError("the run's frame table has no alt_* columns (the exact cone fit beside the circle)")
        return frames["alt_detected"].to_numpy(bool), frames["alt_abs_error_m"].to_numpy(float)
    return frames["detected"].to_numpy(bool), frames["abs_error_m"].to_numpy(float)


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


def pipeline_table(results) -> pd.DataFrame:
    """BP1 and BP2's pipelines per occlusion, target and seed, on the frames both localised.

    One row per (occlusion, target, seed, claim): a and b (pipeline names, :data:`BP_CLAIMS`),
    a_error_m and b_error_m (mean |d_est − d_true| over the measured frames both pipelines
    localised; NaN when there is none), common_rate_pct (those frames' share), a_rate_pct and
    b_rate_pct (each pipeline's own localisation rate, the detection rate beside the error).
    Claims whose runs are not all in ``results`` are left out.
    """
    groups: dict[tuple, dict] = {}
    for r in results:
        occlusion, target, loop = _names(r.config)
        groups.setdefault((occlusion, target, r.config.seed), {})[loop] = r
    rows = []
    for (occlusion, target, seed), runs in groups.items():
        for claim, (a, b) in BP_CLAIMS.items():
            (loop_a, method_a), (loop_b, method_b) = PIPELINES[a], PIPELINES[b]
            if loop_a not in runs or loop_b not in runs:
                continue
            first = [int(round(runs[x].config.frames_per_revolution)) for x in (loop_a, loop_b)]
            (ok_a, err_a), (ok_b, err_b) = (_located(runs[x].frames.iloc[k:], m) for x, k, m in
                                            ((loop_a, first[0], method_a), (loop_b, first[1], method_b)))
            if ok_a.shape != ok_b.shape:
                raise ValueError(f"{occlusion}/{target} seed {seed}: the runs of {a} and {b} have different frames")
            both = ok_a & ok_b
            rows.append({"occlusion": occlusion, "target": target, "seed": seed, "claim": claim, "a": a, "b": b,
                         "method_a": method_a, "method_b": method_b, "a_error_m": _mean(err_a[both]),
                         "b_error_m": _mean(err_b[both]), "common_rate_pct": 100.0 * float(both.mean()),
                         "a_rate_pct": 100.0 * float(ok_a.mean()), "b_rate_pct": 100.0 * float(ok_b.mean())})
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    order = {**_ORDER, **{name: i for i, name in enumerate(BP_CLAIMS)}}
    return table.sort_values(["occlusion", "target", "claim", "seed"],
                             key=lambda col: col if col.name == "seed" else col.map(order), ignore_index=True)


_SUMMARY_COLUMNS = ("hidden_s", "hidden_pointing_deg", "reappear_error_deg", "lost_pct", "reacquire_frames",
                    "after_error_m", "visible_error_m", "visible_offset_px", "detection_rate_pct", "partial_pct",
                    "nees_visible", "nees_hidden", "nees_live", "exact_detection_rate_pct", "exact_error_m")


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


_FLOORS = {"deg": ANGLE_FLOOR_DEG, "m": stats.MIN_EFFECT_M}


def nees_band(n: int, dof: int = 3) -> tuple[float, float]:
    """The two-sided 95 % band of the average of ``n`` independent χ²(``dof``) values:
    [χ²₀.₀₂₅(dof·n)/n, χ²₀.₉₇₅(dof·n)/n] (:func:`scipy.stats.chi2`; docs/design.md, Repairs)."""
    from scipy.stats import chi2

    n = _number("n", n, low=1, integer=True)
    return float(chi2.ppf(0.025, dof * n) / n), float(chi2.ppf(0.975, dof * n) / n)


def _pooled_nees(replicates: pd.DataFrame, target: str, loop: str) -> pd.Series:
    """Per seed: the mean NEES over every measured frame with a live track of the filter's runs on
    the target (all occlusions present), weighted by those frames."""
    sel = replicates[(replicates.target == target) & (replicates.loop == loop) & (replicates.nees_live_frames > 0)]
    weighted = (sel["nees_live"] * sel["nees_live_frames"]).groupby(sel["seed"]).sum()
    return (weighted / sel.groupby("seed")["nees_live_frames"].sum()).sort_index()


def check_hypotheses(replicates: pd.DataFrame, pipelines: pd.DataFrame | None = None) -> pd.DataFrame:
    """H1, H2, H2c, NEES consistency and BP1, BP2 per condition, with three-way verdicts, their
    p-values and Holm's family-level verdicts (every row one family).

    Units: "deg" (pointing errors), "m" (distance errors of BP1, BP2), "NEES" (the consistency
    rows: kind "inside", the band in ``band_low``, ``band_high``). A pair with a missing value (no
    episode measured) drops out; fewer than two pairs is "inconclusive". Cells absent from
    ``replicates`` are skipped; BP1 and BP2 need ``pipelines`` (:func:`pipeline_table`).
    """
    rows = []
    has = lambda o, t, loop: bool(((replicates.occlusion == o) & (replicates.target == t)  # noqa: E731
                                   & (replicates.loop == loop)).any())

    def add(cid, statement, condition, a_label, b_label, a, b, unit, test=stats.less_than):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit=unit,
                         result=test(a.to_numpy(), b.to_numpy(), floor=_FLOORS[unit], drop_missing=True)))

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
                add("H2c", "the IMM is at least as good as CV and CA on the circle (pointing error)",
                    f"circle, {o}", "IMM", other, value(o, "circle", "IMM", "pointing_error_deg"),
                    value(o, "circle", other, "pointing_error_deg"), "deg", test=stats.non_inferior)
    if "nees_live" in replicates:
        has_loop = lambda t, loop: bool(((replicates.target == t) & (replicates.loop == loop)).any())  # noqa: E731
        for t in TARGETS:
            for loop in FILTERS:
                if not has_loop(t, loop):
                    continue
                means = _pooled_nees(replicates, t, loop).dropna()
                if len(means) < 2:  # no live track in the measured part of most replicates: no interval
                    low, high = nees_band(max(len(means), 1))
                    mean = float(means.mean()) if len(means) else math.nan
                    result = stats.Verdict(stats.INCONCLUSIVE, "inside", mean, math.nan, mean, math.nan, math.nan,
                                           math.nan, len(means), 0.95, math.nan)
                else:
                    low, high = nees_band(len(means))
                    result = stats.inside_band(means.to_numpy(), low, high)
                rows.append(dict(id="NEES", statement="the filter's NEES is consistent with χ²(3)",
                                 condition=f"{loop}, {t}", a=loop, b="χ²(3) band", unit="NEES", band_low=low,
                                 band_high=high, result=result))
    if pipelines is not None and len(pipelines):
        for o in OCCLUSIONS:
            for t in TARGETS:
                for claim, (a, b) in BP_CLAIMS.items():
                    sel = pipelines[(pipelines.occlusion == o) & (pipelines.target == t) & (pipelines.claim == claim)]
                    if sel.empty:
                        continue
                    sel = sel.set_index("seed").sort_index()
                    add(claim, f"{a} < {b} (distance error on the frames both localised)", f"{o}, {t}", a, b,
                        sel["a_error_m"], sel["b_error_m"], "m")
    if not rows:
        raise ValueError("the replicate table holds none of the cells the hypotheses compare")
    return stats.holm(stats.verdict_table(rows))


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict (empty for a hypothesis that holds)."""
    kind = getattr(row, "kind", "less")
    if kind == "non-inferior":
        from .lens_sweep import non_inferiority_reason

        return non_inferiority_reason(row, "have a value on both sides")
    if kind == "inside":
        if row.verdict == stats.HOLDS:
            return ""
        if not math.isfinite(row.low):
            return f"only {row.n} replicate(s) have measured frames with a live track: no interval"
        where = (f"lies above the band's top {row.band_high:.2f}" if row.low > row.band_high else
                 f"lies below the band's bottom {row.band_low:.2f}" if row.high < row.band_low else
                 f"overlaps an end of the band [{row.band_low:.2f}, {row.band_high:.2f}]")
        return f"the 95 % interval of the replicates' mean NEES, [{row.low:.2f}, {row.high:.2f}], {where}"
    if row.unit == "m":
        return _params.verdict_reason(row, "have frames both pipelines localised")
    return _params.verdict_reason(row, "have an occlusion episode on both sides")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: OcclusionStudy | None = None, pipelines: pd.DataFrame | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval, δ and
    p-values, the count per hypothesis at both levels (as computed and after Holm), a measured
    reason for each condition that does not hold, the NEES bands, the pipelines' localisation
    rates, and the table per occlusion, target and loop."""
    from .lens_sweep import _markdown_table, family_counts

    study = study or OcclusionStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    hidden = ", ".join(f"{name} {hidden_time_s(occluders_for(name)[0]):.2f} s at "
                       f"{occluders_for(name)[0].centre_m[0] - TrackingConfig().home_camera_m[0]:.2f} m"
                       for name, spec in OCCLUSIONS.items() if spec is not None)
    lines = [
        "# Occlusion and manoeuvres: hypotheses H1, H2, H2c, NEES and the best passive camera (BP1, BP2), measured",
        "",
        "A grey pole (0.15 m) or panel (0.6 m) stands between the home camera and the lowest point of the paper's "
        f"circle, hiding the circle's target per revolution as seen from the home camera: {hidden} ahead of the "
        "camera. Targets: the sphere on the circle and on a seeded manoeuvring path (1 m/s legs, 5 m/s² turns). "
        f"Loops: the paper's PI image loop (repeats its last rate command for {FILTER_COAST_S:g} s while the target "
        "is lost, then holds), pointing driven by a CV, CA or IMM filter on the target's world position, and the "
        "best passive camera (stabilised at home, exact cone fit). The manoeuvring target meets the circle's "
        "occluders (the design's per-seed dose could not be built: see the study's module). "
        f"Up to {n} replicates per cell of {study.revolutions:g} revolutions (the first is acquisition), paired by "
        "replicate. BP1: the paper loop's circle method, BP2: its exact cone fit, each against the passive camera's "
        "exact fit, distance error on the frames both localised.",
        "",
        _params.verdict_rule(f"max({ANGLE_FLOOR_DEG:g}°, 10 % of the smaller mean) for pointing, max(1 mm, 10 %) "
                             "for distance", "H2c is non-inferiority (“IMM at least as good”): **holds** when the "
                             "upper one-sided 95 % bound of IMM − other lies below +δ, **does not hold** when the "
                             "lower one lies above +δ; its interval is the 90 % one. NEES: **holds** when the 95 % "
                             "interval of the replicates' mean NEES (every measured frame with a live track) lies "
                             "inside the 95 % band of an average of N χ²(3) values, [χ²₀.₀₂₅(3N)/N, χ²₀.₉₇₅(3N)/N], "
                             "**does not hold** when it lies outside; its “mean a” is the mean NEES. Every verdict "
                             "carries the p-value of its deciding test; all verdicts are one family, and Holm's "
                             "step-down correction at 5 % gives the family-level verdict."),
        "",
    ]
    lines += _params.verdict_lines(verdicts, verdict_reason, unit_in_list=True)
    lines += ["", "## Verdicts per hypothesis, as computed and after Holm", ""]
    lines += _markdown_table(family_counts(verdicts))
    if "p_holm" in verdicts:
        lines += ["", "## p-values and the family-level verdict of every condition", ""]
        lines += _markdown_table(verdicts[["id", "condition", "a", "b", "verdict", "p_value", "p_holm", "verdict_holm"]],
                                 {"p_value": "{:.2g}", "p_holm": "{:.2g}"})
    nees = verdicts[verdicts["id"] == "NEES"]
    if len(nees):
        lines += ["", "## NEES against the χ²(3) band (mean over replicates, 95 % interval)", ""]
        lines += _markdown_table(nees[["condition", "n", "mean_a", "low", "high", "band_low", "band_high", "verdict"]]
                                 .rename(columns={"mean_a": "mean NEES"}),
                                 {c: "{:.2f}" for c in ("mean NEES", "low", "high", "band_low", "band_high")})
    if pipelines is not None and len(pipelines):
        lines += ["", "## The pipelines of BP1 and BP2: localisation rates and errors (means over replicates)", ""]
        means = pipelines.groupby(["occlusion", "target", "claim", "a", "b"], sort=False)[
            ["a_rate_pct", "b_rate_pct", "common_rate_pct", "a_error_m", "b_error_m"]].mean().reset_index()
        means[["a_error_m", "b_error_m"]] *= 1000.0
        means = means.rename(columns={"a_error_m": "a error mm", "b_error_m": "b error mm"})
        lines += _markdown_table(means, {c: "{:.1f}" for c in means.columns[5:]})
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

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``pipelines.csv``,
    ``verdicts.csv``, ``claims.md``, ``study.json`` and ``figures/`` (the occlusion metrics per loop
    and occlusion, example timelines, the forest plot of every verdict but the NEES bands, which
    claims.md tables), PNG and SVG.
    """
    from .. import plotting

    plt = _params.report_pyplot()
    folder = Path(folder)
    replicates = replicate_table(results)
    summary = summary_table(replicates)
    pipelines = pipeline_table(results)
    verdicts = check_hypotheses(replicates, pipelines)
    written = _params.write_report_files(folder, (
        ("summary.csv", lambda p: summary.to_csv(p, index=False)),
        ("replicates.parquet", lambda p: replicates.to_parquet(p, index=False)),
        ("replicates.csv", lambda p: replicates.to_csv(p, index=False)),
        ("pipelines.csv", lambda p: pipelines.to_csv(p, index=False)),
        ("verdicts.csv", lambda p: verdicts.to_csv(p, index=False)),
        ("claims.md", lambda p: p.write_text(hypotheses_markdown(verdicts, summary, study, pipelines))),
    ), NAME, study, len(results))

    def save(fig, name):
        written.extend(plotting.save_figure(fig, name, folder / "figures", formats=("png", "svg")))

    save(plotting.occlusion.plot_occlusion_metrics(summary), "occlusion_metrics")
    save(plotting.occlusion.plot_occlusion_timelines(timeline_runs(results)), "occlusion_timelines")
    save(plotting.study.plot_forest(verdicts[verdicts["kind"] != "inside"]).figure, "hypotheses_forest")
    plt.close("all")
    return written


def run_study(study: OcclusionStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/occlusion`` atomically.

    ``clips`` is accepted for the command line's sake; this study writes figures, not clips.
    """
    return _params.run_and_report(NAME, "occlusion", grid(study), write_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
