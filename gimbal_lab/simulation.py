"""The closed tracking loop of the study (paper §4.1, Fig. 5).

trajectory → render (with lens distortion and sensor noise) → detect → localise → (active) outer
image loop → inner rate loops → gimbal axes → forward kinematics → next camera pose.

The run is described by a :class:`gimbal_lab.config.TrackingConfig` of parts (camera, gimbal,
platform, target, pointing, estimator), and the loop is composed of what they build: the camera's
renderer, exposure and noise, the estimator, the gimbal's mount on the platform's body, the
pointing's outer loop, the target's path and occluders. It has no branch on a part's kind.

The inner loop and the axis dynamics run at ``gimbal.inner_rate_hz`` (1 kHz by default); the
camera takes a frame every 1/fps seconds. A detection made on frame k reaches the outer loop
``camera.latency_frames`` frames later. A passive pointing holds the camera (stabilised at its
home pose, or fixed to the body); an active one turns the target's image into joint-rate
references: the paper's PI law on the pixel error with Ziegler–Nichols gains
(:meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`), the predictive line-of-sight loop
(:class:`gimbal_lab.tracking.PredictiveLoop`, an extension) or filter-driven pointing
(:class:`gimbal_lab.tracking.FilterPointing`).

A frame is exposed over [t, t + exposure_s]; its truth is taken at the **mid-exposure instant**
t + exposure_s/2 (the target's position and the camera's pose then), and the estimate is mapped
to the world through the camera pose at that same instant. The metric is |d_est − d_true|, with d
the distance from the camera's optical centre to the target's centre (paper §4.1).

Replicates: a config's ``target.start_phase_s`` shifts the target's motion in time and its
``seed`` draws the sensor noise, the body's motion, the gyro noise and a manoeuvring plan, each
from its own named stream (:func:`gimbal_lab.config.seed_stream`), so replicates of one cell differ
only by those draws (:func:`gimbal_lab.studies.paper.grid` draws the phase from the replicate's
"phase" stream).

Rendering needs an OpenGL context: a process that ran :func:`simulate` must not fork
(see :mod:`gimbal_lab.scene`); :mod:`gimbal_lab.runner` runs configs on spawned workers.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .camera import project
from .config import (CONE_FIELD_FRACTION, CONE_RANGE_M, SPHERE_FAMILY_COLUMNS, Measurement,  # noqa: F401
                     TrackingConfig, seed_stream, world_T_base)
from .trajectories import target_pose

__all__ = ["TrackingConfig", "TrackingResult", "simulate", "render_frame", "FRAME_COLUMNS", "frame_columns",
           "world_T_base", "make_renderer", "renderer_key", "CONE_RANGE_M", "CONE_FIELD_FRACTION"]


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
    "streak_px": "the target's blur streak as rendered: length of the true centre's image path over the exposure, px (0 for blur \"none\")",
    "cam_turn_deg": "largest rotation of the camera within the exposure, degrees (pointing jitter)",
    "hidden": "the line of sight to the target's centre passes through an occluder (truth)",
    "visible_fraction": "fraction of the target's outline seen past the occluders (truth; 1 without occluders)",
    "partial": "sphere: the detected silhouette is cut (gimbal_lab.detection.SphereDetection.partial)",
    "filter_x_m, filter_y_m, filter_z_m": "pointing 'filter': the filter's predicted target centre at the truth "
                                          "instant, world frame, while its track is live (NaN otherwise, before "
                                          "the track starts and once its last accepted fix is older than the "
                                          "coasting time: gimbal_lab.tracking.FilterPointing.live)",
    "filter_nees": "normalised error squared of that prediction against the truth (χ² with 3 degrees of freedom "
                   "for a consistent filter)",
    "at_limit_yaw, at_limit_roll, at_limit_pitch": "the joint sits at its mechanical stop (gimbal.kinematics' "
                                                   "joint_limits_rad) when the exposure starts (gimbal_lab.mount)",
    "known_q_yaw_rad, known_q_roll_rad, known_q_pitch_rad": "the joint angles the loop took for the frame: the "
                                                            "truth in-process; behind a link, those of the latest "
                                                            "attitude status received when the exposure starts (the "
                                                            "home pose before the first), carried to the truth "
                                                            "instant by its rates with pointing.link.attitude "
                                                            "'propagated'; est_* use them",
    "known_age_s": "truth instant minus the instant the known joints were sampled, s (0 in-process)",
    "cmd_yaw_rad_s, cmd_roll_rad_s, cmd_pitch_rad_s": "the joint-rate reference the outer loop gave after the "
                                                      "frame, rad/s (held until the next frame's)",
    "<method>_*": "only in runs whose estimator.extra_methods name it, after every other column: the alt_* "
                  "columns for that sphere method (circle_, ellipse_ or streak_) on the same detection and frame",
}


def frame_columns(config: TrackingConfig) -> list:
    """The columns of ``config``'s frame table, in order: every run's (:data:`FRAME_COLUMNS`), then one
    family per method of ``config.estimator.extra_methods`` (``<method>_detected``, ...)."""
    return _COLUMNS + [f"{method}_{name}" for method in config.estimator.extra_methods
                       for name in SPHERE_FAMILY_COLUMNS]


def renderer_key(config: TrackingConfig) -> tuple:
    """What a renderer depends on: two configs with equal keys can share one (:func:`make_renderer`)."""
    return config.renderer_key


def make_renderer(config: TrackingConfig):
    """The scene renderer a config needs (one per :func:`renderer_key`; reusable across runs):
    :meth:`gimbal_lab.config.Camera.make_renderer` of the config's camera and target."""
    return config.camera.make_renderer(config.target)


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
    "at_limit_yaw", "at_limit_roll", "at_limit_pitch",
    "known_q_yaw_rad", "known_q_roll_rad", "known_q_pitch_rad", "known_age_s",
    "cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s",
]


class DirectGimbal:
    """The outer loop's side of an in-process gimbal: it reads the mount's joints and sets its
    axes' references directly (the paper's simulation; :func:`connect`).

    A linked gimbal (:class:`gimbal_lab.mavlink.loop.LinkedGimbal`) offers the same four calls
    through the MAVLink driver; the closed loop calls them alike.

    Parameters
    ----------
    mount : gimbal_lab.mount.GimbalMount
        The gimbal (the truth).
    """

    def __init__(self, mount):
        self.mount = mount

    def joints(self, t_s: float) -> np.ndarray:
        """The joint angles the loop knows when the frame at ``t_s`` starts, rad: the mount's."""
        return self.mount.q

    def frame_pose(self, t_s: float, q_truth, T_world_cam_truth):
        """``(q, T_world_cam, age_s)`` the loop maps the frame's detection with, at its truth instant
        ``t_s``: in-process, the truth itself (age 0)."""
        return q_truth, T_world_cam_truth, 0.0

    def drive(self, n_steps: int, rate_ref, q_known) -> None:
        """Run the axes ``n_steps`` inner steps following ``rate_ref`` (joint rates, rad/s)."""
        self.mount.advance(n_steps, rate_ref)

    def close(self) -> None:
        """Nothing to release in-process."""


def connect(config: TrackingConfig, mount):
    """The outer loop's side of the run's gimbal: :class:`DirectGimbal` in-process, or, when
    ``config.pointing.link`` is set, :class:`gimbal_lab.mavlink.loop.LinkedGimbal` (the mount run by
    the simulated MAVLink device, lock-step over loopback UDP; needs the ``[mavlink]`` extra)."""
    if config.pointing.link is None:
        return DirectGimbal(mount)
    from .mavlink.loop import LinkedGimbal

    return LinkedGimbal(config, mount)


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
        ``q`` and the poses at the truth instant (:meth:`gimbal_lab.config.Camera.truth_time`:
        mid-exposure, or the instant the target's row was read).
    """
    path, phase = config.path, config.target.start_phase_s
    target_fn = lambda t: target_pose(path, t + phase)
    t_truth = config.camera.truth_time(t_s, camera_fn, target_fn)
    q, T_world_cam = camera_fn(t_truth)
    T_world_target = target_fn(t_truth)

    def pose_fn(t):
        return camera_fn(t)[1], target_fn(t)

    if hasattr(camera_fn, "many"):
        pose_fn.many = lambda times: (camera_fn.many(times)[1], np.array([target_fn(t) for t in times]))
    image = config.camera.expose(renderer, pose_fn, t_s, T_world_cam, T_world_target)
    return image, q, T_world_cam, T_world_target, t_truth


def image_motion(config: TrackingConfig, t_truth_s: float, camera_fn, n: int = 33) -> tuple[float, float]:
    """The target's blur streak (px) and the camera's rotation (rad) over the exposure around ``t_truth_s``.

    ``t_truth_s`` is the frame's truth instant (:func:`render_frame` returns it): the middle of the
    exposure of the target's row.

    The streak is the length of the path the target's true centre draws on the image during the
    exposure, sampled at ``n`` instants (for a rolling shutter: over the exposure of the target's
    row): the streak of the frame as rendered, so 0 for ``camera.blur="none"`` (one sharp
    instant). Sub-frames whose count is derived from the streak space their copies at most
    :data:`gimbal_lab.config.SUBFRAME_STEP_PX` apart, so their rendered streak is this one to
    that step; a count given by hand renders (n − 1)/n of it. The camera's rotation is the largest angle between its orientation at the exposure's
    start and at any sampled instant (pointing jitter within one frame). The camera's poses come
    from ``camera_fn.many(times)`` when it has one (:class:`gimbal_lab.mount.ExposurePose`), else
    from ``camera_fn(t)`` at each instant.
    """
    camera = config.camera
    if camera.exposure_s <= 0:
        return 0.0, 0.0
    t0 = t_truth_s - 0.5 * camera.exposure_s
    rendered = camera.blur != "none"  # blur "none": one sharp instant, no streak on the image
    times = np.linspace(t0, t0 + camera.exposure_s, n)
    if hasattr(camera_fn, "many"):
        T_cam = camera_fn.many(times)[1]
    else:
        T_cam = np.array([camera_fn(t)[1] for t in times])
    R, c = T_cam[:, :3, :3], T_cam[:, :3, 3]
    p = np.einsum("nji,nj->ni", R, config.path.position(times + config.target.start_phase_s) - c)  # Rᵀ·(x − c)
    uv = np.full((n, 2), math.nan)
    front = p[:, 2] > 0
    if front.any():
        uv[front] = project(p[front], camera.intrinsics, camera.lens_model)
    streak = float(np.sum(np.hypot(*np.diff(uv, axis=0).T))) if rendered else 0.0
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
    table = pd.DataFrame.from_records(rows, columns=frame_columns(config))
    return TrackingResult(config=config, frames=table, timing=timing)


def closed_loop(config: TrackingConfig, renderer, timing: dict | None = None):
    """The closed loop of :func:`simulate`, frame by frame: yields ``(row, image)``.

    ``row`` is the frame's tuple of values in the order of the frame table's columns
    (:func:`frame_columns`; :data:`FRAME_COLUMNS` describes them) and ``image`` the noisy frame the detector saw (RGB,
    uint8). ``timing`` (optional) accumulates ``render_s`` and ``detect_s``.
    :func:`gimbal_lab.show.replay` runs it again to show a blurred run's frames exactly.
    """
    timing = {"render_s": 0.0, "detect_s": 0.0} if timing is None else timing
    camera, gimbal = config.camera, config.gimbal
    rng = np.random.default_rng(seed_stream(config.seed, "noise"))
    estimate = config.estimator.build(camera, config.target)
    n_steps = int(round(config.n_frames / camera.fps * gimbal.inner_rate_hz))
    mount = gimbal.mount(config.body, config.pointing.mount, n_steps, config.seed)
    pixel_lens = camera.lens_model if config.estimator.knows_lens else None  # the lens the outer loop knows
    outer = config.pointing.build(config, gimbal.kinematics, pixel_lens)
    link = connect(config, mount)
    try:
        yield from _frames(config, renderer, timing, mount, outer, link, rng, estimate, n_steps)
    finally:
        link.close()


def _frames(config, renderer, timing, mount, outer, link, rng, estimate, n_steps):
    """The frames of :func:`closed_loop`: ``mount`` is the truth, ``link`` what the loop knows and drives."""
    camera, gimbal, target = config.camera, config.gimbal, config.target
    K = camera.intrinsics
    lens = camera.lens_model
    n_frames = config.n_frames
    frame_steps = np.round(np.arange(n_frames + 1) * gimbal.inner_rate_hz / camera.fps).astype(int)
    frame_steps[-1] = n_steps

    pending: deque = deque()
    rate_ref = np.zeros(3)
    window_s = camera.window_s
    # A sharp frame is the instant its exposure starts. A blurred frame integrates the camera's
    # real motion, so the frame's inner steps run first (their rate reference comes from frames
    # already detected: latency_frames >= 1) and the exposure is rendered from the joint angles
    # recorded on the way.
    run_first = camera.exposure_s > 0

    def steer(k, q0):
        """The outer loop at frame k: the measurement of frame k − latency arrives."""
        nonlocal rate_ref
        if pending and pending[0].frame <= k - camera.latency_frames:
            outer.observe(pending.popleft(), q0)
        rate_ref = outer.command(k / camera.fps, q0)

    for k in range(n_frames):
        t_s = k / camera.fps
        q0 = mount.q
        qd = mount.qd
        w0 = mount.smooth_axis_rates
        at_limit = mount.at_limit
        q_known = link.joints(t_s)
        if run_first:
            steer(k, q_known)
            link.drive(frame_steps[k + 1] - frame_steps[k], rate_ref, q_known)
            camera_fn = mount.recorded_pose_fn(t_s, t_s + window_s)
        else:
            camera_fn = mount.exposure_pose_fn(t_s, t_s + window_s)

        t0 = time.perf_counter()
        image, q, T_world_cam, T_world_target, t_mid = render_frame(config, renderer, camera_fn, t_s)
        image = camera.add_noise(image, rng)
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
        # the estimate goes to the world through the pose the loop knows (the truth in-process)
        q_frame, T_known, known_age_s = link.frame_pose(t_mid, q, T_world_cam)
        R_known, c_known = T_known[:3, :3], T_known[:3, 3]
        p_est = R_known @ p_cam + c_known if detected else np.full(3, np.nan)
        p_cam_est = p_cam if detected else np.full(3, np.nan)
        d_true = float(np.linalg.norm(p_cam_true))
        d_est = float(np.linalg.norm(p_cam_est)) if detected else math.nan
        alt_ok = p_cam_alt is not None and bool(np.all(np.isfinite(p_cam_alt)))
        p_cam_alt = p_cam_alt if alt_ok else np.full(3, np.nan)
        p_alt = R_known @ p_cam_alt + c_known
        d_alt = float(np.linalg.norm(p_cam_alt))
        extra = ()  # the families of estimator.extra_methods, as the alt_* columns
        for method in config.estimator.extra_methods:
            p_cam_x = estimate.extra[method]
            x_ok = p_cam_x is not None and bool(np.all(np.isfinite(p_cam_x)))
            p_cam_x = p_cam_x if x_ok else np.full(3, np.nan)
            d_x = float(np.linalg.norm(p_cam_x))
            extra += (x_ok, *(R_known @ p_cam_x + c_known), *p_cam_x, d_x, d_x - d_true, abs(d_x - d_true))
        u, v = (uv if uv is not None else (math.nan, math.nan))
        hidden, visible_fraction = target.visibility(c, T_world_target)
        predicted = outer.prediction(t_mid)
        if predicted is None:
            p_filter, filter_nees = np.full(3, np.nan), math.nan
        else:
            p_filter = predicted[0]
            e = p_true - p_filter
            filter_nees = float(e @ np.linalg.solve(predicted[1], e))
        row = (
            (k, t_s, t_mid, int(t_mid // target.period_s), detected, *p_true, *p_est, *p_cam_true, *p_cam_est,
             d_true, d_est, d_est - d_true, abs(d_est - d_true), u, v, math.hypot(u - K.cx, v - K.cy),
             *true_uv, math.hypot(true_uv[0] - K.cx, true_uv[1] - K.cy), *q, *qd,
             alt_ok, *p_alt, *p_cam_alt, d_alt, d_alt - d_true, abs(d_alt - d_true),
             *q0, *w0, streak_px, math.degrees(cam_turn_rad),
             hidden, visible_fraction, partial, *p_filter, filter_nees, *at_limit)
        )
        # the measurement of frame k reaches the outer loop latency_frames frames later
        pending.append(Measurement(k, t_mid, uv, q_frame, d_est if detected else None, p_cam if detected else None,
                                   T_known))
        if not run_first:
            steer(k, q_known)
            link.drive(frame_steps[k + 1] - frame_steps[k], rate_ref, q_known)
        yield row + (*q_frame, known_age_s, *rate_ref) + extra, image
