"""The lab's gimbal as a MAVLink gimbal device (Gimbal Protocol v2), for drivers to talk to.

:class:`SimulatedGimbalDevice` runs :class:`gimbal_lab.mount.GimbalMount` (the three axes'
dynamics and rate loops, on a :class:`gimbal_lab.platform.BodyMotion`, a still body by default)
built by :func:`simulated_gimbal`, and speaks MAVLink 2 on a link:

* HEARTBEAT once a second of wall time (``MAV_TYPE_GIMBAL``, its component id);
* GIMBAL_DEVICE_INFORMATION on MAV_CMD_REQUEST_MESSAGE: the joint limits as the protocol's angle
  limits (yaw sign turned: the lab's yaw is positive to the left) and its capabilities (roll and
  pitch locked to the horizon, yaw following the vehicle or locked to North, neutral);
* GIMBAL_DEVICE_SET_ATTITUDE (module docstring of :mod:`gimbal_lab.mavlink.frames` for frames):

  - **rates** (quaternion NaN): the commanded angular velocity relative to the vehicle or earth
    frame becomes the axes' rate references, w = A(q)⁻¹·ω (:func:`frames.angular_velocity_to_joint_rates`,
    A from the DH Jacobian), recomputed every ``control_period_s`` as the joints move; a NaN
    component counts as 0;
  - **attitude**: a proportional law in the joints, w = k·(q* − q) (k = ``attitude_gain_per_s``,
    20 /s by default: the stabilised mount's gain) plus any feed-forward rate as for rates. q* are
    the joint angles of the commanded attitude on the body now (:func:`frames.quaternion_to_joints`),
    each taken at the whole turn that lies inside the joint's [min, max] nearest the joint
    (:func:`reachable_joint_angle`): a joint never heads for a target across its stops, so yaw
    +170° → −170° with ±170° stops turns back through 0. A target outside a joint's range goes
    to the limit nearest it, and GIMBAL_DEVICE_ERROR_FLAGS_AT_*_LIMIT is reported while it is
    commanded. Near the target this is the attitude law ω = k·log(R_ref·R_cur⁻¹) to first order;
  - the references are scaled down together so that none exceeds ``max_rate_rad_s``, and each
    joint's is bounded by k·(limit − q) towards its limits (the joints approach a limit
    exponentially and stop there; GIMBAL_DEVICE_ERROR_FLAGS_AT_*_LIMIT is reported while the bound
    acts);
  - NEUTRAL or RETRACT: the attitude (1, 0, 0, 0) in the vehicle frame; everything NaN: only the
    flags change. Roll and pitch are always held relative to the horizon (no roll/pitch follow);
* GIMBAL_DEVICE_ATTITUDE_STATUS every 1/``status_rate_hz`` s of simulated time (the first one
  period after the start), in the vehicle frame with ``delta_yaw`` = the body's heading;
* AUTOPILOT_STATE_FOR_GIMBAL_DEVICE: the vehicle's attitude and heading rate, which from then on
  are the body the device knows (below);
* a gimbal manager on the same component (:mod:`gimbal_lab.mavlink.manager`; ``manager=False``
  leaves it out).

The vehicle's attitude
----------------------
Until an AUTOPILOT_STATE_FOR_GIMBAL_DEVICE arrives the body is the simulated one. From the first,
the vehicle frame, the earth-frame conversions (yaw lock) and the reports' ``delta_yaw`` use the
autopilot's attitude ``q`` (NED earth to FRD body). **An attitude and an angular velocity sent
together** are read as one sample: ``q`` is the vehicle's attitude ``q_estimated_delay_us``
before the message arrived, and the heading then moves on from it at ``angular_velocity_z`` (the
earth-frame z rate, rad/s, positive right; when NaN, ``feed_forward_angular_velocity_z``; when both
are NaN, 0) for at most :data:`AUTOPILOT_HORIZON_S` after the sample, then holds; roll and pitch
hold at the sample's. The rate is also the vehicle frame's turn rate in the reports and the
commands. A message with ``q`` NaN (unknown), a ``q`` that is no rotation or an infinite rate is
refused and counted. The simulated mount itself stays on its own body: its axes do not feel the
autopilot's motion (the device moves the joints as a real one would, to hold the earth heading in
yaw lock or to turn with the vehicle in follow).

Time
----
Everything inside runs on the inner step ``dt_s`` (1 ms): events (a command taking effect, a
control update, a status sample, a delayed packet leaving) happen at whole steps, and the mount is
advanced between them. **Real time** (default): the simulated clock follows the wall clock.
**Lock-step**: the clock moves only on the driver's step command (:mod:`gimbal_lab.mavlink.protocol`),
by exactly the steps asked, so a run is a function of the commands and their step times alone. A
command received between steps takes effect at the clock's present step (plus the latency).

Link effects (:class:`LinkEffects`, all seeded)
----------------------------------------------
The status stream's rate; a one-way ``latency_s`` (rounded to whole steps) that delays every status
from its sample and every GIMBAL_DEVICE_SET_ATTITUDE from its arrival; ``quantum_rad``, to which
the reported Z-Y-X angles are rounded (a gimbal reporting in 0.1° units); ``loss``, the chance that
a status is lost (the n-th status is lost when the n-th draw of
``numpy.random.default_rng(seed).random()`` is below it; its sequence number is spent, so the
receiver sees the gap); and ``commanded_only``, which reports the commanded attitude (for rate
commands: their integral from the last commanded attitude, starting at neutral) and the commanded
rate instead of the measured ones, as a gimbal without angle feedback does. Heartbeats,
information and acknowledgements are neither delayed nor lost.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict, deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..kinematics import GimbalKinematics
from ..mount import ATTITUDE_GAIN_PER_S, GimbalMount
from ..platform import BodyMotion
from . import frames
from .link import LinkClosed, UdpLink, open_link
from .manager import GimbalManager, angular_velocity_of_pitch_yaw_rates
from .protocol import MAX_COMMAND_RATE_RAD_S, PROGRESS_PERIOD_S, STEP_COMMAND, frame_of_flags, mavlink, new_mavlink
from .signing import enable_signing, refused_count

__all__ = ["LinkEffects", "SimulatedGimbalDevice", "simulated_gimbal", "DEFAULT_MAX_RATE_RAD_S",
           "firmware_version_word", "MAX_CLIENTS", "MAX_PENDING_COMMANDS", "MAX_COMMAND_RATE_RAD_S",
           "MAX_STATUS_RATE_HZ", "MAX_LATENCY_S", "AUTOPILOT_HORIZON_S", "reachable_joint_angle"]

#: The device's joint-rate limit, rad/s (the lab's image loop limits its rates to the same).
DEFAULT_MAX_RATE_RAD_S = 3.0
#: UDP peers answered at once: each that sent an accepted packet; beyond this the one heard from
#: longest ago gives way.
MAX_CLIENTS = 8
#: Attitude commands waiting out the link's latency at most; more are refused (and counted).
MAX_PENDING_COMMANDS = 4096
#: The status stream's fastest rate, Hz: one status per inner step of 1 ms.
MAX_STATUS_RATE_HZ = 1000.0
#: The longest one-way latency, s (a geostationary satellite hop is about 0.25 s).
MAX_LATENCY_S = 10.0
#: How long the heading from AUTOPILOT_STATE_FOR_GIMBAL_DEVICE is carried forward with its rate, s
#: (autopilots send it at 10 Hz or more); later the heading holds.
AUTOPILOT_HORIZON_S = 0.5
_HEARTBEAT_PERIOD_S = 1.0
_REALTIME_POLL_S = 0.002
_LOCKSTEP_POLL_S = 0.05
_Z = np.array([0.0, 0.0, 1.0])
_LIMIT_FLAGS = (mavlink.GIMBAL_DEVICE_ERROR_FLAGS_AT_YAW_LIMIT, mavlink.GIMBAL_DEVICE_ERROR_FLAGS_AT_ROLL_LIMIT,
                mavlink.GIMBAL_DEVICE_ERROR_FLAGS_AT_PITCH_LIMIT)


def _real(name: str, value, low: float, *, low_open: bool = False, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v) or (v <= low if low_open else v < low) or (high is not None and v > high):
        bound = f"{'>' if low_open else '>='} {low:g}" + (f" and <= {high:g}" if high is not None else "")
        raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
    return v


@dataclass(frozen=True)
class LinkEffects:
    """What the device's link does to the attitude stream (module docstring).

    Parameters
    ----------
    status_rate_hz : float
        GIMBAL_DEVICE_ATTITUDE_STATUS per second of simulated time, in (0, :data:`MAX_STATUS_RATE_HZ`].
    latency_s : float
        One-way delay of statuses and attitude commands, s, in [0, :data:`MAX_LATENCY_S`] (rounded
        to the inner step).
    quantum_rad : float
        Resolution of the reported Z-Y-X angles, rad, >= 0 (0: none).
    loss : float
        Probability that a status is lost, in [0, 1).
    seed : int
        Seed of the losses.
    commanded_only : bool
        Report the commanded attitude and rate instead of the measured ones.
    """

    status_rate_hz: float = 20.0
    latency_s: float = 0.0
    quantum_rad: float = 0.0
    loss: float = 0.0
    seed: int = 0
    commanded_only: bool = False

    def __post_init__(self):
        object.__setattr__(self, "status_rate_hz", _real("status_rate_hz", self.status_rate_hz, 0.0, low_open=True,
                                                         high=MAX_STATUS_RATE_HZ))
        object.__setattr__(self, "latency_s", _real("latency_s", self.latency_s, 0.0, high=MAX_LATENCY_S))
        object.__setattr__(self, "quantum_rad", _real("quantum_rad", self.quantum_rad, 0.0))
        loss = _real("loss", self.loss, 0.0)
        if loss >= 1.0:
            raise ValueError(f"loss must be in [0, 1), got {self.loss!r}")
        object.__setattr__(self, "loss", loss)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not isinstance(self.commanded_only, bool):
            raise TypeError(f"commanded_only must be True or False, got {self.commanded_only!r}")


def simulated_gimbal(kinematics: GimbalKinematics | None = None, body: BodyMotion | None = None,
                     duration_s: float = 3600.0, dt_s: float = 1e-3) -> GimbalMount:
    """The gimbal the device runs: the lab's axes and rate loops on a body (the one place it is built).

    Parameters
    ----------
    kinematics : GimbalKinematics, optional
        Default: :meth:`GimbalKinematics.default` (the study's STorM32-sized gimbal).
    body : BodyMotion, optional
        Default: :meth:`BodyMotion.static` (a still, level body facing North).
    duration_s : float
        Simulated time the device can run, s, > 0 (GimbalMount draws the body's motion and keeps
        the joint path for the whole run when it is built: a moving body costs about 2 s of
        building per simulated second).
    dt_s : float
        Inner step, s (the rate loops' 1 kHz by default).

    Returns
    -------
    GimbalMount
        In "active" mode: its rate references come from the device.
    """
    kinematics = kinematics or GimbalKinematics.default()
    body = body or BodyMotion.static()
    duration_s = _real("duration_s", duration_s, 0.0, low_open=True)
    dt_s = _real("dt_s", dt_s, 0.0, low_open=True)
    return GimbalMount(kinematics, body, "active", dt_s, int(math.ceil(duration_s / dt_s - 1e-9)))


def firmware_version_word(version: str) -> int:
    """MAVLink's version word of "major.minor.patch": Patch << 16 | Minor << 8 | Major."""
    parts = [int(p) if p.isdigit() else 0 for p in (version.split(".") + ["0", "0"])[:3]]
    major, minor, patch = (p & 0xFF for p in parts)
    return (patch << 16) | (minor << 8) | major


def reachable_joint_angle(target_rad: float, q_rad: float, lo_rad: float, hi_rad: float) -> tuple[float, bool]:
    """The joint angle the attitude law steers to for a target angle ``target_rad`` (any turn).

    A joint angle and the same plus any whole turn give the same attitude: of the turns of
    ``target_rad`` inside [lo_rad, hi_rad] the one nearest the joint's angle ``q_rad`` is taken, so
    the joint turns the way that stays inside its range (yaw +170° to −170° with ±170° stops goes
    back through 0, not across ±180°). A target no turn of which is inside (within 1e-6 rad: a
    float32 quaternion holds an angle to 2.4e-7 rad, so a target sent exactly at a limit counts as
    at it) goes to the limit nearest it in angle, and the second value is False.

    Returns
    -------
    (float, bool)
        The angle, rad, inside [lo_rad, hi_rad]; whether the target is reachable.
    """
    eps = 1e-6
    turn = 2.0 * math.pi
    n_min = math.ceil((lo_rad - eps - target_rad) / turn) if math.isfinite(lo_rad) else -math.inf
    n_max = math.floor((hi_rad + eps - target_rad) / turn) if math.isfinite(hi_rad) else math.inf
    if n_min <= n_max:
        n = min(max(round((q_rad - target_rad) / turn), n_min), n_max)
        return min(max(target_rad + turn * n, lo_rad), hi_rad), True

    def gap(a, b):
        return abs((a - b + math.pi) % turn - math.pi)

    to_lo, to_hi = gap(target_rad, lo_rad), gap(target_rad, hi_rad)
    if to_lo == to_hi:  # right opposite the middle of the range: the limit nearer the joint
        return (lo_rad if abs(q_rad - lo_rad) < abs(q_rad - hi_rad) else hi_rad), False
    return (lo_rad if to_lo < to_hi else hi_rad), False


def _whole_number(value, high: int = 2**24) -> int | None:
    """``value`` (a float command parameter) as an integer in 0..high, or None when it is not one."""
    v = float(value)
    if not math.isfinite(v) or v != int(v) or not 0 <= v <= high:
        return None
    return int(v)


class _Outbox:
    """pymavlink's file: keeps the bytes of the packet just packed (the device routes them)."""

    def __init__(self):
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data = data


class SimulatedGimbalDevice:
    """The lab's gimbal as a MAVLink gimbal device (module docstring).

    Parameters
    ----------
    link : str or gimbal_lab.mavlink.link.Link
        Where to listen: ``udpin:HOST:PORT``, ``udpout:HOST:PORT``, a serial device or pyserial URL,
        or an open link.
    mount : GimbalMount, optional
        The simulated gimbal (default: :func:`simulated_gimbal`); mode "active", not yet stepped.
    effects : LinkEffects, optional
    lockstep : bool
        Advance only on the driver's step command (else: real time).
    system_id, component_id : int
        The device's MAVLink identity (default 1, MAV_COMP_ID_GIMBAL).
    max_rate_rad_s : float
        Largest rate reference of any axis, rad/s, > 0.
    attitude_gain_per_s : float
        Gain k of the attitude law and of the approach to the joint limits, 1/s, > 0.
    control_period_s : float
        How often the rate references are recomputed, s (rounded to whole inner steps, >= 1).
    baud : int
        Serial speed, bit/s.
    signing_key : bytes, optional
        A 32-byte MAVLink 2 signing key (:mod:`gimbal_lab.mavlink.signing`): sign what the device
        sends and refuse every packet not signed with it.
    manager : bool
        Run a gimbal manager on the device's component (:mod:`gimbal_lab.mavlink.manager`).

    Attributes
    ----------
    statuses_sent, statuses_lost : int
        Status messages sampled and put on the link / lost by the loss model.
    commands_applied, commands_rejected : int
        GIMBAL_DEVICE_SET_ATTITUDE messages that took effect / were refused at the wire (both yaw
        frames set, an infinite quaternion or one that is not a rotation, an infinite rate or one
        beyond :data:`MAX_COMMAND_RATE_RAD_S`, more than :data:`MAX_PENDING_COMMANDS` waiting).
    packets_dropped : int
        Received bytes that were no packet: bad framing or checksum, a packet torn at the end of a
        datagram, or (with a key) a packet refused for its signature.
    autopilot_states_taken, autopilot_states_rejected : int
        AUTOPILOT_STATE_FOR_GIMBAL_DEVICE messages taken / refused at the wire (attitude unknown or
        not a rotation, an infinite rate or one beyond :data:`MAX_COMMAND_RATE_RAD_S`).
    handler_errors : int
        Packets whose handling failed unexpectedly (each dropped; the device carries on). Zero
        unless the device has a bug: the fuzz tests check it stays so.

    Notes
    -----
    On ``udpin:`` the device answers its clients, the (at most :data:`MAX_CLIENTS`) peers that
    sent it an accepted packet, not whoever sent the last datagram: junk, or a packet refused for
    its signature, neither makes a client nor diverts the replies. Each datagram is parsed on its
    own (a torn packet at its end is dropped, not joined to the next datagram's bytes).
    """

    def __init__(self, link, mount: GimbalMount | None = None, effects: LinkEffects | None = None, *,
                 lockstep: bool = False, system_id: int = 1, component_id: int = mavlink.MAV_COMP_ID_GIMBAL,
                 max_rate_rad_s: float = DEFAULT_MAX_RATE_RAD_S, attitude_gain_per_s: float = ATTITUDE_GAIN_PER_S,
                 control_period_s: float = 0.002, baud: int = 115200, signing_key: bytes | None = None,
                 manager: bool = True):
        mount = mount if mount is not None else simulated_gimbal()
        if not isinstance(mount, GimbalMount):
            raise TypeError(f"mount must be a GimbalMount, got {type(mount).__name__}")
        if mount.mount != "active" or mount.step_index != 0:
            raise ValueError(f"mount must be an 'active' GimbalMount that has not run yet (simulated_gimbal()), got "
                             f"mode {mount.mount!r} at step {mount.step_index}")
        effects = effects if effects is not None else LinkEffects()
        if not isinstance(effects, LinkEffects):
            raise TypeError(f"effects must be a LinkEffects, got {type(effects).__name__}")
        self.mount = mount
        self.kinematics = mount.kinematics
        self.body = mount.body
        self.effects = effects
        self.lockstep = bool(lockstep)
        self.max_rate_rad_s = _real("max_rate_rad_s", max_rate_rad_s, 0.0, low_open=True)
        self.attitude_gain_per_s = _real("attitude_gain_per_s", attitude_gain_per_s, 0.0, low_open=True)
        self.dt_s = mount.dt_s
        self._control_steps = max(1, int(round(_real("control_period_s", control_period_s, 0.0, low_open=True)
                                               / self.dt_s)))
        self._latency_steps = int(round(effects.latency_s / self.dt_s))
        self._steps_per_status = 1.0 / (effects.status_rate_hz * self.dt_s)
        self._lo = np.array([lo for lo, _ in self.kinematics.joint_limits_rad])
        self._hi = np.array([hi for _, hi in self.kinematics.joint_limits_rad])
        self.link = open_link(link, baud)
        self._outbox = _Outbox()
        self._mav = new_mavlink(self._outbox, system_id, component_id)
        if signing_key is not None:
            enable_signing(self._mav, signing_key)
        self.system_id, self.component_id = system_id, component_id
        self._udp_in = isinstance(self.link, UdpLink) and self.link.kind == "udpin"
        self._clients: OrderedDict = OrderedDict()  # UDP peers that sent accepted packets, last heard last
        self._rng = np.random.default_rng(effects.seed)
        # the clock and its events, in inner steps
        self._k = 0
        self._next_control = 0
        self._status_n = 1
        self._next_status = self._status_due(1)
        self._incoming: deque = deque()  # (step it takes effect, GIMBAL_DEVICE_SET_ATTITUDE)
        self._outgoing: deque = deque()  # (step it leaves, packet bytes)
        # the setpoint: neutral in the vehicle frame
        self._mode = "attitude"
        self._frame = "vehicle"
        self._R_ref = np.eye(3)
        self._omega_cmd = np.zeros(3)
        self._cmd_flags = 0
        self._R_cmd = np.eye(3)  # commanded attitude in self._frame (commanded-only reports)
        self._k_cmd = 0  # step up to which _R_cmd has been integrated
        self._w_ref = np.zeros(3)
        self._failure_flags = 0
        self._still = not mount.moving
        self._body_cache = None
        self.statuses_sent = self.statuses_lost = 0
        self.commands_applied = self.commands_rejected = 0
        self.packets_dropped = self.handler_errors = 0
        self._euler_rates = None  # (pitch rate, yaw rate) of a manager's rate setpoint, rad/s
        self._autopilot = None  # (R_vehicle_body, ψ, ψ̇, step of the sample) from AUTOPILOT_STATE_FOR_GIMBAL_DEVICE
        self.autopilot_states_taken = self.autopilot_states_rejected = 0
        self.manager = GimbalManager(self) if manager else None
        self._next_heartbeat_wall = 0.0
        self._stepping = None  # lock-step: (first step, last step, next progress wall time) while a step runs
        self._events()

    # ------------------------------------------------------------------ clock
    @property
    def t_s(self) -> float:
        """The simulated clock, s."""
        return self._k * self.dt_s

    @property
    def end_step(self) -> int:
        """The last inner step the mount was built for."""
        return self.mount.n_steps

    @property
    def packets_refused(self) -> int:
        """Packets refused for their signature (unsigned or wrongly signed; 0 without a key)."""
        return refused_count(self._mav)

    @property
    def clients(self) -> list:
        """The UDP peers (host, port) the device answers, heard from longest ago first (udpin only)."""
        return list(self._clients)

    @property
    def q_rad(self) -> np.ndarray:
        """The joints now (yaw, roll, pitch), rad (the simulation's truth, not the report)."""
        return self.mount.q

    @property
    def setpoint_flags(self) -> int:
        """GIMBAL_MANAGER_FLAGS of the setpoint in force: roll and pitch locked, and its yaw frame."""
        flags = mavlink.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | mavlink.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
        if self._frame == "earth":
            return flags | mavlink.GIMBAL_MANAGER_FLAGS_YAW_LOCK | mavlink.GIMBAL_MANAGER_FLAGS_YAW_IN_EARTH_FRAME
        return flags | mavlink.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME

    def attitude_in(self, frame: str) -> np.ndarray:
        """The gimbal's attitude now (the simulation's truth) in the "vehicle" or "earth" frame, 3x3."""
        R_vb, psi, _ = self._vehicle_state()
        R_vehicle = frames.gimbal_attitude_matrix(self.kinematics, self.mount.q, R_vb)
        return frames.rot_z(psi) @ R_vehicle if frame == "earth" else R_vehicle

    def yaw_in(self, frame: str) -> float:
        """The Z-Y-X yaw of :meth:`attitude_in`, rad (positive right)."""
        R = self.attitude_in(frame)
        return math.atan2(R[1, 0], R[0, 0])

    def pitch_in(self, frame: str) -> float:
        """The Z-Y-X pitch of :meth:`attitude_in`, rad (positive up; the same in both frames)."""
        R = self.attitude_in(frame)
        return math.asin(max(-1.0, min(1.0, -R[2, 0])))

    def _status_due(self, n: int) -> int:
        return int(math.ceil(n * self._steps_per_status - 1e-9))

    def advance_to(self, k_target: int) -> None:
        """Run the simulation to inner step ``k_target``, handling every event on the way."""
        k_target = min(int(k_target), self.end_step)
        mount = self.mount
        while self._k < k_target:
            k_next = min(k_target, self._next_control, self._next_status)
            if self._incoming:
                k_next = min(k_next, self._incoming[0][0])
            if self._outgoing:
                k_next = min(k_next, self._outgoing[0][0])
            if k_next > self._k:
                mount.advance(k_next - self._k, self._w_ref)
                self._k = k_next
            self._events()
            if self._stepping is not None:
                self._step_progress()

    def _events(self) -> None:
        """Everything due at the present step, in order: commands, control, status sample, sending."""
        k = self._k
        recompute = False
        while self._incoming and self._incoming[0][0] <= k:
            self._apply(self._incoming.popleft()[1])
            recompute = True
        if k >= self._next_control or recompute:
            self._integrate_command()
            self._w_ref = self._reference()
            while self._next_control <= k:
                self._next_control += self._control_steps
        if k >= self._next_status:
            self._sample_status()
            self._status_n += 1
            self._next_status = self._status_due(self._status_n)
        while self._outgoing and self._outgoing[0][0] <= k:
            self._write(self._outgoing.popleft()[1])

    # ------------------------------------------------------------------ the body
    def _body_state(self):
        """(R_vehicle_body, heading ψ, heading rate ψ̇) now: the body's FRD axes in the vehicle frame."""
        if self._still and self._body_cache is not None:
            return self._body_cache
        t = self.t_s
        R_wb = self.body.T_world_body(t)[:3, :3]
        angles, rates = self.body.attitude(t)
        psi, psi_rate = -float(angles[0, 0]), -float(rates[0, 0])  # lab yaw is about up, NED heading about down
        F = frames.F_NED_NWU
        state = (frames.rot_z(psi).T @ F @ R_wb @ F, psi, psi_rate)
        if self._still:
            self._body_cache = state
        return state

    def _vehicle_state(self):
        """(R_vehicle_body, heading ψ, heading rate ψ̇) as the device knows them: from the last
        AUTOPILOT_STATE_FOR_GIMBAL_DEVICE when one has been taken (module docstring), else its own
        simulated body's (:meth:`_body_state`)."""
        state = self._autopilot
        if state is None:
            return self._body_state()
        R_vb, psi, psi_rate, k_sample = state
        age_s = max(self._k - k_sample, 0) * self.dt_s
        if age_s >= AUTOPILOT_HORIZON_S:
            return R_vb, psi + psi_rate * AUTOPILOT_HORIZON_S, 0.0
        return R_vb, psi + psi_rate * age_s, psi_rate

    def _take_autopilot_state(self, msg) -> None:
        """AUTOPILOT_STATE_FOR_GIMBAL_DEVICE, checked at the wire (module docstring)."""
        q = np.array(msg.q, dtype=float)
        if np.all(np.isnan(q)):  # the attitude is unknown: nothing to take
            self.autopilot_states_rejected += 1
            return
        rates = [float(msg.angular_velocity_z), float(msg.feed_forward_angular_velocity_z)]
        if (not np.all(np.isfinite(q)) or not 0.5 < float(np.linalg.norm(q)) < 2.0
                or any(math.isinf(r) or abs(r) > MAX_COMMAND_RATE_RAD_S for r in rates)):
            self.autopilot_states_rejected += 1
            return
        R_nb = frames.matrix_from_quaternion(q / np.linalg.norm(q))
        psi = math.atan2(R_nb[1, 0], R_nb[0, 0])
        psi_rate = next((r for r in rates if math.isfinite(r)), 0.0)
        delay_steps = int(round(min(msg.q_estimated_delay_us * 1e-6, AUTOPILOT_HORIZON_S) / self.dt_s))
        self._autopilot = (frames.rot_z(psi).T @ R_nb, psi, psi_rate, self._k - delay_steps)
        self.autopilot_states_taken += 1

    # ------------------------------------------------------------------ commands
    def _apply(self, msg) -> None:
        frame = frame_of_flags(msg.flags)
        if frame is None:
            self.commands_rejected += 1
            return
        q = np.array(msg.q, dtype=float)
        omega = np.array([msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z], dtype=float)
        self._integrate_command()
        if msg.flags & (mavlink.GIMBAL_DEVICE_FLAGS_NEUTRAL | mavlink.GIMBAL_DEVICE_FLAGS_RETRACT):
            mode, frame, R_ref, omega_cmd = "attitude", "vehicle", np.eye(3), np.zeros(3)
        elif np.all(np.isfinite(q)):
            norm = float(np.linalg.norm(q))
            if not 0.5 < norm < 2.0:
                self.commands_rejected += 1
                return
            mode, R_ref, omega_cmd = "attitude", frames.matrix_from_quaternion(q), np.nan_to_num(omega, nan=0.0)
        elif np.any(np.isfinite(omega)):
            mode, R_ref, omega_cmd = "rate", None, np.nan_to_num(omega, nan=0.0)
        else:  # nothing to follow: only the flags change
            self._cmd_flags = int(msg.flags)
            self.commands_applied += 1
            return
        # the commanded attitude carried into the new frame (commanded-only reports)
        if frame != self._frame:
            _, psi, _ = self._vehicle_state()
            turn = frames.rot_z(psi) if frame == "earth" else frames.rot_z(psi).T
            self._R_cmd = turn @ self._R_cmd
        self._mode, self._frame, self._omega_cmd, self._cmd_flags = mode, frame, omega_cmd, int(msg.flags)
        self._euler_rates = getattr(msg, "euler_rates", None) if mode == "rate" else None
        if mode == "attitude":
            self._R_ref = R_ref
            self._R_cmd = R_ref.copy()
        self.commands_applied += 1

    def _integrate_command(self) -> None:
        """Carry the commanded attitude to the present step under a rate command (R ← exp(ω Δt)·R)."""
        k = self._k
        if self._mode == "rate" and k > self._k_cmd:
            rotation = Rotation.from_rotvec(self._omega_cmd * ((k - self._k_cmd) * self.dt_s)).as_matrix()
            self._R_cmd = rotation @ self._R_cmd
        self._k_cmd = k

    def _reference(self) -> np.ndarray:
        """The axes' rate references w (inertial, joint basis), rad/s, for the setpoint now."""
        q = self.mount.q
        R_vb, psi, psi_rate = self._vehicle_state()
        Rz = frames.rot_z(psi)
        flags = 0
        w = np.zeros(3)
        if self._mode == "attitude":
            R_ref = self._R_ref if self._frame == "vehicle" else Rz.T @ self._R_ref
            q_target = frames.quaternion_to_joints(self.kinematics, frames.quaternion_from_matrix(R_ref), R_vb)
            for i in range(3):
                q_target[i], reachable = reachable_joint_angle(q_target[i], q[i], self._lo[i], self._hi[i])
                if not reachable:
                    flags |= _LIMIT_FLAGS[i]
            w = self.attitude_gain_per_s * (q_target - q)
        if self._euler_rates is not None:  # a manager's pitch and yaw rates, about the present yaw
            self._omega_cmd = angular_velocity_of_pitch_yaw_rates(self.yaw_in(self._frame), *self._euler_rates)
        # the commanded (feed-forward) rate, relative to its frame → inertial, in vehicle axes
        omega = self._omega_cmd + psi_rate * _Z if self._frame == "vehicle" else Rz.T @ self._omega_cmd
        if self._autopilot is not None:  # the simulated base turns at its own rate, not at the autopilot's
            omega = omega - (psi_rate - self._body_state()[2]) * _Z
        try:
            w = w + frames.angular_velocity_to_joint_rates(self.kinematics, q, omega, R_vb)
        except ValueError:  # at the roll ±90° singularity: hold
            w = np.zeros(3)
        peak = float(np.max(np.abs(w)))
        if peak > self.max_rate_rad_s:
            w *= self.max_rate_rad_s / peak
        k_lim = self.attitude_gain_per_s
        upper = k_lim * (self._hi - q)
        lower = k_lim * (self._lo - q)
        for i in range(3):
            if w[i] > upper[i]:
                w[i] = upper[i]
                flags |= _LIMIT_FLAGS[i]
            elif w[i] < lower[i]:
                w[i] = lower[i]
                flags |= _LIMIT_FLAGS[i]
        self._failure_flags = flags
        return w

    # ------------------------------------------------------------------ messages out
    def _pack(self, msg) -> bytes:
        self._mav.send(msg)
        return self._outbox.data

    def _send_now(self, msg) -> None:
        self._write(self._pack(msg))

    def _write(self, packet: bytes) -> None:
        """Put ``packet`` on the link: on ``udpin:`` to every client (class Notes)."""
        if not self._udp_in:
            self.link.write(packet)
            return
        link = self.link
        for client in self._clients:
            link.peer = client
            link.write(packet)

    def _time_ms(self) -> int:
        return int(round(self._k * self.dt_s * 1000.0)) & 0xFFFFFFFF

    def _sample_status(self) -> None:
        q = self.mount.q
        R_vb, psi, psi_rate = self._vehicle_state()
        base_rate = psi_rate if self._autopilot is None else self._body_state()[2]
        if self.effects.commanded_only:
            self._integrate_command()  # the commanded attitude now, not at the last control step
            R_vehicle = self._R_cmd if self._frame == "vehicle" else frames.rot_z(psi).T @ self._R_cmd
            if self._mode == "rate":
                omega = self._omega_cmd if self._frame == "vehicle" else frames.rot_z(psi).T @ self._omega_cmd - psi_rate * _Z
            else:
                omega = np.full(3, np.nan)
        else:
            R_vehicle = frames.gimbal_attitude_matrix(self.kinematics, q, R_vb)
            omega = frames.joint_rates_to_angular_velocity(self.kinematics, q, self.mount.axis_rates, R_vb) - base_rate * _Z
        quat = frames.quaternion_from_matrix(R_vehicle)
        quantum = self.effects.quantum_rad
        if quantum > 0:
            quat = frames.quaternion_from_euler(*(round(a / quantum) * quantum for a in frames.euler_from_quaternion(quat)))
        flags = (mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                 | mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME | mavlink.GIMBAL_DEVICE_FLAGS_ACCEPTS_YAW_IN_EARTH_FRAME)
        if self._frame == "earth":
            flags |= mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK
        msg = self._mav.gimbal_device_attitude_status_encode(
            0, 0, self._time_ms(), flags, [float(v) for v in quat], float(omega[0]), float(omega[1]), float(omega[2]),
            self._failure_flags, float(psi), float(psi_rate), 0)
        packet = self._pack(msg)  # the sequence number is spent even when the packet is then lost
        if self.effects.loss > 0 and self._rng.random() < self.effects.loss:
            self.statuses_lost += 1
            return
        self.statuses_sent += 1
        self._outgoing.append((self._k + self._latency_steps, packet))

    def _heartbeat(self) -> None:
        self._send_now(self._mav.heartbeat_encode(mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                  mavlink.MAV_STATE_ACTIVE))

    def _maybe_heartbeat(self, now: float) -> None:
        if now >= self._next_heartbeat_wall:
            self._next_heartbeat_wall = now + _HEARTBEAT_PERIOD_S
            self._heartbeat()
        if self.manager is not None:
            self.manager.maybe_send_status(now)

    def information_message(self):
        """GIMBAL_DEVICE_INFORMATION of this device (pymavlink message)."""
        from .. import __version__

        (y_lo, y_hi), (r_lo, r_hi), (p_lo, p_hi) = self.kinematics.joint_limits_rad
        cap = (mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_AXIS
               | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
               | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
               | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW | mavlink.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK
               | mavlink.GIMBAL_DEVICE_CAP_FLAGS_SUPPORTS_YAW_IN_EARTH_FRAME)
        if math.isinf(y_lo) and math.isinf(y_hi):
            cap |= mavlink.GIMBAL_DEVICE_CAP_FLAGS_SUPPORTS_INFINITE_YAW

        def limit(v):
            return v if math.isfinite(v) else math.nan

        return self._mav.gimbal_device_information_encode(
            self._time_ms(), b"gimbal-lab", b"simulated yaw-roll-pitch", b"", firmware_version_word(__version__), 0, 0,
            cap & 0xFFFF, 0, limit(r_lo), limit(r_hi), limit(p_lo), limit(p_hi), limit(-y_hi), limit(-y_lo), 0, cap)

    # ------------------------------------------------------------------ messages in
    def _addressed_to_me(self, msg) -> bool:
        return msg.target_system in (0, self.system_id) and msg.target_component in (0, self.component_id)

    def handle(self, msg) -> None:
        """React to one received message (the loops call this; tests may too).

        Never raises for what a message holds: every field is checked before use (a refusal is
        acknowledged or counted); a failure of the device itself is counted in
        :attr:`handler_errors` and the message dropped. Link failures still raise.
        """
        try:
            self._dispatch(msg)
        except OSError:
            raise
        except Exception:  # noqa: BLE001 - a packet must never end the device (counted; the fuzz tests keep it 0)
            self.handler_errors += 1

    def _dispatch(self, msg) -> None:
        kind = msg.get_type()
        if not hasattr(msg, "target_system") or not self._addressed_to_me(msg):
            return
        if kind == "GIMBAL_DEVICE_SET_ATTITUDE":
            self.queue_setpoint(msg)
        elif kind == "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE":
            self._take_autopilot_state(msg)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(msg)
        elif kind in ("GIMBAL_MANAGER_SET_ATTITUDE", "GIMBAL_MANAGER_SET_PITCHYAW") and self.manager is not None:
            self.manager.handle_message(msg)

    def queue_setpoint(self, setpoint) -> bool:
        """Check a GIMBAL_DEVICE_SET_ATTITUDE (or the manager's :class:`~gimbal_lab.mavlink.manager.Setpoint`)
        at the wire and queue it to take effect after the latency; False (and counted) when refused
        (None: a setpoint the manager found out of range)."""
        if (setpoint is None or not self._valid_attitude_command(setpoint)
                or len(self._incoming) >= MAX_PENDING_COMMANDS):
            self.commands_rejected += 1
            return False
        self._incoming.append((self._k + self._latency_steps, setpoint))
        if self._latency_steps == 0:
            self._events()
        return True

    @staticmethod
    def _valid_attitude_command(msg) -> bool:
        """GIMBAL_DEVICE_SET_ATTITUDE checked at the wire: one yaw frame at most; the quaternion
        NaN (ignored) or a finite one of norm in (0.5, 2); rates NaN (0) or finite within
        :data:`MAX_COMMAND_RATE_RAD_S`."""
        if frame_of_flags(msg.flags) is None:
            return False
        q = np.array(msg.q, dtype=float)
        if np.any(np.isinf(q)):
            return False
        if np.all(np.isfinite(q)) and not 0.5 < float(np.linalg.norm(q)) < 2.0:
            return False
        omega = np.array([msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z], dtype=float)
        omega = np.nan_to_num(omega, nan=0.0, posinf=np.inf, neginf=np.inf)
        return bool(np.all(np.isfinite(omega)) and np.linalg.norm(omega) <= MAX_COMMAND_RATE_RAD_S)

    def _ack(self, msg, result: int, progress: int = 0, result_param2: int = 0) -> None:
        """COMMAND_ACK to ``msg``'s sender. ``result_param2`` is 0 except for the lock-step command
        (the clock, ms: :mod:`gimbal_lab.mavlink.protocol`)."""
        self._send_now(self._mav.command_ack_encode(msg.command, result, progress, result_param2,
                                                    msg.get_srcSystem(), msg.get_srcComponent()))

    def _command(self, msg) -> None:
        """COMMAND_LONG or COMMAND_INT addressed to the device: every one is acknowledged."""
        manager = self.manager
        if manager is not None:
            result = manager.handle_command(msg)
            if result is not None:
                self._ack(msg, result)
                return
        if msg.command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            wanted = _whole_number(msg.param1)
            answers = {mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION: self.information_message}
            if manager is not None:
                answers[mavlink.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION] = manager.information_message
                answers[mavlink.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS] = manager.status_message
            if wanted is None:
                self._ack(msg, mavlink.MAV_RESULT_DENIED)
            elif wanted in answers:
                self._ack(msg, mavlink.MAV_RESULT_ACCEPTED)
                self._send_now(answers[wanted]())
            else:
                self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
        elif msg.command == STEP_COMMAND and msg.get_type() == "COMMAND_LONG":
            duration = float(msg.param1)
            if not self.lockstep or not (math.isfinite(duration) and 0 <= duration <= self.end_step * self.dt_s):
                self._ack(msg, mavlink.MAV_RESULT_DENIED, result_param2=self._time_ms())
                return
            k_end = self._k + int(round(duration / self.dt_s))
            if k_end > self.end_step:
                self._ack(msg, mavlink.MAV_RESULT_DENIED, result_param2=self._time_ms())
                return
            self._stepping = [msg, self._k, k_end, time.monotonic() + PROGRESS_PERIOD_S]
            try:
                self.advance_to(k_end)
            finally:
                self._stepping = None
            self._ack(msg, mavlink.MAV_RESULT_ACCEPTED, 100, self._time_ms())
        else:
            self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)

    def _step_progress(self) -> None:
        """During a long lock-step step: heartbeats and progress acknowledgements keep the driver informed."""
        now = time.monotonic()
        self._maybe_heartbeat(now)
        msg, first, last, next_progress = self._stepping
        if now >= next_progress:
            self._stepping[3] = now + PROGRESS_PERIOD_S
            done = int(100 * (self._k - first) / max(last - first, 1))
            self._ack(msg, mavlink.MAV_RESULT_IN_PROGRESS, min(done, 99), self._time_ms())

    def _receive(self, timeout_s: float) -> None:
        link, mav = self.link, self._mav
        sender = None
        if self._udp_in:
            peer = link.peer
            data = link.read(timeout_s)
            sender, link.peer = link.peer, peer  # only an accepted packet makes its sender a client
        else:
            data = link.read(timeout_s)
        if not data:
            return
        for msg in mav.parse_buffer(data) or ():
            if msg.get_type() == "BAD_DATA":
                self.packets_dropped += 1
            elif (msg.get_srcSystem(), msg.get_srcComponent()) != (self.system_id, self.component_id):
                if sender is not None:
                    self._hear(sender)
                self.handle(msg)
        if sender is not None and mav.buf_len() > 0:  # a datagram holds whole packets: drop a torn one
            mav.buf, mav.buf_index, mav.expected_length = bytearray(), 0, mavlink.HEADER_LEN_V1 + 2
            self.packets_dropped += 1

    def _hear(self, sender) -> None:
        clients = self._clients
        clients[sender] = None
        clients.move_to_end(sender)
        while len(clients) > MAX_CLIENTS:
            clients.popitem(last=False)

    # ------------------------------------------------------------------ running
    def run(self, stop=None) -> str:
        """Serve until ``stop`` (a ``threading.Event``) is set or the mount's run is over.

        Returns
        -------
        str
            "stopped", "end of run" (the simulated time reached the mount's duration; in
            lock-step the device keeps answering and refuses further steps until stopped) or
            "link closed" (the other side of a serial link went away).
        """
        try:
            return self._serve(stop)
        except LinkClosed:
            return "link closed"

    def _serve(self, stop) -> str:
        if self.lockstep:
            while stop is None or not stop.is_set():
                self._maybe_heartbeat(time.monotonic())
                self._receive(_LOCKSTEP_POLL_S)
            return "stopped"
        start = time.monotonic() - self._k * self.dt_s
        while stop is None or not stop.is_set():
            now = time.monotonic()
            self.advance_to(int((now - start) / self.dt_s))
            if self._k >= self.end_step:
                return "end of run"
            self._maybe_heartbeat(now)
            self._receive(_REALTIME_POLL_S)
        return "stopped"

    def close(self) -> None:
        """Close the link."""
        self.link.close()
