"""The protocol's conventions (gimbal_lab.mavlink.frames) against hand-worked cases, scipy's
Rotation, pymavlink's own quaternion class, and the lab's DH forward kinematics.

Tolerances: the conversions are a few trigonometric evaluations and 3 × 3 products of unit
entries, so agreement with an oracle is to a few ulp of 1 (1e-12 leaves a margin of ~1000 ulp);
finite differences of a smooth rotation with step h = 1e-6 rad agree to O(h) (central: O(h²)).
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from pymavlink.quaternion import QuaternionBase  # the oracle: pymavlink's own quaternions

from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.mavlink import frames

KIN = GimbalKinematics.default()
TOL = 1e-12
D = math.radians

# The frame change, stated once here as the module states it: NED from the lab's NWU/FLU
# components, and the gimbal's FRD axes (forward = optical axis, right = image x, down = image y)
# as columns in OpenCV camera axes.
F = np.diag([1.0, -1.0, -1.0])
P = np.column_stack([(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])

angle = st.floats(-math.pi + 1e-3, math.pi - 1e-3)
pitch = st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)
# pymavlink's Euler angles treat pitch within 1e-3 rad of ±90° as gimbal lock (roll set to 0)
pitch_off_lock = st.floats(-math.pi / 2 + 2e-3, math.pi / 2 - 2e-3)


def joint(i):
    lo, hi = KIN.joint_limits_rad[i]
    return st.floats(lo, hi)


q_in_limits = st.tuples(joint(0), joint(1), joint(2)).map(np.array)


def same_rotation(q1, q2, tol=TOL):
    """q and −q are the same rotation."""
    return min(np.abs(np.asarray(q1) - q2).max(), np.abs(np.asarray(q1) + q2).max()) < tol


# ---------------------------------------------------------------------------------- Euler ↔ quaternion
def test_quaternion_of_yaw_30_pitch_minus_20_worked_by_hand():
    # q = q_z(30°) ⊗ q_y(−20°), roll 0: w = cos15°·cos(−10°), x = −sin15°·sin(−10°),
    # y = cos15°·sin(−10°), z = sin15°·cos(−10°)
    c15, s15, c10, s10 = math.cos(D(15)), math.sin(D(15)), math.cos(D(-10)), math.sin(D(-10))
    expected = np.array([c15 * c10, -s15 * s10, c15 * s10, s15 * c10])
    got = frames.quaternion_from_euler(D(30), D(-20), 0.0)
    assert np.abs(got - expected).max() < TOL


@pytest.mark.parametrize("yaw_deg, pitch_deg, roll_deg, expected", [
    (90, 0, 0, (math.sqrt(0.5), 0, 0, math.sqrt(0.5))),      # yaw right 90°: about down
    (0, 90, 0, (math.sqrt(0.5), 0, math.sqrt(0.5), 0)),      # pitch up 90°: about right
    (0, 0, 90, (math.sqrt(0.5), math.sqrt(0.5), 0, 0)),      # roll right 90°: about forward
    (0, 0, 0, (1, 0, 0, 0)),
])
def test_single_axis_quaternions(yaw_deg, pitch_deg, roll_deg, expected):
    assert np.abs(frames.quaternion_from_euler(D(yaw_deg), D(pitch_deg), D(roll_deg)) - expected).max() < TOL


@settings(max_examples=200, deadline=None)
@given(angle, pitch_off_lock, angle)
def test_euler_quaternion_against_scipy_and_pymavlink(yaw, pitch_rad, roll):
    q = frames.quaternion_from_euler(yaw, pitch_rad, roll)
    x, y, z, w = Rotation.from_euler("ZYX", [yaw, pitch_rad, roll]).as_quat()  # intrinsic Z-Y'-X''
    assert same_rotation(q, [w, x, y, z])
    roll_o, pitch_o, yaw_o = QuaternionBase(list(q)).euler  # pymavlink: [roll, pitch, yaw]
    assert np.abs(np.array(frames.euler_from_quaternion(q)) - (yaw_o, pitch_o, roll_o)).max() < 1e-9
    assert np.abs(np.array(frames.euler_from_quaternion(q)) - (yaw, pitch_rad, roll)).max() < 1e-9


@settings(max_examples=100, deadline=None)
@given(angle, pitch, angle, angle, pitch, angle)
def test_matrix_and_product_against_pymavlink(y1, p1, r1, y2, p2, r2):
    a, b = frames.quaternion_from_euler(y1, p1, r1), frames.quaternion_from_euler(y2, p2, r2)
    A, B = QuaternionBase(list(a)).dcm, QuaternionBase(list(b)).dcm
    assert np.abs(frames.matrix_from_quaternion(a) - A).max() < TOL
    assert np.abs(frames.matrix_from_quaternion(frames.quaternion_multiply(a, b)) - A @ B).max() < 1e-11
    assert same_rotation(frames.quaternion_from_matrix(A), a, 1e-11)
    assert frames.quaternion_from_matrix(A)[0] >= 0


def test_bad_quaternions_are_named():
    with pytest.raises(ValueError, match="four finite numbers"):
        frames.euler_from_quaternion([1, 0, 0])
    with pytest.raises(ValueError, match="unit quaternion"):
        frames.matrix_from_quaternion([0, 0, 0, 0.1])


# ---------------------------------------------------------------------------------- joints ↔ attitude
@pytest.mark.parametrize("q_deg, expected", [
    # the lab's yaw is positive to the left: +30° joint yaw is the protocol's yaw −30° (about down)
    ((30, 0, 0), (math.cos(D(15)), 0, 0, -math.sin(D(15)))),
    # pitch up +20° is the protocol's pitch +20° (about the right axis)
    ((0, 0, 20), (math.cos(D(10)), 0, math.sin(D(10)), 0)),
    # roll +10°, right side down, is the protocol's roll +10° (about forward)
    ((0, 10, 0), (math.cos(D(5)), math.sin(D(5)), 0, 0)),
])
def test_joint_signs_worked_by_hand(q_deg, expected):
    got = frames.joints_to_quaternion(KIN, np.radians(q_deg))
    assert np.abs(got - expected).max() < TOL
    assert np.abs(frames.quaternion_to_joints(KIN, got) - np.radians(q_deg)).max() < TOL


@settings(max_examples=200, deadline=None)
@given(q_in_limits)
def test_quaternion_rotation_is_the_dh_forward_kinematics(q):
    """pymavlink's DCM of the attitude = the lab's FK with the frame change: the gimbal's forward
    axis is the optical axis, its right and down axes are image x and y, all in NED."""
    R_body_cam = KIN.forward(q)[:3, :3]  # T_body_base is the identity
    dcm = QuaternionBase(list(frames.joints_to_quaternion(KIN, q))).dcm
    assert np.abs(dcm[:, 0] - F @ R_body_cam[:, 2]).max() < 1e-11
    assert np.abs(dcm[:, 1] - F @ R_body_cam[:, 0]).max() < 1e-11
    assert np.abs(dcm[:, 2] - F @ R_body_cam[:, 1]).max() < 1e-11
    assert np.abs(frames.gimbal_from_camera(R_body_cam) - F @ R_body_cam @ P).max() < TOL
    # the joint order is Z-X-Y in the protocol's frames: Rz(−yaw)·Rx(roll)·Ry(pitch)
    zxy = Rotation.from_euler("ZXY", [-q[0], q[1], q[2]]).as_matrix()
    assert np.abs(dcm - zxy).max() < 1e-11


@settings(max_examples=200, deadline=None)
@given(q_in_limits)
def test_joint_round_trip(q):
    back = frames.quaternion_to_joints(KIN, frames.joints_to_quaternion(KIN, q))
    assert np.abs(back - q).max() < 1e-9


@settings(max_examples=100, deadline=None)
@given(q_in_limits, st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.5, 0.5))
def test_joint_round_trip_with_a_tilted_mount_and_body(q, body_roll, body_pitch, mount_yaw):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [mount_yaw, 0.1, -0.05]).as_matrix()
    kin = GimbalKinematics(T_body_base=T)
    R_vb = Rotation.from_euler("YX", [body_pitch, body_roll]).as_matrix()
    quat = frames.joints_to_quaternion(kin, q, R_vb)
    expected = R_vb @ F @ kin.T_body_cam(q)[:3, :3] @ P
    assert np.abs(frames.matrix_from_quaternion(quat) - expected).max() < 1e-11
    assert np.abs(frames.quaternion_to_joints(kin, quat, R_vb) - q).max() < 1e-9


def test_not_a_rotation_for_the_body_is_named():
    with pytest.raises(ValueError, match="R_vehicle_body must be a rotation"):
        frames.joints_to_quaternion(KIN, np.zeros(3), 2 * np.eye(3))


# ---------------------------------------------------------------------------------- rates
@pytest.mark.parametrize("qdot, expected", [
    ((0.5, 0, 0), (0, 0, -0.5)),   # joint yaw left → yawing left, negative z (down) rate
    ((0, 0.2, 0), (0.2, 0, 0)),    # roll right side down → rolling right
    ((0, 0, 0.3), (0, 0.3, 0)),    # pitch up → pitching up
])
def test_joint_rates_at_home_by_hand(qdot, expected):
    assert np.abs(frames.joint_rates_to_angular_velocity(KIN, np.zeros(3), qdot) - expected).max() < TOL


@settings(max_examples=100, deadline=None)
@given(q_in_limits, st.tuples(*[st.floats(-2.0, 2.0)] * 3).map(np.array))
def test_angular_velocity_is_the_attitude_derivative(q, qdot):
    """ω = vee(Ṙ·Rᵀ) of the attitude along q + t·q̇ (central difference, h = 1e-6 s)."""
    h = 1e-6
    R_plus = frames.matrix_from_quaternion(frames.joints_to_quaternion(KIN, q + h * qdot))
    R_minus = frames.matrix_from_quaternion(frames.joints_to_quaternion(KIN, q - h * qdot))
    R = frames.matrix_from_quaternion(frames.joints_to_quaternion(KIN, q))
    S = (R_plus - R_minus) / (2 * h) @ R.T
    omega_fd = np.array([S[2, 1], S[0, 2], S[1, 0]])
    omega = frames.joint_rates_to_angular_velocity(KIN, q, qdot)
    # O(h²)·|q̇|³ truncation plus rounding of the quaternion round trip (1e-16/h)
    assert np.abs(omega - omega_fd).max() < 1e-7
    assert np.abs(frames.angular_velocity_to_joint_rates(KIN, q, omega) - qdot).max() < 1e-9


def test_camera_rates_by_hand():
    # at home the camera's y axis (down) is NED down: turning about it pans right, a yaw right
    assert np.abs(frames.camera_rates_to_angular_velocity(KIN, np.zeros(3), (0, 0.4, 0)) - (0, 0, 0.4)).max() < TOL
    # its x axis (right) is NED east: turning about it (right-hand rule) lifts the optical axis, a pitch up
    assert np.abs(frames.camera_rates_to_angular_velocity(KIN, np.zeros(3), (0.4, 0, 0)) - (0, 0.4, 0)).max() < TOL
    # and the camera's rates are the joint rates' through the camera Jacobian
    q = np.radians([20, -10, -30])
    qdot = np.array([0.3, -0.2, 0.5])
    omega_cam = KIN.angular_jacobian(q, frame="camera") @ qdot
    assert np.abs(frames.camera_rates_to_angular_velocity(KIN, q, omega_cam)
                  - frames.joint_rates_to_angular_velocity(KIN, q, qdot)).max() < TOL


def test_euler_rates_by_hand():
    """Level: a turn about Down is the yaw rate. Yawed 90° right, the pitch axis is Rz(90°)·e_y =
    −e_x, so ω = (−0.2, 0, 0) is a pitch rate of +0.2 rad/s (up)."""
    np.testing.assert_allclose(frames.euler_rates_from_angular_velocity([1, 0, 0, 0], [0, 0, 0.3]), (0.3, 0, 0),
                               rtol=0, atol=1e-15)
    q = frames.quaternion_from_euler(math.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(frames.euler_rates_from_angular_velocity(q, [-0.2, 0, 0]), (0, 0.2, 0),
                               rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="not separable"):
        frames.euler_rates_from_angular_velocity(frames.quaternion_from_euler(0.3, math.pi / 2, 0.0), [0, 0, 1])


@settings(max_examples=50, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-1.4, 1.4), st.floats(-0.7, 0.7),
       st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3))
def test_euler_rates_match_scipy_by_central_difference(yaw, pitch, roll, omega):
    """Oracle: scipy turns the attitude by ω·dt about the frame's axes (left product) and reads its
    intrinsic Z-Y-X angles; their central difference over dt = 1e-6 s is the Euler rates
    (truncation ~ ω³·dt² < 1e-11, rounding ~ 1e-16 / dt = 1e-10; tolerance 1e-7 rad/s)."""
    R = Rotation.from_matrix(frames.matrix_from_quaternion(frames.quaternion_from_euler(yaw, pitch, roll)))
    dt = 1e-6
    ahead = (Rotation.from_rotvec(np.array(omega) * dt) * R).as_euler("ZYX")
    behind = (Rotation.from_rotvec(-np.array(omega) * dt) * R).as_euler("ZYX")
    diff = (ahead - behind + math.pi) % (2 * math.pi) - math.pi  # yaw and roll wrap at ±180°
    np.testing.assert_allclose(frames.euler_rates_from_angular_velocity(frames.quaternion_from_euler(yaw, pitch, roll),
                                                                        omega), diff / (2 * dt), rtol=0, atol=1e-7)
