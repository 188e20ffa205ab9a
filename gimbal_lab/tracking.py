"""A predictive outer loop: line-of-sight Kalman filter + pointing with rate feed-forward.

The paper's outer loop (§3.2.3, Fig. 5; :class:`gimbal_lab.control.ImageLoop`) feeds the pixel
error back through a PI law. With a camera at 30 frames/s and one frame of vision latency, pure
feedback cannot keep up with a target that sweeps the field of view at about 1 rad/s: the loop's
bandwidth is limited by the delay, and the target trails the image centre by tens of pixels.

:class:`PredictiveLoop` removes that lag. Each detection is turned into the target's line of
sight in the gimbal base frame, using the camera pose *at the instant the frame was taken*; a
constant-velocity Kalman filter on (azimuth, elevation) smooths it and predicts it forward to
the current time, compensating the latency; the joints are commanded to the predicted pointing
angles with the line-of-sight rate fed forward:

    q̇_ref = q̇_ff + kp · (q_des − q),   q_des = look_at(predicted line of sight).

When detections stop, the filter coasts on its velocity for ``coast_s`` and then holds.

:class:`FilterPointing` is the same pointing law driven by a filter on the target's 3-D world
position (:mod:`gimbal_lab.filters`: constant velocity, constant acceleration or IMM), for the
occlusion study (docs/design.md, "Occlusion and manoeuvres"): each sphere fix (the circle
method's camera-frame position) is fused with the covariance of the detector's stated pixel
errors (:func:`circle_measurement_covariance`), and the joints follow the filter's prediction,
coasting through missed frames.

Notes
-----
Beyond the paper: its future work asks for a Bayesian filter to keep tracking through
occlusions (§5); this is the constant-velocity special case.
"""

from __future__ import annotations

import math

import numpy as np

from .camera import BrownConrady, Intrinsics, backproject
from .control import _check_real
from .kinematics import _check_rigid

__all__ = ["LineOfSightFilter", "PredictiveLoop", "MAX_ANGULAR_ACCEL_RAD_S2", "MANOEUVRE_TIME_S",
           "FilterPointing", "circle_measurement_covariance", "CENTRE_STD_PX", "RADIUS_STD_PX", "FILTER_COAST_S"]


#: The target class the predictive loop is built for, stated before any run and independent of
#: the study's scene: a target whose line of sight, seen from the gimbal, accelerates by at most
#: 6 rad/s² (e.g. 1.2 g of lateral acceleration at 2 m) ...
MAX_ANGULAR_ACCEL_RAD_S2 = 6.0
#: ... and changes that acceleration over no less than 0.5 s. The filter's white-jerk intensity is
#: (MAX_ANGULAR_ACCEL_RAD_S2 / MANOEUVRE_TIME_S)² = (12 rad/s³)².
MANOEUVRE_TIME_S = 0.5


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class LineOfSightFilter:
    """Constant-acceleration Kalman filter on the line of sight's azimuth and elevation.

    State per angle: angle (rad), rate (rad/s), acceleration (rad/s²); process noise: white jerk
    of spectral density ``jerk_std_rad_s3²``; measurement noise ``meas_std_rad``. A constant-
    velocity model would extrapolate a target that circles in the image along its tangent and
    point the camera outside the circle; the acceleration state removes that bias.

    Parameters
    ----------
    jerk_std_rad_s3 : float
        Standard deviation of the unmodelled angular jerk, rad/s³, > 0. Default: the target
        class's limits, :data:`MAX_ANGULAR_ACCEL_RAD_S2` / :data:`MANOEUVRE_TIME_S`.
    meas_std_rad : float
        Standard deviation of one bearing measurement, rad, > 0 (0.5 mrad ≈ 0.3 px at 60° FOV).
    max_accel_rad_s2 : float
        Largest angular acceleration of the target class, rad/s², > 0: the prior spread of the
        acceleration state when a track starts.
    """

    def __init__(self, jerk_std_rad_s3: float | None = None, meas_std_rad: float = 5e-4,
                 max_accel_rad_s2: float | None = None):
        if max_accel_rad_s2 is None:
            max_accel_rad_s2 = MAX_ANGULAR_ACCEL_RAD_S2
        if jerk_std_rad_s3 is None:
            jerk_std_rad_s3 = max_accel_rad_s2 / MANOEUVRE_TIME_S
        for name, value in (("jerk_std_rad_s3", jerk_std_rad_s3), ("meas_std_rad", meas_std_rad),
                            ("max_accel_rad_s2", max_accel_rad_s2)):
            if isinstance(value, bool) or not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        self.q = float(jerk_std_rad_s3) ** 2
        self.r = float(meas_std_rad) ** 2
        self.max_accel_rad_s2 = float(max_accel_rad_s2)
        self.reset()

    def reset(self) -> None:
        """Forget the target."""
        self.x = np.zeros((2, 3))  # rows: azimuth, elevation; columns: angle, rate, acceleration
        self.P = np.zeros((2, 3, 3))
        self.t_s = None

    @property
    def initialised(self) -> bool:
        return self.t_s is not None

    @staticmethod
    def _transition(dt: float) -> np.ndarray:
        return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])

    def _predict_state(self, dt: float):
        F = self._transition(dt)
        Q = self.q * np.array([
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ])
        x = self.x @ F.T
        P = F @ self.P @ F.T + Q
        return x, P

    def update(self, t_s: float, azimuth_rad: float, elevation_rad: float) -> None:
        """Fuse a bearing measured at time ``t_s`` (times must not decrease)."""
        z = np.array([azimuth_rad, elevation_rad])
        if not self.initialised:
            self.x = np.column_stack((z, np.zeros(2), np.zeros(2)))
            # rate ±2 rad/s, acceleration ± the target class's limit
            self.P = np.array([np.diag([self.r, 4.0, self.max_accel_rad_s2**2])] * 2)
            self.t_s = float(t_s)
            return
        dt = float(t_s) - self.t_s
        if dt < 0:
            raise ValueError(f"t_s must not decrease: {t_s} < {self.t_s}")
        x, P = self._predict_state(dt)
        for i in range(2):
            innovation = _wrap(z[i] - x[i, 0])
            S = P[i, 0, 0] + self.r
            K = P[i, :, 0] / S
            x[i] = x[i] + K * innovation
            P[i] = P[i] - np.outer(K, P[i, 0, :])
        self.x, self.P, self.t_s = x, P, float(t_s)

    def predict(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(azimuth, elevation) and their rates predicted at ``t_s``, each shape (2,)."""
        if not self.initialised:
            raise RuntimeError("the filter has no measurement yet")
        dt = float(t_s) - self.t_s
        angle = self.x[:, 0] + self.x[:, 1] * dt + 0.5 * self.x[:, 2] * dt * dt
        rate = self.x[:, 1] + self.x[:, 2] * dt
        return angle, rate


def _direction(azimuth: float, elevation: float) -> np.ndarray:
    ce = math.cos(elevation)
    return np.array([ce * math.cos(azimuth), ce * math.sin(azimuth), math.sin(elevation)])


class PredictiveLoop:
    """Outer loop: detections → line-of-sight filter → joint-rate references (yaw, roll, pitch).

    Parameters
    ----------
    intrinsics : Intrinsics
    kinematics : GimbalKinematics
        Provides ``forward`` (camera pose at capture) and ``look_at`` (pointing angles).
    kp_per_s : float
        Gain on the joint-angle error, 1/s (> 0).
    max_rate_rad_s : float
        Largest joint-rate reference, rad/s (> 0).
    coast_s : float
        How long the filter's prediction is followed after the last detection (>= 0); then the
        joints hold their angles.
    range_m : float or None
        Distance used to point through the line of sight when a detection brings no range of its
        own (the pointing angles hardly depend on it: the camera centre is a few cm from the
        gimbal's centre of rotation). None (default): every detection must bring its range, the
        detector's own estimate (:meth:`observe`); the last one is kept for later commands.
    distortion : BrownConrady or None
        Lens model used to turn pixels into rays (None: pinhole, as the paper assumes).
    filter : LineOfSightFilter, optional
    """

    def __init__(self, intrinsics: Intrinsics, kinematics, kp_per_s: float = 15.0, max_rate_rad_s: float = 6.0,
                 coast_s: float = 0.5, range_m: float | None = None, distortion: BrownConrady | None = None,
                 filter: LineOfSightFilter | None = None):
        checks = [("kp_per_s", kp_per_s), ("max_rate_rad_s", max_rate_rad_s)]
        if range_m is not None:
            checks.append(("range_m", range_m))
        for name, value in checks:
            if isinstance(value, bool) or not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(coast_s) and coast_s >= 0):
            raise ValueError(f"coast_s must be >= 0, got {coast_s!r}")
        self.intrinsics = intrinsics
        self.kinematics = kinematics
        self.kp_per_s = float(kp_per_s)
        self.max_rate_rad_s = float(max_rate_rad_s)
        self.coast_s = float(coast_s)
        self.range_m = None if range_m is None else float(range_m)
        self.distortion = distortion
        self.filter = filter if filter is not None else LineOfSightFilter()
        self._pivot = np.asarray(kinematics.centre_base, float)  # the joints' common centre of rotation

    def observe(self, t_capture_s: float, uv_px, q_capture_rad, range_m: float | None = None) -> None:
        """Fuse a detection made on the frame taken at ``t_capture_s`` with joints ``q_capture_rad``.

        ``range_m`` is the detector's own distance estimate (camera → target), m; without it the
        last known range (or the constructor's ``range_m``) is used.
        """
        if uv_px is None:
            return
        if range_m is not None and math.isfinite(range_m) and range_m > 0:
            self.range_m = float(range_m)
        if self.range_m is None:
            raise ValueError("the first detection must bring a range (range_m): the loop has no default range")
        T = self.kinematics.forward(np.asarray(q_capture_rad, float), check_limits=False)
        ray_cam = backproject(np.asarray(uv_px, float).reshape(1, 2), self.intrinsics, self.distortion)[0]
        ray_base = T[:3, :3] @ ray_cam
        # the point on the ray at the nominal range, seen from the centre of rotation
        point = T[:3, 3] + self.range_m * ray_base / np.linalg.norm(ray_base) - self._pivot
        azimuth = math.atan2(point[1], point[0])
        elevation = math.atan2(point[2], math.hypot(point[0], point[1]))
        self.filter.update(t_capture_s, azimuth, elevation)

    def command(self, t_s: float, q_rad) -> np.ndarray:
        """Joint-rate references at time ``t_s`` for joint angles ``q_rad``, shape (3,)."""
        q = np.asarray(q_rad, float)
        if not self.filter.initialised or t_s - self.filter.t_s > self.coast_s:
            return np.zeros(3)
        (az, el), (az_rate, el_rate) = self.filter.predict(t_s)
        h = 1e-3
        q_des = self._pointing(az, el)
        q_ahead = self._pointing(az + az_rate * h, el + el_rate * h)
        rate = (q_ahead - q_des) / h + self.kp_per_s * (q_des - q)
        peak = float(np.max(np.abs(rate)))
        if peak > self.max_rate_rad_s:
            rate *= self.max_rate_rad_s / peak
        return rate

    def _pointing(self, azimuth: float, elevation: float) -> np.ndarray:
        return np.asarray(self.kinematics.look_at(self._pivot + self.range_m * _direction(azimuth, elevation)), float)


# ----------------------------------------------------------------------------------------------
# pointing driven by a world-position target filter (occlusion study)

#: Standard deviation of the detected circle's centre, px, per image axis: the detector's stated
#: accuracy, fixed before any run. The minimum enclosing circle is set by two or three outline
#: points, each a boundary pixel's centre, i.e. quantised to the pixel grid (±0.5 px); half a
#: pixel per axis covers that quantisation. Not tuned on tracking results.
CENTRE_STD_PX = 0.5
#: Standard deviation of the detected circle's radius, px, by the same argument as
#: :data:`CENTRE_STD_PX` (the radius is set by the same quantised outline points).
RADIUS_STD_PX = 0.5
#: How long :class:`FilterPointing` follows a filter's prediction after its last accepted
#: measurement, s: the occlusion study's longest occlusion (1.0 s, docs/design.md) plus 0.5 s for
#: re-acquisition (the filter's gate may reject the first fixes after a long coast until the track
#: restarts: 10 frames, 0.33 s, at the filters' default ``restart_after``).
FILTER_COAST_S = 1.5
#: Step of the finite difference that turns the predicted velocity into joint rates, s (the
#: truncation error is about ½ q̈ h: under 1e-3 rad/s for joint accelerations under 2 rad/s²).
_FEED_FORWARD_STEP_S = 1e-3


def _check_rotation(name: str, R) -> np.ndarray:
    """Return ``R`` as a float (3, 3) rotation or raise ValueError (the tolerance of _check_rigid)."""
    arr = np.asarray(R, dtype=float)
    if arr.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 rotation matrix, got shape {arr.shape}")
    T = np.eye(4)
    T[:3, :3] = arr
    try:
        _check_rigid(name, T)
    except ValueError:
        raise ValueError(f"{name} must be a finite rotation matrix (orthonormal, det +1)") from None
    return arr


def circle_measurement_covariance(p_cam_m, R_world_cam, focal_px: float, radius_m: float,
                                  centre_std_px: float = CENTRE_STD_PX,
                                  radius_std_px: float = RADIUS_STD_PX) -> np.ndarray:
    """World covariance of the circle method's sphere position, from its pixel errors.

    The circle method (:func:`gimbal_lab.detection.locate_sphere_circle`) gives
    p = z·(û, v̂, 1) with z = r·f/R_px and (û, v̂) = ((u − cx)/f, (v − cy)/f). With independent
    errors of standard deviation σ_c on u and v and σ_R on R_px, linearised:

        ∂p/∂u = (z/f)·e_x,   ∂p/∂v = (z/f)·e_y,   ∂p/∂R_px = −(z²/(r f))·(û, v̂, 1),

    so R_cam = σ_lat² (e_x e_xᵀ + e_y e_yᵀ) + σ_z² (û, v̂, 1)(û, v̂, 1)ᵀ with the lateral
    σ_lat = z·σ_c/f and the depth σ_z = z²·σ_R/(r·f). On the optical axis (û = v̂ = 0) this is
    diag(σ_lat², σ_lat², σ_z²); off the axis the range error lies along the line of sight, not
    along the optical axis (at 3 m it is about 30 times the lateral error, so the difference
    matters). In the world, R = R_wc R_cam R_wcᵀ.

    Parameters
    ----------
    p_cam_m : array_like, shape (3,)
        The sphere centre in the camera optical frame (OpenCV axes), m, in front (z > 0).
    R_world_cam : ndarray, shape (3, 3)
        Rotation of the camera frame in the world (columns: the camera axes in world coordinates).
    focal_px : float
        Focal length f, px (> 0); the study camera has fx = fy.
    radius_m : float
        Sphere radius r, m (> 0).
    centre_std_px, radius_std_px : float
        σ_c and σ_R, px (> 0); default :data:`CENTRE_STD_PX`, :data:`RADIUS_STD_PX`.

    Returns
    -------
    ndarray, shape (3, 3)
        Symmetric positive-definite covariance of the world position, m².

    Notes
    -----
    Paper §3.2.1 (d = r·f/R, x₀ = d·K⁻¹(u, v, 1)ᵀ), first-order error propagation. Beyond the
    paper: its §5 asks for a Bayesian filter, which needs this covariance.

    Examples
    --------
    >>> R = circle_measurement_covariance([0.0, 0.0, 3.0], np.eye(3), 554.26, 0.1)
    >>> np.round(np.sqrt(np.diag(R)), 4).tolist()  # 3 m · 0.5 px / f; 9 m² · 0.5 px / (0.1 m · f)
    [0.0027, 0.0027, 0.0812]
    """
    p = np.asarray(p_cam_m, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"p_cam_m must be three finite numbers (camera frame, m), got {p_cam_m!r}")
    if not p[2] > 0:
        raise ValueError(f"p_cam_m must lie in front of the camera (z > 0), got z = {p[2]!r} m")
    R_wc = _check_rotation("R_world_cam", R_world_cam)
    f = _check_real("focal_px", focal_px, low=0.0, low_open=True)
    r = _check_real("radius_m", radius_m, low=0.0, low_open=True)
    s_c = _check_real("centre_std_px", centre_std_px, low=0.0, low_open=True)
    s_r = _check_real("radius_std_px", radius_std_px, low=0.0, low_open=True)
    z = float(p[2])
    lateral_std_m = z * s_c / f
    depth_std_m = z * z * s_r / (r * f)
    ray = p / z  # (û, v̂, 1)
    R_cam = lateral_std_m**2 * np.diag([1.0, 1.0, 0.0]) + depth_std_m**2 * np.outer(ray, ray)
    R = R_wc @ R_cam @ R_wc.T
    return 0.5 * (R + R.T)


class FilterPointing:
    """Outer loop: sphere fixes → world target filter → joint-rate references (yaw, roll, pitch).

    Each fix (the sphere centre in the camera frame of the frame it was found on) is mapped to
    the world with that frame's camera pose and fused into ``filter`` with the covariance of the
    detector's pixel errors (:func:`circle_measurement_covariance`); a frame without a fix is a
    missed frame. :meth:`command` predicts the target's world position p and velocity v to the
    current time, maps them to the gimbal base and returns

        q̇_ref = (look_at(p_b + v_b·h) − look_at(p_b))/h + kp·(q_des − q),   q_des = look_at(p_b),

    with h = 1 ms, scaled down as a whole (direction kept) so that no joint exceeds
    ``max_rate_rad_s``. It returns zeros (the joints hold, as the paper's loop does when it loses
    the target) before the first fix, once the last accepted fix is more than ``coast_s`` old, and
    when the predicted point (or the point h ahead) is out of the gimbal's reach
    (:meth:`gimbal_lab.kinematics.GimbalKinematics.look_at` raises ValueError: more than 45°
    above the horizon, behind the yaw limits, or inside the camera's offset).

    Parameters
    ----------
    kinematics : GimbalKinematics
        Provides ``look_at`` (pointing angles in the base frame).
    T_world_base : ndarray, shape (4, 4)
        Pose of the gimbal base in the world (constant: the body is static in this study; see
        :func:`gimbal_lab.simulation.world_T_base`).
    filter : ConstantVelocity, ConstantAcceleration or IMM
        A target filter with the interface of :mod:`gimbal_lab.filters` (``update``,
        ``predict``, ``initialised``, ``t_s``); it is used as given, not copied.
    focal_px : float
        Focal length of the camera, px (> 0).
    radius_m : float
        Radius of the sphere, m (> 0).
    kp_per_s : float
        Gain on the joint-angle error, 1/s (> 0); as :class:`PredictiveLoop`.
    max_rate_rad_s : float
        Largest joint-rate reference, rad/s (> 0). The default, 3 rad/s, is about three times
        the study circle's largest line-of-sight rate (π m/s at about 3.2 m: ≈ 1 rad/s).
    coast_s : float
        How long the prediction is followed after the last accepted fix, s (>= 0); default
        :data:`FILTER_COAST_S`.
    centre_std_px, radius_std_px : float
        The detector's error model, px (> 0); default :data:`CENTRE_STD_PX`, :data:`RADIUS_STD_PX`.

    Attributes
    ----------
    n_accepted, n_rejected, n_missed : int
        Fixes the filter accepted (a track start or restart included), fixes its gate rejected,
        and frames without a fix.

    Notes
    -----
    Beyond the paper: its §5 asks for a Bayesian filter to keep tracking through occlusions;
    docs/design.md, "Occlusion and manoeuvres" (filter-driven pointing with CV, CA and IMM
    filters). The pointing law is :class:`PredictiveLoop`'s.

    Examples
    --------
    >>> from gimbal_lab.filters import ConstantVelocity
    >>> from gimbal_lab.kinematics import GimbalKinematics
    >>> kin = GimbalKinematics.default()
    >>> loop = FilterPointing(kin, np.eye(4), ConstantVelocity(), focal_px=554.26, radius_m=0.1)
    >>> T_world_cam = kin.forward(np.zeros(3))  # world = base here; camera at home, looking along +x
    >>> loop.observe(0.0, [0.0, 0.0, 3.0], T_world_cam)
    True
    >>> bool(np.allclose(loop.command(0.01, np.zeros(3)), 0.0, atol=1e-9))  # already on target
    True
    """

    def __init__(self, kinematics, T_world_base, filter, focal_px: float, radius_m: float,
                 kp_per_s: float = 15.0, max_rate_rad_s: float = 3.0, coast_s: float = FILTER_COAST_S,
                 centre_std_px: float = CENTRE_STD_PX, radius_std_px: float = RADIUS_STD_PX):
        if not callable(getattr(kinematics, "look_at", None)):
            raise TypeError(f"kinematics must provide look_at (a GimbalKinematics), got {type(kinematics).__name__}")
        missing = [name for name in ("update", "predict", "initialised", "t_s") if not hasattr(filter, name)]
        if missing:
            raise TypeError(f"filter must have the interface of gimbal_lab.filters (missing {', '.join(missing)}), "
                            f"got {type(filter).__name__}")
        self.kinematics = kinematics
        self.T_world_base = _check_rigid("T_world_base", T_world_base)
        T_base_world = np.eye(4)
        T_base_world[:3, :3] = self.T_world_base[:3, :3].T
        T_base_world[:3, 3] = -self.T_world_base[:3, :3].T @ self.T_world_base[:3, 3]
        self._T_base_world = T_base_world
        self.filter = filter
        self.focal_px = _check_real("focal_px", focal_px, low=0.0, low_open=True)
        self.radius_m = _check_real("radius_m", radius_m, low=0.0, low_open=True)
        self.kp_per_s = _check_real("kp_per_s", kp_per_s, low=0.0, low_open=True)
        self.max_rate_rad_s = _check_real("max_rate_rad_s", max_rate_rad_s, low=0.0, low_open=True)
        self.coast_s = _check_real("coast_s", coast_s, low=0.0)
        self.centre_std_px = _check_real("centre_std_px", centre_std_px, low=0.0, low_open=True)
        self.radius_std_px = _check_real("radius_std_px", radius_std_px, low=0.0, low_open=True)
        self.n_accepted = 0
        self.n_rejected = 0
        self.n_missed = 0

    def measurement_covariance(self, p_cam_m, R_world_cam) -> np.ndarray:
        """World covariance of a fix at ``p_cam_m`` (camera frame, m), m², shape (3, 3).

        :func:`circle_measurement_covariance` with this loop's focal length, sphere radius and
        pixel errors.
        """
        return circle_measurement_covariance(p_cam_m, R_world_cam, self.focal_px, self.radius_m,
                                             self.centre_std_px, self.radius_std_px)

    def observe(self, t_capture_s: float, p_cam_m, T_world_cam) -> bool:
        """Fuse the fix made on the frame taken at ``t_capture_s``.

        Parameters
        ----------
        t_capture_s : float
            When the frame was taken, s (not before the filter's last accepted fix).
        p_cam_m : array_like, shape (3,), or None
            The sphere centre found on that frame, in its camera optical frame, m (the circle
            method's estimate); None for a frame without a detection (a missed frame).
        T_world_cam : ndarray, shape (4, 4)
            The camera pose when the frame was taken (unused for a missed frame).

        Returns
        -------
        bool
            Whether the filter accepted the fix (False for a missed frame or a gated-out fix).
        """
        t = _check_real("t_capture_s", t_capture_s)
        if p_cam_m is None:
            self.filter.update(t, None)
            self.n_missed += 1
            return False
        T = _check_rigid("T_world_cam", T_world_cam)
        p_cam = np.asarray(p_cam_m, dtype=float)
        R_world = self.measurement_covariance(p_cam, T[:3, :3])
        p_world = T[:3, :3] @ p_cam + T[:3, 3]
        accepted = bool(self.filter.update(t, p_world, R_world))
        if accepted:
            self.n_accepted += 1
        else:
            self.n_rejected += 1
        return accepted

    def live(self, t_s: float) -> bool:
        """Whether the track is live at ``t_s``: the filter has a track and its last accepted fix
        is at most ``coast_s`` old (what :meth:`command` follows)."""
        t = _check_real("t_s", t_s)
        return bool(self.filter.initialised) and t - self.filter.t_s <= self.coast_s

    def prediction(self, t_s: float):
        """The filter's estimate of the target at ``t_s`` while the track is live, for logging
        (estimate, NEES).

        Returns
        -------
        tuple (ndarray, shape (3,), ndarray, shape (3, 3)) or None
            World position, m, and its covariance, m²; None before the first fix and once the last
            accepted fix is more than ``coast_s`` old (:meth:`live`): a track the pointing no longer
            follows is not logged (docs/design.md, "When does a gimbal pay off?": the filters' NEES
            is judged over the frames with a live track).
        """
        if not self.live(t_s):
            return None
        t = float(t_s)
        mean, cov = self.filter.predict(t)
        return np.array(mean[:3], dtype=float), np.array(cov[:3, :3], dtype=float)

    def command(self, t_s: float, q_rad) -> np.ndarray:
        """Joint-rate references (yaw, roll, pitch) at time ``t_s`` for joint angles ``q_rad``, rad/s.

        Parameters
        ----------
        t_s : float
            Current time, s (not before the filter's last accepted fix).
        q_rad : array_like, shape (3,)
            Current joint angles (yaw, roll, pitch), rad.

        Returns
        -------
        ndarray, shape (3,)
            Rate references, rad/s, each within ±``max_rate_rad_s``; zeros when holding (before
            the first fix, after ``coast_s`` without one, or when the prediction is out of reach).
        """
        t = _check_real("t_s", t_s)
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (3,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_rad must be three finite joint angles (yaw, roll, pitch), rad, got {q_rad!r}")
        if not self.filter.initialised or t - self.filter.t_s > self.coast_s:
            return np.zeros(3)
        mean, _ = self.filter.predict(t)
        R_bw, t_bw = self._T_base_world[:3, :3], self._T_base_world[:3, 3]
        p_base = R_bw @ np.asarray(mean[:3], dtype=float) + t_bw
        v_base = R_bw @ np.asarray(mean[3:6], dtype=float)
        h = _FEED_FORWARD_STEP_S
        try:
            q_des = np.asarray(self.kinematics.look_at(p_base), dtype=float)
            q_ahead = np.asarray(self.kinematics.look_at(p_base + v_base * h), dtype=float)
        except ValueError:  # the prediction is out of the gimbal's reach: hold
            return np.zeros(3)
        rate = (q_ahead - q_des) / h + self.kp_per_s * (q_des - q)
        peak = float(np.max(np.abs(rate)))
        if peak > self.max_rate_rad_s:
            rate *= self.max_rate_rad_s / peak
        return rate
