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

Notes
-----
Beyond the paper: its future work asks for a Bayesian filter to keep tracking through
occlusions (§5); this is the constant-velocity special case.
"""

from __future__ import annotations

import math

import numpy as np

from .camera import BrownConrady, Intrinsics, backproject

__all__ = ["LineOfSightFilter", "PredictiveLoop", "MAX_ANGULAR_ACCEL_RAD_S2", "MANOEUVRE_TIME_S"]


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
