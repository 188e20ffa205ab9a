"""A driver for MAVLink gimbal devices (Gimbal Protocol v2): find, command and read a gimbal.

:class:`MavlinkGimbal` opens a link (:func:`gimbal_lab.mavlink.link.open_link`), waits for a
gimbal's HEARTBEAT (``MAV_TYPE_GIMBAL`` or a component id ``MAV_COMP_ID_GIMBAL`` ..
``MAV_COMP_ID_GIMBAL6``), asks for GIMBAL_DEVICE_INFORMATION with ``MAV_CMD_REQUEST_MESSAGE``, and
then

* commands it with GIMBAL_DEVICE_SET_ATTITUDE: an attitude quaternion (angular velocity NaN) or
  angular rates (quaternion NaN), flags from :data:`gimbal_lab.mavlink.protocol.FRAME_FLAGS`; or
  through a gimbal manager (the device's own or an autopilot's, :meth:`MavlinkGimbal.find_manager`,
  control taken with MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE), GIMBAL_MANAGER_SET_PITCHYAW;
* keeps every GIMBAL_DEVICE_ATTITUDE_STATUS it receives as an :class:`AttitudeReport`;
* notices a silent device: no message from it for ``timeout_s`` (real time) or no answer to a
  request within ``timeout_s`` (lock-step) makes every later call raise :class:`GimbalLinkLost`;
* in lock-step, advances the device's clock (:meth:`MavlinkGimbal.step`).

Frames, quaternion order and angle signs are those of :mod:`gimbal_lab.mavlink.frames`; the joint
helpers (``send_joint_rates``, ``AttitudeReport.q_rad``) use the lab's
:class:`~gimbal_lab.kinematics.GimbalKinematics` and assume a level body (the vehicle frame is the
body's FRD frame).

A background thread reads the link, sends the driver's own HEARTBEAT at 1 Hz (a device on
``udpin:`` learns where to answer from it) and watches the device's silence.

With a signing key (``signing_key_file``, :mod:`gimbal_lab.mavlink.signing`) the driver signs
everything it sends and refuses every packet not signed with the same key (counted in
:attr:`MavlinkGimbal.refused_packets`): a device with another key, or none, is never found.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..kinematics import GimbalKinematics
from . import frames
from .link import open_link
from .protocol import GIMBAL_COMPONENT_IDS, STEP_COMMAND, frame_flags, frame_of_flags, mavlink, new_mavlink
from .signing import enable_signing, read_key, refused_count

__all__ = ["MavlinkGimbal", "AttitudeReport", "GimbalDeviceInfo", "GimbalLinkError", "GimbalNotFound",
           "GimbalLinkLost", "GimbalCommandFailed"]

_POLL_S = 0.05
_HEARTBEAT_PERIOD_S = 1.0
_NAN = float("nan")


class GimbalLinkError(RuntimeError):
    """Base of the driver's link errors."""


class GimbalNotFound(GimbalLinkError):
    """No gimbal's HEARTBEAT (or no GIMBAL_DEVICE_INFORMATION) arrived in time."""


class GimbalLinkLost(GimbalLinkError):
    """The device fell silent. ``silence_s``: seconds without a message from it when noticed."""

    def __init__(self, message: str, silence_s: float):
        super().__init__(message)
        self.silence_s = silence_s


class GimbalCommandFailed(GimbalLinkError):
    """The device refused a command (COMMAND_ACK other than MAV_RESULT_ACCEPTED)."""


def _version_text(encoded: int) -> str:
    """"major.minor.patch" of a MAVLink version word (Dev << 24 | Patch << 16 | Minor << 8 | Major)."""
    return f"{encoded & 0xFF}.{(encoded >> 8) & 0xFF}.{(encoded >> 16) & 0xFF}"


@dataclass(frozen=True)
class GimbalDeviceInfo:
    """GIMBAL_DEVICE_INFORMATION, decoded. Angle limits are the protocol's (rad): roll positive
    right side down, pitch positive up, yaw positive right (NaN: unknown or unlimited).

    The message has no field for a rate limit.
    """

    system_id: int
    component_id: int
    vendor_name: str
    model_name: str
    custom_name: str
    firmware_version: str
    hardware_version: str
    uid: int
    cap_flags: int
    roll_limits_rad: tuple[float, float]
    pitch_limits_rad: tuple[float, float]
    yaw_limits_rad: tuple[float, float]

    def has(self, cap_flag: int) -> bool:
        """Whether every bit of ``cap_flag`` (GIMBAL_DEVICE_CAP_FLAGS_*) is set."""
        return (self.cap_flags & cap_flag) == cap_flag

    @property
    def joint_limits_rad(self) -> tuple[tuple[float, float], ...]:
        """The limits as the lab's joint ranges (yaw, roll, pitch): the lab's yaw is positive to
        the left, so its range is (−yaw_max, −yaw_min); unknown limits become ±inf."""
        def pair(lo, hi):
            return (-math.inf if math.isnan(lo) else lo, math.inf if math.isnan(hi) else hi)

        y_lo, y_hi = pair(*self.yaw_limits_rad)
        return ((-y_hi, -y_lo), pair(*self.roll_limits_rad), pair(*self.pitch_limits_rad))


@dataclass(frozen=True, eq=False)
class AttitudeReport:
    """One GIMBAL_DEVICE_ATTITUDE_STATUS.

    Attributes
    ----------
    time_s : float
        The device's clock at the sample (``time_boot_ms`` / 1000), s: simulated time for the lab's
        device, in lock-step and in real time.
    received_s : float
        ``time.monotonic()`` of this process when the message was parsed, s.
    quaternion : ndarray, shape (4,)
        Attitude (w, x, y, z) of the gimbal's FRD axes in ``frame`` (normalised float32 values);
        NaN when the received one is not finite or all zero.
    quaternion_norm : float
        The norm of the quaternion as received (1 to float32 precision for a valid attitude; NaN
        when a component is not finite): a device that sends a non-unit attitude is at fault.
    frame : {"vehicle", "earth"}
        The frame of ``quaternion`` and ``angular_velocity_rad_s`` (from the status flags).
    angular_velocity_rad_s : ndarray, shape (3,)
        The gimbal's angular velocity relative to ``frame`` in its axes (x roll right, y pitch up,
        z yaw right), rad/s; NaN where the device does not know it.
    flags, failure_flags : int
        GIMBAL_DEVICE_FLAGS and GIMBAL_DEVICE_ERROR_FLAGS.
    delta_yaw_rad, delta_yaw_rate_rad_s : float
        The vehicle's heading (NED yaw) and its rate, which relate the two frames; NaN if unknown.
    seq : int
        The MAVLink packet sequence number (0..255; a gap means packets were lost).
    q_rad : ndarray, shape (3,)
        The lab's joint angles (yaw, roll, pitch), rad, that give this attitude on a level body
        (:func:`gimbal_lab.mavlink.frames.quaternion_to_joints`); NaN when the attitude is in the
        earth frame and the heading is unknown.
    """

    time_s: float
    received_s: float
    quaternion: np.ndarray
    quaternion_norm: float
    frame: str
    angular_velocity_rad_s: np.ndarray
    flags: int
    failure_flags: int
    delta_yaw_rad: float
    delta_yaw_rate_rad_s: float
    seq: int
    q_rad: np.ndarray = field(repr=False)

    @property
    def euler_rad(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll) of ``quaternion`` in ``frame``, Z-Y-X, rad."""
        return frames.euler_from_quaternion(self.quaternion)

    def quaternion_in(self, frame: str) -> np.ndarray:
        """The attitude in ``frame`` ("vehicle" or "earth"): q_earth = q_z(delta_yaw) ⊗ q_vehicle.

        Raises
        ------
        ValueError
            For another frame, or when the conversion needs an unknown (NaN) delta yaw.
        """
        frame_flags(frame)
        if frame == self.frame:
            return self.quaternion.copy()
        if math.isnan(self.delta_yaw_rad):
            raise ValueError("the report's delta_yaw is unknown (NaN): it cannot be converted to another frame")
        sign = 1.0 if frame == "earth" else -1.0
        return frames.quaternion_multiply(_yaw_quaternion(sign * self.delta_yaw_rad), self.quaternion)


class _Writer:
    """The file object pymavlink writes to (the driver serialises its sends under a lock)."""

    def __init__(self, link):
        self.link = link

    def write(self, data: bytes) -> None:
        self.link.write(data)


class MavlinkGimbal:
    """A MAVLink gimbal device, found on a link and commanded through Gimbal Protocol v2.

    Parameters
    ----------
    address : str or gimbal_lab.mavlink.link.Link
        ``udpin:HOST:PORT``, ``udpout:HOST:PORT``, a serial device path or pyserial URL, or an
        open link.
    baud : int
        Serial speed, bit/s.
    target : (int, int), optional
        (system id, component id) of the device; None: the first gimbal heard (:meth:`discover`).
    request_info : bool
        Ask for GIMBAL_DEVICE_INFORMATION on connecting (:attr:`info`).
    kinematics : GimbalKinematics, optional
        The gimbal for the joint ↔ attitude mapping (default: the lab's).
    lockstep : bool
        The device runs in lock-step: the silence watch applies only while a request waits for
        its answer, and :meth:`step` advances the device.
    timeout_s : float
        Silence after which the device counts as lost, s (> 0). In real time, keep it above the
        device's longest gap between messages (its status period; 1 s of heartbeat if it sends no
        status).
    discover_timeout_s : float
        How long :meth:`discover` waits for a gimbal's HEARTBEAT, s.
    system_id, component_id : int
        The driver's own MAVLink identity (default: system 1, MAV_COMP_ID_ONBOARD_COMPUTER).
    history : int
        How many reports :meth:`reports` keeps between calls (the oldest are dropped).
    signing_key_file : str or os.PathLike, optional
        A MAVLink 2 signing key (32 raw bytes or 64 hexadecimal characters,
        :func:`gimbal_lab.mavlink.signing.read_key`): sign what the driver sends, refuse what is
        not signed with it. None: no signing (signed packets are read without a check).

    Raises
    ------
    GimbalNotFound
        No gimbal heard, or no information received, in time (the message counts the packets
        refused for their signature: a sign of a wrong or missing key).
    ValueError
        The key file cannot be read or holds no key.

    Examples
    --------
    A pointing loop against the lab's device in lock-step (``gimbal-lab gimbal-device --lockstep``)::

        with MavlinkGimbal("udpout:127.0.0.1:14555", lockstep=True) as gimbal:
            for k in range(100):
                report = gimbal.latest()              # attitude, joints and time stamp
                gimbal.send_joint_rates([0.2, 0.0, -0.1], report.q_rad if report else None)
                gimbal.step(0.01)                     # the device runs 10 ms, its statuses arrive
    """

    def __init__(self, address, *, baud: int = 115200, target: tuple[int, int] | None = None,
                 request_info: bool = True, kinematics: GimbalKinematics | None = None, lockstep: bool = False,
                 timeout_s: float = 1.0, discover_timeout_s: float = 5.0, system_id: int = 1,
                 component_id: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER, history: int = 100_000,
                 signing_key_file=None):
        for name, value in (("timeout_s", timeout_s), ("discover_timeout_s", discover_timeout_s)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number > 0 s, got {value!r}")
        if target is not None:
            if (not isinstance(target, tuple) or len(target) != 2
                    or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 255 for v in target)):
                raise ValueError(f"target must be (system id, component id), each in 1..255, got {target!r}")
        if kinematics is not None and not isinstance(kinematics, GimbalKinematics):
            raise TypeError(f"kinematics must be a GimbalKinematics, got {type(kinematics).__name__}")
        if isinstance(history, bool) or not isinstance(history, int) or history < 1:
            raise ValueError(f"history must be an integer >= 1, got {history!r}")
        key = None if signing_key_file is None else read_key(signing_key_file)
        self.kinematics = kinematics or GimbalKinematics.default()
        self.lockstep = bool(lockstep)
        self.timeout_s = float(timeout_s)
        self.discover_timeout_s = float(discover_timeout_s)
        self._link = open_link(address, baud)
        self.address = self._link.address
        self._send_lock = threading.Lock()
        self._mav = new_mavlink(_Writer(self._link), system_id, component_id)
        self.signed = key is not None
        if self.signed:
            enable_signing(self._mav, key)
        self._cond = threading.Condition()
        self._target = target
        self._heard: dict[tuple[int, int], int] = {}  # (system, component) -> MAV_TYPE of gimbals heard
        self._last_heard_s = None  # monotonic time of the last message from the target
        self._awaiting_since = None  # lock-step: monotonic time a request started waiting
        self._lost: GimbalLinkLost | None = None
        self._latest: AttitudeReport | None = None
        self._reports: deque[AttitudeReport] = deque(maxlen=history)
        self._acks: dict[int, object] = {}
        self._command_acks: dict[tuple[tuple[int, int], int], object] = {}  # (source, command) -> COMMAND_ACK
        self._managers: dict[tuple[int, int], float] = {}  # managers of the target heard: source -> when first
        self.manager: tuple[int, int] | None = None
        self.manager_status = None  # the manager's latest GIMBAL_MANAGER_STATUS
        self._info_msg = None
        self.info: GimbalDeviceInfo | None = None
        self.bad_packets = 0
        self._closing = threading.Event()
        self._next_heartbeat_s = 0.0
        self._thread = threading.Thread(target=self._receive_loop, name=f"mavlink-gimbal {self.address}", daemon=True)
        self._thread.start()
        try:
            if self._target is None:
                self.discover()
            if request_info:
                self.request_information()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> "MavlinkGimbal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the receiving thread and close the link (the device keeps running)."""
        if not self._closing.is_set():
            self._closing.set()
            if self._thread is not threading.current_thread():
                self._thread.join(timeout=2.0)
            self._link.close()

    @property
    def target(self) -> tuple[int, int] | None:
        """(system id, component id) of the device."""
        return self._target

    @property
    def refused_packets(self) -> int:
        """Packets refused for their signature (unsigned or wrongly signed; 0 without a key)."""
        return refused_count(self._mav) if self.signed else 0

    def refusals_note(self) -> str:
        """A clause on refused packets for a not-found message ("" when none were refused)."""
        count = self.refused_packets
        return (f"; {count} packets were refused for their signature (is the device's signing key this one, and "
                "does it sign?)" if count else "")

    @property
    def last_heard_s(self) -> float | None:
        """``time.monotonic()`` when the last message of any kind came from the device (None
        before it was found)."""
        with self._cond:
            return self._last_heard_s

    @property
    def lost(self) -> GimbalLinkLost | None:
        """The error that will be raised once the device has been found silent, else None."""
        return self._lost

    # ------------------------------------------------------------------ the receiving thread
    def _receive_loop(self) -> None:
        try:
            while not self._closing.is_set():
                now = time.monotonic()
                if now >= self._next_heartbeat_s:
                    self._next_heartbeat_s = now + _HEARTBEAT_PERIOD_S
                    self._send(self._mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                          mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE))
                data = self._link.read(_POLL_S)
                now = time.monotonic()
                if data:
                    for msg in self._mav.parse_buffer(data) or ():
                        self._handle(msg, now)
                self._watch(now)
        except Exception as exc:  # the link failed: every waiting and later call raises
            if self._closing.is_set():
                return
            with self._cond:
                silence = math.nan if self._last_heard_s is None else time.monotonic() - self._last_heard_s
                self._lost = GimbalLinkLost(f"the link {self.address} failed: {exc}", silence)
                self._cond.notify_all()

    def _send(self, msg) -> None:
        with self._send_lock:
            try:
                self._mav.send(msg)
            except OSError:
                if not self._closing.is_set():
                    raise

    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.bad_packets += 1
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT" and (msg.type == mavlink.MAV_TYPE_GIMBAL or source[1] in GIMBAL_COMPONENT_IDS):
            with self._cond:
                self._heard[source] = msg.type
                self._cond.notify_all()
        if kind in ("GIMBAL_MANAGER_STATUS", "GIMBAL_MANAGER_INFORMATION") and self._target is not None and (
                source[0] == self._target[0] and msg.gimbal_device_id == self._target[1]):
            with self._cond:
                self._managers.setdefault(source, now)
                if kind == "GIMBAL_MANAGER_STATUS" and source == self.manager:
                    self.manager_status = msg
                self._cond.notify_all()
        if kind == "COMMAND_ACK" and source in (self._target, self.manager):
            with self._cond:
                self._command_acks[(source, msg.command)] = msg
                self._cond.notify_all()
        if source != self._target:
            return
        with self._cond:
            self._last_heard_s = now
            if kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                report = self._report(msg, now)
                self._latest = report
                self._reports.append(report)
            elif kind == "GIMBAL_DEVICE_INFORMATION":
                self._info_msg = msg
            elif kind == "COMMAND_ACK":
                self._acks[msg.command] = msg
            else:
                return
            self._cond.notify_all()

    def _watch(self, now: float) -> None:
        with self._cond:
            if self._lost is not None or self._last_heard_s is None:
                return
            if self.lockstep:
                if self._awaiting_since is None:
                    return
                since = max(self._last_heard_s, self._awaiting_since)
            else:
                since = self._last_heard_s
            silence = now - since
            if silence > self.timeout_s:
                what = "answer" if self.lockstep else "message"
                self._lost = GimbalLinkLost(
                    f"gimbal {self._target[0]}/{self._target[1]} on {self.address} is silent: no {what} from it "
                    f"for {silence:.2f} s (timeout {self.timeout_s:g} s); it was stopped or the link is down",
                    silence)
                self._cond.notify_all()

    def _report(self, msg, now: float) -> AttitudeReport:
        q = np.array(msg.q, dtype=float)
        norm = float(np.linalg.norm(q)) if np.all(np.isfinite(q)) else _NAN
        q = q / norm if norm > 0 else np.full(4, _NAN)
        frame = frame_of_flags(msg.flags) or "vehicle"
        delta_yaw = float(msg.delta_yaw)
        q_rad = np.full(3, _NAN)
        if np.all(np.isfinite(q)):
            if frame == "vehicle":
                q_rad = frames.quaternion_to_joints(self.kinematics, q)
            elif not math.isnan(delta_yaw):
                q_vehicle = frames.quaternion_multiply(_yaw_quaternion(-delta_yaw), q)
                q_rad = frames.quaternion_to_joints(self.kinematics, q_vehicle)
        return AttitudeReport(
            time_s=msg.time_boot_ms / 1000.0, received_s=now, quaternion=q, quaternion_norm=norm, frame=frame,
            angular_velocity_rad_s=np.array([msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z],
                                            dtype=float),
            flags=int(msg.flags), failure_flags=int(msg.failure_flags), delta_yaw_rad=delta_yaw,
            delta_yaw_rate_rad_s=float(msg.delta_yaw_velocity), seq=msg.get_seq(), q_rad=q_rad)

    def _check(self) -> None:
        if self._lost is not None:
            raise self._lost
        if self._closing.is_set():
            raise GimbalLinkError(f"the driver on {self.address} is closed")

    def _wait(self, predicate, timeout_s: float, awaiting: bool = False):
        """Wait under the condition until ``predicate()`` is truthy; its value, or None on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            if awaiting:
                self._awaiting_since = time.monotonic()
            try:
                while True:
                    self._check()
                    value = predicate()
                    if value:
                        return value
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return None
                    self._cond.wait(min(left, _POLL_S))
            finally:
                if awaiting:
                    self._awaiting_since = None

    # ------------------------------------------------------------------ discovery and information
    def discover(self, timeout_s: float | None = None) -> tuple[int, int]:
        """Wait for a gimbal's HEARTBEAT and take it as the target; returns (system, component).

        Raises
        ------
        GimbalNotFound
            When none is heard within ``timeout_s`` (default ``discover_timeout_s``).
        """
        timeout_s = self.discover_timeout_s if timeout_s is None else timeout_s
        found = self._wait(lambda: next(iter(sorted(self._heard)), None), timeout_s)
        if found is None:
            raise GimbalNotFound(f"no gimbal HEARTBEAT (MAV_TYPE_GIMBAL or component {GIMBAL_COMPONENT_IDS[0]}, "
                                 f"{GIMBAL_COMPONENT_IDS[1]}..{GIMBAL_COMPONENT_IDS[-1]}) on {self.address} "
                                 f"within {timeout_s:g} s{self.refusals_note()}")
        with self._cond:
            self._target = found
            self._last_heard_s = time.monotonic()
        return found

    def _require_target(self) -> tuple[int, int]:
        self._check()
        if self._target is None:
            raise GimbalNotFound(f"no gimbal selected on {self.address}: call discover() first")
        return self._target

    def request_information(self, timeout_s: float | None = None, attempts: int = 3) -> GimbalDeviceInfo:
        """Ask for GIMBAL_DEVICE_INFORMATION (MAV_CMD_REQUEST_MESSAGE) and keep it in :attr:`info`.

        Each attempt waits ``timeout_s`` (default ``timeout_s`` of the driver); the request is
        repeated with its confirmation counter raised.

        Raises
        ------
        GimbalNotFound
            When no answer arrives after ``attempts`` requests.
        """
        system, component = self._require_target()
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        with self._cond:
            self._info_msg = None
        for confirmation in range(attempts):
            self._send(self._mav.command_long_encode(
                system, component, mavlink.MAV_CMD_REQUEST_MESSAGE, confirmation,
                mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, 0, 0, 0, 0, 0, 0))
            msg = self._wait(lambda: self._info_msg, timeout_s, awaiting=True)
            if msg is not None:
                self.info = GimbalDeviceInfo(
                    system_id=system, component_id=component, vendor_name=msg.vendor_name,
                    model_name=msg.model_name, custom_name=msg.custom_name,
                    firmware_version=_version_text(msg.firmware_version),
                    hardware_version=_version_text(msg.hardware_version), uid=int(msg.uid),
                    cap_flags=int(msg.cap_flags2 or msg.cap_flags),
                    roll_limits_rad=(float(msg.roll_min), float(msg.roll_max)),
                    pitch_limits_rad=(float(msg.pitch_min), float(msg.pitch_max)),
                    yaw_limits_rad=(float(msg.yaw_min), float(msg.yaw_max)))
                return self.info
        raise GimbalNotFound(f"gimbal {system}/{component} on {self.address} sent no GIMBAL_DEVICE_INFORMATION "
                             f"after {attempts} requests of {timeout_s:g} s each{self.refusals_note()}")

    # ------------------------------------------------------------------ commands
    def send_quaternion(self, q_wxyz, frame: str = "vehicle", angular_velocity_rad_s=None) -> None:
        """GIMBAL_DEVICE_SET_ATTITUDE with an attitude.

        Parameters
        ----------
        q_wxyz : array_like, shape (4,)
            The gimbal's FRD axes in ``frame``, (w, x, y, z) (normalised before sending).
        frame : {"vehicle", "earth"}
            Yaw relative to the vehicle's heading or to North (flags: FRAME_FLAGS[frame]).
        angular_velocity_rad_s : array_like, shape (3,), optional
            Feed-forward rate relative to ``frame`` in its axes, rad/s; None sends NaN.
        """
        q = frames.quaternion_from_matrix(frames.matrix_from_quaternion(q_wxyz))
        omega = np.full(3, _NAN) if angular_velocity_rad_s is None else _vector3("angular_velocity_rad_s",
                                                                                 angular_velocity_rad_s)
        self._send_set_attitude(frame_flags(frame), q, omega)

    def send_attitude(self, yaw_rad: float, pitch_rad: float, roll_rad: float = 0.0, frame: str = "vehicle") -> None:
        """GIMBAL_DEVICE_SET_ATTITUDE to the Z-Y-X angles (yaw right, pitch up, roll right side down),
        rad, in ``frame``; angular velocity NaN."""
        angles = _vector3("(yaw_rad, pitch_rad, roll_rad)", (yaw_rad, pitch_rad, roll_rad))
        self._send_set_attitude(frame_flags(frame), frames.quaternion_from_euler(*angles), np.full(3, _NAN))

    def send_rates(self, omega_rad_s, frame: str = "vehicle") -> None:
        """GIMBAL_DEVICE_SET_ATTITUDE with angular rates only (quaternion NaN).

        ``omega_rad_s`` (x roll right, y pitch up, z yaw right), rad/s, is the gimbal's angular
        velocity relative to ``frame`` in that frame's axes (:mod:`gimbal_lab.mavlink.frames`).
        """
        self._send_set_attitude(frame_flags(frame), np.full(4, _NAN), _vector3("omega_rad_s", omega_rad_s))

    def send_joint_angles(self, q_rad) -> None:
        """Point the lab's gimbal at joint angles ``q_rad`` (yaw, roll, pitch), rad: the attitude
        they give on a level body (:func:`frames.joints_to_quaternion`), vehicle frame."""
        q = _vector3("q_rad", q_rad)
        self._send_set_attitude(frame_flags("vehicle"), frames.joints_to_quaternion(self.kinematics, q),
                                np.full(3, _NAN))

    def send_joint_rates(self, qdot_rad_s, q_rad=None) -> None:
        """Turn the lab's gimbal's joints at ``qdot_rad_s`` (yaw, roll, pitch), rad/s.

        Sent as the angular velocity those rates give at joints ``q_rad`` on a level body
        (:func:`frames.joint_rates_to_angular_velocity`), vehicle frame; ``q_rad`` None takes the
        joints of the latest report. The device turns its joints at these rates only while the
        joints stay near ``q_rad``: send again as they move (a pointing loop does, every frame).
        """
        q = self._joints(q_rad)
        omega = frames.joint_rates_to_angular_velocity(self.kinematics, q, _vector3("qdot_rad_s", qdot_rad_s))
        self._send_set_attitude(frame_flags("vehicle"), np.full(4, _NAN), omega)

    def send_camera_rates(self, omega_cam_rad_s, q_rad=None) -> None:
        """Turn the camera at ``omega_cam_rad_s`` in its own OpenCV axes (x right, y down, z forward),
        rad/s, at joints ``q_rad`` (None: the latest report's), level body, vehicle frame."""
        q = self._joints(q_rad)
        omega = frames.camera_rates_to_angular_velocity(self.kinematics, q, _vector3("omega_cam_rad_s", omega_cam_rad_s))
        self._send_set_attitude(frame_flags("vehicle"), np.full(4, _NAN), omega)

    def send_neutral(self) -> None:
        """GIMBAL_DEVICE_SET_ATTITUDE with GIMBAL_DEVICE_FLAGS_NEUTRAL: back to level, forward."""
        self._send_set_attitude(frame_flags("vehicle") | mavlink.GIMBAL_DEVICE_FLAGS_NEUTRAL, np.full(4, _NAN),
                                np.full(3, _NAN))

    def send_manager_pitch_yaw(self, pitch_rad: float = _NAN, yaw_rad: float = _NAN, pitch_rate_rad_s: float = _NAN,
                               yaw_rate_rad_s: float = _NAN, frame: str = "vehicle",
                               manager: tuple[int, int] | None = None) -> None:
        """GIMBAL_MANAGER_SET_PITCHYAW to a gimbal manager for this gimbal.

        Angles (pitch up, yaw right) in rad, rates in rad/s, NaN where not set; the manager
        passes them on to the device (a manager obeys only the sender in control:
        :meth:`take_manager_control`). ``manager``: (system, component) of the manager (default:
        the one :meth:`find_manager` found, else the device's system, MAV_COMP_ID_AUTOPILOT1).
        """
        system, component = self._require_target()
        manager = manager or self.manager or (system, mavlink.MAV_COMP_ID_AUTOPILOT1)
        values = [float(v) for v in (pitch_rad, yaw_rad, pitch_rate_rad_s, yaw_rate_rad_s)]
        if any(math.isinf(v) for v in values):
            raise ValueError(f"pitch_rad, yaw_rad and their rates must be finite or NaN, got {values}")
        self._send(self._mav.gimbal_manager_set_pitchyaw_encode(manager[0], manager[1], frame_flags(frame), component,
                                                                *values))

    def send_manager_joint_rates(self, qdot_rad_s, q_rad=None) -> None:
        """Turn the lab's gimbal's joints at ``qdot_rad_s`` (yaw, roll, pitch), rad/s, through the
        gimbal manager (:meth:`find_manager`): GIMBAL_MANAGER_SET_PITCHYAW with the pitch and yaw
        rates of the angular velocity those joint rates give at joints ``q_rad`` (None: the latest
        report's) on a level body, vehicle frame
        (:func:`frames.euler_rates_from_angular_velocity`); angles NaN. The manager holds roll
        level itself, so the roll part of the motion is not sent."""
        q = self._joints(q_rad)
        omega = frames.joint_rates_to_angular_velocity(self.kinematics, q, _vector3("qdot_rad_s", qdot_rad_s))
        yaw_rate, pitch_rate, _ = frames.euler_rates_from_angular_velocity(
            frames.joints_to_quaternion(self.kinematics, q), omega)
        self.send_manager_pitch_yaw(pitch_rate_rad_s=pitch_rate, yaw_rate_rad_s=yaw_rate,
                                    manager=self._require_manager())

    def _send_set_attitude(self, flags: int, q, omega) -> None:
        system, component = self._require_target()
        self._send(self._mav.gimbal_device_set_attitude_encode(system, component, flags, [float(v) for v in q],
                                                               float(omega[0]), float(omega[1]), float(omega[2])))

    def _joints(self, q_rad) -> np.ndarray:
        if q_rad is not None:
            return _vector3("q_rad", q_rad)
        report = self.latest()
        if report is None or not np.all(np.isfinite(report.q_rad)):
            raise ValueError("q_rad is needed: no attitude report with joint angles has arrived yet")
        return report.q_rad

    # ------------------------------------------------------------------ a gimbal manager
    def find_manager(self, timeout_s: float | None = None) -> tuple[int, int]:
        """Find a gimbal manager responsible for this device and keep it in :attr:`manager`.

        A manager is the first source of the device's system whose GIMBAL_MANAGER_STATUS (which
        managers send at a low steady rate) or GIMBAL_MANAGER_INFORMATION names the device's
        component as its ``gimbal_device_id``: the device's own component for a gimbal with its
        manager built in, an autopilot's otherwise. GIMBAL_MANAGER_INFORMATION is requested from
        every component of the system meanwhile.

        Raises
        ------
        GimbalNotFound
            When none is heard within ``timeout_s`` (default ``discover_timeout_s``).
        """
        system, component = self._require_target()
        timeout_s = self.discover_timeout_s if timeout_s is None else timeout_s
        self._send(self._mav.command_long_encode(system, 0, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                 mavlink.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION, 0, 0, 0, 0, 0, 0))
        found = self._wait(lambda: min(self._managers, key=self._managers.get) if self._managers else None, timeout_s)
        if found is None:
            raise GimbalNotFound(f"no gimbal manager for gimbal {system}/{component} on {self.address} (no "
                                 f"GIMBAL_MANAGER_STATUS or _INFORMATION with gimbal_device_id {component}) within "
                                 f"{timeout_s:g} s{self.refusals_note()}")
        with self._cond:
            self.manager = found
        return found

    def _require_manager(self) -> tuple[int, int]:
        self._check()
        if self.manager is None:
            raise GimbalNotFound(f"no gimbal manager selected on {self.address}: call find_manager() first")
        return self.manager

    def take_manager_control(self, timeout_s: float | None = None, attempts: int = 3) -> None:
        """Become the manager's primary control (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: param1, param2
        = this driver's system and component; secondary control unchanged; param7 = the device's
        component id), as the protocol asks before pitch/yaw commands.

        Raises
        ------
        GimbalCommandFailed
            When the manager refuses (its COMMAND_ACK's result is named) or does not answer.
        """
        self._manager_command(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, (
            self._mav.srcSystem, self._mav.srcComponent, -1, -1, 0, 0, self._require_target()[1]), timeout_s, attempts)

    def release_manager_control(self, timeout_s: float | None = None, attempts: int = 3) -> None:
        """Give up primary control (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, param1 = param2 = −3:
        "remove control if in control"; secondary unchanged)."""
        self._manager_command(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, (
            -3, -3, -1, -1, 0, 0, self._require_target()[1]), timeout_s, attempts)

    def _manager_command(self, command: int, params, timeout_s, attempts: int):
        """COMMAND_LONG ``command`` with seven ``params`` to the manager; its accepting COMMAND_ACK."""
        manager = self._require_manager()
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        name = mavlink.enums["MAV_CMD"][command].name
        with self._cond:
            self._command_acks.pop((manager, command), None)
        for confirmation in range(attempts):
            self._send(self._mav.command_long_encode(manager[0], manager[1], command, confirmation,
                                                     *(float(p) for p in params)))
            ack = self._wait(lambda: self._command_acks.get((manager, command)), timeout_s)
            if ack is None:
                continue
            if ack.result != mavlink.MAV_RESULT_ACCEPTED:
                result = mavlink.enums["MAV_RESULT"].get(ack.result)
                raise GimbalCommandFailed(f"gimbal manager {manager[0]}/{manager[1]} on {self.address} refused {name} "
                                          f"({result.name if result else ack.result})")
            return ack
        raise GimbalCommandFailed(f"gimbal manager {manager[0]}/{manager[1]} on {self.address} did not answer {name} "
                                  f"after {attempts} attempts of {timeout_s:g} s each")

    # ------------------------------------------------------------------ reports
    def latest(self) -> AttitudeReport | None:
        """The most recent GIMBAL_DEVICE_ATTITUDE_STATUS (None before the first).

        Raises
        ------
        GimbalLinkLost
            When the device has fallen silent.
        """
        with self._cond:
            self._check()
            return self._latest

    def reports(self) -> list[AttitudeReport]:
        """Every report received since the last call, oldest first (at most ``history``)."""
        with self._cond:
            self._check()
            out = list(self._reports)
            self._reports.clear()
            return out

    def wait_report(self, timeout_s: float | None = None, after_s: float | None = None) -> AttitudeReport:
        """Wait for a report whose ``time_s`` is later than ``after_s`` (default: the latest's).

        Raises
        ------
        GimbalLinkLost
            When the device falls silent first.
        TimeoutError
            When none arrives within ``timeout_s`` (default ``timeout_s`` of the driver) while the
            device still speaks (e.g. its status messages are all lost).
        """
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        with self._cond:
            self._check()
            if after_s is None:
                after_s = -math.inf if self._latest is None else self._latest.time_s
        report = self._wait(lambda: self._latest if self._latest is not None and self._latest.time_s > after_s
                            else None, timeout_s)
        if report is None:
            raise TimeoutError(f"no attitude report later than {after_s:g} s from {self.address} "
                               f"within {timeout_s:g} s")
        return report

    # ------------------------------------------------------------------ lock-step
    def step(self, duration_s: float) -> float:
        """Lock-step: advance the device's clock by ``duration_s`` (rounded to its inner step).

        Returns after the device has run the step; every status it sent within the step has been
        received by then (they precede the acknowledgement on the link).

        Returns
        -------
        float
            The device's clock after the step, s.

        Raises
        ------
        GimbalCommandFailed
            When the device refuses (it runs in real time, or the step passes the end of its run).
        GimbalLinkLost
            When the device does not answer within ``timeout_s`` (a long step keeps it alive with
            progress reports).
        """
        if not self.lockstep:
            raise GimbalCommandFailed("step() needs a driver made with lockstep=True (and a device in lock-step)")
        if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or not (
                duration_s >= 0 and math.isfinite(duration_s)):
            raise ValueError(f"duration_s must be a finite number >= 0 s, got {duration_s!r}")
        system, component = self._require_target()
        with self._cond:
            self._acks.pop(STEP_COMMAND, None)
        self._send(self._mav.command_long_encode(system, component, STEP_COMMAND, 0, float(duration_s), 0, 0, 0, 0,
                                                 0, 0))

        def final_ack():
            ack = self._acks.get(STEP_COMMAND)
            return ack if ack is not None and ack.result != mavlink.MAV_RESULT_IN_PROGRESS else None

        ack = self._wait(final_ack, math.inf, awaiting=True)
        if ack.result != mavlink.MAV_RESULT_ACCEPTED:
            name = mavlink.enums["MAV_RESULT"][ack.result].name if ack.result in mavlink.enums["MAV_RESULT"] else ack.result
            raise GimbalCommandFailed(f"gimbal {system}/{component} refused a step of {duration_s:g} s ({name}; its "
                                      f"clock is at {ack.result_param2 / 1000:g} s)")
        return ack.result_param2 / 1000.0


def _yaw_quaternion(yaw_rad: float) -> np.ndarray:
    """(w, x, y, z) of a rotation by ``yaw_rad`` about z (the delta yaw between the two frames)."""
    return frames.quaternion_from_euler(yaw_rad, 0.0, 0.0)


def _vector3(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be three finite numbers, got {value!r}")
    return arr
