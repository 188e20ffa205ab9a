"""Denavit–Hartenberg kinematics of the 3-DoF yaw → roll → pitch camera gimbal.

Frames (stated once, pinned by tests):

* **body** – the UAV body: x forward, y left, z up (in the study the UAV is static, its axes equal
  the world's, so the world is Z-up).
* **base** – the gimbal's mounting point on the body (``T_body_base``, identity by default): the
  yaw motor sits there, its axis along base +z.
* **link 1, 2, 3** – the standard DH frames after the yaw, roll and pitch joints.
* **cam** – the camera's optical frame, OpenCV axes: x right, y down, z forward.

Standard DH link transform (frame i−1 → frame i)::

    A_i = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)

          ⎡ cθ   −sθ·cα    sθ·sα   a·cθ ⎤
        = ⎢ sθ    cθ·cα   −cθ·sα   a·sθ ⎥
          ⎢ 0      sα       cα      d   ⎥
          ⎣ 0      0        0       1   ⎦

Geometry of :class:`GimbalKinematics` (a small STorM32-sized gimbal carrying an action camera).
The three joint axes meet in one point, the gimbal's centre of rotation, which hangs
``centre_drop_m`` below the mount on the yaw axis; the camera's optical centre lies on the optical
axis, ``camera_offset_m`` ahead of the centre of rotation. The only link offset is therefore
along a joint axis (d₁), every a_i is zero, and pointing has a closed form. DH table, with q the
joint angles (q = 0 is the home pose)::

    i  joint   θ_i          d_i              a_i   α_i
    1  yaw     q_yaw + 90°  −centre_drop_m    0    +90°
    2  roll    q_roll − 90°  0                0    +90°
    3  pitch   q_pitch + 90° 0                0     0°

The constant θ offsets exist because the DH rules fix each x_i along the common normal of z_{i−1}
and z_i (paper Fig. 7: the frames are drawn in a joint configuration that is not the home pose).
Frame 3 has x₃ along the optical axis, y₃ up and z₃ (the pitch axis) to the camera's right at home;
``T_link3_cam`` re-labels these as OpenCV axes and moves ``camera_offset_m`` along x₃.

Joint axes and signs (right-hand rule about each axis, q = 0 at home):

* yaw about base +z (up): positive yaw pans the camera to the **left** (towards body +y);
* roll about the yawed forward axis: positive roll turns the camera **clockwise seen from behind**
  (its right side goes down), so the scene turns counter-clockwise in the image;
* pitch about the camera's right axis: positive pitch tilts the camera **up**.

At home the camera looks along body +x with the horizon level: image x (right) = body −y,
image y (down) = body −z.

Notes
-----
Paper §3.2.4 (DH frames of the 3-DoF gimbal, Figs. 6–7, T₀³ = A₁A₂A₃).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["dh_transform", "GimbalKinematics", "JOINT_NAMES"]

JOINT_NAMES = ("yaw", "roll", "pitch")

# look_at accepts a solution this far past a joint limit (rounding of atan2/acos) and clips it
_LIMIT_SLACK_RAD = 1e-12


def dh_transform(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard Denavit–Hartenberg link transform A = Rz(θ)·Tz(d)·Tx(a)·Rx(α).

    ::

        ⎡ cos θ   −sin θ cos α    sin θ sin α   a cos θ ⎤
        ⎢ sin θ    cos θ cos α   −cos θ sin α   a sin θ ⎥
        ⎢   0         sin α          cos α         d    ⎥
        ⎣   0           0              0           1    ⎦

    Parameters
    ----------
    theta : float
        Joint angle θ about z_{i−1}, rad.
    d : float
        Offset along z_{i−1}, m.
    a : float
        Link length along x_i, m.
    alpha : float
        Link twist about x_i, rad.

    Returns
    -------
    ndarray, shape (4, 4)
        The homogeneous transform from frame i to frame i−1 (maps points in frame i to i−1).

    Notes
    -----
    Paper §3.2.4 (the A_i matrix).

    Examples
    --------
    >>> import numpy as np
    >>> A = dh_transform(np.pi / 2, 0.1, 0.0, 0.0)
    >>> np.round(A[:3, 0], 12).tolist(), float(A[2, 3])
    ([0.0, 1.0, 0.0], 0.1)
    """
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _check_rigid(name: str, T) -> np.ndarray:
    """Return ``T`` as a read-only float (4, 4) proper rigid transform or raise ValueError."""
    arr = np.array(T, dtype=float)
    if arr.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 homogeneous transform, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    R = arr[:3, :3]
    # 1e-9: hand-written transforms with rounded cos/sin entries pass, a scaled or sheared one does not
    if (
        not np.allclose(arr[3], (0.0, 0.0, 0.0, 1.0), atol=1e-12)
        or not np.allclose(R.T @ R, np.eye(3), atol=1e-9)
        or np.linalg.det(R) < 0
    ):
        raise ValueError(f"{name} must be a rigid transform (orthonormal rotation, det +1, last row 0 0 0 1)")
    arr.flags.writeable = False
    return arr


def _default_limits() -> tuple[tuple[float, float], ...]:
    return (
        (math.radians(-170.0), math.radians(170.0)),
        (math.radians(-45.0), math.radians(45.0)),
        (math.radians(-90.0), math.radians(45.0)),
    )


# camera optical axes (columns: x right, y down, z forward) expressed in link frame 3
# (x3 forward along the optical axis, y3 up, z3 right)
_R_LINK3_CAM = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True, eq=False)
class GimbalKinematics:
    """The 3-DoF yaw → roll → pitch gimbal as a standard DH chain (module docstring: frames, signs).

    Parameters
    ----------
    centre_drop_m : float
        Distance from the mount (base origin) down the yaw axis to the centre of rotation where the
        three joint axes meet, m, >= 0 (DH d₁ = −centre_drop_m).
    camera_offset_m : float
        Distance from the centre of rotation to the camera's optical centre along the optical
        axis, m, >= 0.
    joint_limits_rad : tuple of 3 (lo, hi) pairs
        Joint ranges for (yaw, roll, pitch), rad, lo < hi (±inf allowed, e.g. a slip-ring yaw).
    T_body_base : ndarray, shape (4, 4)
        Fixed pose of the mount in the UAV body frame (a rigid transform).

    Notes
    -----
    Paper §3.2.4 and §4.1 (HawkRC STorM32 three-axis gimbal). The default sizes are those of a
    small STorM32 gimbal for an action camera: the roll/pitch cross sits 45 mm below the yaw
    motor's mounting face, the lens 30 mm ahead of it. The default limits are those such a gimbal
    reaches without a slip ring or its frame hitting the camera: yaw ±170°, roll ±45°, pitch −90°
    (straight down) to +45° (up).

    Examples
    --------
    >>> import numpy as np
    >>> kin = GimbalKinematics.default()
    >>> T = kin.forward(np.zeros(3))
    >>> np.round(T[:3, 2], 12).tolist()  # the optical axis at home: body +x
    [1.0, 0.0, 0.0]
    """

    centre_drop_m: float = 0.045
    camera_offset_m: float = 0.030
    joint_limits_rad: tuple = field(default_factory=_default_limits)
    T_body_base: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        for name in ("centre_drop_m", "camera_offset_m"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise TypeError(f"{name} must be a real number, got {value!r}") from None
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0 m, got {value}")
            object.__setattr__(self, name, value)
        limits = self.joint_limits_rad
        try:
            limits = tuple((float(lo), float(hi)) for lo, hi in limits)
        except (TypeError, ValueError):
            raise ValueError("joint_limits_rad must be three (lo, hi) pairs in rad") from None
        if len(limits) != 3:
            raise ValueError(f"joint_limits_rad must be three (lo, hi) pairs, got {len(limits)}")
        for joint, (lo, hi) in zip(JOINT_NAMES, limits):
            if math.isnan(lo) or math.isnan(hi) or not lo < hi:
                raise ValueError(f"joint_limits_rad for {joint} must satisfy lo < hi, got ({lo}, {hi})")
        object.__setattr__(self, "joint_limits_rad", limits)
        object.__setattr__(self, "T_body_base", _check_rigid("T_body_base", self.T_body_base))
        T = np.eye(4)
        T[:3, :3] = _R_LINK3_CAM
        T[0, 3] = self.camera_offset_m
        T.flags.writeable = False
        object.__setattr__(self, "_T_link3_cam", T)
        object.__setattr__(self, "_lo", np.array([lo for lo, _ in limits]))
        object.__setattr__(self, "_hi", np.array([hi for _, hi in limits]))

    @classmethod
    def default(cls) -> "GimbalKinematics":
        """The study's gimbal: 45 mm drop, 30 mm lens offset, STorM32-like limits, mount = body."""
        return cls()

    # ------------------------------------------------------------------ DH description
    @property
    def dh_parameters(self) -> tuple[tuple[float, float, float, float], ...]:
        """Per joint (θ offset rad, d m, a m, α rad): θ_i = q_i + θ offset."""
        h = self.centre_drop_m
        return (
            (math.pi / 2, -h, 0.0, math.pi / 2),
            (-math.pi / 2, 0.0, 0.0, math.pi / 2),
            (math.pi / 2, 0.0, 0.0, 0.0),
        )

    @property
    def T_link3_cam(self) -> np.ndarray:
        """Fixed transform from the camera optical frame to link frame 3, shape (4, 4)."""
        return self._T_link3_cam

    @property
    def joint_names(self) -> tuple[str, str, str]:
        """("yaw", "roll", "pitch"), the order of q."""
        return JOINT_NAMES

    @property
    def centre_base(self) -> np.ndarray:
        """The centre of rotation in the base frame, m, shape (3,)."""
        return np.array([0.0, 0.0, -self.centre_drop_m])

    def dh_table(self):
        """The DH table as a pandas DataFrame (one row per joint; angles in degrees for display).

        Returns
        -------
        pandas.DataFrame
            Columns ``joint``, ``theta`` (the symbolic θ_i), ``theta_offset_deg``, ``d_m``,
            ``a_m``, ``alpha_deg``, ``lower_limit_deg``, ``upper_limit_deg``.
        """
        import pandas as pd

        rows = []
        for joint, (off, d, a, alpha), (lo, hi) in zip(JOINT_NAMES, self.dh_parameters, self.joint_limits_rad):
            sign = "+" if off >= 0 else "−"
            rows.append(
                dict(
                    joint=joint,
                    theta=f"q_{joint} {sign} {abs(math.degrees(off)):g}°",
                    theta_offset_deg=math.degrees(off),
                    d_m=d,
                    a_m=a,
                    alpha_deg=math.degrees(alpha),
                    lower_limit_deg=math.degrees(lo),
                    upper_limit_deg=math.degrees(hi),
                )
            )
        return pd.DataFrame(rows).set_index(pd.RangeIndex(1, 4, name="i"))

    # ------------------------------------------------------------------ validation
    def check_q(self, q_rad, check_limits: bool = True) -> np.ndarray:
        """Return ``q_rad`` as a float array of shape (3,), raising ValueError when invalid.

        Parameters
        ----------
        q_rad : array_like, shape (3,)
            Joint angles (yaw, roll, pitch), rad.
        check_limits : bool
            Also require every joint inside ``joint_limits_rad``.
        """
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (3,):
            raise ValueError(f"q_rad must have shape (3,) (yaw, roll, pitch), got {q.shape}")
        if not np.isfinite(q).all():
            raise ValueError(f"q_rad must be finite, got {q}")
        if check_limits and ((q < self._lo).any() or (q > self._hi).any()):
            i = int(np.flatnonzero((q < self._lo) | (q > self._hi))[0])
            raise ValueError(
                f"q_rad[{i}] ({JOINT_NAMES[i]}) = {math.degrees(q[i]):.3f}° is outside its range "
                f"[{math.degrees(self._lo[i]):g}°, {math.degrees(self._hi[i]):g}°]"
            )
        return q

    # ------------------------------------------------------------------ kinematics
    def link_transforms(self, q_rad, check_limits: bool = True) -> list[np.ndarray]:
        """The DH link transforms [A₁, A₂, A₃] at ``q_rad``, each of shape (4, 4)."""
        q = self.check_q(q_rad, check_limits)
        return [
            dh_transform(qi + off, d, a, alpha)
            for qi, (off, d, a, alpha) in zip(q.tolist(), self.dh_parameters)
        ]

    def frames(self, q_rad, check_limits: bool = True) -> list[np.ndarray]:
        """Poses of every frame in the base frame, for drawing.

        Returns
        -------
        list of ndarray, shape (4, 4)
            [T_base_base (identity), T_base_link1, T_base_link2, T_base_link3, T_base_cam].
        """
        out = [np.eye(4)]
        for A in self.link_transforms(q_rad, check_limits):
            out.append(out[-1] @ A)
        out.append(out[-1] @ self._T_link3_cam)
        return out

    def forward(self, q_rad, check_limits: bool = True) -> np.ndarray:
        """Camera pose in the base frame, T_base_cam = A₁·A₂·A₃·T_link3_cam.

        Parameters
        ----------
        q_rad : array_like, shape (3,)
            Joint angles (yaw, roll, pitch), rad.
        check_limits : bool
            Raise ValueError when a joint is outside its range (False: any finite angle).

        Returns
        -------
        ndarray, shape (4, 4)
            Maps points in the camera optical frame (OpenCV axes) to the base frame, m.

        Notes
        -----
        Paper §3.2.4, T₀³ = A₁A₂A₃.
        """
        A1, A2, A3 = self.link_transforms(q_rad, check_limits)
        return A1 @ A2 @ A3 @ self._T_link3_cam

    def forward_many(self, q_rad) -> np.ndarray:
        """:meth:`forward` at many joint angles at once, without the limit check.

        Parameters
        ----------
        q_rad : array_like, shape (N, 3)
            Joint angles (yaw, roll, pitch), rad, one set per row (finite).

        Returns
        -------
        ndarray, shape (N, 4, 4)
            T_base_cam for each row: the same link transforms and the same products, in the same
            order, as :meth:`forward` (stacked), so equal to it to round-off and, with numpy's
            matmul taking each stacked product as it takes one, bit for bit.
        """
        q = np.asarray(q_rad, dtype=float)
        if q.ndim != 2 or q.shape[1] != 3:
            raise ValueError(f"q_rad must have shape (N, 3) (yaw, roll, pitch), got {q.shape}")
        if not np.isfinite(q).all():
            raise ValueError("q_rad must be finite")
        n = len(q)
        links = []
        for column, (off, d, a, alpha) in zip(q.T.tolist(), self.dh_parameters):
            ct = np.array([math.cos(v + off) for v in column])
            st = np.array([math.sin(v + off) for v in column])
            ca, sa = math.cos(alpha), math.sin(alpha)
            A = np.zeros((n, 4, 4))
            A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, a * ct
            A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, a * st
            A[:, 2, 1], A[:, 2, 2], A[:, 2, 3], A[:, 3, 3] = sa, ca, d, 1.0
            links.append(A)
        return links[0] @ links[1] @ links[2] @ self._T_link3_cam

    def T_body_cam(self, q_rad, check_limits: bool = True) -> np.ndarray:
        """Camera pose in the UAV body frame, T_body_base · T_base_cam, shape (4, 4)."""
        return self.T_body_base @ self.forward(q_rad, check_limits)

    def look_at(self, p_base) -> np.ndarray:
        """Joint angles that put a point on the camera's optical axis, in front of the camera.

        The optical axis passes through the centre of rotation, so it must point along
        v = p − centre. With roll 0 the optical axis is (cos p cos y, cos p sin y, sin p) in the base
        frame: yaw = atan2(v_y, v_x), pitch = atan2(v_z, √(v_x² + v_y²)). When that yaw is outside
        its range (a point behind the gimbal), yaw is held at the nearer limit and roll and pitch
        solve the rest in closed form (the least roll that does it); the result is checked
        against every joint range.

        Parameters
        ----------
        p_base : array_like, shape (3,)
            The point in the base frame, m.

        Returns
        -------
        ndarray, shape (3,)
            (yaw, roll, pitch), rad, inside the joint ranges.

        Raises
        ------
        ValueError
            If the point is not finite, lies no farther from the centre of rotation than the
            optical centre (it cannot be in front of the camera), or no joint angles inside the
            ranges point at it (e.g. more than 45° above the horizon).
        """
        p = np.asarray(p_base, dtype=float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"p_base must be a finite point of shape (3,), got {p!r}")
        v = p - self.centre_base
        dist = float(np.linalg.norm(v))
        if dist <= self.camera_offset_m:
            raise ValueError(
                f"p_base is {dist:.4g} m from the gimbal's centre of rotation, which is not farther than "
                f"the camera's optical centre ({self.camera_offset_m:g} m): it cannot be in front of the camera"
            )
        f = v / dist
        yaw = math.atan2(f[1], f[0])
        pitch = math.atan2(f[2], math.hypot(f[0], f[1]))
        roll = 0.0
        lo, hi = self._lo, self._hi
        if not lo[0] <= yaw <= hi[0]:
            # Hold yaw at the nearer limit; in that yawed frame the optical axis is
            # g = (cos p, −sin p sin r, sin p cos r), |r| < 90° so sign(sin p) = sign(g_z).
            yaw = float(hi[0] if abs(_wrap(yaw - hi[0])) <= abs(_wrap(yaw - lo[0])) else lo[0])
            c, s = math.cos(yaw), math.sin(yaw)
            g = (c * f[0] + s * f[1], -s * f[0] + c * f[1], f[2])
            pitch = math.copysign(math.acos(min(1.0, max(-1.0, g[0]))), g[2])
            sp = math.sin(pitch)
            roll = math.atan2(-g[1] / sp, g[2] / sp) if sp != 0.0 else 0.0
        q = np.array([yaw, roll, pitch])
        # a point reached exactly at a limit may come out a rounding error past it
        bad = (q < lo - _LIMIT_SLACK_RAD) | (q > hi + _LIMIT_SLACK_RAD)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"p_base is unreachable: pointing at it needs {JOINT_NAMES[i]} = {math.degrees(q[i]):.2f}°, "
                f"outside [{math.degrees(lo[i]):g}°, {math.degrees(hi[i]):g}°] "
                f"(direction: azimuth {math.degrees(math.atan2(f[1], f[0])):.2f}°, "
                f"elevation {math.degrees(math.asin(max(-1.0, min(1.0, f[2])))):.2f}°)"
            )
        return np.clip(q, lo, hi)

    def base_axes(self, q0: float, q1: float, q2: float) -> tuple[float, ...]:
        """The joint axes z₀, z₁, z₂ in the base frame at joint angles (q0, q1, q2) rad, as nine floats
        (z₀, z₁, z₂, three components each): the columns of ``angular_jacobian(q, "base")``, without
        checks or arrays.

        For the 1 kHz inner loop (:class:`gimbal_lab.mount.GimbalMount`), where building the DH chain
        with arrays costs more than the step itself. z₀ is the base's z; z₁ = R₁·e_z and
        z₂ = R₁·R₂·e_z with Rᵢ the rotation of the DH link transform Aᵢ (:func:`dh_transform`), so
        z₂ = R₁·(sin θ₂ sin α₂, −cos θ₂ sin α₂, cos α₂). Equal to the chain's product to round-off
        (tests/test_kinematics.py).
        """
        (off1, _, _, alpha1), (off2, _, _, alpha2), _ = self.dh_parameters
        t1, t2 = q0 + off1, q1 + off2
        ct1, st1, ca1, sa1 = math.cos(t1), math.sin(t1), math.cos(alpha1), math.sin(alpha1)
        ct2, st2, ca2, sa2 = math.cos(t2), math.sin(t2), math.cos(alpha2), math.sin(alpha2)
        # R₁'s columns: (cos θ, sin θ, 0), (−sin θ cos α, cos θ cos α, sin α), (sin θ sin α, −cos θ sin α, cos α)
        x = (st2 * sa2, -ct2 * sa2, ca2)  # A₂'s z axis in frame 1
        z1 = (st1 * sa1, -ct1 * sa1, ca1)
        z2 = (ct1 * x[0] - st1 * ca1 * x[1] + z1[0] * x[2],
              st1 * x[0] + ct1 * ca1 * x[1] + z1[1] * x[2],
              sa1 * x[1] + ca1 * x[2])
        return (0.0, 0.0, 1.0) + z1 + z2

    def angular_jacobian(self, q_rad, frame: str = "base", check_limits: bool = True) -> np.ndarray:
        """Matrix J with ω = J·q̇: joint rates to the camera's angular velocity.

        Column i is joint i's unit axis z_{i−1} (ω = Σ z_{i−1} q̇_i for revolute joints).

        Parameters
        ----------
        q_rad : array_like, shape (3,)
            Joint angles (yaw, roll, pitch), rad.
        frame : {"base", "camera"}
            Frame in which ω is expressed (camera: OpenCV optical axes).
        check_limits : bool
            Raise ValueError when a joint is outside its range.

        Returns
        -------
        ndarray, shape (3, 3)
            rad/s of camera angular velocity per rad/s of joint rate.
        """
        if frame not in ("base", "camera"):
            raise ValueError(f"frame must be 'base' or 'camera', got {frame!r}")
        T = self.frames(q_rad, check_limits)
        J = np.column_stack([T[0][:3, 2], T[1][:3, 2], T[2][:3, 2]])
        if frame == "camera":
            J = T[4][:3, :3].T @ J
        return J


def _wrap(angle_rad: float) -> float:
    """Wrap an angle to (−π, π]."""
    return math.atan2(math.sin(angle_rad), math.cos(angle_rad))
