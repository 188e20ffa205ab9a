"""A gimbal manager on the simulated device's own component (Gimbal Protocol v2), as integrated gimbals have.

The manager shares the device's system and component id and manages that one gimbal
(``gimbal_device_id`` = the device's component id; 0 in a message means "all", which is the same
one). It speaks:

* GIMBAL_MANAGER_INFORMATION on MAV_CMD_REQUEST_MESSAGE (280): the device's capabilities and joint
  limits (the same as GIMBAL_DEVICE_INFORMATION's);
* GIMBAL_MANAGER_STATUS about 5 times a second of wall time (:data:`STATUS_PERIOD_S`), and on
  request (281): the flags of the setpoint in force and who is in control;
* MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (COMMAND_LONG or COMMAND_INT): param1/param2 the primary
  controller's system and component id, param3/param4 the secondary's, each ≥ 0 to set, −1 to
  leave, −2 for the sender itself, −3 to give up control the sender holds; param7 the gimbal.
  Anyone may configure (the protocol lets a controller take over; its status tells everyone);
* MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (COMMAND_LONG, or COMMAND_INT with the flags in ``x``):
  pitch and yaw, deg (NaN: keep the present angle), pitch and yaw rates, deg/s (NaN: 0), the
  GIMBAL_MANAGER_FLAGS;
* GIMBAL_MANAGER_SET_PITCHYAW (the same in rad and rad/s) and GIMBAL_MANAGER_SET_ATTITUDE (as
  GIMBAL_DEVICE_SET_ATTITUDE).

Control: while a primary or secondary controller is set, commands and setpoints from any other
sender are refused (a command acknowledged MAV_RESULT_DENIED, a message dropped and counted in
:attr:`GimbalManager.refused`); while nobody is in control, anyone's are taken. Every command
addressed to the manager is acknowledged (COMMAND_ACK with ``progress`` and ``result_param2`` 0);
a parameter out of its range (non-finite, an unknown gimbal, both yaw frames) gets
MAV_RESULT_DENIED.

Pitch and yaw become a setpoint of the device (:class:`Setpoint`): angles the attitude
Rz(yaw)·Ry(pitch) (roll 0, Z-Y-X, yaw positive right) in the frame the flags name; rates the
angular velocity ω = ψ̇·e_z + θ̇·Rz(ψ)·e_y (:func:`angular_velocity_of_pitch_yaw_rates`). A rate
setpoint without angles keeps its Euler rates and the device recomputes ω from the present yaw at
every control step, so pitch and yaw rates stay pitch and yaw rates as the gimbal turns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import frames
from .protocol import MAX_COMMAND_RATE_RAD_S, frame_of_flags, mavlink

__all__ = ["GimbalManager", "Setpoint", "STATUS_PERIOD_S", "angular_velocity_of_pitch_yaw_rates"]

#: GIMBAL_MANAGER_STATUS period, s of wall time (about 5 Hz).
STATUS_PERIOD_S = 0.2
_NAN = math.nan
_CONFIGURE = mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
_PITCHYAW = mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
_LEAVE, _SELF, _RELEASE = -1, -2, -3


@dataclass(frozen=True)
class Setpoint:
    """A setpoint for the device, read as a GIMBAL_DEVICE_SET_ATTITUDE is (same field names).

    ``euler_rates`` (pitch rate, yaw rate), rad/s, when set, makes the device recompute the
    angular velocity from the present yaw at every control step (a rate setpoint without angles).
    """

    flags: int
    q: tuple
    angular_velocity_x: float
    angular_velocity_y: float
    angular_velocity_z: float
    euler_rates: tuple | None = None


def angular_velocity_of_pitch_yaw_rates(yaw_rad: float, pitch_rate_rad_s: float, yaw_rate_rad_s: float) -> np.ndarray:
    """Angular velocity, rad/s, in the frame's axes (x North or forward, y East or right, z down)
    of an attitude Rz(ψ)·Ry(θ) whose pitch and yaw change at θ̇ and ψ̇: ω = ψ̇·e_z + θ̇·Rz(ψ)·e_y.

    (The inverse, for any roll, is :func:`gimbal_lab.mavlink.frames.euler_rates_from_angular_velocity`.)
    """
    return np.array([-math.sin(yaw_rad) * pitch_rate_rad_s, math.cos(yaw_rad) * pitch_rate_rad_s, yaw_rate_rad_s])


def _finite_or_nan(value: float, bound: float) -> bool:
    """A parameter that is NaN (not set) or finite within ±bound."""
    return math.isnan(value) or (math.isfinite(value) and abs(value) <= bound)


class GimbalManager:
    """The manager of one simulated device, on its component (module docstring).

    Parameters
    ----------
    device : gimbal_lab.mavlink.device.SimulatedGimbalDevice
        The device it manages and speaks through.

    Attributes
    ----------
    primary, secondary : (int, int)
        (system id, component id) in control; (0, 0): nobody.
    refused : int
        Setpoint messages dropped because their sender was not in control.
    """

    def __init__(self, device):
        self.device = device
        self.primary = (0, 0)
        self.secondary = (0, 0)
        self.refused = 0
        self._next_status_wall = 0.0

    # ------------------------------------------------------------------ out
    @property
    def gimbal_device_id(self) -> int:
        return self.device.component_id

    def information_message(self):
        """GIMBAL_MANAGER_INFORMATION (pymavlink message): the device's capabilities and limits."""
        info = self.device.information_message()
        return self.device._mav.gimbal_manager_information_encode(
            info.time_boot_ms, info.cap_flags, self.gimbal_device_id, info.roll_min, info.roll_max, info.pitch_min,
            info.pitch_max, info.yaw_min, info.yaw_max)

    def status_message(self):
        """GIMBAL_MANAGER_STATUS (pymavlink message): the setpoint's flags and who is in control."""
        device = self.device
        return device._mav.gimbal_manager_status_encode(
            device._time_ms(), device.setpoint_flags, self.gimbal_device_id, *self.primary, *self.secondary)

    def maybe_send_status(self, now_s: float) -> None:
        """Send GIMBAL_MANAGER_STATUS when :data:`STATUS_PERIOD_S` of wall time has passed."""
        if now_s >= self._next_status_wall:
            self._next_status_wall = now_s + STATUS_PERIOD_S
            self.device._send_now(self.status_message())

    # ------------------------------------------------------------------ in
    def _mine(self, gimbal_device_id) -> bool:
        return gimbal_device_id in (0, self.gimbal_device_id)

    def _in_control(self, sender) -> bool:
        return (self.primary == (0, 0) and self.secondary == (0, 0)) or sender in (self.primary, self.secondary)

    def handle_message(self, msg) -> None:
        """GIMBAL_MANAGER_SET_ATTITUDE or GIMBAL_MANAGER_SET_PITCHYAW addressed to the manager."""
        if not self._mine(msg.gimbal_device_id):
            return
        if not self._in_control((msg.get_srcSystem(), msg.get_srcComponent())):
            self.refused += 1
            return
        if msg.get_type() == "GIMBAL_MANAGER_SET_ATTITUDE":
            setpoint = Setpoint(int(msg.flags), tuple(float(v) for v in msg.q), float(msg.angular_velocity_x),
                                float(msg.angular_velocity_y), float(msg.angular_velocity_z))
        else:
            setpoint = self._pitch_yaw(int(msg.flags), float(msg.pitch), float(msg.yaw), float(msg.pitch_rate),
                                       float(msg.yaw_rate))
        self.device.queue_setpoint(setpoint)

    def handle_command(self, msg) -> int | None:
        """A COMMAND_LONG or COMMAND_INT addressed to the device: the MAV_RESULT for the manager's
        own commands (after acting on them), None for the others."""
        if msg.command == _CONFIGURE:
            return self._configure(msg)
        if msg.command == _PITCHYAW:
            return self._pitchyaw_command(msg)
        return None

    def _configure(self, msg) -> int:
        device_id = msg.z if msg.get_type() == "COMMAND_INT" else msg.param7
        if not (math.isfinite(device_id) and self._mine(device_id)):
            return mavlink.MAV_RESULT_DENIED
        params = (msg.param1, msg.param2, msg.param3, msg.param4)
        if not all(math.isfinite(p) and p == int(p) and -3 <= p <= 255 for p in params):
            return mavlink.MAV_RESULT_DENIED
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        roles = []
        for (system, component), current in zip((params[:2], params[2:]), (self.primary, self.secondary)):
            system, component = int(system), int(component)
            if _SELF in (system, component):
                roles.append(sender)
            elif _RELEASE in (system, component):
                roles.append((0, 0) if current == sender else current)
            elif _LEAVE in (system, component):
                roles.append(current)
            else:
                roles.append((system, component))
        self.primary, self.secondary = roles
        return mavlink.MAV_RESULT_ACCEPTED

    def _pitchyaw_command(self, msg) -> int:
        command_int = msg.get_type() == "COMMAND_INT"
        flags, device_id = (msg.x, msg.z) if command_int else (msg.param5, msg.param7)
        if not (math.isfinite(device_id) and self._mine(device_id)):
            return mavlink.MAV_RESULT_DENIED
        if not (math.isfinite(flags) and flags == int(flags) and 0 <= flags <= 0xFFFFFFFF):
            return mavlink.MAV_RESULT_DENIED
        if not self._in_control((msg.get_srcSystem(), msg.get_srcComponent())):
            return mavlink.MAV_RESULT_DENIED
        pitch, yaw, pitch_rate, yaw_rate = (math.radians(float(p)) for p in (msg.param1, msg.param2, msg.param3,
                                                                               msg.param4))
        setpoint = self._pitch_yaw(int(flags), pitch, yaw, pitch_rate, yaw_rate)
        if setpoint is None or not self.device.queue_setpoint(setpoint):
            return mavlink.MAV_RESULT_DENIED
        return mavlink.MAV_RESULT_ACCEPTED

    def _pitch_yaw(self, flags: int, pitch: float, yaw: float, pitch_rate: float, yaw_rate: float):
        """The device setpoint of a pitch/yaw command (rad, rad/s; NaN: not set), or None when a
        value is out of range (an angle beyond ±π, a rate beyond the device's bound, both frames)."""
        frame = frame_of_flags(flags & 0xFFFF)
        if frame is None or not (_finite_or_nan(pitch, math.pi / 2) and _finite_or_nan(yaw, math.pi)
                                 and _finite_or_nan(pitch_rate, MAX_COMMAND_RATE_RAD_S)
                                 and _finite_or_nan(yaw_rate, MAX_COMMAND_RATE_RAD_S)):
            return None
        flags &= 0xFFFF
        rates = (0.0 if math.isnan(pitch_rate) else pitch_rate, 0.0 if math.isnan(yaw_rate) else yaw_rate)
        rates_set = not (math.isnan(pitch_rate) and math.isnan(yaw_rate))
        if math.isnan(pitch) and math.isnan(yaw):
            if not rates_set:  # only the flags change
                return Setpoint(flags, (_NAN,) * 4, _NAN, _NAN, _NAN)
            omega = angular_velocity_of_pitch_yaw_rates(self.device.yaw_in(frame), *rates)
            return Setpoint(flags, (_NAN,) * 4, *(float(v) for v in omega), euler_rates=rates)
        if math.isnan(pitch) or math.isnan(yaw):  # keep the other angle where it is
            now_yaw, now_pitch = self.device.yaw_in(frame), self.device.pitch_in(frame)
            pitch = now_pitch if math.isnan(pitch) else pitch
            yaw = now_yaw if math.isnan(yaw) else yaw
        q = frames.quaternion_from_euler(yaw, pitch, 0.0)
        omega = angular_velocity_of_pitch_yaw_rates(yaw, *rates) if rates_set else (_NAN,) * 3
        return Setpoint(flags, tuple(float(v) for v in q), *(float(v) for v in omega))
