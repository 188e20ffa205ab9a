"""MAVLink Gimbal Protocol v2: a driver for gimbal devices and the lab's gimbal as a simulated one.

Modules
-------
frames    the protocol's NED/FRD frames, quaternions (w, x, y, z), Z-Y-X angles, and the mapping
          between the lab's joint angles and the protocol's attitude (no pymavlink needed)
protocol  the MAVLink 2 message set (pymavlink's ``common`` dialect), flags, the lock-step command
link      byte links: udpin:/udpout:, serial ports and pyserial URLs, file descriptors
driver    :class:`MavlinkGimbal`: discovery, information, commands, attitude reports, lock-step
device    :class:`SimulatedGimbalDevice` and :func:`simulated_gimbal`: the lab's gimbal as a device
cli       ``gimbal-lab gimbal-device``

``driver``, ``device``, ``protocol`` and ``link`` need the ``[mavlink]`` extra (pymavlink,
pyserial). Every name is importable from here and loads on first use. docs/design.md,
"MAVLink gimbal", describes the design.
"""

from importlib import import_module

_FRAMES = (
    "F_NED_NWU", "R_CAM_GIMBAL", "angular_velocity_to_joint_rates", "camera_from_gimbal",
    "camera_rates_to_angular_velocity", "euler_from_quaternion", "gimbal_attitude_matrix", "gimbal_from_camera",
    "joint_rates_to_angular_velocity", "joints_to_quaternion", "matrix_from_quaternion", "quaternion_from_euler",
    "quaternion_from_matrix", "quaternion_multiply", "quaternion_to_joints", "rot_z",
)

# Every name loads on first use: ``gimbal-lab --help`` imports this package (for the
# gimbal-device command) and must not pay for numpy or pymavlink.
_LAZY = {
    **dict.fromkeys(_FRAMES, "frames"),
    "MavlinkGimbal": "driver", "AttitudeReport": "driver", "GimbalDeviceInfo": "driver",
    "GimbalLinkError": "driver", "GimbalNotFound": "driver", "GimbalLinkLost": "driver",
    "GimbalCommandFailed": "driver",
    "SimulatedGimbalDevice": "device", "LinkEffects": "device", "simulated_gimbal": "device",
    "open_link": "link",
}

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        return getattr(import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
