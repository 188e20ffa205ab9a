"""DH transform and gimbal kinematics against hand derivations, finite differences and round trips."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_lab.kinematics import GimbalKinematics, dh_transform

KIN = GimbalKinematics.default()
LIMITS = KIN.joint_limits_rad


# --- elementary transforms written out here, independent of the module -------------------------
def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def so3_log(R):
    """Rotation vector of R (angle < π), from the axis-angle formula."""
    angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-12:
        return w / 2
    return angle / (2 * math.sin(angle)) * w


angles = st.floats(-2 * math.pi, 2 * math.pi)
lengths = st.floats(-1.0, 1.0)


def joint(i):
    lo, hi = LIMITS[i]
    return st.floats(lo, hi)


q_in_limits = st.tuples(joint(0), joint(1), joint(2)).map(np.array)
# yaw within 20° of a limit: with roll and pitch these directions often lie behind the yaw range
near_yaw_limit = st.floats(LIMITS[0][1] - math.radians(20), LIMITS[0][1]) | st.floats(
    LIMITS[0][0], LIMITS[0][0] + math.radians(20)
)
q_near_yaw_limit = st.tuples(near_yaw_limit, joint(1), joint(2)).map(np.array)


# --- dh_transform --------------------------------------------------------------------------------
@given(angles, lengths, lengths, angles)
def test_dh_transform_is_rz_tz_tx_rx(theta, d, a, alpha):
    expected = rot_z(theta) @ trans(0, 0, d) @ trans(a, 0, 0) @ rot_x(alpha)
    # 1e-12: both are a handful of products of O(1) numbers; double rounding is ~1e-16 per term
    assert np.allclose(dh_transform(theta, d, a, alpha), expected, atol=1e-12, rtol=0)


# --- home pose -----------------------------------------------------------------------------------
def test_home_pose_is_hand_derived():
    h, c = KIN.centre_drop_m, KIN.camera_offset_m
    # At home the camera axes in the base frame (x fwd, y left, z up) are:
    # x_cam (right) = −y, y_cam (down) = −z, z_cam (forward) = +x; the optical centre is c ahead
    # of the centre of rotation, which hangs h below the mount.
    expected = np.array(
        [
            [0.0, 0.0, 1.0, c],
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, -1.0, 0.0, -h],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    # 1e-15 scale: cos(±π/2) = 6e-17 enters the products
    assert np.allclose(KIN.forward(np.zeros(3)), expected, atol=1e-15, rtol=0)
    assert np.allclose(KIN.T_body_cam(np.zeros(3)), expected, atol=1e-15, rtol=0)


def test_joint_signs_follow_the_docstring():
    """Each joint alone equals a rotation about its body axis at the centre of rotation."""
    home = KIN.forward(np.zeros(3))
    centre = trans(0, 0, -KIN.centre_drop_m)
    about = lambda R: centre @ R @ np.linalg.inv(centre) @ home  # noqa: E731
    t = 0.3
    # yaw about +z (left), roll about +x (right side down), pitch about −y (up)
    assert np.allclose(KIN.forward([t, 0, 0]), about(rot_z(t)), atol=1e-14)
    assert np.allclose(KIN.forward([0, t, 0]), about(rot_x(t)), atol=1e-14)
    assert np.allclose(KIN.forward([0, 0, t]), about(rot_y(-t)), atol=1e-14)
    assert KIN.forward([t, 0, 0])[1, 2] > 0  # optical axis turns to body +y (left)
    assert KIN.forward([0, 0, t])[2, 2] > 0  # optical axis tilts up
    assert KIN.forward([0, t, 0])[2, 0] < 0  # camera's right side goes down


def test_composite_pose_is_yaw_roll_pitch_about_the_centre():
    q = np.array([0.7, -0.3, -1.1])
    centre = trans(0, 0, -KIN.centre_drop_m)
    expected = centre @ rot_z(q[0]) @ rot_x(q[1]) @ rot_y(-q[2]) @ np.linalg.inv(centre) @ KIN.forward(np.zeros(3))
    assert np.allclose(KIN.forward(q), expected, atol=1e-14)


def test_frames_chain_ends_at_forward():
    q = np.array([0.2, 0.1, -0.4])
    frames = KIN.frames(q)
    assert len(frames) == 5
    assert np.array_equal(frames[0], np.eye(4))
    assert np.allclose(frames[-1], KIN.forward(q), atol=1e-15)
    # the three joint axes meet at the centre of rotation: frames 1-3 share their origin
    for T in frames[1:4]:
        assert np.allclose(T[:3, 3], KIN.centre_base, atol=1e-15)


def test_body_base_offset_is_applied():
    T_body_base = trans(0.1, -0.02, -0.05) @ rot_z(0.4)
    kin = GimbalKinematics(T_body_base=T_body_base)
    q = np.array([0.3, 0.2, -0.5])
    assert np.allclose(kin.T_body_cam(q), T_body_base @ kin.forward(q), atol=1e-15)
    assert np.allclose(kin.forward(q), KIN.forward(q), atol=0)


# --- rigid transforms ----------------------------------------------------------------------------
@given(q_in_limits)
def test_forward_is_a_proper_rigid_transform(q):
    T = KIN.forward(q)
    R = T[:3, :3]
    # 1e-12: a product of five exactly-orthonormal-up-to-rounding matrices
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1.0) < 1e-12
    assert np.array_equal(T[3], [0, 0, 0, 1])
    # the optical centre stays camera_offset_m from the centre of rotation
    assert abs(np.linalg.norm(T[:3, 3] - KIN.centre_base) - KIN.camera_offset_m) < 1e-12


# --- look-at -------------------------------------------------------------------------------------
def angle_off_axis(T_base_cam, p):
    """Angle between the optical axis and the ray from the optical centre to p, rad."""
    r = T_base_cam[:3, :3].T @ (p - T_base_cam[:3, 3])
    return math.atan2(math.hypot(r[0], r[1]), r[2])


@settings(max_examples=300)
@given(q_in_limits | q_near_yaw_limit, st.floats(0.05, 50.0))
def test_look_at_puts_the_point_on_the_optical_axis(q_seed, range_m):
    # a reachable point: range_m ahead of the camera posed at q_seed (roll included)
    T = KIN.forward(q_seed)
    p = T[:3, 3] + range_m * T[:3, 2]
    q = KIN.look_at(p)
    KIN.check_q(q)  # inside the joint ranges
    # Past the yaw range look_at takes the pitch as acos(x), and near x = 1 (pitch near 0) acos
    # turns an error of k ε in x into up to √(2 k ε) in the angle, 2.1e-8 rad for k = 1 (elsewhere
    # atan2 of exact directions: 1e-15 rad). One run found 1.9e-9 rad at pitch 6e-8 rad; 200 000
    # poses at the yaw limit with pitches of 1e-12 to 1e-3 rad gave at most 3.9e-8 rad. 2e-7 rad
    # allows k up to 90; a wrong joint angle is off by far more.
    assert angle_off_axis(KIN.forward(q), p) < 2e-7


@given(st.floats(-math.radians(170), math.radians(170)), st.floats(-math.pi / 2, math.radians(45)), st.floats(0.1, 20))
def test_look_at_keeps_the_horizon_level_when_it_can(azimuth, elevation, range_m):
    f = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])
    p = KIN.centre_base + range_m * f
    q = KIN.look_at(p)
    assert q[1] == 0.0
    assert angle_off_axis(KIN.forward(q), p) < 1e-9
    # level horizon: the camera's x axis (image right) stays horizontal
    assert abs(KIN.forward(q)[2, 0]) < 1e-12


def test_look_at_study_target_centre():
    # study: base at world (0, 0, 2), target centre (3, 0, 2): straight ahead, slightly up
    p = np.array([3.0, 0.0, 0.0])
    q = KIN.look_at(p)
    assert q[0] == 0.0 and q[1] == 0.0
    assert math.isclose(q[2], math.atan2(KIN.centre_drop_m, 3.0), rel_tol=1e-12)


def test_look_at_behind_uses_roll_at_the_yaw_limit():
    # 5° past the yaw limit, looking well down: reachable only with some roll
    az, el = math.radians(175.0), math.radians(-60.0)
    p = KIN.centre_base + 2.0 * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    q = KIN.look_at(p)
    assert math.isclose(q[0], LIMITS[0][1], rel_tol=0, abs_tol=1e-15)
    assert q[1] != 0.0
    assert angle_off_axis(KIN.forward(q), p) < 1e-9


@pytest.mark.parametrize(
    "p, match",
    [
        ([0.0, 0.0, -0.045], "centre of rotation"),  # at the centre of rotation
        ([0.01, 0.0, -0.045], "centre of rotation"),  # behind the optical centre
        ([1.0, 0.0, 2.0], "pitch"),  # 63° above the horizon
        ([-3.0, 0.0, 0.0], "roll"),  # straight behind, level: needs roll ±90°
        ([1.0, np.nan, 0.0], "p_base"),
        ([1.0, 0.0], "p_base"),
    ],
)
def test_look_at_rejects_unreachable_points(p, match):
    with pytest.raises(ValueError, match=match):
        KIN.look_at(p)


# --- angular Jacobian ----------------------------------------------------------------------------
@settings(max_examples=100)
@given(q_in_limits, st.sampled_from(["base", "camera"]))
def test_angular_jacobian_matches_finite_differences(q, frame):
    h = 1e-6
    R0 = KIN.forward(q, check_limits=False)[:3, :3]
    J_fd = np.empty((3, 3))
    for i in range(3):
        dq = np.zeros(3)
        dq[i] = h
        Rp = KIN.forward(q + dq, check_limits=False)[:3, :3]
        Rm = KIN.forward(q - dq, check_limits=False)[:3, :3]
        if frame == "base":  # spatial velocity: log(R(q+h) R(q)ᵀ)
            w = so3_log(Rp @ R0.T) - so3_log(Rm @ R0.T)
        else:  # body velocity: log(R(q)ᵀ R(q+h))
            w = so3_log(R0.T @ Rp) - so3_log(R0.T @ Rm)
        J_fd[:, i] = w / (2 * h)
    # central difference: truncation O(h²) ~ 1e-12, rounding ~ 1e-16 / h ~ 1e-10; 1e-8 covers both
    assert np.allclose(KIN.angular_jacobian(q, frame=frame), J_fd, atol=1e-8, rtol=0)


@pytest.mark.parametrize("kin", [KIN, GimbalKinematics(centre_drop_m=0.1, camera_offset_m=0.0)])
def test_base_axes_are_the_columns_of_the_chains_jacobian(kin):
    # the inner loop's closed form against the DH chain's product (frames → z axes), within round-off
    rng = np.random.default_rng(7)
    for q in rng.uniform(-math.pi, math.pi, (500, 3)):
        J = kin.angular_jacobian(q, "base", check_limits=False)
        assert np.allclose(np.reshape(kin.base_axes(*q), (3, 3)).T, J, rtol=0.0, atol=1e-15)


def test_forward_many_is_forward_at_each_row():
    # the stacked chain against forward() one pose at a time (the same products; equal to
    # round-off, 1e-15), across and beyond the joint ranges; bad shapes and NaN are refused
    q = np.random.default_rng(3).uniform(-math.pi, math.pi, (300, 3))
    expected = np.array([KIN.forward(row, check_limits=False) for row in q])
    assert np.allclose(KIN.forward_many(q), expected, rtol=0.0, atol=1e-15)
    assert KIN.forward_many(q[:0]).shape == (0, 4, 4)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        KIN.forward_many(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        KIN.forward_many([[0.0, math.nan, 0.0]])


def test_angular_jacobian_at_home_by_hand():
    # base frame: yaw about z, roll about x, pitch about −y
    assert np.allclose(KIN.angular_jacobian(np.zeros(3)), [[0, 1, 0], [0, 0, -1], [1, 0, 0]], atol=1e-15)
    # camera frame (x right = −y, y down = −z, z forward = x): yaw about −y_cam, roll about z_cam,
    # pitch about x_cam (right)
    assert np.allclose(KIN.angular_jacobian(np.zeros(3), "camera"), [[0, 0, 1], [-1, 0, 0], [0, 1, 0]], atol=1e-15)


# --- bad input -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "q, match",
    [
        (np.zeros(2), r"q_rad.*shape"),
        (np.zeros((3, 1)), r"q_rad.*shape"),
        ([0.0, np.nan, 0.0], r"q_rad.*finite"),
        ([0.0, 0.0, np.inf], r"q_rad.*finite"),
        ([math.radians(171), 0.0, 0.0], r"yaw.*-170°, 170°"),
        ([0.0, math.radians(-46), 0.0], r"roll.*-45°, 45°"),
        ([0.0, 0.0, math.radians(50)], r"pitch.*-90°, 45°"),
        ([0.0, 0.0, math.radians(-91)], r"pitch.*-90°, 45°"),
    ],
)
def test_bad_joint_angles_are_rejected(q, match):
    with pytest.raises(ValueError, match=match):
        KIN.forward(q)
    with pytest.raises(ValueError, match=match):
        KIN.angular_jacobian(q)


def test_limit_check_can_be_skipped():
    q = np.array([0.0, 0.0, math.radians(60)])
    assert KIN.forward(q, check_limits=False)[2, 2] > 0.8  # looks 60° up
    with pytest.raises(ValueError, match="q_rad"):
        KIN.forward([0.0, np.nan, 0.0], check_limits=False)  # finiteness is always checked


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(centre_drop_m=-0.01), "centre_drop_m"),
        (dict(camera_offset_m=np.nan), "camera_offset_m"),
        (dict(joint_limits_rad=((-1, 1), (-1, 1))), "joint_limits_rad"),
        (dict(joint_limits_rad=((-1, 1), (1, -1), (-1, 1))), "joint_limits_rad.*roll"),
        (dict(T_body_base=np.eye(3)), "T_body_base"),
        (dict(T_body_base=np.diag([2.0, 1, 1, 1])), "T_body_base"),
        (dict(T_body_base=np.diag([-1.0, 1, 1, 1])), "T_body_base"),
    ],
)
def test_bad_configs_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GimbalKinematics(**kwargs)


def test_jacobian_frame_is_validated():
    with pytest.raises(ValueError, match="frame"):
        KIN.angular_jacobian(np.zeros(3), frame="world")
