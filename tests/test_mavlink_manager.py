"""The gimbal manager on the simulated device's component: information, status, control, pitch/yaw.

Messages are built and read back with pymavlink's own encoder and parser (the oracle of the wire
format); most tests drive a lock-step device in process (its link records what it sends), the
last drives it over loopback UDP with MAVSDK's Gimbal plugin, a client nobody here wrote.

By hand: the Z-Y-X angles (yaw right, pitch up) of a level vehicle frame are the joints
(−yaw, 0, pitch) (the lab's yaw joint turns left). Tolerances: angles to 1e-5 rad after the
attitude law's settling (see tests/test_mavlink.py, settle_s); rates as slopes over 0.5 s after
0.5 s of settling, to 1e-4 rad/s (the rate loops settle with time constants below 7 ms).
"""

import math
import socket
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from gimbal_lab.mavlink.device import LinkEffects, SimulatedGimbalDevice, simulated_gimbal
from gimbal_lab.mavlink.link import Link
from gimbal_lab.mavlink.manager import STATUS_PERIOD_S, angular_velocity_of_pitch_yaw_rates
from gimbal_lab.mavlink.protocol import STEP_COMMAND

D = math.radians
NAN = math.nan
CONFIGURE, PITCHYAW = mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
ACCEPTED, DENIED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
VEHICLE = 4 | 8 | 32  # GIMBAL_MANAGER_FLAGS ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME
EARTH = 4 | 8 | 16 | 64  # ... | YAW_LOCK | YAW_IN_EARTH_FRAME
LIVENESS_S = 30.0


class Recorder(Link):
    """A link that keeps everything the device sends, parsed by a fresh pymavlink parser."""

    def __init__(self):
        self.parser, self.messages = mavlink.MAVLink(None), []

    def read(self, timeout_s):
        return b""

    def write(self, data):
        self.messages += self.parser.parse_buffer(data) or []

    def last(self, kind):
        return [m for m in self.messages if m.get_type() == kind][-1]


class Client:
    """A MAVLink sender (system, component) whose packets the device receives off the wire."""

    def __init__(self, device, system, component=mavlink.MAV_COMP_ID_ONBOARD_COMPUTER):
        self.device, self.mav = device, mavlink.MAVLink(None, srcSystem=system, srcComponent=component)

    def send(self, msg):
        (received,) = mavlink.MAVLink(None).parse_buffer(msg.pack(self.mav))
        self.device.handle(received)

    def command(self, command, *params, kind="long"):
        """Send a command (params 1..7; for COMMAND_INT, params 5 and 6 are x and y); the ack's result."""
        p = list(params) + [0.0] * (7 - len(params))
        if kind == "long":
            self.send(self.mav.command_long_encode(1, 154, command, 0, *p))
        else:
            self.send(self.mav.command_int_encode(1, 154, 0, command, 0, 0, *p[:4], int(p[4]), int(p[5]), p[6]))
        ack = self.device.link.last("COMMAND_ACK")
        assert ack.command == command and (ack.target_system, ack.target_component) == (self.mav.srcSystem,
                                                                                        self.mav.srcComponent)
        assert ack.progress == 0 and ack.result_param2 == 0
        return ack.result


def device_in_process(duration_s=6.0, **kwargs):
    return SimulatedGimbalDevice(Recorder(), simulated_gimbal(duration_s=duration_s), LinkEffects(status_rate_hz=100.0),
                                 lockstep=True, **kwargs)


def run(device, seconds):
    device.advance_to(device._k + int(round(seconds / device.dt_s)))


def test_information_and_status_on_request():
    device = device_in_process()
    gcs = Client(device, 200)
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 280) == ACCEPTED
    info, device_info = device.link.last("GIMBAL_MANAGER_INFORMATION"), device.information_message()
    # the manager's capability bits mean what the device's do (GIMBAL_MANAGER_CAP_FLAGS 2..4096)
    assert info.gimbal_device_id == 154 and info.cap_flags == device_info.cap_flags
    for name in ("roll_min", "roll_max", "pitch_min", "pitch_max", "yaw_min", "yaw_max"):
        assert getattr(info, name) == pytest.approx(getattr(device_info, name), rel=6e-8)  # float32: half an ulp
    assert info.yaw_min == pytest.approx(D(-170), abs=1e-6) and info.pitch_min == pytest.approx(D(-90), abs=1e-6)
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 281) == ACCEPTED
    status = device.link.last("GIMBAL_MANAGER_STATUS")
    assert (status.gimbal_device_id, status.flags) == (154, VEHICLE)
    assert (status.primary_control_sysid, status.primary_control_compid) == (0, 0)
    without = device_in_process(manager=False)
    assert Client(without, 200).command(mavlink.MAV_CMD_REQUEST_MESSAGE, 280) == mavlink.MAV_RESULT_UNSUPPORTED
    assert Client(without, 200).command(CONFIGURE, -2, -2, -1, -1, 0, 0, 154) == mavlink.MAV_RESULT_UNSUPPORTED


def test_control_is_configured_and_others_are_refused():
    """A takes primary control (−2: itself); B's command is DENIED and B's setpoint message dropped
    (counted); A's are taken; A gives control up (−3) and B's are taken again. Configure with a
    parameter that is no id, or for another gimbal, is DENIED."""
    device = device_in_process()
    a, b = Client(device, 200), Client(device, 201, 191)
    assert a.command(CONFIGURE, NAN, -2, -1, -1, 0, 0, 154) == DENIED
    assert a.command(CONFIGURE, -2, -2, -1, -1, 0, 0, 155) == DENIED
    assert a.command(CONFIGURE, 300, 1, -1, -1, 0, 0, 154) == DENIED
    assert a.command(CONFIGURE, -2, -2, -1, -1, 0, 0, 154) == ACCEPTED
    assert device.manager.primary == (200, 191) and device.manager.secondary == (0, 0)
    assert b.command(PITCHYAW, -10, 20, NAN, NAN, VEHICLE, 0, 154) == DENIED
    assert b.command(PITCHYAW, NAN, NAN, NAN, 5, VEHICLE, 0, 154, kind="int") == DENIED
    b.send(b.mav.gimbal_manager_set_pitchyaw_encode(1, 154, VEHICLE, 154, D(-10), D(20), NAN, NAN))
    run(device, 0.3)
    assert device.manager.refused == 1 and np.abs(device.q_rad).max() < 1e-9
    b.send(b.mav.command_long_encode(1, 154, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 281, 0, 0, 0, 0, 0, 0))
    status = device.link.last("GIMBAL_MANAGER_STATUS")
    assert (status.primary_control_sysid, status.primary_control_compid) == (200, 191)
    # B made secondary by A: now B's setpoints are taken
    assert a.command(CONFIGURE, -1, -1, 201, 191, 0, 0, 0) == ACCEPTED
    assert device.manager.secondary == (201, 191)
    assert b.command(PITCHYAW, -10, 20, NAN, NAN, VEHICLE, 0, 154) == ACCEPTED
    assert b.command(CONFIGURE, -3, -3, -3, -3, 0, 0, 154) == ACCEPTED  # B gives up what it holds
    assert (device.manager.primary, device.manager.secondary) == ((200, 191), (0, 0))
    assert b.command(PITCHYAW, -10, 20, NAN, NAN, VEHICLE, 0, 154) == DENIED
    assert a.command(CONFIGURE, -3, -3, -1, -1, 0, 0, 154) == ACCEPTED
    assert device.manager.primary == (0, 0)
    assert b.command(PITCHYAW, -10, 20, NAN, NAN, VEHICLE, 0, 154) == ACCEPTED


def test_pitch_yaw_angles_as_command_long_and_message():
    device = device_in_process()
    gcs = Client(device, 200)
    assert gcs.command(PITCHYAW, -20, 30, NAN, NAN, VEHICLE, 0, 154) == ACCEPTED
    run(device, 1.0)
    assert np.abs(device.q_rad - (D(-30), 0.0, D(-20))).max() < 1e-5
    # yaw NaN keeps the present yaw
    assert gcs.command(PITCHYAW, 10, NAN, NAN, NAN, VEHICLE, 0, 0) == ACCEPTED
    run(device, 1.0)
    assert np.abs(device.q_rad - (D(-30), 0.0, D(10))).max() < 1e-5
    gcs.send(gcs.mav.gimbal_manager_set_pitchyaw_encode(1, 154, VEHICLE, 0, D(-45), D(-60), NAN, NAN))
    run(device, 1.0)
    assert np.abs(device.q_rad - (D(60), 0.0, D(-45))).max() < 1e-5
    q = [math.cos(D(10)), 0.0, 0.0, math.sin(D(10))]  # yaw 20° right
    gcs.send(gcs.mav.gimbal_manager_set_attitude_encode(1, 154, VEHICLE, 154, q, NAN, NAN, NAN))
    run(device, 1.0)
    assert np.abs(device.q_rad - (D(-20), 0.0, 0.0)).max() < 1e-5
    assert device.commands_applied == 4 and device.handler_errors == 0


@pytest.mark.parametrize("kind", ["long", "int"])
def test_pitch_yaw_rates_stay_pitch_and_yaw_rates(kind):
    """Pitch 8°/s and yaw −20°/s at once: the Z-Y-X pitch and yaw change at those rates while the
    yaw turns (the device recomputes ω = ψ̇·e_z + θ̇·Rz(ψ)·e_y every control step)."""
    device = device_in_process()
    gcs = Client(device, 200)
    assert gcs.command(PITCHYAW, NAN, NAN, 8, -20, VEHICLE, 0, 154, kind=kind) == ACCEPTED
    run(device, 0.5)
    yaw0, pitch0 = device.yaw_in("vehicle"), device.pitch_in("vehicle")
    run(device, 1.0)
    yaw1, pitch1 = device.yaw_in("vehicle"), device.pitch_in("vehicle")
    assert abs((yaw1 - yaw0) - D(-20)) < 1e-4 and abs((pitch1 - pitch0) - D(8)) < 1e-4
    assert gcs.command(PITCHYAW, NAN, NAN, NAN, NAN, VEHICLE, 0, 154, kind=kind) == ACCEPTED  # flags only


def test_pitch_yaw_rates_to_angular_velocity_by_hand():
    # yaw 90° right: a pitch rate turns about −North (x), i.e. ω = (−θ̇, 0, ψ̇)
    assert np.allclose(angular_velocity_of_pitch_yaw_rates(D(90), 0.3, 0.2), (-0.3, 0.0, 0.2), atol=1e-15)
    assert np.allclose(angular_velocity_of_pitch_yaw_rates(0.0, 0.3, 0.2), (0.0, 0.3, 0.2), atol=1e-15)


@pytest.mark.parametrize("params", [
    (NAN, 200, NAN, NAN, VEHICLE, 0, 154),  # yaw beyond ±180°
    (-91, 0, NAN, NAN, VEHICLE, 0, 154),  # pitch beyond ±90°
    (math.inf, 0, NAN, NAN, VEHICLE, 0, 154),
    (NAN, NAN, NAN, 1e4, VEHICLE, 0, 154),  # 174 rad/s
    (0, 0, NAN, NAN, 32 | 64, 0, 154),  # both yaw frames
    (0, 0, NAN, NAN, VEHICLE, 0, 7),  # another gimbal
    (0, 0, NAN, NAN, NAN, 0, 154),  # flags not a number
])
def test_pitch_yaw_out_of_range_is_denied(params):
    device = device_in_process()
    assert Client(device, 200).command(PITCHYAW, *params) == DENIED
    assert device.handler_errors == 0


def test_status_about_five_times_a_second():
    """GIMBAL_MANAGER_STATUS on wall time while a lock-step device waits (about 5 Hz: between 3
    and 8 in 1.2 s leaves room for a slow machine)."""
    device = SimulatedGimbalDevice("udpin:127.0.0.1:0", simulated_gimbal(duration_s=1.0), lockstep=True)
    stop = threading.Event()
    thread = threading.Thread(target=device.run, args=(stop,), daemon=True)
    thread.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", 0))
        mav = mavlink.MAVLink(None, srcSystem=200, srcComponent=191)
        sock.sendto(mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav), ("127.0.0.1", device.link.local_address[1]))
        parser, times = mavlink.MAVLink(None), []
        sock.settimeout(0.05)
        end = time.monotonic() + 1.2
        while time.monotonic() < end:
            try:
                data = sock.recv(65535)
            except socket.timeout:
                continue
            times += [time.monotonic() for m in parser.parse_buffer(data) or () if m.get_type() == "GIMBAL_MANAGER_STATUS"]
    finally:
        stop.set()
        thread.join(LIVENESS_S)
        sock.close()
        device.close()
    assert 3 <= len(times) <= 8 and STATUS_PERIOD_S == 0.2


# ---------------------------------------------------------------------------------- MAVSDK
def test_mavsdk_gimbal_plugin_drives_the_device():
    """MAVSDK (the native `mavsdk` binding, BSD; no server process) on loopback UDP: the gimbal is
    listed, control taken, angles and rates set, control released. The device runs lock-step
    (heartbeats and manager status on wall time; MAVSDK needs no stepping) and a second client
    advances it; bounded by LIVENESS_S per wait."""
    mavsdk = pytest.importorskip("mavsdk", reason="the mavsdk wheel is not installed")
    from mavsdk.plugins.gimbal import ControlMode, Gimbal, GimbalMode, SendMode

    device = SimulatedGimbalDevice("udpin:127.0.0.1:0", simulated_gimbal(duration_s=10.0), LinkEffects(),
                                   lockstep=True)
    stop = threading.Event()
    thread = threading.Thread(target=device.run, args=(stop,), daemon=True)
    thread.start()
    port = device.link.local_address[1]
    stepper = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stepper.bind(("127.0.0.1", 0))
    stepper.connect(("127.0.0.1", port))
    stepper.settimeout(LIVENESS_S)
    mav = mavlink.MAVLink(None, srcSystem=250, srcComponent=190)

    def step(seconds):
        stepper.send(mav.command_long_encode(1, 154, STEP_COMMAND, 0, seconds, 0, 0, 0, 0, 0, 0).pack(mav))
        parser = mavlink.MAVLink(None)
        while True:
            for m in parser.parse_buffer(stepper.recv(65535)) or ():
                if m.get_type() == "COMMAND_ACK" and m.command == STEP_COMMAND and m.result == ACCEPTED:
                    return

    def until(predicate):
        deadline = time.monotonic() + LIVENESS_S
        while time.monotonic() < deadline:
            value = predicate()
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError("MAVSDK did not get there in time")

    sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION))
    try:
        assert sdk.add_any_connection(f"udpout://127.0.0.1:{port}") == mavsdk.ConnectionResult.SUCCESS
        system = until(lambda: (sdk.get_systems() or [None])[0])
        gimbal = Gimbal(system)
        (item,) = until(lambda: gimbal.gimbal_list().gimbals)
        assert (item.gimbal_manager_component_id, item.gimbal_device_id) == (154, 154)
        gimbal.take_control(item.gimbal_id, ControlMode.PRIMARY)
        sdk_id = (device.manager.primary[0], device.manager.primary[1])
        assert sdk_id[0] != 0 and until(lambda: gimbal.get_control_status(item.gimbal_id).control_mode
                                        == ControlMode.PRIMARY)
        gimbal.set_angles(item.gimbal_id, 0.0, -20.0, 30.0, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
        step(1.0)
        assert np.abs(device.q_rad - (D(-30), 0.0, D(-20))).max() < 1e-5
        gimbal.set_angular_rates(item.gimbal_id, 0.0, 0.0, 10.0, GimbalMode.YAW_FOLLOW, SendMode.ONCE)  # COMMAND_INT
        step(0.5)
        yaw0 = device.q_rad[0]
        step(0.5)
        assert abs((device.q_rad[0] - yaw0) / 0.5 - D(-10)) < 1e-4
        gimbal.release_control(item.gimbal_id)
        assert device.manager.primary == (0, 0)
        until(lambda: gimbal.get_control_status(item.gimbal_id).control_mode == ControlMode.NONE)
        assert device.handler_errors == 0 and device.commands_rejected == 0
    finally:
        sdk.destroy()
        stop.set()
        thread.join(LIVENESS_S)
        stepper.close()
        device.close()
