"""Filter-driven pointing (tracking.FilterPointing) against independent oracles.

Oracles
-------
- Measurement covariance: Monte Carlo through the detector's own localiser. Pixel centre and
  radius are perturbed with the stated standard deviations and turned into positions by
  :func:`gimbal_lab.detection.locate_sphere_circle`; the sample covariance, whitened by the
  formula's, must be the identity within 0.05 per entry (20 000 samples: sampling error about
  0.01 on the diagonal, 0.007 off it; the linearisation of z = r f / R adds about 3 (σ_R/R)²,
  0.6 % at 5 m).
- Pointing: the line-of-sight angles written out by hand (roll 0 inside the yaw range):
  yaw = atan2(Y, X), pitch = atan2(Z, √(X² + Y²)) with (X, Y, Z) the target seen from the
  centre of rotation; their time derivatives along the velocity are the feed-forward.
- Closed loop: kinematics only (perfect joints integrated at 1 kHz), fixes at 30 frames/s with
  one frame of latency, made by projecting the true target and perturbing its pixels as above.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_lab.camera import Intrinsics
from gimbal_lab.detection import SphereDetection, locate_sphere_circle
from gimbal_lab.filters import ConstantVelocity
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.simulation import world_T_base
from gimbal_lab.trajectories import Trajectory
from gimbal_lab.tracking import (
    CENTRE_STD_PX,
    FILTER_COAST_S,
    RADIUS_STD_PX,
    FilterPointing,
    circle_measurement_covariance,
)

KIN = GimbalKinematics.default()
CAM = Intrinsics.default()  # fx = fy
T_WB = world_T_base(KIN)
RADIUS_M = 0.1  # the study's sphere


def _rigid(yaw_rad, pitch_rad, t_m) -> np.ndarray:
    cy, sy, cp, sp = math.cos(yaw_rad), math.sin(yaw_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    T = np.eye(4)
    T[:3, :3] = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    T[:3, 3] = t_m
    return T


def _detect(p_cam_m, rng=None, n=1):
    """Circle-method fixes of a sphere at ``p_cam_m`` with the stated pixel errors, shape (n, 3)."""
    z = p_cam_m[2]
    uv = np.array([CAM.fx * p_cam_m[0] / z + CAM.cx, CAM.fy * p_cam_m[1] / z + CAM.cy])
    R_px = RADIUS_M * CAM.fx / z  # the circle method's own model, so that only the noise differs
    out = np.empty((n, 3))
    ring = np.column_stack((np.cos(np.arange(8) * math.pi / 4), np.sin(np.arange(8) * math.pi / 4)))
    for i in range(n):
        c = uv if rng is None else uv + rng.normal(0.0, CENTRE_STD_PX, 2)
        r = R_px if rng is None else R_px + rng.normal(0.0, RADIUS_STD_PX)
        det = SphereDetection(center_px=c, radius_px=r, contour_px=c + r * ring, area_px=math.pi * r * r)
        out[i] = locate_sphere_circle(det, CAM, RADIUS_M)
    return out


def _angle(a, b) -> float:
    return math.acos(min(1.0, float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))))


class _FixedState:
    """A stand-in filter whose prediction is a given straight-line motion (isolates the pointing law)."""

    def __init__(self, p_world, v_world, t_s=0.0):
        self.p, self.v, self.t_s, self.initialised = np.asarray(p_world, float), np.asarray(v_world, float), t_s, True

    def update(self, t_s, z_m, R_m2=None):
        raise AssertionError("not used")

    def predict(self, t_s):
        dt = t_s - self.t_s
        return np.concatenate((self.p + self.v * dt, self.v)), np.eye(6)


# ----------------------------------------------------------------------------------------------
# measurement covariance

@pytest.mark.parametrize("uv_offset_px, depth_m", [((0.0, 0.0), 3.0), ((200.0, -150.0), 3.0), ((-250.0, 180.0), 5.0)])
def test_covariance_matches_monte_carlo_through_the_circle_method(uv_offset_px, depth_m):
    rng = np.random.default_rng(7)
    p_cam = depth_m * np.array([uv_offset_px[0] / CAM.fx, uv_offset_px[1] / CAM.fy, 1.0])
    T_wc = T_WB @ KIN.forward(np.array([0.4, 0.1, -0.3]))  # a camera turned on every joint
    R_wc = T_wc[:3, :3]
    samples = _detect(p_cam, rng, n=20_000) @ R_wc.T + T_wc[:3, 3]
    R = circle_measurement_covariance(p_cam, R_wc, CAM.fx, RADIUS_M)
    L = np.linalg.cholesky(R)
    whitened = np.linalg.solve(L, np.linalg.solve(L, np.cov(samples.T)).T)
    assert np.abs(whitened - np.eye(3)).max() < 0.05  # module docstring: sampling + linearisation
    if uv_offset_px != (0.0, 0.0):
        # the oracle can tell: diag(σ_lat², σ_lat², σ_z²) in the camera frame, without the range error
        # along the line of sight, is far off the axis
        z = p_cam[2]
        naive = R_wc @ np.diag([(z * 0.5 / CAM.fx) ** 2] * 2 + [(z * z * 0.5 / (RADIUS_M * CAM.fx)) ** 2]) @ R_wc.T
        L = np.linalg.cholesky(naive)
        assert np.abs(np.linalg.solve(L, np.linalg.solve(L, np.cov(samples.T)).T) - np.eye(3)).max() > 1.0


def test_covariance_on_axis_by_hand_and_properties():
    # on the axis at 3 m: σ_lat = 3 · 0.5 / f, σ_z = 9 · 0.5 / (0.1 f), in the camera frame (R_wc = I)
    f = CAM.fx
    R = circle_measurement_covariance([0.0, 0.0, 3.0], np.eye(3), f, RADIUS_M)
    assert np.allclose(R, np.diag([(1.5 / f) ** 2, (1.5 / f) ** 2, (45.0 / f) ** 2]), rtol=1e-12, atol=0)
    # any pose: symmetric, positive definite, and the same spectrum as in the camera frame (a rotation)
    p_cam = np.array([0.4, -0.3, 2.5])
    R_wc = _rigid(0.7, -0.4, [0, 0, 0])[:3, :3]
    Rw = circle_measurement_covariance(p_cam, R_wc, f, RADIUS_M)
    Rc = circle_measurement_covariance(p_cam, np.eye(3), f, RADIUS_M)
    assert np.array_equal(Rw, Rw.T)
    assert np.linalg.eigvalsh(Rw).min() > 0
    assert np.allclose(np.linalg.eigvalsh(Rw), np.linalg.eigvalsh(Rc), rtol=1e-9)
    # the method equals the function with the loop's parameters
    loop = FilterPointing(KIN, T_WB, ConstantVelocity(), focal_px=f, radius_m=RADIUS_M, centre_std_px=1.0)
    assert np.array_equal(loop.measurement_covariance(p_cam, R_wc),
                          circle_measurement_covariance(p_cam, R_wc, f, RADIUS_M, 1.0, RADIUS_STD_PX))


def test_covariance_rejects_bad_input():
    with pytest.raises(ValueError, match="in front"):
        circle_measurement_covariance([0.0, 0.0, -1.0], np.eye(3), 500.0, 0.1)
    with pytest.raises(ValueError, match="R_world_cam"):
        circle_measurement_covariance([0.0, 0.0, 3.0], 2 * np.eye(3), 500.0, 0.1)
    with pytest.raises(ValueError, match="radius_std_px"):
        circle_measurement_covariance([0.0, 0.0, 3.0], np.eye(3), 500.0, 0.1, radius_std_px=0.0)
    with pytest.raises(ValueError, match="p_cam_m"):
        circle_measurement_covariance([0.0, 3.0], np.eye(3), 500.0, 0.1)


# ----------------------------------------------------------------------------------------------
# command

def _loop(filter, T_world_base=T_WB, **kw):
    kw = dict(focal_px=CAM.fx, radius_m=RADIUS_M) | kw
    return FilterPointing(KIN, T_world_base, filter, **kw)


def test_command_is_zero_on_a_still_target_already_in_view():
    target_world = np.array([3.0, 0.8, 2.4])
    f = ConstantVelocity()
    loop = _loop(f)
    T_wc = T_WB @ KIN.forward(np.array([0.1, 0.0, -0.1]))
    p_cam = T_wc[:3, :3].T @ (target_world - T_wc[:3, 3])
    assert loop.observe(0.0, p_cam, T_wc)  # a track starts at the fix, with zero velocity
    q = KIN.look_at(target_world - T_WB[:3, 3])
    assert np.allclose(loop.command(0.2, q), 0.0, atol=1e-12)
    # off by δ: pure feedback, kp δ (no velocity, so no feed-forward)
    delta = np.array([0.01, -0.02, 0.005])
    assert np.allclose(loop.command(0.2, q - delta), 15.0 * delta, rtol=1e-9)


def test_feed_forward_is_the_line_of_sight_rate_in_the_base_frame():
    # a tilted, turned and shifted base: catches a missing or swapped world → base transform
    T_wb = _rigid(0.6, 0.2, [1.0, -2.0, 2.0])
    p_base = np.array([2.5, 0.9, 0.6])
    v_base = np.array([-0.3, 1.2, 0.5])
    loop = _loop(_FixedState(T_wb[:3, :3] @ p_base + T_wb[:3, 3], T_wb[:3, :3] @ v_base), T_wb,
                 max_rate_rad_s=100.0)
    q = KIN.look_at(p_base)  # on target: the feedback term is zero
    X, Y, Z = p_base - KIN.centre_base
    dX, dY, dZ = v_base
    rho = math.hypot(X, Y)
    yaw_rate = (X * dY - Y * dX) / rho**2
    pitch_rate = (rho * dZ - Z * (X * dX + Y * dY) / rho) / (rho**2 + Z**2)
    # forward difference over 1 ms: error ½ q̈ h, below 1e-4 rad/s for these rates (≲ 0.5 rad/s at 2.7 m)
    assert np.allclose(loop.command(0.0, q), [yaw_rate, 0.0, pitch_rate], atol=1e-3)
    # the sideways case by hand: straight ahead at X, moving along +y at v: yaw rate v / X
    loop = _loop(_FixedState(T_WB[:3, :3] @ [3.0, 0.0, -0.045] + T_WB[:3, 3], [0.0, 0.6, 0.0]), max_rate_rad_s=100.0)
    assert np.allclose(loop.command(0.0, np.zeros(3)), [0.6 / 3.0, 0.0, 0.0], atol=1e-4)


def test_command_respects_the_rate_limit_and_keeps_direction():
    p_world = np.array([3.0, 0.0, 2.0])
    loop = _loop(_FixedState(p_world, [0.0, 0.0, 0.0]), max_rate_rad_s=3.0)
    q = KIN.look_at(p_world - T_WB[:3, 3])
    delta = np.array([1.0, 0.2, -0.5])
    rate = loop.command(0.0, q - delta)  # unlimited: 15 · δ, 15 rad/s on yaw
    assert math.isclose(np.abs(rate).max(), 3.0, rel_tol=1e-12)
    assert np.allclose(rate, 3.0 * delta / np.abs(delta).max(), rtol=1e-9)


def test_command_holds_before_the_first_fix_after_coasting_and_out_of_reach():
    f = ConstantVelocity()
    loop = _loop(f, coast_s=0.5)
    q = np.zeros(3)
    assert np.array_equal(loop.command(0.0, q), np.zeros(3))  # no fix yet
    assert loop.prediction(0.0) is None
    T_wc = T_WB @ KIN.forward(q)
    loop.observe(0.0, [0.3, 0.1, 3.0], T_wc)  # off the axis: the loop turns
    assert np.any(loop.command(0.5, q) != 0)  # exactly coast_s: still following
    assert np.array_equal(loop.command(0.5 + 1e-9, q), np.zeros(3))  # past it: hold
    p, P = loop.prediction(0.5)  # the live track's estimate is logged up to coast_s ...
    assert np.allclose(p, T_wc[:3, :3] @ [0.3, 0.1, 3.0] + T_wc[:3, 3]) and P.shape == (3, 3)
    assert loop.live(0.5) and not loop.live(0.5 + 1e-9)
    assert loop.prediction(0.5 + 1e-9) is None  # ... and not past it: the track is no longer live
    loop.observe(0.6, None, T_wc)  # a missed frame does not revive it; a fix does
    assert loop.prediction(0.6) is None
    loop.observe(0.7, [0.3, 0.1, 3.0], T_wc)
    assert loop.live(0.7) and loop.prediction(0.7) is not None
    # a prediction 60° above the horizon is out of the gimbal's reach (pitch ≤ 45°): hold
    up = T_WB[:3, 3] + KIN.centre_base + 3.0 * np.array([math.cos(math.pi / 3), 0.0, math.sin(math.pi / 3)])
    assert np.array_equal(_loop(_FixedState(up, [0.0, 0.0, 0.0])).command(0.0, q), np.zeros(3))
    # reachable now, but not 1 ms ahead (crossing 45° at 100 m/s): hold too
    edge = T_WB[:3, 3] + KIN.centre_base + 3.0 * np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4) - 1e-6])
    KIN.look_at(edge - T_WB[:3, 3])  # reachable (does not raise)
    assert np.array_equal(_loop(_FixedState(edge, [0.0, 0.0, 100.0])).command(0.0, q), np.zeros(3))


def test_observe_fuses_world_position_with_the_stated_covariance_and_counts():
    f = ConstantVelocity()
    loop = _loop(f)
    T_wc = T_WB @ KIN.forward(np.array([0.3, 0.0, 0.1]))
    p_cam = np.array([0.2, -0.1, 3.0])
    assert loop.observe(0.0, p_cam, T_wc) is True
    # a track starts at the fix with P_pp = R: both pass through unchanged
    assert np.allclose(f.position(0.0), T_wc[:3, :3] @ p_cam + T_wc[:3, 3], atol=1e-12)
    assert np.allclose(f.P[:3, :3], loop.measurement_covariance(p_cam, T_wc[:3, :3]), rtol=1e-12)
    assert loop.observe(1 / 30, p_cam, T_wc) is True
    assert loop.observe(2 / 30, None, T_wc) is False  # missed frame
    assert loop.observe(3 / 30, p_cam + [0.0, 1.0, 0.0], T_wc) is False  # 1 m off: gated out (σ ≈ 6 mm)
    assert (loop.n_accepted, loop.n_rejected, loop.n_missed) == (2, 1, 1)
    assert (f.n_accepted, f.n_rejected) == (2, 1)


def test_rejects_bad_arguments():
    f = ConstantVelocity()
    for kw, match in [(dict(focal_px=0.0), "focal_px"), (dict(radius_m=-0.1), "radius_m"),
                      (dict(kp_per_s=math.nan), "kp_per_s"), (dict(max_rate_rad_s=0), "max_rate_rad_s"),
                      (dict(coast_s=-1.0), "coast_s"), (dict(centre_std_px=0.0), "centre_std_px")]:
        with pytest.raises(ValueError, match=match):
            _loop(f, **kw)
    with pytest.raises(TypeError, match="kp_per_s"):
        _loop(f, kp_per_s=True)
    with pytest.raises(ValueError, match="T_world_base"):
        _loop(f, T_world_base=2 * np.eye(4))
    with pytest.raises(TypeError, match="filter"):
        _loop(object())
    with pytest.raises(TypeError, match="kinematics"):
        FilterPointing(object(), T_WB, f, focal_px=500.0, radius_m=0.1)
    with pytest.raises(TypeError):
        _loop(f, gain=1.0)  # unknown keyword
    loop = _loop(f)
    with pytest.raises(ValueError, match="q_rad"):
        loop.command(0.0, np.zeros(2))
    with pytest.raises(ValueError, match="T_world_cam"):
        loop.observe(0.0, [0.0, 0.0, 3.0], np.eye(3))
    assert FILTER_COAST_S > 1.0  # the study's longest occlusion is 1.0 s


# ----------------------------------------------------------------------------------------------
# closed loop, kinematics only

def _closed_loop(duration_s=5.0, gap_s=(2.0, 2.5), seed=0):
    """The study's circle tracked by a CV filter; returns times, pointing error, frozen-joint error.

    The CV filter's white acceleration follows Bar-Shalom et al. (2001, §6.2.2): the velocity
    changes by about √(q T) per period T, which should match the circle's a·T, so q = a² T with
    a = (2π/2 s)² · 1 m = π² m/s² and T = 1/30 s.
    """
    rng = np.random.default_rng(seed)
    traj = Trajectory.circular()
    loop = _loop(ConstantVelocity(q_accel_m2_s3=math.pi**4 / 30.0))
    T_bw = np.linalg.inv(T_WB)
    q = KIN.look_at(T_bw[:3, :3] @ traj.position(0.0) + T_bw[:3, 3])
    dt = 1e-3
    n = int(round(duration_s / dt))
    frames = {int(round(k * 1000 / 30)) for k in range(int(duration_s * 30) + 1)}  # 30 Hz on the 1 ms grid
    pending, q_frozen = None, None
    t = np.arange(n) * dt
    error, frozen_error, qs = np.zeros(n), np.full(n, np.nan), np.zeros((n, 3))
    for k in range(n):
        T_wc = T_WB @ KIN.forward(q)
        p = traj.position(t[k])
        error[k] = _angle(T_wc[:3, 2], p - T_wc[:3, 3])
        if q_frozen is not None:  # what the paper's loop does while blind: hold the joints
            T_f = T_WB @ KIN.forward(q_frozen)
            frozen_error[k] = _angle(T_f[:3, 2], p - T_f[:3, 3])
        if k in frames:
            if pending is not None:  # one frame of latency: last frame's fix arrives now
                loop.observe(*pending)
            if gap_s[0] <= t[k] < gap_s[1]:
                pending = (t[k], None, T_wc)
                q_frozen = q.copy() if q_frozen is None else q_frozen
            else:
                pending = (t[k], _detect(T_wc[:3, :3].T @ (p - T_wc[:3, 3]), rng)[0], T_wc)
        qs[k] = q
        q = q + loop.command(t[k], q) * dt
    return t, error, frozen_error, qs, loop


def test_closed_loop_keeps_the_sphere_on_the_axis_and_coasts_through_a_gap():
    t, error, frozen_error, qs, loop = _closed_loop()
    # bound: the optical axis passes through the sphere, angle asin(r / D) ≥ 1.81° (D ≤ √10 m). The CV
    # model's own lag on the circle (9.9 m/s² over up to two frames of latency) is about 1°.
    bound = math.asin(RADIUS_M / math.sqrt(10.0))
    before = (t >= 0.5) & (t < 2.0)  # 0.5 s for the track to learn the velocity
    after = t >= 3.5  # 1 s after the gap: the gate rejects the first fixes until the track restarts
    assert error[before].max() < bound
    assert error[after].max() < bound
    # coasting: the CV prediction runs along the circle's tangent, off by R(1 − cos ωτ) after τ; frozen
    # joints are off by the chord 2R sin(ωτ/2), larger by 1/sin(ωτ/2) > 1.41 for ωτ ≤ π/2
    gap = (t >= 2.0 + 1 / 30) & (t <= 2.5)
    assert np.all(error[gap] < frozen_error[gap])
    assert error[gap].mean() < 0.75 * frozen_error[gap].mean()
    i0, i1 = np.searchsorted(t, [2.0, 2.5])
    assert abs(qs[i1, 2] - qs[i0, 2]) > math.radians(15)  # pitch keeps turning (the target climbs ~25°)
    assert loop.n_missed == 15


def test_closed_loop_is_deterministic():
    a, b = _closed_loop(duration_s=1.0), _closed_loop(duration_s=1.0)
    assert np.array_equal(a[1], b[1])
