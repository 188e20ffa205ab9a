"""Steering through a gimbal manager (MavlinkGimbal.find_manager / take_manager_control /
send_manager_joint_rates, GimbalSteer(via_manager=True), track --via-manager).

The vehicle is a small one in the test, over loopback UDP with pymavlink's generated code: a gimbal
device (1/154) that reports a fixed attitude, and a gimbal manager for it, either an autopilot's
(1/1) or built into the device (1/154), that sends GIMBAL_MANAGER_STATUS at 5 Hz, answers
MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE as the protocol says (param1/param2 the new primary control,
−3 to release) and records every GIMBAL_MANAGER_SET_PITCHYAW with whether its sender was in
control. Oracle for the rates: with the roll joint at 0 and not turning, the protocol's yaw is
−q_yaw and its pitch q_pitch (docs/design.md, "MAVLink gimbal"), so the manager's yaw and pitch
rates are −q̇_yaw and q̇_pitch. Time bounds are liveness bounds.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402
from _loopback_gimbal import LoopbackGimbal, running  # noqa: E402  (tests/_loopback_gimbal.py)

from gimbal_lab.camera import Intrinsics  # noqa: E402
from gimbal_lab.mavlink import frames  # noqa: E402
from gimbal_lab.mavlink.driver import GimbalCommandFailed, GimbalNotFound, MavlinkGimbal  # noqa: E402
from gimbal_lab.mavlink.steer import GimbalSteer  # noqa: E402

LIVENESS_S = 60.0
YAW_RAD, PITCH_RAD = 0.2, -0.1  # the device's attitude: yaw right 0.2 rad, pitch down 0.1 rad, roll 0
DRIVER = (1, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)


class FakeVehicle(LoopbackGimbal):
    """A gimbal device and its manager on one loopback UDP socket (class docstring of the module;
    the device is tests/_loopback_gimbal.py's). ``manager_component``: 1 (an autopilot's manager)
    or 154 (built into the device); None: no manager. ``refuse``: the manager denies every
    CONFIGURE. ``managed``: the gimbal_device_id its status names (another device's for a manager
    that is not this gimbal's)."""

    MANAGER_STATUS_S = 0.2

    def __init__(self, manager_component=1, refuse=False, managed=mavlink.MAV_COMP_ID_GIMBAL):
        super().__init__()
        self.manager_component, self.refuse, self.managed = manager_component, refuse, managed
        self.manager = None if manager_component is None else mavlink.MAVLink(self, 1, manager_component)
        self.primary = (0, 0)
        self.pitchyaw = []  # (message, sender in control?)
        self.configures = []  # COMMAND_LONG CONFIGURE
        self.next_manager = self.start_s
        self.q = frames.quaternion_from_euler(YAW_RAD, PITCH_RAD, 0.0)

    @property
    def device_commands(self) -> list:
        """Every GIMBAL_DEVICE_SET_ATTITUDE."""
        return self.commands

    def quaternion(self):
        return self.q

    def _command(self, msg, sender) -> None:
        if msg.command != mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE:
            return
        self.configures.append(msg)
        result = mavlink.MAV_RESULT_ACCEPTED
        if self.refuse:
            result = mavlink.MAV_RESULT_DENIED
        elif msg.param1 == -3 and msg.param2 == -3:
            if self.primary == sender:
                self.primary = (0, 0)
        elif msg.param1 >= 0 and msg.param2 >= 0:
            self.primary = (int(msg.param1), int(msg.param2))
        self.manager.send(mavlink.MAVLink_command_ack_message(msg.command, result, 0, 0, sender[0], sender[1]))

    def received(self, msg) -> None:
        kind, sender = msg.get_type(), (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "GIMBAL_DEVICE_SET_ATTITUDE":
            self.commands.append(msg)
        elif self.manager is not None and kind == "COMMAND_LONG" and msg.target_component in (0, self.manager_component):
            self._command(msg, sender)
        elif (self.manager is not None and kind == "GIMBAL_MANAGER_SET_PITCHYAW"
              and msg.target_component == self.manager_component):
            self.pitchyaw.append((msg, sender == self.primary))

    def tick(self, now: float) -> None:
        if self.manager is not None and now >= self.next_manager:
            self.next_manager = now + self.MANAGER_STATUS_S
            self.manager.send(mavlink.MAVLink_gimbal_manager_status_message(
                self.boot_ms(now), 0, self.managed, *self.primary, 0, 0))


def fake_vehicle(**kwargs):
    return running(FakeVehicle(**kwargs))


def wait_for(predicate):
    deadline = time.monotonic() + LIVENESS_S
    while not predicate():
        assert time.monotonic() < deadline
        time.sleep(0.01)


@pytest.mark.parametrize("component", [1, 154], ids=["an autopilot's manager", "the device's own manager"])
def test_the_driver_finds_the_manager_takes_control_steers_and_releases(component):
    """find_manager names the manager's source; CONFIGURE makes the driver primary control (the
    manager's next status says so); joint rates (yaw, roll, pitch) = (0.3, 0, −0.2) rad/s at the
    reported joints go out as yaw rate −0.3 and pitch rate −0.2 rad/s, angles NaN, from the sender
    in control; release hands control back (primary 0/0); the device itself got no command."""
    with fake_vehicle(manager_component=component) as vehicle:
        with MavlinkGimbal(vehicle.address, request_info=False, discover_timeout_s=LIVENESS_S) as gimbal:
            assert gimbal.find_manager(LIVENESS_S) == (1, component) == gimbal.manager
            gimbal.take_manager_control()
            assert vehicle.primary == DRIVER
            wait_for(lambda: gimbal.manager_status is not None and (
                gimbal.manager_status.primary_control_sysid, gimbal.manager_status.primary_control_compid) == DRIVER)
            report = gimbal.wait_report(LIVENESS_S)
            np.testing.assert_allclose(report.q_rad, [-YAW_RAD, 0.0, PITCH_RAD], rtol=0, atol=1e-6)
            gimbal.send_manager_joint_rates([0.3, 0.0, -0.2])
            wait_for(lambda: vehicle.pitchyaw)
            gimbal.release_manager_control()
            assert vehicle.primary == (0, 0)
        msg, in_control = vehicle.pitchyaw[0]
        assert in_control and not vehicle.device_commands
        assert math.isnan(msg.pitch) and math.isnan(msg.yaw)
        assert msg.gimbal_device_id == mavlink.MAV_COMP_ID_GIMBAL
        assert msg.flags == mavlink.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | mavlink.GIMBAL_MANAGER_FLAGS_PITCH_LOCK | \
            mavlink.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME
        # float32 on the wire; the reported joints are float32-quaternion exact to ~1e-7 rad
        np.testing.assert_allclose([msg.yaw_rate, msg.pitch_rate], [-0.3, -0.2], rtol=0, atol=1e-6)
        configure = vehicle.configures[0]
        assert (configure.param1, configure.param2, configure.param3, configure.param4, configure.param7) == (
            *DRIVER, -1, -1, mavlink.MAV_COMP_ID_GIMBAL)


def test_a_manager_that_refuses_control_and_a_missing_manager_are_one_line_errors():
    """A manager that denies CONFIGURE; no manager, or only one for another device (component 171)."""
    with fake_vehicle(refuse=True) as vehicle:
        with MavlinkGimbal(vehicle.address, request_info=False, discover_timeout_s=LIVENESS_S) as gimbal:
            gimbal.find_manager(LIVENESS_S)
            with pytest.raises(GimbalCommandFailed, match=r"gimbal manager 1/1 .* refused "
                                                          r"MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE \(MAV_RESULT_DENIED\)"):
                gimbal.take_manager_control()
    for kwargs in ({"manager_component": None}, {"managed": mavlink.MAV_COMP_ID_GIMBAL2}):  # none; another's
        with fake_vehicle(**kwargs) as vehicle:
            with MavlinkGimbal(vehicle.address, request_info=False, discover_timeout_s=LIVENESS_S) as gimbal:
                with pytest.raises(GimbalNotFound, match=r"no gimbal manager for gimbal 1/154 .* gimbal_device_id 154"):
                    gimbal.find_manager(1.0)


def test_gimbal_steer_via_manager_steers_towards_the_target_through_the_manager_only(tmp_path):
    """GimbalSteer(via_manager=True), the ball right of and below the image centre: every frame's
    command reaches the manager from the sender in control, yaw right and pitch down (towards the
    ball), each the pitch/yaw rate of the logged joint rates; the device itself gets nothing;
    closing sends zero rates through the manager and releases control."""
    import pandas as pd

    cam = Intrinsics.default()
    uv = (cam.cx + 80.0, cam.cy + 50.0)  # right of and below the centre
    with fake_vehicle() as vehicle:
        lines = []
        steer = GimbalSteer(vehicle.address, cam, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S,
                            max_age_s=2.0, via_manager=True, say=lines.append)
        try:
            assert vehicle.primary == DRIVER
            assert all(steer.frame(n, uv, 30.0) for n in range(5))
        finally:
            steer.close()
        wait_for(lambda: len(vehicle.pitchyaw) == 6)
        assert vehicle.primary == (0, 0) and not vehicle.device_commands
    assert lines[-1] == "gimbal manager 1/1 found; this driver is its primary control"
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert len(log) == 5
    q = np.array([-YAW_RAD, 0.0, PITCH_RAD])
    for (msg, in_control), row in zip(vehicle.pitchyaw, log.itertuples()):
        rate = np.array([row.cmd_yaw_rad_s, row.cmd_roll_rad_s, row.cmd_pitch_rad_s])
        omega = frames.joint_rates_to_angular_velocity(steer.kinematics, q, rate)
        yaw_rate, pitch_rate, _ = frames.euler_rates_from_angular_velocity(
            frames.quaternion_from_euler(YAW_RAD, PITCH_RAD, 0.0), omega)
        assert in_control and msg.yaw_rate > 0 and msg.pitch_rate < 0, (msg.yaw_rate, msg.pitch_rate)
        np.testing.assert_allclose([msg.yaw_rate, msg.pitch_rate], [yaw_rate, pitch_rate], rtol=1e-5, atol=1e-6)
    last, in_control = vehicle.pitchyaw[-1]
    assert in_control and (last.yaw_rate, last.pitch_rate) == (0.0, 0.0)


def test_track_via_manager_needs_gimbal(tmp_path, capsys):
    from gimbal_lab import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["track", "x.mp4", "--target", "sphere", "--calibration", "cam.yaml", "--out", str(tmp_path),
                  "--via-manager"])
    assert exit_.value.code == 2 and "--via-manager needs --gimbal" in capsys.readouterr().err
