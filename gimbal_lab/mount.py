"""The camera mount on a moving drone: fixed, stabilised or active (docs/design.md "Moving drone").

Three joint axes (yaw, roll, pitch) turn the camera relative to the drone's body, whose motion
comes from :class:`gimbal_lab.platform.BodyMotion`. Each axis is the nonlinear
:class:`gimbal_lab.control.GimbalAxis` driven by its rate loop (:class:`gimbal_lab.control.RateLoop`)
at the inner rate; this module adds what a moving base brings:

* **Kinematics, exact.** Write the camera's angular velocity in the basis of the three joint axes,
  ω_cam = Z(q)·w, with Z the joint axes in the world (columns of the angular Jacobian rotated by the
  body). The body's own rotation in the same basis is b = Z⁻¹·ω_body, and the joint rates are
  q̇ = w − b exactly (the camera turns with the body plus its joints). Each axis simulates its
  coordinate w_i; the joint angle is its integral minus the integral of b_i.
* **Dynamics, per axis.** J·ẇ_i = T_i − c·(w_i − b_i): the bearing friction c (the plant's
  ``damping_Nms_per_rad``) drags each axis with the body, the disturbance torque c·b_i
  (:meth:`gimbal_lab.control.AxisPlant.base_rate_torque_Nm`). Coupling of inertia between axes is
  left out (the axes are orthogonal at home and stay within a few degrees of it here).
* **Joint stops.** Each joint turns within the kinematics' ``joint_limits_rad``. A joint that
  reaches a limit stops there, an inelastic contact: its angle is the limit and its rate relative
  to the base zero (the axis turns with the body), for as long as its motor pushes it into the
  stop; it leaves as soon as the motor pulls it back. While a joint sits at its stop and its rate
  loop's error points further into it, the loop's integral is held (conditional integration), so
  it does not wind up against the stop and the joint answers a reversed reference at once.
  :attr:`GimbalMount.at_limit` says which joints sit at a stop. (The few milliseconds of a
  rolling-shutter window that reach past the steps already run are extrapolated from the axes'
  mean rates, :func:`exposure_pose_fn`, without the stops.)
* **Gyro.** The camera-platform gyro measures w (body plus joint rates) through the axis's own
  160 Hz low-pass and delay, plus white noise of density ``gyro_noise_rad_s_rthz`` through the
  same low-pass (docs/design.md: 0.005 °/s/√Hz).
* **Mounts.** ``fixed``: the joints are locked at home, the camera moves rigidly with the body.
  ``stabilised``: the rate loops hold the home orientation in the world from the gyro alone, with
  an attitude estimate w-integrated from an initial attitude known exactly (an AHRS that has
  converged before the run) and the outer law w_ref = −k_att·(estimated attitude error).
  ``active``: the paper's image loop gives the rate references (:mod:`gimbal_lab.simulation`).

With a still body (``BodyMotion.static()``) and no gyro noise this reduces exactly to the axes of
the paper's study: every disturbance is zero and the numbers are bit-equal.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import scipy.signal
from scipy.spatial.transform import Rotation

from .control import AxisPlant, GimbalAxis, RateLoop
from .platform import BodyMotion

__all__ = ["MOUNTS", "ATTITUDE_GAIN_PER_S", "GYRO_NOISE_RAD_S_RTHZ", "GimbalMount", "attitude_error_rad",
           "exposure_pose_fn", "ExposurePose", "RecordedPose", "camera_pose",
           "stabilised_attitude_transfer"]

MOUNTS = ("fixed", "stabilised", "active")
#: Gain of the stabilised mount's attitude hold, 1/s (a 3.2 Hz loop, far inside the rate loops').
ATTITUDE_GAIN_PER_S = 20.0
#: The axes' rate an exposure extrapolates is their mean over this window, s (one blade-pass period).
RATE_WINDOW_S = 1.0 / 120.0
#: The gyro's white-noise density, rad/s/√Hz (docs/design.md: 0.005 °/s/√Hz).
GYRO_NOISE_RAD_S_RTHZ = math.radians(0.005)


def attitude_error_rad(R_world_cam, R_world_home) -> np.ndarray:
    """Rotation vector (rad) taking the home orientation to the camera's, in the home camera frame.

    Its components are the camera's attitude error about its own x (right: pitch), y (down: yaw)
    and z (optical axis: roll) axes at home; shape (3,) or (N, 3).
    """
    R = np.asarray(R_world_cam, dtype=float)
    rel = np.swapaxes(R_world_home, -1, -2) @ R if R.ndim == 3 else np.asarray(R_world_home).T @ R
    return Rotation.from_matrix(rel).as_rotvec()


def stabilised_attitude_transfer(plant: AxisPlant, dt_s: float = 1e-3, attitude_gain_per_s: float = ATTITUDE_GAIN_PER_S,
                                 pade_order: int = 6):
    """Linear transfer, body rotation about an axis → camera attitude error about it, stabilised mount.

    One axis: J·ẇ = T − c(w − b), T = motor lag · PID(w_ref − w_meas), w_meas = gyro low-pass · delay · w,
    w_ref = −k_att·∫w_meas. With θ_b the body angle (b = θ̇_b) and e = ∫w the camera's error,
    e/θ_b = w/b = c·P/(1 + P·M·(C_e·(1 + k_att/s) + C_y)·G), P = 1/(Js + c), M the motor lag,
    C_e and C_y the PID's error and derivative paths, G the gyro low-pass and delay: the friction
    drag c·P attenuated by the loop's sensitivity.

    Returns
    -------
    control.TransferFunction
    """
    import control as ct

    from .control import pid_transfer_function

    loop = RateLoop(plant, dt_s=dt_s)
    body = ct.tf([1.0], [plant.inertia_kgm2, plant.damping_Nms_per_rad])
    motor = ct.tf([1.0], [plant.motor_tau_s, 1.0])
    gyro = ct.tf([1.0], [plant.gyro_tau_s, 1.0])
    if plant.delay_s > 0:
        gyro = gyro * ct.tf(*ct.pade(plant.delay_s, pade_order))
    C_e, C_y = pid_transfer_function(loop.gains, loop.pid.derivative_tau_s)
    hold = ct.tf([1.0, attitude_gain_per_s], [1.0, 0.0])  # w_ref = −(k_att/s)·w_meas enters the error path
    # state space keeps the high-order loop (Padé delay) well conditioned; a transfer-function
    # feedback of these polynomials loses every digit
    forward = ct.tf2ss(plant.damping_Nms_per_rad * body)
    return ct.feedback(forward, ct.tf2ss(motor * (C_e * hold + C_y) * gyro) * (1.0 / plant.damping_Nms_per_rad))


class GimbalMount:
    """The gimbal's three axes on a moving body, stepped at the inner rate.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    body : BodyMotion
    mount : {"fixed", "stabilised", "active"}
    dt_s : float
        Inner-loop step, s.
    n_steps : int
        Steps the run will take (the body's motion and the gyro noise are drawn for them at once).
    gyro_noise_rad_s_rthz : float
        White-noise density of the gyro, rad/s/√Hz (>= 0).
    rng : numpy.random.Generator, optional
        Source of the gyro noise (needed when the density is > 0).
    attitude_gain_per_s : float
        The stabilised mount's attitude-hold gain.
    plants : sequence of 3 AxisPlant, optional
        The (yaw, roll, pitch) axes (default: :meth:`AxisPlant.storm32` for each).
    rate_gains : sequence of 3 PIDGains, optional
        The rate loops' gains (default: Ziegler–Nichols from each plant, :class:`RateLoop`).

    Notes
    -----
    The body's angular rate in the joint basis is evaluated at every step's midpoint from the exact
    body motion and Z(q) is refreshed every step, so the joint angles integrate q̇ = w − b to second
    order in the step (a left-point rule would leave an error of b·dt/2, about 0.01° in hover sway,
    the size of the stabilised camera's whole error).
    """

    def __init__(self, kinematics, body: BodyMotion, mount: str, dt_s: float, n_steps: int,
                 gyro_noise_rad_s_rthz: float = 0.0, rng: np.random.Generator | None = None,
                 attitude_gain_per_s: float = ATTITUDE_GAIN_PER_S, plants=None, rate_gains=None):
        if mount not in MOUNTS:
            raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
        if not isinstance(body, BodyMotion):
            raise TypeError(f"body must be a BodyMotion, got {type(body).__name__}")
        if not (gyro_noise_rad_s_rthz >= 0 and math.isfinite(gyro_noise_rad_s_rthz)):
            raise ValueError(f"gyro_noise_rad_s_rthz must be >= 0, got {gyro_noise_rad_s_rthz!r}")
        if gyro_noise_rad_s_rthz > 0 and rng is None:
            raise ValueError("rng is needed when gyro_noise_rad_s_rthz > 0")
        self.kinematics = kinematics
        self.body = body
        self.mount = mount
        self.dt_s = float(dt_s)
        self.n_steps = int(n_steps)
        self.attitude_gain_per_s = float(attitude_gain_per_s)
        if plants is None:
            plants = [AxisPlant.storm32(axis) for axis in ("yaw", "roll", "pitch")]
        if rate_gains is None:
            rate_gains = (None, None, None)
        if len(plants) != 3 or len(rate_gains) != 3:
            raise ValueError("plants and rate_gains must give the three axes (yaw, roll, pitch)")
        self.plants = list(plants)
        self.axes = [GimbalAxis(p, self.dt_s) for p in self.plants]
        self.rate_loops = [RateLoop(p, gains=g, dt_s=self.dt_s) for p, g in zip(self.plants, rate_gains)]
        self._friction = [p.damping_Nms_per_rad for p in self.plants]
        self._lo = tuple(float(lo) for lo, _ in kinematics.joint_limits_rad)
        self._hi = tuple(float(hi) for _, hi in kinematics.joint_limits_rad)
        self._stop = [0, 0, 0]  # per joint: +1 at its upper stop, -1 at its lower stop, 0 free
        self.step_index = 0
        # the joint angles after every inner step: an exposure already run is rendered from them
        self._q_path = np.zeros((self.n_steps + 1, 3))
        # axis angles of the last RATE_WINDOW_S: their slope is the rate an exposure extrapolates
        self._history = deque([tuple(a.angle_rad for a in self.axes)], maxlen=max(int(round(RATE_WINDOW_S / self.dt_s)), 1) + 1)
        self.moving = body.sway is not None or body.vibration is not None or body.flight is not None
        self._T_body_base = kinematics.T_body_base
        self._R_body_base = self._T_body_base[:3, :3]
        self._R_rows = self._R_body_base.tolist()
        self._base_angle = [0.0, 0.0, 0.0]  # ∫ b_i dt
        self._w_body = None
        if self.moving:
            # at each step's midpoint: the joint angle's integral of b is then second-order exact
            t = (np.arange(self.n_steps + 1) + 0.5) * self.dt_s
            self._w_body = body.angular_rate_body(t)
            self._w_body_rows = self._w_body.tolist()
        self._noise = None
        if gyro_noise_rad_s_rthz > 0:
            sigma = gyro_noise_rad_s_rthz * math.sqrt(0.5 / self.dt_s)
            white = rng.standard_normal((self.n_steps + 1, 3)) * sigma
            # the gyro's own low-pass (the plant's gyro_tau_s), discretised exactly
            a = math.exp(-self.dt_s / self.plants[0].gyro_tau_s)
            self._noise = scipy.signal.lfilter([1.0 - a], [1.0, -a], white, axis=0)
        # home in the world: the camera at the joints' zero on a level body at its mean heading
        home = np.eye(4)
        home[:3, :3] = Rotation.from_euler("z", body.yaw_rad).as_matrix()
        self.R_world_home = (home @ self._T_body_base @ kinematics.forward(np.zeros(3), check_limits=False))[:3, :3]
        # the stabilised mount's attitude estimate, in the joint basis, starts at the true error
        self._estimate = [0.0, 0.0, 0.0]
        if mount == "stabilised" and self.moving:
            e0 = self._axis_basis_error(np.zeros(3), 0.0)
            self._estimate = [float(v) for v in e0]

    # ------------------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        return self.step_index * self.dt_s

    @property
    def q(self) -> np.ndarray:
        """Joint angles now, rad."""
        if self.mount == "fixed":
            return np.zeros(3)
        return np.array([a.angle_rad - b for a, b in zip(self.axes, self._base_angle)])

    def _base_rates(self, q, k: int) -> np.ndarray:
        """The body's angular rate in the joint basis, b = (R_body_base·J_base(q))⁻¹·ω_body."""
        if self._w_body is None:
            return np.zeros(3)
        return np.array(self._base_rate_values(float(q[0]), float(q[1]), float(q[2]), k))

    def _base_rate_values(self, q0: float, q1: float, q2: float, k: int) -> tuple[float, float, float]:
        """:meth:`_base_rates` of a moving body as three floats, by Cramer's rule on the 3 × 3 system
        (the inner loop solves it twice a step; numpy's solver costs more in calls than in work)."""
        z = self.kinematics.base_axes(q0, q1, q2)
        R = self._R_rows
        # M = R_body_base · [z₀ z₁ z₂], row by row
        m = [R[i][0] * z[j] + R[i][1] * z[j + 1] + R[i][2] * z[j + 2] for i in range(3) for j in (0, 3, 6)]
        w0, w1, w2 = self._w_body_rows[k]
        # the cofactors of M's first column's rows, and of the right-hand side in its place
        c0 = m[4] * m[8] - m[5] * m[7]
        c1 = m[5] * m[6] - m[3] * m[8]
        c2 = m[3] * m[7] - m[4] * m[6]
        det = m[0] * c0 + m[1] * c1 + m[2] * c2
        return ((w0 * c0 + m[1] * (w2 * m[5] - w1 * m[8]) + m[2] * (w1 * m[7] - w2 * m[4])) / det,
                (m[0] * (w1 * m[8] - w2 * m[5]) + w0 * c1 + m[2] * (w2 * m[3] - w1 * m[6])) / det,
                (m[0] * (w2 * m[4] - w1 * m[7]) + m[1] * (w1 * m[6] - w2 * m[3]) + w0 * c2) / det)

    @property
    def at_limit(self) -> tuple[bool, bool, bool]:
        """Whether each joint (yaw, roll, pitch) sits at a mechanical stop now."""
        return tuple(s != 0 for s in self._stop)

    @property
    def qd(self) -> np.ndarray:
        """Joint rates now, rad/s (q̇ = w − b)."""
        if self.mount == "fixed":
            return np.zeros(3)
        w = np.array([a.rate_rad_s for a in self.axes])
        return w - self._base_rates(self.q, self.step_index)

    @property
    def axis_rates(self) -> np.ndarray:
        """w: the camera's inertial angular velocity in the joint basis, rad/s."""
        if self.mount == "fixed":
            return self._base_rates(np.zeros(3), self.step_index)
        return np.array([a.rate_rad_s for a in self.axes])

    @property
    def smooth_axis_rates(self) -> np.ndarray:
        """w averaged over the last :data:`RATE_WINDOW_S` (the instantaneous w before that much has run).

        The axes answer blade-pass vibration with a small oscillation of w (about ±0.1 rad/s at
        120 Hz on a stabilised mount, i.e. ±1e-4 rad of camera angle); extrapolating its
        instantaneous value over an exposure would turn it into a drift of 1e-3 rad.
        """
        if self.mount == "fixed" or len(self._history) < self._history.maxlen:
            return self.axis_rates
        first, last = self._history[0], self._history[-1]
        return (np.array(last) - np.array(first)) / ((len(self._history) - 1) * self.dt_s)

    def T_world_cam(self, q, t_s: float) -> np.ndarray:
        """Camera pose in the world for joint angles ``q`` at time ``t_s`` (the body's pose then)."""
        return camera_pose(self.kinematics, self.body, q, t_s)

    def _axis_basis_error(self, q, t_s) -> np.ndarray:
        """The camera's attitude error from home, in the joint basis (small-angle), rad."""
        T = self.T_world_cam(q, t_s)
        rotvec_world = Rotation.from_matrix(T[:3, :3] @ self.R_world_home.T).as_rotvec()
        Z = self.body.T_world_body(t_s)[:3, :3] @ self._R_body_base @ \
            self.kinematics.angular_jacobian(q, frame="base", check_limits=False)
        return np.linalg.solve(Z, rotvec_world)

    # ------------------------------------------------------------------------------------------
    def advance(self, n: int, rate_ref=None) -> None:
        """Step the axes ``n`` inner steps with the outer ``rate_ref`` held (active mount).

        The fixed mount only advances time; the stabilised mount computes its own references.
        """
        if self.step_index + n > self.n_steps:
            raise ValueError(f"the mount was built for {self.n_steps} steps; {self.step_index + n} requested")
        if self.mount == "fixed":
            self.step_index += n
            return
        axes, loops, friction = self.axes, self.rate_loops, self._friction
        base, estimate = self._base_angle, self._estimate
        noise, dt = self._noise, self.dt_s
        stabilised = self.mount == "stabilised"
        k_att = self.attitude_gain_per_s
        lo, hi, stop = self._lo, self._hi, self._stop
        ref = (0.0, 0.0, 0.0) if rate_ref is None else tuple(float(r) for r in rate_ref)
        for _ in range(n):
            k = self.step_index
            b = None
            if self.moving:  # b at the step's midpoint, with the joints predicted there (midpoint rule)
                q = [axes[i].angle_rad - base[i] for i in range(3)]
                b = self._base_rate_values(*q, k)
                half = 0.5 * dt
                b = self._base_rate_values(*(q[i] + half * (axes[i].rate_rad_s - b[i]) for i in range(3)), k)
            for i in range(3):
                axis = axes[i]
                measured = axis.measured_rate_rad_s
                if noise is not None:
                    measured += noise[k, i]
                if stabilised:
                    r = -k_att * estimate[i]
                    estimate[i] += measured * dt
                else:
                    r = ref[i]
                # against a stop, an error pushing further into it is not integrated
                torque = loops[i].update(r, measured, stop[i] != 0 and (r - measured) * stop[i] > 0.0)
                if b is None:
                    axis.step(torque)
                    b_i = 0.0
                else:
                    b_i = b[i]
                    axis.step(torque, friction[i] * b_i)
                    base[i] += b_i * dt
                q_i = axis.angle_rad - base[i]
                if q_i > hi[i]:
                    axis.stop(hi[i] + base[i], b_i)  # at the stop the joint turns with the base
                    stop[i] = 1
                elif q_i < lo[i]:
                    axis.stop(lo[i] + base[i], b_i)
                    stop[i] = -1
                else:
                    stop[i] = 0
            self.step_index = k + 1
            self._history.append((axes[0].angle_rad, axes[1].angle_rad, axes[2].angle_rad))
            self._q_path[k + 1] = (axes[0].angle_rad - base[0], axes[1].angle_rad - base[1],
                                   axes[2].angle_rad - base[2])

    def exposure_pose_fn(self, t0_s: float, t1_s: float, n_grid: int = 64):
        """``camera_fn(t) -> (q, T_world_cam)`` on [t0_s, t1_s] from the state now, taken as the
        state at ``t0_s`` (a frame's time, which the inner steps meet to within one step): an
        :class:`ExposurePose`, with ``camera_fn.many(times)`` for arrays (see :func:`exposure_pose_fn`)."""
        return exposure_pose_fn(self.kinematics, self.body, self.mount, self.q, self.smooth_axis_rates, t0_s, t1_s,
                                n_grid)

    def recorded_pose_fn(self, t0_s: float, t1_s: float, n_grid: int = 64):
        """The camera on [t0_s, t1_s] as the mount actually moved: a :class:`RecordedPose`.

        Up to now (:attr:`t_s`) the joint angles are those recorded after every inner step,
        interpolated by a cubic spline; past now they continue from the present state as
        :meth:`exposure_pose_fn` extrapolates. The closed loop runs a frame's inner steps before
        rendering it, so an exposure sees the axes' real response to the rate reference issued at
        its start (the active mount's references change every frame, and its axes answer within
        milliseconds: holding the rate of the exposure's start misplaces the camera by ~8 mrad
        RMS 17 ms later).
        """
        if self.mount == "fixed":
            return exposure_pose_fn(self.kinematics, self.body, "fixed", np.zeros(3), np.zeros(3), t0_s, t1_s)
        dt = self.dt_s
        margin = _exposure_margin_s(t0_s, t1_s)
        first = max(0, min(int(math.floor((t0_s - margin) / dt)) - 2, self.step_index - 3))
        times = np.arange(first, self.step_index + 1) * dt
        tail = None
        if t1_s + margin > self.t_s:
            tail = exposure_pose_fn(self.kinematics, self.body, self.mount, self.q, self.smooth_axis_rates, self.t_s,
                                    t1_s, n_grid)
        return RecordedPose(self.kinematics, self.body, times, self._q_path[first: self.step_index + 1], tail)


def camera_pose(kinematics, body: BodyMotion, q, t_s) -> np.ndarray:
    """``T_world_cam`` for joint angles ``q`` at time ``t_s``: body pose · mount · gimbal kinematics.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    body : BodyMotion
    q : array_like, shape (3,) or (N, 3)
        Joint angles (yaw, roll, pitch), rad: one set for every instant, or one per instant.
    t_s : float or array_like, shape (N,)
        Time(s), s; an array evaluates the body once for all instants.

    Returns
    -------
    ndarray, shape (4, 4) for a scalar ``t_s``, else (N, 4, 4)
    """
    T_world_base = body.T_world_body(t_s) @ kinematics.T_body_base
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        return T_world_base @ kinematics.forward(q, check_limits=False)
    return T_world_base @ kinematics.forward_many(q)


def _exposure_margin_s(t0_s: float, t1_s: float) -> float:
    """How far either side of an exposure its camera path is kept: a renderer may sample its
    motion a little outside the exposure."""
    return 0.25 * max(t1_s - t0_s, 0.004)


class _CameraPath:
    """``camera_fn(t) -> (q, T_world_cam)`` and ``camera_fn.many(times)`` from ``joint_angles``."""

    kinematics = body = None

    def joint_angles(self, t_s) -> np.ndarray:
        raise NotImplementedError

    def __call__(self, t_s: float):
        q = self.joint_angles(t_s)
        return q, camera_pose(self.kinematics, self.body, q, t_s)

    def many(self, times_s):
        """``(q, T_world_cam)`` at each of ``times_s``: shapes (N, 3) and (N, 4, 4).

        Equal to calling the pose at each time in turn (to round-off), with the body evaluated once.
        """
        t = np.asarray(times_s, dtype=float).reshape(-1)
        q = self.joint_angles(t)
        return q, camera_pose(self.kinematics, self.body, q, t)


class ExposurePose(_CameraPath):
    """The camera during one exposure (built by :func:`exposure_pose_fn`).

    ``camera_fn(t) -> (q, T_world_cam)`` for a scalar time t, s: the joint angles, shape (3,), and
    the camera pose, (4, 4). :meth:`many` gives the same for an array of times at once.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    body : BodyMotion
    q0, w : array_like, shape (3,)
        Joint angles (rad) and the axes' inertial rates (rad/s) at ``t0_s``.
    t0_s : float
        The instant of ``q0``, s.
    grid_s : ndarray, shape (M,), optional
        Times at which ``integral`` is given, s (None: nothing to subtract, a still body).
    integral : ndarray, shape (M, 3), optional
        ∫ b dτ from ``t0_s``, rad: the body's rate in the joint basis, integrated.

    Notes
    -----
    q(t) = q0 + w·(t − t0) − ∫ b dτ, the integral interpolated linearly on ``grid_s`` (held at its
    end values outside it).
    """

    def __init__(self, kinematics, body: BodyMotion, q0, w, t0_s: float, grid_s=None, integral=None):
        self.kinematics, self.body = kinematics, body
        self.q0, self.w, self.t0_s = np.asarray(q0, dtype=float), np.asarray(w, dtype=float), float(t0_s)
        self._grid_s, self._integral = grid_s, integral

    def joint_angles(self, t_s) -> np.ndarray:
        """q at time(s) ``t_s``, rad: shape (3,) for a scalar, (N, 3) for (N,)."""
        q = self.q0 + (np.asarray(t_s, dtype=float) - self.t0_s)[..., None] * self.w
        if self._grid_s is None:
            return q
        return q - np.stack([np.interp(t_s, self._grid_s, column) for column in self._integral.T], axis=-1)


class RecordedPose(_CameraPath):
    """The camera along joint angles recorded at the inner steps (built by
    :meth:`GimbalMount.recorded_pose_fn`); callable like :class:`ExposurePose`.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    body : BodyMotion
    times_s : ndarray, shape (M,), M >= 2
        Instants of the recorded joint angles, s, increasing.
    q_path : ndarray, shape (M, 3)
        Joint angles there, rad.
    tail : ExposurePose or None
        The camera after ``times_s[-1]`` (None: the spline's own extrapolation).

    Notes
    -----
    Between samples q(t) is the not-a-knot cubic spline through them: the axes move smoothly at
    1 ms steps, so its error is far below a pixel where a linear one would not be (a 120 Hz
    vibration of 7 mrad amplitude, followed at 1 kHz, leaves 0.5 mrad between linear samples).
    """

    def __init__(self, kinematics, body: BodyMotion, times_s, q_path, tail: ExposurePose | None = None):
        from scipy.interpolate import CubicSpline

        self.kinematics, self.body, self._tail = kinematics, body, tail
        times_s = np.asarray(times_s, dtype=float)
        self._t_end = float(times_s[-1])
        self._spline = CubicSpline(times_s, np.asarray(q_path, dtype=float), axis=0)

    def joint_angles(self, t_s) -> np.ndarray:
        """q at time(s) ``t_s``, rad: shape (3,) for a scalar, (N, 3) for (N,)."""
        t = np.asarray(t_s, dtype=float)
        if self._tail is None:
            return self._spline(t)
        late = t > self._t_end
        q = self._spline(np.minimum(t, self._t_end))
        if np.any(late):
            q = np.where(late[..., None], self._tail.joint_angles(t), q)
        return q


def exposure_pose_fn(kinematics, body: BodyMotion, mount: str, q0, w, t0_s: float, t1_s: float,
                     n_grid: int = 64) -> ExposurePose:
    """The camera during one exposure: ``camera_fn(t) -> (q, T_world_cam)`` for t in [t0_s, t1_s].

    Within a frame's exposure the axes keep their inertial rates ``w`` (the closed loop passes the
    rates averaged over the last blade-pass period, :attr:`GimbalMount.smooth_axis_rates`; the
    axes' inertia and loops leave only a ~1e-4 rad oscillation about that) while the body moves
    exactly: the joint
    angles are q(t) = q0 + w·(t − t0) − ∫ b dτ, the integral of the body's rate in the joint basis
    on ``n_grid`` points. A still body gives q0 + w·(t − t0); the fixed mount keeps q = 0.
    ``q0`` and ``w`` are the state at ``t0_s`` (recorded per frame by the closed loop, so a finished
    run's frames can be rendered again exactly).

    Returns
    -------
    ExposurePose
        Callable with a scalar time; ``camera_fn.many(times)`` evaluates an array of times at once.
    """
    if mount == "fixed":
        return ExposurePose(kinematics, body, np.zeros(3), np.zeros(3), t0_s)
    q0 = np.asarray(q0, dtype=float)
    if body.sway is None and body.vibration is None and body.flight is None:
        return ExposurePose(kinematics, body, q0, w, t0_s)
    margin = _exposure_margin_s(t0_s, t1_s)
    grid = np.linspace(t0_s - margin, max(t1_s, t0_s + 1e-9) + margin, max(int(n_grid), 2))
    J = kinematics.T_body_base[:3, :3] @ kinematics.angular_jacobian(q0, frame="base", check_limits=False)
    b = np.linalg.solve(J, body.angular_rate_body(grid).T).T
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (b[1:] + b[:-1]) * np.diff(grid)[:, None], axis=0)])
    integral -= np.array([np.interp(t0_s, grid, integral[:, i]) for i in range(3)])  # zero at t0
    return ExposurePose(kinematics, body, q0, w, t0_s, grid, integral)
