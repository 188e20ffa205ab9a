"""MAVLink 2 message set, the gimbal's constants, and the lab's lock-step command (one home for each).

Everything is MAVLink 2 framed through pymavlink's generated ``common`` dialect, used directly
(not through ``pymavlink.mavutil``, which chooses its dialect and wire version through process-wide
state and environment variables).

Lock-step
---------
The simulated device (:mod:`gimbal_lab.mavlink.device`) in lock-step mode advances its clock only
when told, through ``COMMAND_LONG`` with command :data:`STEP_COMMAND` (``MAV_CMD_USER_1``, a
command id the MAVLink common set leaves to its users): ``param1`` is the simulated time to
advance, s, rounded to the device's inner step. The device answers ``COMMAND_ACK`` with
``MAV_RESULT_IN_PROGRESS`` (``progress`` in percent) every :data:`PROGRESS_PERIOD_S` of wall time
while it computes a long step, then ``MAV_RESULT_ACCEPTED`` with ``result_param2`` = its clock
after the step in ms; ``MAV_RESULT_DENIED`` when the step is negative, not finite, past the end of
the device's run, or the device runs in real time.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["mavlink", "new_mavlink", "STEP_COMMAND", "PROGRESS_PERIOD_S", "MAX_COMMAND_RATE_RAD_S", "GIMBAL_COMPONENT_IDS",
           "FRAME_FLAGS", "frame_flags", "frame_of_flags"]

#: Lock-step: advance the simulated clock by param1 seconds (module docstring).
STEP_COMMAND = mavlink.MAV_CMD_USER_1
#: A device busy with a long step reports progress this often, s of wall time.
PROGRESS_PERIOD_S = 0.25

#: A commanded angular velocity of larger magnitude, rad/s, is refused as out of range by the
#: device and its manager (no gimbal turns 16 revolutions a second).
MAX_COMMAND_RATE_RAD_S = 100.0

#: MAV_COMP_ID_GIMBAL .. MAV_COMP_ID_GIMBAL6.
GIMBAL_COMPONENT_IDS = (mavlink.MAV_COMP_ID_GIMBAL, mavlink.MAV_COMP_ID_GIMBAL2, mavlink.MAV_COMP_ID_GIMBAL3,
                        mavlink.MAV_COMP_ID_GIMBAL4, mavlink.MAV_COMP_ID_GIMBAL5, mavlink.MAV_COMP_ID_GIMBAL6)

#: GIMBAL_DEVICE_FLAGS of a command in each yaw frame. Roll and pitch are always locked to the
#: horizon; the earth frame also sets YAW_LOCK, as the message set's older rule reads it.
FRAME_FLAGS = {
    "vehicle": (mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                | mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME),
    "earth": (mavlink.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
              | mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK | mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME),
}


def frame_flags(frame: str) -> int:
    """GIMBAL_DEVICE_FLAGS for ``frame`` in ("vehicle", "earth") (:data:`FRAME_FLAGS`)."""
    try:
        return FRAME_FLAGS[frame]
    except (KeyError, TypeError):
        raise ValueError(f"frame must be 'vehicle' or 'earth', got {frame!r}") from None


def frame_of_flags(flags: int) -> str | None:
    """The yaw frame that GIMBAL_DEVICE_FLAGS name: "vehicle", "earth", or None when both frame
    flags are set (not allowed). Without either frame flag the older rule holds: YAW_LOCK means
    the earth frame, else the vehicle frame."""
    vehicle = bool(flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
    earth = bool(flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)
    if vehicle and earth:
        return None
    if earth or (not vehicle and flags & mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK):
        return "earth"
    return "vehicle"


def new_mavlink(file, system_id: int, component_id: int):
    """A pymavlink ``MAVLink`` object (MAVLink 2) writing to ``file`` as (system_id, component_id),
    parsing robustly (bad bytes become BAD_DATA messages instead of exceptions)."""
    for name, value in (("system_id", system_id), ("component_id", component_id)):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 255:
            raise ValueError(f"{name} must be an integer in 1..255, got {value!r}")
    mav = mavlink.MAVLink(file, srcSystem=system_id, srcComponent=component_id)
    mav.robust_parsing = True
    return mav
