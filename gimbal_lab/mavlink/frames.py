"""The MAVLink gimbal protocol's frames and the lab's gimbal joints (conventions stated once).

Frames
------
The lab (:mod:`gimbal_lab.kinematics`, :mod:`gimbal_lab.platform`) works in a Z-up world and an
x-forward, y-left, z-up body (FLU). The MAVLink gimbal protocol v2 works in NED and FRD frames:

* **earth frame** – NED: x North, y East, z Down. The lab's world is read as North–West–Up (x
  North, y West, z up), so a vector's NED components are ``F @ v_world`` with
  ``F = diag(1, −1, −1)``. The same ``F`` turns body FLU components into body FRD ones.
* **vehicle frame** – the earth frame turned about Down by the vehicle's heading ψ (NED yaw,
  positive to the right): x forward and level, y right and level, z down. It follows the vehicle's
  heading but not its roll or pitch. ``R_earth_vehicle = Rz(ψ)``.
* **gimbal frame** – the camera's FRD axes: x along the optical axis, y to the image's right,
  z to the image's bottom. In the lab's OpenCV camera axes (x right, y down, z forward) they are
  the columns of :data:`R_CAM_GIMBAL`.

The protocol's attitude is the rotation ``R_frame_gimbal`` (gimbal axes in the vehicle or earth
frame) as a unit quaternion **(w, x, y, z)**, (1, 0, 0, 0) the null rotation. Its Tait–Bryan
angles are taken in the **Z-Y-X order**: R = Rz(yaw)·Ry(pitch)·Rx(roll), yaw positive to the right
(clockwise seen from above), pitch positive up, roll positive right side down; all in rad.

An angular velocity in a message is the gimbal's angular velocity **relative to** that frame,
with components along that frame's axes (x: rolling right, y: pitching up, z: yawing right),
rad/s. The vehicle frame itself turns at the heading rate ψ̇ about Down, so the gimbal's angular
velocity relative to the earth, in NED axes, is ``Rz(ψ)·(ω_vehicle + (0, 0, ψ̇))``; the message set
writes the z part of this as ``w_earth = w_delta_yaw_velocity + w_vehicle``.

Joints ↔ protocol attitude
--------------------------
The lab's gimbal turns yaw → roll → pitch from the body to the camera (module docstring of
:mod:`gimbal_lab.kinematics`: yaw positive to the left about up, roll positive right side down,
pitch positive up; q = 0 looks along body +x with the horizon level). With the body level and the
mount aligned with the body, the camera's attitude in the vehicle frame is

    R_vehicle_gimbal = F · R_body_cam(q) · R_CAM_GIMBAL = Rz(−q_yaw) · Rx(q_roll) · Ry(q_pitch),

a Z-X-Y sequence (the gimbal's joint order), not the protocol's Z-Y-X: with roll 0 the protocol's
yaw is −q_yaw and its pitch is q_pitch; with roll ≠ 0 the angles mix and the quaternion carries the
exact rotation. ``R_body_cam`` comes from the lab's DH forward kinematics
(:meth:`GimbalKinematics.T_body_cam`); :func:`quaternion_to_joints` inverts the Z-X-Y product in
closed form (the roll joint's ±45° range keeps it away from its ±90° singularity). A tilted body is
passed as ``R_vehicle_body``, its FRD axes in the vehicle frame (identity for a level body).

Notes
-----
MAVLink common message set: GIMBAL_DEVICE_SET_ATTITUDE (284), GIMBAL_DEVICE_ATTITUDE_STATUS (285),
GIMBAL_DEVICE_FLAGS. Paper §3.2.4 for the gimbal's joints.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "F_NED_NWU",
    "R_CAM_GIMBAL",
    "rot_z",
    "quaternion_from_euler",
    "euler_from_quaternion",
    "quaternion_from_matrix",
    "matrix_from_quaternion",
    "quaternion_multiply",
    "gimbal_from_camera",
    "camera_from_gimbal",
    "gimbal_attitude_matrix",
    "joints_to_quaternion",
    "quaternion_to_joints",
    "joint_rates_to_angular_velocity",
    "angular_velocity_to_joint_rates",
    "camera_rates_to_angular_velocity",
    "euler_rates_from_angular_velocity",
]

#: NED components of a vector given in the lab's North–West–Up world (and FRD of FLU body ones).
F_NED_NWU = np.diag([1.0, -1.0, -1.0])
F_NED_NWU.flags.writeable = False

#: The gimbal's FRD axes (columns: forward, right, down) in the lab's OpenCV camera axes.
R_CAM_GIMBAL = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
R_CAM_GIMBAL.flags.writeable = False


def rot_z(angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about z, shape (3, 3) (in NED: a heading, positive to the right)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quaternion(q, name: str = "q") -> np.ndarray:
    arr = np.asarray(q, dtype=float)
    if arr.shape != (4,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be four finite numbers (w, x, y, z), got {q!r}")
    norm = float(np.linalg.norm(arr))
    if not 0.5 < norm < 2.0:
        raise ValueError(f"{name} must be a unit quaternion (w, x, y, z), got norm {norm:.6g}")
    return arr / norm


def quaternion_from_euler(yaw_rad: float, pitch_rad: float, roll_rad: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of R = Rz(yaw)·Ry(pitch)·Rx(roll) (Tait–Bryan Z-Y-X).

    Parameters
    ----------
    yaw_rad, pitch_rad, roll_rad : float
        Yaw (positive right), pitch (positive up), roll (positive right side down), rad, in the
        frame the quaternion is given in (vehicle or earth; module docstring).

    Returns
    -------
    ndarray, shape (4,)
        q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll), with w >= 0 when all half-angles lie in [−90°, 90°].

    Examples
    --------
    >>> import math
    >>> quaternion_from_euler(math.pi / 2, 0.0, 0.0).round(6).tolist()
    [0.707107, 0.0, 0.0, 0.707107]
    """
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    return np.array([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ])


def euler_from_quaternion(q) -> tuple[float, float, float]:
    """(yaw, pitch, roll), rad, of a quaternion (w, x, y, z), Z-Y-X order (inverse of
    :func:`quaternion_from_euler`; pitch in [−90°, 90°], yaw and roll in (−180°, 180°]).

    At pitch ±90° yaw and roll are not separable; the split returned there is arbitrary.
    """
    w, x, y, z = _quaternion(q)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - x * z))))
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    return yaw, pitch, roll


def quaternion_from_matrix(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix, shape (3, 3)."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    q = np.array([w, x, y, z])
    return -q if w < 0 else q


def matrix_from_quaternion(q) -> np.ndarray:
    """Rotation matrix, shape (3, 3), of a quaternion (w, x, y, z) (normalised first)."""
    w, x, y, z = _quaternion(q)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def quaternion_multiply(a, b) -> np.ndarray:
    """Hamilton product a ⊗ b of two quaternions (w, x, y, z): the rotation b, then a."""
    aw, ax, ay, az = np.asarray(a, dtype=float)
    bw, bx, by, bz = np.asarray(b, dtype=float)
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def gimbal_from_camera(R_lab_cam) -> np.ndarray:
    """``R_ned_gimbal`` from the OpenCV camera's rotation in a lab frame (NWU world or FLU body).

    ``F · R_lab_cam · R_CAM_GIMBAL``: the one place where the lab's frames meet the protocol's.
    """
    return F_NED_NWU @ np.asarray(R_lab_cam, dtype=float) @ R_CAM_GIMBAL


def camera_from_gimbal(R_ned_gimbal) -> np.ndarray:
    """Inverse of :func:`gimbal_from_camera`: the OpenCV camera's rotation in the lab frame."""
    return F_NED_NWU @ np.asarray(R_ned_gimbal, dtype=float) @ R_CAM_GIMBAL.T


def _vehicle_body(R_vehicle_body) -> np.ndarray:
    if R_vehicle_body is None:
        return np.eye(3)
    R = np.asarray(R_vehicle_body, dtype=float)
    # orthonormal to 1e-9 with determinant +1 (a rotation); written out: this runs in the device's
    # control loop, where numpy's allclose and det cost more than the rest of the step
    if R.shape != (3, 3) or not np.isfinite(R).all() or np.abs(R.T @ R - np.eye(3)).max() > 1e-9 \
            or _det3(R) < 0:
        raise ValueError("R_vehicle_body must be a rotation matrix, shape (3, 3)")
    return R


def _det3(M) -> float:
    """Determinant of a 3 × 3 matrix by cofactors."""
    return float(M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
                 - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
                 + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


def gimbal_attitude_matrix(kinematics, q_rad, R_vehicle_body=None) -> np.ndarray:
    """``R_vehicle_gimbal``: the lab's camera at joint angles ``q_rad`` as the protocol's attitude.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    q_rad : array_like, shape (3,)
        Joint angles (yaw, roll, pitch), rad (any finite values; limits are not checked).
    R_vehicle_body : ndarray, shape (3, 3), optional
        The body's FRD axes in the vehicle frame (its roll and pitch); None: a level body.

    Returns
    -------
    ndarray, shape (3, 3)
        ``R_vehicle_body · F · R_body_cam(q) · R_CAM_GIMBAL``, R_body_cam from the lab's DH forward
        kinematics.
    """
    R_body_cam = kinematics.T_body_cam(q_rad, check_limits=False)[:3, :3]
    return _vehicle_body(R_vehicle_body) @ gimbal_from_camera(R_body_cam)


def joints_to_quaternion(kinematics, q_rad, R_vehicle_body=None) -> np.ndarray:
    """The protocol's attitude (vehicle frame), (w, x, y, z) with w >= 0, of the lab's camera at
    joint angles ``q_rad`` (yaw, roll, pitch), rad: :func:`gimbal_attitude_matrix` as a quaternion."""
    return quaternion_from_matrix(gimbal_attitude_matrix(kinematics, q_rad, R_vehicle_body))


def quaternion_to_joints(kinematics, q_wxyz, R_vehicle_body=None) -> np.ndarray:
    """Joint angles (yaw, roll, pitch), rad, that give the attitude ``q_wxyz`` (vehicle frame).

    Inverse of :func:`joints_to_quaternion`: in the mount's FRD frame the camera's attitude is
    G = Rz(a)·Rx(b)·Ry(c) with (a, b, c) = (−q_yaw, q_roll, q_pitch), so
    a = atan2(−G₀₁, G₁₁), b = atan2(G₂₁, √(G₂₀² + G₂₂²)), c = atan2(−G₂₀, G₂₂) (roll within
    ±90°, yaw in (−180°, 180°]). Joint limits are not applied: an attitude the gimbal cannot reach
    comes back as the angles that would reach it.

    Parameters
    ----------
    kinematics : gimbal_lab.kinematics.GimbalKinematics
    q_wxyz : array_like, shape (4,)
        Attitude in the vehicle frame, (w, x, y, z).
    R_vehicle_body : ndarray, shape (3, 3), optional
        The body's FRD axes in the vehicle frame; None: a level body.

    Returns
    -------
    ndarray, shape (3,)
    """
    R_vehicle_gimbal = matrix_from_quaternion(q_wxyz)
    R_body_base = kinematics.T_body_base[:3, :3]
    # the gimbal's attitude in the mount's (base) FRD axes
    G = (F_NED_NWU @ R_body_base @ F_NED_NWU).T @ _vehicle_body(R_vehicle_body).T @ R_vehicle_gimbal
    a = math.atan2(-G[0, 1], G[1, 1])
    b = math.atan2(G[2, 1], math.hypot(G[2, 0], G[2, 2]))
    c = math.atan2(-G[2, 0], G[2, 2])
    return np.array([-a, b, c])


def _rates_matrix(kinematics, q_rad, R_vehicle_body) -> np.ndarray:
    """A with ω_vehicle = A·q̇ (inertial joint-basis rates to the gimbal's rate in vehicle axes)."""
    J_base = kinematics.angular_jacobian(q_rad, frame="base", check_limits=False)
    return _vehicle_body(R_vehicle_body) @ F_NED_NWU @ kinematics.T_body_base[:3, :3] @ J_base


def joint_rates_to_angular_velocity(kinematics, q_rad, qdot_rad_s, R_vehicle_body=None) -> np.ndarray:
    """The gimbal's angular velocity in vehicle-frame axes (x roll right, y pitch up, z yaw right),
    rad/s, from joint rates ``qdot_rad_s`` (yaw, roll, pitch) at joint angles ``q_rad``.

    ω = R_vehicle_body · F · R_body_base · J_base(q) · q̇. Joint rates relative to the body give
    the rate relative to the body; the axes' inertial rates (the body's own rotation in the joint
    basis included, :attr:`gimbal_lab.mount.GimbalMount.axis_rates`) give the inertial rate.
    """
    qdot = np.asarray(qdot_rad_s, dtype=float)
    if qdot.shape != (3,) or not np.all(np.isfinite(qdot)):
        raise ValueError(f"qdot_rad_s must be three finite rates (yaw, roll, pitch), got {qdot_rad_s!r}")
    return _rates_matrix(kinematics, q_rad, R_vehicle_body) @ qdot


def angular_velocity_to_joint_rates(kinematics, q_rad, omega_rad_s, R_vehicle_body=None) -> np.ndarray:
    """Joint rates (yaw, roll, pitch), rad/s, that turn the gimbal at ``omega_rad_s`` (vehicle-frame
    axes): the inverse of :func:`joint_rates_to_angular_velocity`.

    Raises
    ------
    ValueError
        When the joints are at the roll ±90° singularity (the yaw and pitch axes aligned).
    """
    omega = np.asarray(omega_rad_s, dtype=float)
    if omega.shape != (3,) or not np.all(np.isfinite(omega)):
        raise ValueError(f"omega_rad_s must be three finite rates, got {omega_rad_s!r}")
    A = _rates_matrix(kinematics, q_rad, R_vehicle_body)
    # A's columns are the unit joint axes (turned), so |det A| <= 1 measures how far from aligned
    # they are (cos roll for the lab's gimbal)
    if abs(_det3(A)) < 1e-8:
        raise ValueError(f"the joints {np.asarray(q_rad).tolist()} are at a singularity (roll ±90°)")
    return np.linalg.solve(A, omega)


def camera_rates_to_angular_velocity(kinematics, q_rad, omega_cam_rad_s, R_vehicle_body=None) -> np.ndarray:
    """The gimbal's angular velocity in vehicle-frame axes from the camera's own angular velocity
    ``omega_cam_rad_s`` in OpenCV camera axes (x right, y down, z forward), rad/s, at joints ``q_rad``.

    ω = R_vehicle_body · F · R_body_cam(q) · ω_cam (a vector turned into other axes).
    """
    omega = np.asarray(omega_cam_rad_s, dtype=float)
    if omega.shape != (3,) or not np.all(np.isfinite(omega)):
        raise ValueError(f"omega_cam_rad_s must be three finite rates, got {omega_cam_rad_s!r}")
    R_body_cam = kinematics.T_body_cam(q_rad, check_limits=False)[:3, :3]
    return _vehicle_body(R_vehicle_body) @ F_NED_NWU @ R_body_cam @ omega


def euler_rates_from_angular_velocity(q_wxyz, omega_rad_s) -> tuple[float, float, float]:
    """(yaw rate, pitch rate, roll rate), rad/s, of the Z-Y-X angles of attitude ``q_wxyz`` while
    the gimbal turns at ``omega_rad_s`` (relative to the quaternion's frame, in its axes).

    With R = Rz(ψ)·Ry(θ)·Rx(φ), ω = ψ̇·e_z + θ̇·Rz(ψ)·e_y + φ̇·Rz(ψ)·Ry(θ)·e_x; this solves that
    for (ψ̇, θ̇, φ̇). A gimbal manager's pitch and yaw rates (GIMBAL_MANAGER_SET_PITCHYAW) are θ̇ and
    ψ̇; the manager holds roll itself.

    Raises
    ------
    ValueError
        For a pitch within 10⁻⁶ rad of ±90°, where yaw and roll rates are not separable.
    """
    yaw, pitch, _ = euler_from_quaternion(q_wxyz)
    omega = np.asarray(omega_rad_s, dtype=float)
    if omega.shape != (3,) or not np.all(np.isfinite(omega)):
        raise ValueError(f"omega_rad_s must be three finite numbers, got {omega_rad_s!r}")
    if abs(math.cos(pitch)) < 1e-6:
        raise ValueError(f"pitch {math.degrees(pitch):g} deg is at ±90 deg: yaw and roll rates are not separable")
    Rz = rot_z(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    M = np.column_stack([(0.0, 0.0, 1.0), Rz[:, 1], (Rz @ Ry)[:, 0]])
    yaw_rate, pitch_rate, roll_rate = np.linalg.solve(M, omega)
    return float(yaw_rate), float(pitch_rate), float(roll_rate)
