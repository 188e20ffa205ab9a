"""The closed tracking loop of the study (paper §4.1, Fig. 5).

trajectory → render (with lens distortion and sensor noise) → detect → localise → (active) outer
image loop → inner rate loops → gimbal axes → forward kinematics → next camera pose.

The inner loop and the axis dynamics run at ``inner_rate_hz`` (1 kHz by default); the camera
takes a frame every 1/fps seconds. A detection made on frame k reaches the outer loop
``latency_frames`` frames later. In passive mode the gimbal is stabilised at its home pose (rate
references zero); in active mode an outer loop turns the target's image into joint-rate
references: the paper's PI law on the pixel error with Ziegler–Nichols gains
(:meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`, the default), or the predictive
line-of-sight loop (:class:`gimbal_lab.tracking.PredictiveLoop`, an extension).

A frame is exposed over [t, t + exposure_s]; its truth is taken at the **mid-exposure instant**
t + exposure_s/2 (the target's position and the camera's pose then), and the estimate is mapped
to the world through the camera pose at that same instant. The metric is |d_est − d_true|, with d
the distance from the camera's optical centre to the target's centre (paper §4.1).

Replicates: a config's ``start_phase_s`` shifts the target's motion in time and its ``seed``
draws the sensor noise, so replicates of one cell differ only by those draws
(:func:`gimbal_lab.studies.paper.grid` draws both from the replicate's seed).

Rendering needs an OpenGL context: a process that ran :func:`simulate` must not fork
(see :mod:`gimbal_lab.scene`); :mod:`gimbal_lab.runner` runs configs on spawned workers.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import time
from collections import deque
from typing import NamedTuple
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import pandas as pd

from .camera import BrownConrady, Intrinsics, KannalaBrandt, project
from .trajectories import Trajectory, target_pose

__all__ = ["TrackingConfig", "TrackingResult", "simulate", "render_frame", "FRAME_COLUMNS", "world_T_base",
           "make_renderer", "renderer_key", "CONE_RANGE_M", "CONE_FIELD_FRACTION"]

_TARGETS = ("sphere", "aruco")
_MODES = ("passive", "active")
_DISTORTIONS = ("none", "default")
_SPHERE_METHODS = ("circle", "ellipse")
_REFINEMENTS = ("none", "subpix", "contour", "apriltag")
_OUTER_LOOPS = ("paper", "predictive", "filter")
_TARGET_FILTERS = ("cv", "ca", "imm")
_MOTIONS = ("static", "hover", "vibration", "flight")
_PASSIVE_MOUNTS = ("stabilised", "fixed")
_BLURS = ("subframes", "fast")
_TRAJECTORIES = ("circular", "diagonal", "cone", "manoeuvring")
_LENS_STRATEGIES = ("ignore", "undistort", "rectify")

#: The cone trajectory (docs/design.md, "Lens sweep"): the target circles the home optical axis at
#: this range from the home camera, off the axis by this fraction of the half horizontal field.
CONE_RANGE_M = 3.0
CONE_FIELD_FRACTION = 0.7

#: Upper bounds that keep a config's sizes sane (a run, not a typo, decides the cost).
_MAX_IMAGE_PX = 8192
_MAX_INNER_RATE_HZ = 100_000.0
_MAX_FRAMES = 1_000_000
_MAX_SUBFRAMES = 1024


def _number(name, value, *, low=None, high=None, low_open=False, integer=False):
    """A real number from ``value`` (never a bool, a string or NaN/inf), or a clear error."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    lo = "" if low is None else (f"> {low:g}" if low_open else f">= {low:g}")
    hi = "" if high is None else f"<= {high:g}"
    allowed = " and ".join(t for t in (lo, hi) if t) or "finite"
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite ({allowed}), got {value!r}")
    if (low is not None and (v <= low if low_open else v < low)) or (high is not None and v > high):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    if integer:
        if not v.is_integer():
            raise ValueError(f"{name} must be an integer ({allowed}), got {value!r}")
        return int(v)
    return v


def _choice(name, value, allowed):
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return value


@dataclass(frozen=True)
class TrackingConfig:
    """One run of the study. Defaults are the study's fixed parameters (docs/design.md).

    Parameters
    ----------
    target : {"sphere", "aruco"}
    distortion : {"none", "default"}, BrownConrady or KannalaBrandt
        The lens; "default" is :meth:`BrownConrady.default`. A :class:`KannalaBrandt` fisheye is
        rendered through :class:`gimbal_lab.widefield.WideFieldRenderer`, its focal length set by
        ``hfov_rad`` (f = (W/2)/(hfov/2), the equidistant rule of
        :meth:`KannalaBrandt.equidistant_for_fov`).
    trajectory : {"circular", "diagonal", "cone", "manoeuvring"}
        The paper's two motions, or the lens sweep's cone: a circle about the home optical axis
        at :data:`CONE_RANGE_M` from the home camera, :data:`CONE_FIELD_FRACTION` of the half
        horizontal field off the axis (so it reaches as far into the field for every lens); or
        the occlusion study's manoeuvring target
        (:class:`gimbal_lab.trajectories.ManoeuvringTarget`, its plan drawn from ``seed``).
    mode : {"passive", "active"}
    revolutions : float
        Number of periods simulated (> 0). The study: 2, the first being acquisition.
    period_s : float
        Period of the trajectory (paper: 2 s).
    start_phase_s : float
        Time offset of the target's motion, s, in [0, period_s): the target starts where the
        trajectory is at t = start_phase_s. Replicates draw it from their seed.
    fps : float
        Camera frame rate (30).
    width, height : int
        Image size in pixels (640 × 480).
    hfov_rad : float
        Horizontal field of view (60°); below 179° for a pinhole or Brown–Conrady lens, up to twice
        the fisheye's ``max_field_rad`` for a Kannala–Brandt lens.
    inner_rate_hz : float
        Rate of the inner loop and of the axis integration (1 kHz), >= fps.
    latency_frames : int
        Frames between taking an image and its detection reaching the outer loop (>= 0; 1),
        fewer than the run's frames; >= 1 with an exposure.
    sphere_method : {"circle", "ellipse"}
        Paper's enclosing-circle estimate, or the exact cone (ellipse) method.
    aruco_refinement : {"none", "subpix", "contour", "apriltag"}
        OpenCV corner refinement. The paper does not say which it used; OpenCV's default is
        none. The study uses sub-pixel refinement, the common choice for pose estimation: on
        static rendered poses it halves the translation error of "none" at 3 m (0.48 % vs
        0.79 % of distance, notebook 05). Notebook 08 also runs "none".
    outer_loop : {"paper", "predictive", "filter"}
        Active mode's outer loop: "paper" is the paper's PI law on the pixel error with
        Ziegler–Nichols gains from the outer loop's own plant
        (:meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`); it holds the joints when the
        target is lost. "predictive" filters the line of sight with priors from a stated target
        class and feeds its rate forward (:class:`gimbal_lab.tracking.PredictiveLoop`, an
        extension). "filter" points where a filter on the target's world position predicts it,
        coasting through misses (:class:`gimbal_lab.tracking.FilterPointing`, the occlusion
        study).
    target_filter : {"cv", "ca", "imm"}
        The filter of ``outer_loop="filter"`` (:mod:`gimbal_lab.filters`, default parameters):
        constant velocity, constant acceleration, or the IMM of both with a coordinated turn.
    occluders : tuple of gimbal_lab.scene.Occluder
        Boxes in the world that can hide the target (the occlusion study); none by default.
    lens_strategy : {"ignore", "undistort", "rectify"}
        How the estimator treats the lens (docs/design.md, "Lens sweep"). "ignore" (the paper):
        it assumes a pinhole camera whatever the lens. "undistort": it knows the lens and
        undistorts the detected points (the sphere's contour before its circle or cone fit, the
        marker's corners before solvePnP). "rectify": each frame is first resampled to a pinhole
        image (:class:`gimbal_lab.detection.Rectifier`: the same K for a Brown–Conrady lens, a 90°
        pinhole for a fisheye) and detected there. Both known-lens strategies also give the outer
        loop the lens. Needs a lens unless "ignore".
    sphere_radius_m, marker_length_m : float
        Target sizes (0.10 m sphere; 0.30 m marker on a plate 4/3 as wide); the lens sweep scales
        them with the focal length.
    altitude_m : float
        Height of the drone body above the ground, m (2.0; the lens sweep flies higher so its
        widest cones stay above the ground). Not with ``motion="flight"``, whose path is fixed.
    exposure_s, n_subframes : float, int
        Motion blur: frames integrate ``n_subframes`` renders over ``exposure_s`` (0 s, 1: sharp).
    blur : {"subframes", "fast"}
        How an exposure is integrated: "subframes" averages ``n_subframes`` full renders;
        "fast" is :meth:`gimbal_lab.scene.SceneRenderer.render_motion` (warped layers, global or
        rolling shutter; ``n_subframes`` is then unused).
    readout_s : float
        Rolling-shutter readout time (0: global shutter); row r is exposed from t + r·readout_s/H.
        Needs ``blur="fast"``.
    motion : {"static", "hover", "vibration", "flight"}
        The drone body's motion (:mod:`gimbal_lab.platform`): still (the paper), hover sway, hover
        sway with blade-pass vibration, or the waypoint pass with sway. Drawn from ``seed``.
    motion_phase_s : float
        Time offset into the body's motion, s (>= 0): replicates of the flight start at different
        points of the pass.
    passive_mount : {"stabilised", "fixed"}
        What "passive" means: the gimbal holding its home orientation in the world (the paper's
        passive case; identical to a rigid camera while the body is still), or a camera fixed
        rigidly to the body (:mod:`gimbal_lab.mount`).
    gyro_noise_rad_s_rthz : float
        White-noise density of the camera-platform gyro, rad/s/√Hz (0: ideal, the paper study;
        the moving-drone study: 0.005 °/s/√Hz).
    noise_std : float
        Sensor noise standard deviation in 8-bit grey levels (the study: 2).
    seed : int
        Seed of the run's sensor noise, >= 0.
    """

    target: str = "sphere"
    distortion: object = "none"
    trajectory: str = "circular"
    mode: str = "passive"
    revolutions: float = 2.0
    period_s: float = 2.0
    start_phase_s: float = 0.0
    fps: float = 30.0
    width: int = 640
    height: int = 480
    hfov_rad: float = math.radians(60.0)
    inner_rate_hz: float = 1000.0
    latency_frames: int = 1
    sphere_method: str = "circle"
    aruco_refinement: str = "subpix"
    outer_loop: str = "paper"
    target_filter: str = "imm"
    occluders: tuple = ()
    lens_strategy: str = "ignore"
    sphere_radius_m: float = 0.10
    marker_length_m: float = 0.30
    altitude_m: float = 2.0
    exposure_s: float = 0.0
    n_subframes: int = 1
    blur: str = "subframes"
    readout_s: float = 0.0
    motion: str = "static"
    motion_phase_s: float = 0.0
    passive_mount: str = "stabilised"
    gyro_noise_rad_s_rthz: float = 0.0
    noise_std: float = 2.0
    seed: int = 0

    def __post_init__(self):
        _choice("target", self.target, _TARGETS)
        _choice("trajectory", self.trajectory, _TRAJECTORIES)
        _choice("lens_strategy", self.lens_strategy, _LENS_STRATEGIES)
        _choice("mode", self.mode, _MODES)
        _choice("sphere_method", self.sphere_method, _SPHERE_METHODS)
        _choice("aruco_refinement", self.aruco_refinement, _REFINEMENTS)
        _choice("outer_loop", self.outer_loop, _OUTER_LOOPS)
        _choice("target_filter", self.target_filter, _TARGET_FILTERS)
        from .scene import Occluder

        if isinstance(self.occluders, Occluder) or isinstance(self.occluders, (str, bytes, dict)):
            raise TypeError("occluders must be a sequence of Occluder objects")
        set_occluders = tuple(Occluder(**o) if isinstance(o, dict) else o for o in self.occluders)
        for occluder in set_occluders:
            if not isinstance(occluder, Occluder):
                raise TypeError(f"occluders must be Occluder objects, got {type(occluder).__name__}")
        object.__setattr__(self, "occluders", set_occluders)
        _choice("blur", self.blur, _BLURS)
        _choice("motion", self.motion, _MOTIONS)
        _choice("passive_mount", self.passive_mount, _PASSIVE_MOUNTS)
        if not isinstance(self.distortion, (BrownConrady, KannalaBrandt)):
            if not isinstance(self.distortion, str):
                raise TypeError(f"distortion must be one of {_DISTORTIONS}, a BrownConrady or a KannalaBrandt, "
                                f"got {type(self.distortion).__name__}")
            _choice("distortion", self.distortion, _DISTORTIONS)
        set_ = lambda name, value: object.__setattr__(self, name, value)
        for name in ("revolutions", "period_s", "fps"):
            set_(name, _number(name, getattr(self, name), low=0.0, low_open=True))
        fisheye = isinstance(self.distortion, KannalaBrandt)
        widest = min(2.0 * self.distortion.max_field_rad, 2.0 * math.pi) if fisheye else math.radians(179.0)
        set_("hfov_rad", _number("hfov_rad", self.hfov_rad, low=0.0, high=widest, low_open=True))
        for name in ("sphere_radius_m", "marker_length_m"):
            set_(name, _number(name, getattr(self, name), low=0.0, high=10.0, low_open=True))
        set_("altitude_m", _number("altitude_m", self.altitude_m, low=0.0, high=1000.0, low_open=True))
        if self.motion == "flight" and self.altitude_m != 2.0:
            raise ValueError(f"altitude_m={self.altitude_m:g} needs a static or hovering body; the flight's path is "
                             "fixed at 2 m")
        if self.lens_strategy != "ignore" and self.lens is None:
            raise ValueError(f"lens_strategy={self.lens_strategy!r} needs a lens; this config's camera is an ideal "
                             "pinhole (use 'ignore')")
        if fisheye and self.exposure_s > 0 and self.blur == "fast":
            raise ValueError("a KannalaBrandt lens integrates exposures from sub-frames: use blur='subframes'")
        set_("inner_rate_hz", _number("inner_rate_hz", self.inner_rate_hz, low=self.fps, high=_MAX_INNER_RATE_HZ))
        set_("start_phase_s", _number("start_phase_s", self.start_phase_s, low=0.0))
        if self.start_phase_s >= self.period_s:
            raise ValueError(f"start_phase_s must be in [0, period_s = {self.period_s:g}), got {self.start_phase_s!r}")
        for name in ("width", "height"):
            set_(name, _number(name, getattr(self, name), low=16, high=_MAX_IMAGE_PX, integer=True))
        set_("n_subframes", _number("n_subframes", self.n_subframes, low=1, high=_MAX_SUBFRAMES, integer=True))
        n_frames = self.revolutions * self.period_s * self.fps
        if n_frames > _MAX_FRAMES:
            raise ValueError(f"revolutions × period_s × fps must be <= {_MAX_FRAMES} frames, got {n_frames:g}")
        if self.n_frames < 1:
            raise ValueError(f"the run must hold at least one frame: revolutions × period_s × fps = {n_frames:g}")
        set_("latency_frames", _number("latency_frames", self.latency_frames, low=0, high=max(self.n_frames - 1, 0),
                                       integer=True))
        set_("exposure_s", _number("exposure_s", self.exposure_s, low=0.0, high=1.0 / self.fps))
        if self.exposure_s > 0 and self.latency_frames < 1:
            raise ValueError("exposure_s > 0 needs latency_frames >= 1: a frame is detected after its exposure, so its "
                             "detection cannot steer the camera during it")
        set_("noise_std", _number("noise_std", self.noise_std, low=0.0, high=128.0))
        set_("readout_s", _number("readout_s", self.readout_s, low=0.0, high=1.0 / self.fps))
        if self.readout_s > 0 and self.blur != "fast":
            raise ValueError(f"readout_s > 0 (a rolling shutter) needs blur='fast', got blur={self.blur!r}")
        set_("motion_phase_s", _number("motion_phase_s", self.motion_phase_s, low=0.0, high=1e6))
        set_("gyro_noise_rad_s_rthz", _number("gyro_noise_rad_s_rthz", self.gyro_noise_rad_s_rthz, low=0.0, high=1.0))
        if self.mode == "active" and self.passive_mount != "stabilised":
            raise ValueError(f"passive_mount={self.passive_mount!r} needs mode='passive' (the active camera is "
                             "always on the gimbal)")
        if self.motion != "static" and self.mode == "active" and self.outer_loop != "paper":
            raise ValueError(f"outer_loop={self.outer_loop!r} assumes a still body; use motion='static' or "
                             "outer_loop='paper'")
        if self.occluders and self.exposure_s > 0 and self.blur == "fast":
            raise ValueError("occluders need blur='subframes': the fast blur cannot put the target behind them")
        set_("seed", _number("seed", self.seed, low=0, high=2**63 - 1, integer=True))

    # Derived quantities -------------------------------------------------------------------
    @property
    def intrinsics(self) -> Intrinsics:
        if isinstance(self.distortion, KannalaBrandt):
            f_px = KannalaBrandt.equidistant_for_fov(self.width, self.hfov_rad)[1]
            return Intrinsics(f_px, f_px, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.width, self.height)
        return Intrinsics.from_fov(self.width, self.height, self.hfov_rad)

    @property
    def lens(self) -> BrownConrady | KannalaBrandt | None:
        """The camera's lens model, or None for an ideal pinhole lens."""
        if isinstance(self.distortion, KannalaBrandt):
            return self.distortion
        if isinstance(self.distortion, BrownConrady):
            return None if self.distortion.is_identity else self.distortion
        return BrownConrady.default() if self.distortion == "default" else None

    @property
    def calibrated(self) -> bool:
        """Whether the estimator and the outer loop know the lens (any strategy but "ignore")."""
        return self.lens_strategy != "ignore"

    @property
    def distortion_label(self) -> str:
        if isinstance(self.distortion, KannalaBrandt):
            return "fisheye"
        if isinstance(self.distortion, BrownConrady):
            return "custom"
        return "distorted" if self.distortion == "default" else "undistorted"

    @property
    def home_camera_m(self) -> np.ndarray:
        """The camera's optical centre at the gimbal's home pose with the body at rest, world frame, m."""
        return np.array(BODY_POSITION_M[:2] + (self.altitude_m,)) + _home_camera_offset_m()

    @property
    def path(self) -> Trajectory:
        if self.trajectory == "manoeuvring":
            return _manoeuvring_path(self.seed, self.revolutions * self.period_s + self.period_s)
        if self.trajectory != "cone":
            return Trajectory(self.trajectory, period_s=self.period_s)
        half_angle = CONE_FIELD_FRACTION * 0.5 * self.hfov_rad
        centre = self.home_camera_m + np.array([CONE_RANGE_M * math.cos(half_angle), 0.0, 0.0])
        return Trajectory("circular", period_s=self.period_s, centre_m=centre,
                          radius_m=CONE_RANGE_M * math.sin(half_angle))

    @property
    def mount(self) -> str:
        """The camera mount: "active", or the passive mount ("stabilised" or "fixed")."""
        return "active" if self.mode == "active" else self.passive_mount

    @property
    def body(self):
        """The drone body's motion (:class:`gimbal_lab.platform.BodyMotion`), seeded from ``seed``."""
        from .platform import BodyMotion

        seed = int(np.random.SeedSequence([self.seed, 1]).generate_state(1)[0])
        position_m = BODY_POSITION_M[:2] + (self.altitude_m,)
        if self.motion == "static":
            return BodyMotion.static(position_m)
        if self.motion == "flight":
            body = BodyMotion.flying(seed)
        else:
            body = BodyMotion.hover(seed, vibration=self.motion == "vibration", position_m=position_m)
        return replace(body, time_offset_s=self.motion_phase_s)

    @property
    def n_frames(self) -> int:
        return int(round(self.revolutions * self.period_s * self.fps))

    @property
    def frames_per_revolution(self) -> float:
        return self.period_s * self.fps

    def replace(self, **changes) -> "TrackingConfig":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["occluders"] = [asdict(o) for o in self.occluders]
        if isinstance(self.distortion, BrownConrady):
            out["distortion"] = {k: float(v) for k, v in asdict(self.distortion).items()}
        elif isinstance(self.distortion, KannalaBrandt):
            out["distortion"] = {"model": "kannala_brandt",
                                 **{k: float(v) for k, v in asdict(self.distortion).items()}}
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "TrackingConfig":
        """The config :meth:`to_dict` described (unknown keys are an error naming them)."""
        data = dict(data)
        unknown = sorted(set(data) - {f for f in cls.__dataclass_fields__})
        if unknown:
            raise ValueError(f"unknown TrackingConfig field(s): {', '.join(unknown)}")
        if isinstance(data.get("distortion"), dict):
            lens = dict(data["distortion"])
            model = lens.pop("model", "brown_conrady")
            if model not in ("brown_conrady", "kannala_brandt"):
                raise ValueError(f"unknown lens model {model!r} (brown_conrady or kannala_brandt)")
            data["distortion"] = (KannalaBrandt if model == "kannala_brandt" else BrownConrady)(**lens)
        return cls(**data)

    @property
    def key(self) -> str:
        """A short stable hash of every field (the results store adds the package's source hash)."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @property
    def label(self) -> str:
        if self.motion != "static":
            return f"{self.target}/{self.motion}/{self.mount}"
        base = f"{self.target}/{self.distortion_label}/{self.trajectory}/{self.mode}"
        return base if self.lens_strategy == "ignore" else f"{base}/{self.lens_strategy}"


@dataclass
class TrackingResult:
    """What :func:`simulate` returns.

    Attributes
    ----------
    config : TrackingConfig
    frames : pandas.DataFrame
        One row per camera frame; see :data:`FRAME_COLUMNS` for the columns and units.
    timing : dict
        Wall-clock seconds spent rendering, detecting and in the rest of the loop (not part of
        the science; varies between machines).
    """

    config: TrackingConfig
    frames: pd.DataFrame
    timing: dict = field(default_factory=dict)

    @property
    def error_m(self) -> pd.Series:
        """|d_est − d_true| on detected frames, metres."""
        return self.frames.loc[self.frames["detected"], "abs_error_m"]


FRAME_COLUMNS = {
    "frame": "frame index",
    "t_s": "time the frame's exposure starts, s (run time; the target's motion time is t_s + start_phase_s)",
    "t_mid_s": "truth instant, s: mid-exposure (rolling shutter: mid-exposure of the target's row); the truth "
               "and the camera pose refer to it",
    "revolution": "revolution the mid-exposure instant falls in, counted from 0 (0: acquisition)",
    "detected": "target detected and localised",
    "true_x_m, true_y_m, true_z_m": "true target centre, world frame",
    "est_x_m, est_y_m, est_z_m": "estimated target centre, world frame (NaN if not detected)",
    "true_cam_x_m, true_cam_y_m, true_cam_z_m": "true centre, camera optical frame",
    "est_cam_x_m, est_cam_y_m, est_cam_z_m": "estimate, camera optical frame",
    "d_true_m, d_est_m": "distance camera optical centre → target centre",
    "error_m": "signed d_est − d_true",
    "abs_error_m": "|d_est − d_true|",
    "u_px, v_px": "detected target centre in the image (circle centre / marker corner mean)",
    "offset_px": "distance of the detected centre from the image centre (cx, cy)",
    "true_u_px, true_v_px, true_offset_px": "projection of the true centre through the lens",
    "q_yaw_rad, q_roll_rad, q_pitch_rad": "joint angles at the mid-exposure instant",
    "qd_yaw_rad_s, qd_roll_rad_s, qd_pitch_rad_s": "joint rates when the exposure starts",
    "alt_*": "sphere only: the same columns for the other localiser (circle ↔ ellipse) on the same frame",
    "q0_yaw_rad, q0_roll_rad, q0_pitch_rad": "joint angles when the exposure starts",
    "w_yaw_rad_s, w_roll_rad_s, w_pitch_rad_s": "the camera's inertial rate in the joint basis when the exposure "
                                                "starts (gimbal_lab.mount); with q0 it re-renders a sharp frame",
    "streak_px": "the target's blur streak: length of the true centre's image path over the exposure, px",
    "cam_turn_deg": "largest rotation of the camera within the exposure, degrees (pointing jitter)",
    "hidden": "the line of sight to the target's centre passes through an occluder (truth)",
    "visible_fraction": "fraction of the target's outline seen past the occluders (truth; 1 without occluders)",
    "partial": "sphere: the detected silhouette is cut (gimbal_lab.detection.SphereDetection.partial)",
    "filter_x_m, filter_y_m, filter_z_m": "outer_loop='filter': the filter's predicted target centre at the truth "
                                          "instant, world frame (NaN otherwise or before the track starts)",
    "filter_nees": "normalised error squared of that prediction against the truth (χ² with 3 degrees of freedom "
                   "for a consistent filter)",
}


class _Estimator:
    """Detector + localiser for one config: image → (pixel centre, centre in camera frame, alt).

    For the sphere both localisers run on the same detection: the config's method gives the
    estimate, the other one (circle ↔ ellipse) is recorded alongside as ``alt`` so the two can be
    compared on identical frames (the closed loop only uses the pixel centre, which they share).

    The lens strategy (:class:`TrackingConfig` ``lens_strategy``) decides what the localisers
    know: nothing ("ignore": pinhole with the camera's K), the lens ("undistort": the circle
    method on the undistorted contour, the cone fit on it, solvePnP on undistorted corners), or
    the rectified camera ("rectify": detection and localisation on the pinhole image that
    :class:`gimbal_lab.detection.Rectifier` resamples; the pixel centre is mapped back to the
    camera's own image, where the outer loop measures it).
    """

    def __init__(self, config: TrackingConfig):
        from . import detection

        self.config = config
        self.partial = False
        lens = config.lens
        self.rectifier = detection.Rectifier(config.intrinsics, lens) if config.lens_strategy == "rectify" else None
        self.intrinsics = self.rectifier.out_intrinsics if self.rectifier is not None else config.intrinsics
        self.lens = lens if config.lens_strategy == "undistort" else None
        self.radius_m = config.sphere_radius_m
        K, r, known = self.intrinsics, self.radius_m, self.lens
        if config.target == "sphere":
            self.detector = detection.SphereDetector()
            if known is None:
                circle = lambda det: detection.locate_sphere_circle(det, K, r)  # noqa: E731
            else:
                circle = lambda det: detection.locate_sphere_circle_undistorted(det, K, r, known)  # noqa: E731
            ellipse = lambda det: detection.locate_sphere_ellipse(det, K, r, distortion=known)  # noqa: E731
            self._methods = (circle, ellipse) if config.sphere_method == "circle" else (ellipse, circle)
        else:
            self.detector = detection.ArucoTracker(
                K, marker_length_m=config.marker_length_m, refinement=config.aruco_refinement, distortion=known
            )

    def _centre(self, uv) -> np.ndarray:
        uv = np.asarray(uv, float)
        return uv if self.rectifier is None else self.rectifier.to_source_px(uv).reshape(2)

    def __call__(self, image):
        """(pixel centre, centre in the camera frame, alt) of one frame; ``partial`` says whether
        the sphere's silhouette was cut."""
        from .camera import UndistortionError

        self.partial = False
        if self.rectifier is not None:
            image = self.rectifier.rectify(image)
        if self.config.target == "sphere":
            det = self.detector.detect(image)
            if det is None:
                return None, None, None
            self.partial = det.partial

            def locate(method):
                try:
                    p = method(det)
                except UndistortionError:  # a contour point beyond the lens's field: no estimate
                    return None
                return None if p is None else np.asarray(p, float)

            p, alt = (locate(m) for m in self._methods)
            return self._centre(det.center_px), p, alt
        pose = self.detector.detect(image).get(0)
        if pose is None:
            return None, None, None
        return self._centre(pose.center_px), np.asarray(pose.t_cam_marker_m, float), None


@functools.lru_cache(maxsize=8)
def _manoeuvring_path(seed: int, duration_s: float):
    """The manoeuvring target of a run (its plan drawn once per seed and length)."""
    from .trajectories import ManoeuvringTarget

    plan_seed = int(np.random.SeedSequence([seed, 3]).generate_state(1)[0])
    return ManoeuvringTarget(seed=plan_seed, duration_s=duration_s)


@functools.lru_cache(maxsize=1)
def _home_camera_offset_m() -> np.ndarray:
    """The study gimbal's optical centre at its home pose, body frame, m (computed once: the cone
    trajectory needs it on every frame)."""
    from .kinematics import GimbalKinematics

    offset = GimbalKinematics.default().T_body_cam(np.zeros(3))[:3, 3]
    offset.setflags(write=False)
    return offset


#: Where the UAV body sits in the world during the study (static, level, facing +x).
BODY_POSITION_M = (0.0, 0.0, 2.0)


def world_T_base(kinematics, altitude_m: float = BODY_POSITION_M[2]) -> np.ndarray:
    """4 × 4 ``T_world_base`` of the study: the body still at :data:`BODY_POSITION_M` (at ``altitude_m``
    above the ground), axes = world's."""
    T_world_body = np.eye(4)
    T_world_body[:3, 3] = BODY_POSITION_M[:2] + (altitude_m,)
    return T_world_body @ kinematics.T_body_base


#: Width of the marker's white plate over the marker's own (0.40 m for the study's 0.30 m marker).
PLATE_TO_MARKER = 0.40 / 0.30


def renderer_key(config: TrackingConfig) -> tuple:
    """What a renderer depends on: two configs with equal keys can share one (:func:`make_renderer`)."""
    return (config.target, config.lens, config.width, config.height, config.hfov_rad, config.sphere_radius_m,
            config.marker_length_m, config.occluders)


def make_renderer(config: TrackingConfig):
    """The scene renderer a config needs (one per :func:`renderer_key`; reusable across runs).

    A Kannala–Brandt lens gets a :class:`gimbal_lab.widefield.WideFieldRenderer` (a cube map
    remapped to the lens); any other lens a :class:`gimbal_lab.scene.SceneRenderer`.
    """
    sizes = dict(sphere_radius_m=config.sphere_radius_m, marker_length_m=config.marker_length_m,
                 plate_size_m=PLATE_TO_MARKER * config.marker_length_m, occluders=config.occluders)
    if isinstance(config.lens, KannalaBrandt):
        from .widefield import WideFieldRenderer

        return WideFieldRenderer(config.intrinsics, config.lens, target=config.target, **sizes)
    from .scene import SceneRenderer

    return SceneRenderer(config.intrinsics, distortion=config.lens, target=config.target, **sizes)


class Measurement(NamedTuple):
    """What the estimator made of one frame, as it reaches the outer loop ``latency_frames`` later."""

    frame: int
    t_s: float  # the frame's truth instant (mid-exposure)
    uv_px: np.ndarray | None  # detected centre, px (None: not detected)
    q_rad: np.ndarray  # joint angles at that instant
    range_m: float | None  # the estimator's distance to the target
    p_cam_m: np.ndarray | None  # the estimated target centre, camera optical frame
    T_world_cam: np.ndarray  # the camera's pose at that instant


class _OuterLoopPart:
    """What every outer-loop part offers: ``observe(measurement, q0)``, ``command(t_s, q0)`` and
    ``prediction(t_s)``, the target estimate it logs (None: it keeps none)."""

    def prediction(self, t_s: float):
        return None


class _PaperLoop(_OuterLoopPart):
    """The paper's image loop as an outer-loop part: a new rate reference per measurement, held
    between measurements; zero rate (hold) while the target is not detected."""

    def __init__(self, image_loop, kin, fps: float):
        self.image_loop, self.kin, self.dt_s = image_loop, kin, 1.0 / fps
        self.rate = np.zeros(3)

    def observe(self, m: Measurement, q0) -> None:
        J_cam = self.kin.angular_jacobian(q0, frame="camera", check_limits=False)
        self.rate = np.asarray(self.image_loop.update(m.uv_px, self.dt_s, J_cam, q0), float)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.rate


class _PredictiveLoop(_OuterLoopPart):
    """The line-of-sight predictive loop as an outer-loop part."""

    def __init__(self, loop):
        self.loop = loop

    def observe(self, m: Measurement, q0) -> None:
        self.loop.observe(m.t_s, m.uv_px, m.q_rad, range_m=m.range_m)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.loop.command(t_s, q0)


class _FilterLoop(_OuterLoopPart):
    """Pointing driven by a filter on the target's world position, as an outer-loop part."""

    def __init__(self, pointing):
        self.pointing = pointing

    def observe(self, m: Measurement, q0) -> None:
        self.pointing.observe(m.t_s, m.p_cam_m, m.T_world_cam)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.pointing.command(t_s, q0)

    def prediction(self, t_s: float):
        return self.pointing.prediction(t_s)


def make_target_filter(name: str):
    """The target filter ``name`` ("cv", "ca" or "imm") with its default parameters."""
    from . import filters

    _choice("target_filter", name, _TARGET_FILTERS)
    return {"cv": filters.ConstantVelocity, "ca": filters.ConstantAcceleration, "imm": filters.IMM}[name]()


def _outer_loop(config: TrackingConfig, kin, pixel_lens):
    """The active mode's outer-loop part (``observe(measurement, q0)``, ``command(t_s, q0)``,
    ``prediction(t_s)``), or None for passive (zero rate references)."""
    if config.mode != "active":
        return None
    if config.outer_loop == "paper":
        from .control import ImageLoop

        image_loop = ImageLoop.ziegler_nichols(config.intrinsics, config.fps, config.latency_frames,
                                               distortion=pixel_lens)
        return _PaperLoop(image_loop, kin, config.fps)
    if config.outer_loop == "predictive":
        from .tracking import PredictiveLoop

        return _PredictiveLoop(PredictiveLoop(config.intrinsics, kin, distortion=pixel_lens))
    from .tracking import FilterPointing

    return _FilterLoop(FilterPointing(kin, world_T_base(kin, config.altitude_m), make_target_filter(config.target_filter),
                                      focal_px=config.intrinsics.fx, radius_m=config.sphere_radius_m))


_COLUMNS = [
    "frame", "t_s", "t_mid_s", "revolution", "detected",
    "true_x_m", "true_y_m", "true_z_m", "est_x_m", "est_y_m", "est_z_m",
    "true_cam_x_m", "true_cam_y_m", "true_cam_z_m", "est_cam_x_m", "est_cam_y_m", "est_cam_z_m",
    "d_true_m", "d_est_m", "error_m", "abs_error_m", "u_px", "v_px", "offset_px",
    "true_u_px", "true_v_px", "true_offset_px",
    "q_yaw_rad", "q_roll_rad", "q_pitch_rad", "qd_yaw_rad_s", "qd_roll_rad_s", "qd_pitch_rad_s",
    "alt_detected", "alt_est_x_m", "alt_est_y_m", "alt_est_z_m",
    "alt_est_cam_x_m", "alt_est_cam_y_m", "alt_est_cam_z_m", "alt_d_est_m", "alt_error_m", "alt_abs_error_m",
    "q0_yaw_rad", "q0_roll_rad", "q0_pitch_rad", "w_yaw_rad_s", "w_roll_rad_s", "w_pitch_rad_s",
    "streak_px", "cam_turn_deg",
    "hidden", "visible_fraction", "partial", "filter_x_m", "filter_y_m", "filter_z_m", "filter_nees",
]


def truth_time(config: TrackingConfig, t_s: float, camera_fn, target_fn) -> float:
    """The instant a frame exposed from ``t_s`` shows the target: its truth time, s.

    Global shutter: mid-exposure, t_s + exposure_s/2. Rolling shutter: the row v through the
    target's true centre is read from t_s + v·readout_s/H, so the instant is
    t_s + v·readout_s/H + exposure_s/2, with v the row at that instant (a fixed point, found by
    iteration: the target moves a fraction of a row per iteration's change of time).
    """
    t = t_s + 0.5 * config.exposure_s
    if config.readout_s <= 0:
        return t
    K, lens, rows = config.intrinsics, config.lens, config.height
    for _ in range(4):
        T_cam = camera_fn(t)[1]
        p = T_cam[:3, :3].T @ (target_fn(t)[:3, 3] - T_cam[:3, 3])
        v = project(p, K, lens)[0, 1] if p[2] > 0 else 0.5 * (rows - 1)
        t = t_s + min(max(v, 0.0), rows - 1) * config.readout_s / rows + 0.5 * config.exposure_s
    return t


def _target_visibility(config: TrackingConfig, camera_m, T_world_target) -> np.ndarray:
    """Which of the target's centre and outline points the camera sees past the occluders.

    Returns
    -------
    ndarray of bool, shape (1 + n,)
        The centre first, then the outline: 32 points of the sphere's silhouette circle
        (:func:`gimbal_lab.scene.sphere_rim_points`) or the marker's 4 corners.
    """
    from .scene import marker_corners, points_visible, sphere_rim_points

    centre = T_world_target[:3, 3]
    if config.target == "sphere":
        outline = sphere_rim_points(camera_m, centre, config.sphere_radius_m)
    else:
        outline = marker_corners(T_world_target, config.marker_length_m)
    return points_visible(config.occluders, camera_m, np.vstack([centre, outline]))


def render_frame(config: TrackingConfig, renderer, camera_fn, t_s: float):
    """The image of the frame exposed from ``t_s`` (before sensor noise) and its state at the truth time.

    ``camera_fn(t) -> (q, T_world_cam)`` gives the joint angles and the camera pose at any instant
    of the exposure (:func:`gimbal_lab.mount.exposure_pose_fn`); when it also offers
    ``camera_fn.many(times)`` (:class:`gimbal_lab.mount.ExposurePose`), the renderer samples the
    motion at all its instants at once through it. With ``exposure_s > 0`` the image
    integrates the exposure (``blur``: several full renders, or the fast warped layers with a
    global or rolling shutter); otherwise it is the single instant ``t_s``.

    Returns
    -------
    image, q, T_world_cam, T_world_target, t_truth_s
        ``q`` and the poses at the truth instant (:func:`truth_time`: mid-exposure, or the instant
        the target's row was read).
    """
    path, phase = config.path, config.start_phase_s
    target_fn = lambda t: target_pose(path, t + phase)
    t_truth = truth_time(config, t_s, camera_fn, target_fn)
    q, T_world_cam = camera_fn(t_truth)
    T_world_target = target_fn(t_truth)

    def pose_fn(t):
        return camera_fn(t)[1], target_fn(t)

    if hasattr(camera_fn, "many"):
        pose_fn.many = lambda times: (camera_fn.many(times)[1], np.array([target_fn(t) for t in times]))
    if config.exposure_s > 0 and config.blur == "fast":
        image = renderer.render_motion(pose_fn, t_s, config.exposure_s, config.readout_s)
    elif config.exposure_s > 0 and config.n_subframes > 1:
        image = renderer.render_exposure(pose_fn, t_s, config.exposure_s, config.n_subframes)
    else:
        image = renderer.render(T_world_cam, T_world_target)
    return image, q, T_world_cam, T_world_target, t_truth


def image_motion(config: TrackingConfig, t_truth_s: float, camera_fn, n: int = 33) -> tuple[float, float]:
    """The target's blur streak (px) and the camera's rotation (rad) over the exposure around ``t_truth_s``.

    ``t_truth_s`` is the frame's truth instant (:func:`render_frame` returns it): the middle of the
    exposure of the target's row.

    The streak is the length of the path the target's true centre draws on the image during the
    exposure, sampled at ``n`` instants (for a rolling shutter: over the exposure of the target's
    row). The camera's rotation is the largest angle between its orientation at the exposure's
    start and at any sampled instant (pointing jitter within one frame). The camera's poses come
    from ``camera_fn.many(times)`` when it has one (:class:`gimbal_lab.mount.ExposurePose`), else
    from ``camera_fn(t)`` at each instant.
    """
    if config.exposure_s <= 0:
        return 0.0, 0.0
    t0 = t_truth_s - 0.5 * config.exposure_s
    times = np.linspace(t0, t0 + config.exposure_s, n)
    if hasattr(camera_fn, "many"):
        T_cam = camera_fn.many(times)[1]
    else:
        T_cam = np.array([camera_fn(t)[1] for t in times])
    R, c = T_cam[:, :3, :3], T_cam[:, :3, 3]
    p = np.einsum("nji,nj->ni", R, config.path.position(times + config.start_phase_s) - c)  # Rᵀ·(x − c)
    uv = np.full((n, 2), math.nan)
    front = p[:, 2] > 0
    if front.any():
        uv[front] = project(p[front], config.intrinsics, config.lens)
    streak = float(np.sum(np.hypot(*np.diff(uv, axis=0).T)))
    cos_angle = (np.trace(R[0].T @ R[1:], axis1=1, axis2=2) - 1.0) / 2.0
    return streak, float(np.max(np.arccos(np.clip(cos_angle, -1.0, 1.0)), initial=0.0))


def simulate(config: TrackingConfig, renderer=None, progress: bool = False) -> TrackingResult:
    """Run one closed-loop tracking experiment.

    Parameters
    ----------
    config : TrackingConfig
    renderer : gimbal_lab.scene.SceneRenderer, optional
        A renderer built for this config's camera, lens and target (reused across runs by
        :mod:`gimbal_lab.runner`); built and closed here when omitted.
    progress : bool
        Show a progress bar over frames.

    Returns
    -------
    TrackingResult

    Notes
    -----
    Paper §4.1 and Fig. 5. Same config (seed included) → identical frame table.
    """
    if not isinstance(config, TrackingConfig):
        raise TypeError(f"config must be a TrackingConfig, got {type(config).__name__}")
    own_renderer = renderer is None
    if own_renderer:
        renderer = make_renderer(config)
    timing = {"render_s": 0.0, "detect_s": 0.0, "total_s": 0.0}
    t_start = time.perf_counter()
    try:
        frames = closed_loop(config, renderer, timing)
        if progress:
            from tqdm.auto import tqdm

            frames = tqdm(frames, total=config.n_frames, desc=config.label, unit="frame")
        rows = [row for row, _ in frames]
    finally:
        if own_renderer:
            renderer.close()
    timing["total_s"] = time.perf_counter() - t_start
    table = pd.DataFrame.from_records(rows, columns=_COLUMNS)
    return TrackingResult(config=config, frames=table, timing=timing)


def closed_loop(config: TrackingConfig, renderer, timing: dict | None = None):
    """The closed loop of :func:`simulate`, frame by frame: yields ``(row, image)``.

    ``row`` is the frame's tuple of values in the order of the frame table's columns
    (:data:`FRAME_COLUMNS` describes them) and ``image`` the noisy frame the detector saw (RGB,
    uint8). ``timing`` (optional) accumulates ``render_s`` and ``detect_s``.
    :func:`gimbal_lab.show.replay` runs it again to show a blurred run's frames exactly.
    """
    from .kinematics import GimbalKinematics
    from .mount import GimbalMount
    from .scene import add_sensor_noise

    timing = {"render_s": 0.0, "detect_s": 0.0} if timing is None else timing
    rng = np.random.default_rng(config.seed)
    K = config.intrinsics
    lens = config.lens
    estimate = _Estimator(config)
    kin = GimbalKinematics.default()

    dt_s = 1.0 / config.inner_rate_hz
    n_frames = config.n_frames
    n_steps = int(round(n_frames / config.fps * config.inner_rate_hz))
    frame_steps = np.round(np.arange(n_frames + 1) * config.inner_rate_hz / config.fps).astype(int)
    frame_steps[-1] = n_steps
    body = config.body
    gyro_rng = np.random.default_rng(np.random.SeedSequence([config.seed, 2]))
    mount = GimbalMount(kin, body, config.mount, dt_s, n_steps, config.gyro_noise_rad_s_rthz, gyro_rng)
    pixel_lens = lens if config.calibrated else None  # the lens the outer loop knows
    outer = _outer_loop(config, kin, pixel_lens)
    occluders = config.occluders

    pending: deque = deque()
    rate_ref = np.zeros(3)
    window_s = config.exposure_s + config.readout_s
    # A sharp frame is the instant its exposure starts. A blurred frame integrates the camera's
    # real motion, so the frame's inner steps run first (their rate reference comes from frames
    # already detected: latency_frames >= 1) and the exposure is rendered from the joint angles
    # recorded on the way.
    run_first = config.exposure_s > 0

    def steer(k, q0):
        """The outer loop at frame k: the measurement of frame k − latency arrives."""
        nonlocal rate_ref
        if outer is None:
            return
        if pending and pending[0].frame <= k - config.latency_frames:
            outer.observe(pending.popleft(), q0)
        rate_ref = outer.command(k / config.fps, q0)

    for k in range(n_frames):
        t_s = k / config.fps
        q0 = mount.q
        qd = mount.qd
        w0 = mount.smooth_axis_rates
        if run_first:
            steer(k, q0)
            mount.advance(frame_steps[k + 1] - frame_steps[k], rate_ref)
            camera_fn = mount.recorded_pose_fn(t_s, t_s + window_s)
        else:
            camera_fn = mount.exposure_pose_fn(t_s, t_s + window_s)

        t0 = time.perf_counter()
        image, q, T_world_cam, T_world_target, t_mid = render_frame(config, renderer, camera_fn, t_s)
        image = add_sensor_noise(image, config.noise_std, rng)
        t1 = time.perf_counter()
        uv, p_cam, p_cam_alt = estimate(image)
        partial = estimate.partial
        timing["detect_s"] += time.perf_counter() - t1
        timing["render_s"] += t1 - t0
        streak_px, cam_turn_rad = image_motion(config, t_mid, camera_fn)

        p_true = T_world_target[:3, 3]
        R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
        p_cam_true = R.T @ (p_true - c)
        true_uv = project(p_cam_true, K, lens)[0]
        detected = p_cam is not None and bool(np.all(np.isfinite(p_cam)))
        p_est = R @ p_cam + c if detected else np.full(3, np.nan)
        p_cam_est = p_cam if detected else np.full(3, np.nan)
        d_true = float(np.linalg.norm(p_cam_true))
        d_est = float(np.linalg.norm(p_cam_est)) if detected else math.nan
        alt_ok = p_cam_alt is not None and bool(np.all(np.isfinite(p_cam_alt)))
        p_cam_alt = p_cam_alt if alt_ok else np.full(3, np.nan)
        p_alt = R @ p_cam_alt + c
        d_alt = float(np.linalg.norm(p_cam_alt))
        u, v = (uv if uv is not None else (math.nan, math.nan))
        if occluders:
            visible = _target_visibility(config, c, T_world_target)
            hidden, visible_fraction = not visible[0], float(np.mean(visible[1:]))
        else:
            hidden, visible_fraction = False, 1.0
        predicted = outer.prediction(t_mid) if outer is not None else None
        if predicted is None:
            p_filter, filter_nees = np.full(3, np.nan), math.nan
        else:
            p_filter = predicted[0]
            e = p_true - p_filter
            filter_nees = float(e @ np.linalg.solve(predicted[1], e))
        row = (
            (k, t_s, t_mid, int(t_mid // config.period_s), detected, *p_true, *p_est, *p_cam_true, *p_cam_est,
             d_true, d_est, d_est - d_true, abs(d_est - d_true), u, v, math.hypot(u - K.cx, v - K.cy),
             *true_uv, math.hypot(true_uv[0] - K.cx, true_uv[1] - K.cy), *q, *qd,
             alt_ok, *p_alt, *p_cam_alt, d_alt, d_alt - d_true, abs(d_alt - d_true),
             *q0, *w0, streak_px, math.degrees(cam_turn_rad),
             hidden, visible_fraction, partial, *p_filter, filter_nees)
        )
        # the measurement of frame k reaches the outer loop latency_frames frames later
        pending.append(Measurement(k, t_mid, uv, q, d_est if detected else None, p_cam if detected else None,
                                   T_world_cam))
        if not run_first:
            steer(k, q0)
            mount.advance(frame_steps[k + 1] - frame_steps[k], rate_ref)
        yield row, image
