"""Occlusion and manoeuvres (docs/design.md): can a filter keep the gimbal pointing while the
target is hidden, and which filter for which motion? (paper §5: a Bayesian filter should keep
tracking through occlusion; its related work uses an IMM).

Occluders (:data:`OCCLUSIONS`): a vertical pole 0.15 m wide and a 0.6 m square panel, matte
grey boxes (:class:`gimbal_lab.scene.Occluder`), their faces parallel to the world's axes.

* The circle's: each stands on the line from the home camera to the lowest point of the paper's
  circle, its top edge level with the home camera's optical centre, at the distance from the
  camera where the circle's target is hidden (the line of sight to its centre blocked) for the
  stated time per revolution, seen from the home camera: :func:`place_occluder` solves for that
  distance. A top edge at the camera's height can hide at most the arc below that height, 0.97 s
  of the 2 s period, so the "1.0 s" panel hides that arc and stands where it first does.
* The manoeuvring target's own, placed per run (the occlusion *dose*, docs/design.md, "When does
  a gimbal pay off?", Repairs and the decision of 2026-12-02): at the middle of the measured part,
  t_m (:func:`dose_time_s`), the occluder's vertical mid-line crosses the line from the home
  camera to the target's centre; it stands on the ground, top edge at the camera's height, where
  the target is below the camera's optical centre at t_m, and hangs from above, mirrored (bottom
  edge at the camera's height, same size), where it is above. Its distance along that line is
  found with Brent's method so that the pass around t_m (the hidden interval containing t_m, seen
  from the home camera) lasts the condition's 0.2, 0.5 or 1.0 s; when no distance between 0.3 m
  and 0.3 m short of the target gives that time, it stands where the pass comes closest
  (:func:`place_dose_occluder`). Other passes behind it may occur.

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
* ``hidden_s``: hidden time per measured revolution; ``hidden_total_s``: hidden time over the
  measured part, s; ``dose_s`` (manoeuvring target only, NaN on the circle): the realised dose,
  the length of the run of hidden frames containing the frame at t_m (0 when that frame is seen);
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
(the replicates' mean NEES tested against 3, :func:`nees_consistency`);
**BP1** "active (paper) < best passive" and **BP2** "active (best) < best passive" per occlusion
and target: the paper loop's circle method and its exact cone fit against the passive camera's
exact fit, distance error on the frames both localised (:func:`pipeline_table`). Every verdict of
the report is one family held to 5 % by Holm (:func:`gimbal_lab.stats.holm`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..evaluation import pointing_error_deg
from ..config import Camera, Pointing, Target, TrackingConfig, _choice, _number
from ..scene import Occluder, points_visible
from ..tracking import FILTER_COAST_S
from . import _params
from . import report as _report
from ._params import StudyParams
from .paper import replicate_phase_s

__all__ = [
    "OcclusionStudy", "Study", "OCCLUSIONS", "TARGETS", "LOOPS", "FILTERS", "AFTER_FRAMES", "ANGLE_FLOOR_DEG",
    "PIPELINES", "BP_CLAIMS", "DOSE_MARGIN_M", "DOSE_STEP_S", "place_occluder", "hidden_time_s", "dose_time_s",
    "dose_hidden_s", "DosePlacement", "dose_placement", "place_dose_occluder", "dose_table", "occluders_for", "grid",
    "episodes", "timeline_runs", "replicate_table", "pipeline_table", "summary_table", "dose_summary", "NEES_DOF",
    "NEES_MARGIN", "nees_consistency",
    "check_hypotheses", "hypotheses_markdown", "make_report", "run_study", "example_view",
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


# ----------------------------------------------------------------------------------------------
# the manoeuvring target's occlusion dose
# ----------------------------------------------------------------------------------------------
#: The dose's occluder stands at least this far from the home camera and this far short of the
#: target, along the line of sight, m (docs/design.md, the decision of 2026-12-02).
DOSE_MARGIN_M = 0.3
#: Step at which the target's path is sampled when measuring a dose, s: a dose is met within it.
DOSE_STEP_S = 1e-3
#: Step of the scan along the line of sight that brackets the distances for Brent's method, m.
_DOSE_SCAN_M = 0.05


def dose_time_s(config: TrackingConfig) -> float:
    """t_m: the middle of a run's measured part (the revolutions after the first), run time, s
    (the target's motion time is t_m + ``config.target.start_phase_s``)."""
    return 0.5 * (1.0 + config.revolutions) * config.target.period_s


def _run_around(flags, i: int) -> int:
    """Length of the run of True in ``flags`` that holds index ``i`` (0 when ``flags[i]`` is False).

    Examples
    --------
    >>> _run_around([True, False, True, True, True, False], 3), _run_around([True, False], 1)
    (3, 0)
    """
    flags = np.asarray(flags, bool)
    if not flags[i]:
        return 0
    before, after = np.flatnonzero(~flags[:i]), np.flatnonzero(~flags[i:])
    start = int(before[-1]) + 1 if before.size else 0
    end = i + int(after[0]) if after.size else len(flags)
    return end - start


def _dose_samples(config: TrackingConfig) -> tuple[np.ndarray, int]:
    """The target's centre every :data:`DOSE_STEP_S` across the measured part, symmetric about
    t_m, shape (2k + 1, 3), m, and k (the index of t_m)."""
    half_s = 0.5 * (config.revolutions - 1.0) * config.target.period_s
    k = int(math.floor(half_s / DOSE_STEP_S + 1e-9))
    t = dose_time_s(config) + DOSE_STEP_S * np.arange(-k, k + 1)
    return config.path.position(t + config.target.start_phase_s), k


def dose_hidden_s(occluders, config: TrackingConfig) -> tuple[float, float]:
    """The dose the ``occluders`` give a run, seen from the home camera: ``(dose_s, total_s)``.

    ``dose_s`` is the pass around t_m (:func:`dose_time_s`), the length of the hidden interval
    that contains t_m (0 when the target's centre is seen at t_m); ``total_s`` is the hidden time
    over the whole measured part. The path is sampled every :data:`DOSE_STEP_S` over the
    measured part, so both are multiples of it, and the pass is cut where the measured part ends.
    """
    points, k = _dose_samples(config)
    hidden = ~points_visible(tuple(occluders), config.home_camera_m, points)
    return _run_around(hidden, k) * DOSE_STEP_S, float(hidden.sum()) * DOSE_STEP_S


def _dose_occluder(kind: str, distance_m: float, camera_m, target_m, hidden_s: float) -> Occluder:
    """The pole or panel whose vertical mid-line crosses the line from ``camera_m`` to ``target_m``
    ``distance_m`` along it: standing on the ground, top edge at the camera's height, when the
    target is below the camera; hanging from above, bottom edge at the camera's height (mirrored,
    same size), when it is above. Faces parallel to the world's axes, as the circle's. Its name
    holds the dose it stands for ("panel, dose 0.5 s"): where two doses fall back to the same
    place, their runs stay apart."""
    camera, target = np.asarray(camera_m, float), np.asarray(target_m, float)
    sight = (target - camera) / np.linalg.norm(target - camera)
    x, y = (camera + distance_m * sight)[:2]
    height_m = float(camera[2])
    size = _dose_size_m(kind, camera)
    hanging = target[2] > camera[2]
    return Occluder(f"{kind}, dose {hidden_s:g} s", (x, y, height_m + 0.5 * size[2] if hanging
                                                     else height_m - 0.5 * size[2]), size)


def _dose_size_m(kind: str, camera_m) -> tuple[float, float, float]:
    """Extents (x, y, z) of the dose's pole or panel, m: the circle's (the pole as tall as the
    camera's height)."""
    if kind == "pole":
        return (POLE_WIDTH_M, POLE_WIDTH_M, float(camera_m[2]))
    return (PANEL_THICKNESS_M, PANEL_SIZE_M, PANEL_SIZE_M)


@dataclass(frozen=True)
class DosePlacement:
    """Where one dose's occluder stands for one run (:func:`dose_placement`).

    Attributes
    ----------
    occluder : gimbal_lab.scene.Occluder
    distance_m : float
        Along the line of sight from the home camera to the target's centre at t_m, m.
    hanging : bool
        True where the target is above the camera's optical centre at t_m (the occluder hangs).
    wanted_s, dose_s, total_s : float
        The condition's dose, the pass around t_m the occluder gives and the measured part's
        hidden time, seen from the home camera (:func:`dose_hidden_s`), s.
    attained : bool
        ``dose_s`` is within :data:`DOSE_STEP_S` of ``wanted_s``; False where the fallback placed
        it (the closest pass between the margins).
    """

    occluder: Occluder
    distance_m: float
    hanging: bool
    wanted_s: float
    dose_s: float
    total_s: float
    attained: bool


@functools.lru_cache(maxsize=512)
def _dose_placement(kind: str, wanted_s: float, base: TrackingConfig) -> DosePlacement:
    from scipy.optimize import brentq

    camera = base.home_camera_m
    target = base.path.position(dose_time_s(base) + base.target.start_phase_s)
    points, k = _dose_samples(base)

    def miss(d):  # the pass around t_m at distance d, less the wanted dose, s
        hidden = _dose_occluder(kind, d, camera, target, wanted_s).blocks(camera, points)
        return _run_around(hidden, k) * DOSE_STEP_S - wanted_s

    length = float(np.linalg.norm(target - camera))
    # beyond ``reach`` the line of sight runs under a standing occluder (over a hanging one): its
    # vertical mid-line no longer crosses it
    climb = abs(target[2] - camera[2]) / length
    reach = _dose_size_m(kind, camera)[2] / climb if climb > 0 else math.inf
    near, far = DOSE_MARGIN_M, min(length - DOSE_MARGIN_M, reach)
    if far <= near:
        raise ValueError(f"the target is {length:.2f} m from the camera at t_m, {climb * length:.2f} m above or "
                         f"below it: no room for a {kind} {DOSE_MARGIN_M} m from both that crosses the line of sight")
    scan = np.append(np.arange(near, far, _DOSE_SCAN_M), far)
    misses = [miss(d) for d in scan]
    met = lambda m: abs(m) <= DOSE_STEP_S * (1.0 + 1e-9)  # noqa: E731 (the pass is sampled every step)
    tried = list(zip(scan, misses))
    distance = None
    for i, d in enumerate(scan):  # the nearest distance that gives the dose
        if met(misses[i]):
            distance = d
            break
        if i + 1 < len(scan) and misses[i] * misses[i + 1] < 0:
            root = brentq(miss, d, scan[i + 1], xtol=1e-4)
            tried.append((root, miss(root)))
            if met(tried[-1][1]):
                distance = root
                break
    if distance is None:  # the fallback: where the pass comes closest to the dose (the nearest such)
        distance = min(tried, key=lambda pair: (abs(pair[1]), pair[0]))[0]
    occluder = _dose_occluder(kind, float(distance), camera, target, wanted_s)
    dose_s, total_s = dose_hidden_s((occluder,), base)
    return DosePlacement(occluder, float(distance), bool(target[2] > camera[2]), wanted_s, dose_s, total_s,
                         met(dose_s - wanted_s))


def dose_placement(kind: str, hidden_s: float, config: TrackingConfig) -> DosePlacement:
    """The manoeuvring target's occluder of ``kind`` ("pole" or "panel") for the run ``config``,
    placed so that the pass around t_m lasts ``hidden_s`` (docs/design.md, Repairs and the
    decision of 2026-12-02; the module's rule).

    The target's centre at t_m (:func:`dose_time_s`) above or below the home camera's optical
    centre decides whether the occluder hangs or stands (:class:`DosePlacement`). The pass is
    sampled every :data:`DOSE_STEP_S` (:func:`dose_hidden_s`); the line of sight is scanned every
    5 cm from :data:`DOSE_MARGIN_M` to :data:`DOSE_MARGIN_M` short of the target (or, nearer, to
    where the line leaves the occluder's height: its vertical mid-line must cross the line), and
    where the pass crosses ``hidden_s`` between two scanned distances Brent's method
    (:func:`scipy.optimize.brentq`, 0.1 mm) finds the distance; the nearest distance that gives
    ``hidden_s`` within one sampling step wins. When none does (the pass is too short everywhere,
    or jumps past ``hidden_s`` where it merges with another), the occluder stands where the pass
    comes closest, and ``attained`` is False. Placements are cached per run (what they depend on:
    the path, the phase, the run's length and the home camera; the loop does not matter).
    """
    _choice("kind", kind, ("pole", "panel"))
    hidden_s = _number("hidden_s", hidden_s, low=0.0, low_open=True)
    if not isinstance(config, TrackingConfig):
        raise TypeError(f"config must be a TrackingConfig, got {type(config).__name__}")
    if config.target.trajectory != TARGETS["manoeuvring"]:
        raise ValueError(f"the dose is placed for the manoeuvring target, got target.trajectory "
                         f"{config.target.trajectory!r}")
    return _dose_placement(kind, float(hidden_s), config.with_(target__occluders=(), pointing=Pointing()))


def place_dose_occluder(kind: str, hidden_s: float, config: TrackingConfig) -> Occluder:
    """The occluder of :func:`dose_placement`."""
    return dose_placement(kind, hidden_s, config).occluder


def occluders_for(occlusion: str, config: TrackingConfig | None = None) -> tuple[Occluder, ...]:
    """The occluders of one :data:`OCCLUSIONS` condition: the circle's (:func:`place_occluder`),
    or, when ``config`` is a run of the manoeuvring target, that run's own dose
    (:func:`place_dose_occluder`)."""
    _choice("occlusion", occlusion, tuple(OCCLUSIONS))
    spec = OCCLUSIONS[occlusion]
    if spec is None:
        return ()
    if config is not None and config.target.trajectory == TARGETS["manoeuvring"]:
        return (place_dose_occluder(*spec, config),)
    return (place_occluder(*spec),)


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
        _choice("occlusion", occlusion, tuple(OCCLUSIONS))
        bare = TrackingConfig(
            camera=Camera(fps=self.fps, latency_frames=self.latency_frames, noise_std=self.noise_std),
            target=Target(kind="sphere", trajectory=TARGETS[target], period_s=self.period_s,
                          start_phase_s=replicate_phase_s(seed, self.period_s)),
            pointing=LOOPS[loop], revolutions=self.revolutions, seed=seed)
        return bare.with_(target__occluders=occluders_for(occlusion, bare)) if OCCLUSIONS[occlusion] else bare


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


def dose_table(study: OcclusionStudy | None = None, occlusions=None) -> pd.DataFrame:
    """The manoeuvring target's doses as placed, one row per occlusion (with an occluder) and seed.

    Columns: occlusion, seed, occluder ("pole", "panel"), placement ("standing", "hanging"),
    distance_m (along the line of sight), wanted_s, dose_s (the pass around t_m), total_s (the
    measured part's hidden time), both seen from the home camera (:func:`dose_placement`), and
    attained (``dose_s`` within :data:`DOSE_STEP_S` of ``wanted_s``).
    """
    study = study or OcclusionStudy()
    occlusions = tuple(OCCLUSIONS) if occlusions is None else tuple(occlusions)
    for occlusion in occlusions:
        _choice("occlusion", occlusion, tuple(OCCLUSIONS))
    occlusions = [o for o in occlusions if OCCLUSIONS[o] is not None]
    rows = []
    for occlusion in occlusions:
        for seed in study.seeds:
            p = dose_placement(*OCCLUSIONS[occlusion], study.config("none", "manoeuvring", "paper", seed))
            rows.append({"occlusion": occlusion, "seed": seed, "occluder": OCCLUSIONS[occlusion][0],
                         "placement": "hanging" if p.hanging else "standing", "distance_m": p.distance_m,
                         "wanted_s": p.wanted_s, "dose_s": p.dose_s, "total_s": p.total_s, "attained": p.attained})
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _names(config: TrackingConfig) -> tuple[str, str, str]:
    """(occlusion, target, loop) names of a config of the study."""
    target = next((name for name, traj in TARGETS.items() if traj == config.target.trajectory), None)
    occlusion = None if target is None else next(
        (name for name in OCCLUSIONS if occluders_for(name, config) == config.target.occluders), None)
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
    # the realised dose: the run of hidden frames holding the frame at t_m (the manoeuvring target's)
    at_mid = int(round(dose_time_s(c) * c.camera.fps))
    dose = (_run_around(hidden, at_mid) / c.camera.fps if c.target.trajectory == TARGETS["manoeuvring"]
            and at_mid < len(f) else math.nan)
    return {
        "episodes": len(found),
        "hidden_s": hidden[first:].sum() / c.camera.fps / ((len(f) - first) / c.frames_per_revolution),
        "hidden_total_s": hidden[first:].sum() / c.camera.fps,
        "dose_s": dose,
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


_SUMMARY_COLUMNS = ("hidden_s", "hidden_total_s", "dose_s", "hidden_pointing_deg", "reappear_error_deg", "lost_pct",
                    "reacquire_frames", "after_error_m", "visible_error_m", "visible_offset_px", "detection_rate_pct",
                    "partial_pct",
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


def dose_summary(replicates: pd.DataFrame) -> pd.DataFrame:
    """The manoeuvring target's realised doses per occlusion with an occluder, over every loop and
    replicate: runs, the dose (``dose_s``: the hidden frames around t_m) and the measured part's
    hidden time (``hidden_total_s``), each as mean, min and max, s."""
    with_occluder = replicates.occlusion.map(lambda o: OCCLUSIONS[o] is not None).astype(bool)
    sel = replicates[(replicates.target == "manoeuvring") & with_occluder]
    rows = []
    for occlusion, g in sel.groupby("occlusion", sort=False):
        row = {"occlusion": occlusion, "wanted_s": OCCLUSIONS[occlusion][1], "runs": len(g)}
        for col, name in (("dose_s", "dose"), ("hidden_total_s", "hidden")):
            row.update({f"{name}_mean_s": _mean(g[col]), f"{name}_min_s": float(g[col].min()),
                        f"{name}_max_s": float(g[col].max())})
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


#: Expected NEES of a consistent filter's predicted position: its dimension (χ²(3) has mean 3).
NEES_DOF = 3
#: Margin within which "consistent" bounds the mean NEES: the equivalence margin of "Verdicts",
#: 20 % of 3 (a covariance off by less than about ×1.2).
NEES_MARGIN = stats.EQUIVALENCE_MARGIN * NEES_DOF


def nees_consistency(means) -> stats.Verdict:
    """Verdict on "the filter's NEES is consistent with χ²(3)" from its replicates' mean NEES.

    :func:`gimbal_lab.stats.mean_equals` against :data:`NEES_DOF` with margin :data:`NEES_MARGIN`:
    **does not hold** when the 95 % interval of the mean excludes 3, **holds** when it contains 3
    and the 90 % interval lies inside 3 ± 0.6, **inconclusive** otherwise (docs/design.md, "When
    does a gimbal pay off?", Repairs, "Filter consistency as a verdict": the replicates are
    independent, the frames inside one are not, so the test runs on the N replicate means).

    Parameters
    ----------
    means : array_like, shape (n,)
        Each replicate's mean NEES over its measured frames with a live track; non-finite values
        (no live track) are left out, and fewer than two left give "inconclusive" with a NaN
        interval and p-value.
    """
    x = np.asarray(means, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 2:  # no live track in the measured part of most replicates: no interval
        mean = float(x.mean()) if x.size else math.nan
        return stats.Verdict(stats.INCONCLUSIVE, "equals", mean, float(NEES_DOF), mean - NEES_DOF, math.nan,
                             math.nan, NEES_MARGIN, int(x.size), 0.95, math.nan)
    return stats.mean_equals(x, NEES_DOF, NEES_MARGIN)


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
    rows, :func:`nees_consistency`: kind "equals", 3 ± the margin in ``band_low``, ``band_high``,
    the 90 % interval in ``low90``, ``high90``). A pair with a missing value (no
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
                means = _pooled_nees(replicates, t, loop).dropna().to_numpy()
                _, low90, high90 = stats.mean_interval(means, 0.90)
                rows.append(dict(id="NEES", statement="the filter's NEES is consistent with χ²(3)",
                                 condition=f"{loop}, {t}", a=loop, b="χ²(3)", unit="NEES",
                                 band_low=NEES_DOF - NEES_MARGIN, band_high=NEES_DOF + NEES_MARGIN, low90=low90,
                                 high90=high90, result=nees_consistency(means)))
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
    if kind == "equals":
        if row.verdict == stats.HOLDS:
            return ""
        if not math.isfinite(row.low):
            return f"only {row.n} replicate(s) have measured frames with a live track: no interval"
        interval = f"the 95 % interval of the replicates' mean NEES, [{row.low:.2f}, {row.high:.2f}]"
        if row.low > row.mean_b:
            return f"{interval}, lies above {row.mean_b:g}: the filter claims a smaller covariance than its errors have"
        if row.high < row.mean_b:
            return f"{interval}, lies below {row.mean_b:g}: the filter claims a larger covariance than its errors have"
        return (f"{interval}, holds {row.mean_b:g}, but the 90 % one reaches beyond {row.mean_b:g} ± {row.delta:.2f}: "
                "too wide to call it consistent")
    if row.unit == "m":
        return _params.verdict_reason(row, "have frames both pipelines localised")
    return _params.verdict_reason(row, "have an occlusion episode on both sides")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: OcclusionStudy | None = None, pipelines: pd.DataFrame | None = None,
                        replicates: pd.DataFrame | None = None) -> str:
    """claims.md of the study: the setting, every condition's verdict with its interval, δ and
    p-values, the count per hypothesis at both levels (as computed and after Holm), a measured
    reason for each condition that does not hold, the NEES bands, the pipelines' localisation
    rates, the manoeuvring target's realised doses (from ``replicates``), and the table per
    occlusion, target and loop (its realised dose and total hidden time beside)."""
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
        "best passive camera (stabilised at home, exact cone fit). The manoeuvring target meets occluders of its "
        "own, placed per replicate (the dose): at the middle of the measured part the occluder's vertical mid-line "
        "crosses the line of sight, standing (top edge at the camera's height) where the target is below the camera "
        "and hanging (bottom edge there) where it is above, at the distance where the pass around that moment "
        "lasts the condition's 0.2, 0.5 or 1.0 s seen from the home camera; its realised dose and the run's total "
        "hidden time are tabled below. "
        f"Up to {n} replicates per cell of {study.revolutions:g} revolutions (the first is acquisition), paired by "
        "replicate. BP1: the paper loop's circle method, BP2: its exact cone fit, each against the passive camera's "
        "exact fit, distance error on the frames both localised.",
        "",
        _params.verdict_rule(f"max({ANGLE_FLOOR_DEG:g}°, 10 % of the smaller mean) for pointing, max(1 mm, 10 %) "
                             "for distance", "H2c is non-inferiority (“IMM at least as good”): **holds** when the "
                             "upper one-sided 95 % bound of IMM − other lies below +δ, **does not hold** when the "
                             "lower one lies above +δ; its interval is the 90 % one. NEES (each replicate's mean NEES over "
                             "every measured frame with a live track, tested across the independent replicates with "
                             "Student's t): **does not hold** when the 95 % interval of their mean excludes 3, "
                             f"**holds** when it contains 3 and the 90 % interval lies inside 3 ± {NEES_MARGIN:g}, "
                             "inconclusive otherwise; its “mean a” is the mean NEES. Every verdict "
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
        lines += ["", f"## NEES against 3 (mean over replicates, 95 % and 90 % intervals, margin 3 ± {NEES_MARGIN:g})",
                  ""]
        lines += _markdown_table(nees[["condition", "n", "mean_a", "low", "high", "low90", "high90", "verdict"]]
                                 .rename(columns={"mean_a": "mean NEES"}),
                                 {c: "{:.2f}" for c in ("mean NEES", "low", "high", "low90", "high90")})
    if pipelines is not None and len(pipelines):
        lines += ["", "## The pipelines of BP1 and BP2: localisation rates and errors (means over replicates)", ""]
        means = pipelines.groupby(["occlusion", "target", "claim", "a", "b"], sort=False)[
            ["a_rate_pct", "b_rate_pct", "common_rate_pct", "a_error_m", "b_error_m"]].mean().reset_index()
        means[["a_error_m", "b_error_m"]] *= 1000.0
        means = means.rename(columns={"a_error_m": "a error mm", "b_error_m": "b error mm"})
        lines += _markdown_table(means, {c: "{:.1f}" for c in means.columns[5:]})
    if replicates is not None and len(replicates) and "dose_s" in replicates:
        doses = dose_summary(replicates)
        if len(doses):
            lines += ["", "## The manoeuvring target's occlusion dose, realised (every loop and replicate, s)", "",
                      "The dose is the run of hidden frames around the middle of the measured part "
                      f"({study.fps:g} frames/s, seen from the camera where it is, which turns with the gimbal); the "
                      "total is every hidden frame of the measured part, other passes behind the occluder included. "
                      "As placed, seen from the home camera every 1 ms: `doses.csv`.", ""]
            lines += _markdown_table(doses, {c: "{:.3f}" for c in doses.columns if c.endswith("_s")})
    if summary is not None and len(summary):
        lines += ["", "## Per occlusion, target and loop (measured revolutions, means over replicates)", "",
                  "| occlusion | target | loop | episodes | dose s | hidden s | pointing ° [95 % CI] | hidden ° | "
                  "reappear ° | lost % | re-acquire frames | error after mm | visible error mm | detected % | "
                  "NEES visible | NEES hidden |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in summary.itertuples():
            lines.append(
                f"| {row.occlusion} | {row.target} | {row.loop} | {row.episodes} | {row.dose_s:.2f} | "
                f"{row.hidden_total_s:.2f} | {row.pointing_error_deg:.2f} "
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


def make_report(results, study: OcclusionStudy) -> _report.Report:
    """The study's report (:class:`gimbal_lab.studies.report.Report`): its tables, hypotheses and figures.

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``pipelines.csv``,
    ``verdicts.csv``, ``doses.csv`` (the manoeuvring target's doses as placed, :func:`dose_table`),
    ``claims.md``, ``study.json`` and ``figures/`` (the occlusion metrics per loop and occlusion,
    example timelines, the forest plot of every verdict but the NEES rows, which claims.md
    tables), PNG and SVG.
    """
    from .. import plotting

    replicates = replicate_table(results)
    summary = summary_table(replicates)
    pipelines = pipeline_table(results)
    verdicts = check_hypotheses(replicates, pipelines)
    return _report.Report(NAME, study, len(results), [
        ("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
        ("pipelines.csv", pipelines), ("verdicts.csv", verdicts), ("doses.csv", dose_table(study)),
        ("claims.md", hypotheses_markdown(verdicts, summary, study, pipelines, replicates)),
    ], [("occlusion_metrics", lambda: plotting.occlusion.plot_occlusion_metrics(summary)),
        ("occlusion_timelines", lambda: plotting.occlusion.plot_occlusion_timelines(timeline_runs(results)))],
        verdicts, forest_rows=verdicts[verdicts["kind"] != "equals"])


def run_study(study: OcclusionStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/occlusion``
    (:func:`gimbal_lab.studies.report.run_and_report`).

    ``clips`` is accepted for the command line's sake; this study writes figures, not clips.
    """
    return _report.run_and_report(NAME, "occlusion", grid(study), make_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
