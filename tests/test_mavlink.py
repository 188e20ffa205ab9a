"""The MAVLink gimbal driver and the simulated gimbal device, over loopback links only.

Encoding: the driver sends to a plain UDP socket and each datagram is decoded with a fresh
pymavlink parser and, for GIMBAL_DEVICE_SET_ATTITUDE, also by hand from the message set's wire
layout. Behaviour: the driver talks to the device (in a thread of this process, or the
``gimbal-lab gimbal-device`` command in a subprocess) on 127.0.0.1 or a pseudo-terminal; nothing
leaves the machine. Lock-step runs are exact (whole inner steps of 1 ms); real-time runs are
checked for liveness only, with generous timeouts.

Tolerances: a float32 field holds a value of magnitude <= 1 to 2⁻²⁴ ≈ 6e-8 (half an ulp), so a
quaternion's angle is good to about 2·2·6e-8 ≈ 2.4e-7 rad; slopes over 0.5 s of two such angles
to 1e-6 rad/s. The rate loops settle with time constants below 7 ms (their slowest closed-loop
pole, python-control, checked below), so 0.5 s after a command their transient is e^-70 of its
start: nothing but float32 rounding is left.
"""

import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tty
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink  # the oracle's parser, fresh per use

import gimbal_lab
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.mavlink import frames
from gimbal_lab.mavlink.device import LinkEffects, SimulatedGimbalDevice, firmware_version_word, simulated_gimbal
from gimbal_lab.mavlink.driver import GimbalCommandFailed, GimbalLinkLost, GimbalNotFound, MavlinkGimbal
from gimbal_lab.mavlink.link import FdLink, Link, SerialLink, open_link
from gimbal_lab.platform import BodyMotion

D = math.radians
F32 = 2.4e-7  # rad: a float32 quaternion's angle (module docstring)
# GIMBAL_DEVICE_FLAGS as the MAVLink common message set numbers them
ROLL_LOCK, PITCH_LOCK, YAW_LOCK, YAW_IN_VEHICLE_FRAME, YAW_IN_EARTH_FRAME, NEUTRAL = 4, 8, 16, 32, 64, 2
AT_PITCH_LIMIT = 2  # GIMBAL_DEVICE_ERROR_FLAGS_AT_PITCH_LIMIT
LIVENESS_S = 60.0  # generous bound for anything that must merely happen


# ---------------------------------------------------------------------------------- helpers
def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def running_device(*, kinematics=None, body=None, duration_s=30.0, lockstep=True, **kwargs):
    """A device on udpin:127.0.0.1:<free port> served by a thread; yields (device, driver address,
    the event that stops it)."""
    effect_names = set(LinkEffects.__dataclass_fields__)
    effects = LinkEffects(**{k: kwargs.pop(k) for k in list(kwargs) if k in effect_names})
    device = SimulatedGimbalDevice("udpin:127.0.0.1:0", simulated_gimbal(kinematics, body, duration_s), effects,
                                   lockstep=lockstep, **kwargs)
    stop, errors = threading.Event(), []

    def serve():
        try:
            device.run(stop)
        except BaseException as exc:  # surfaced by the test below
            errors.append(exc)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield device, f"udpout:127.0.0.1:{device.link.local_address[1]}", stop
    finally:
        stop.set()
        thread.join(LIVENESS_S)
        device.close()
    assert not errors, errors


@contextmanager
def lockstep_pair(**kwargs):
    with running_device(lockstep=True, **kwargs) as (device, address, _):
        with MavlinkGimbal(address, lockstep=True) as gimbal:
            yield device, gimbal


@contextmanager
def sniffer():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(LIVENESS_S)
    try:
        yield sock
    finally:
        sock.close()


def sniff(sock, kind):
    """The next datagram holding a message of type ``kind``: (message, raw bytes of the packet)."""
    parser = mavlink.MAVLink(None)
    while True:
        data, _ = sock.recvfrom(65535)
        for msg in parser.parse_buffer(data) or ():
            if msg.get_type() == kind:
                return msg, data


def cli(*args):
    return [sys.executable, "-m", "gimbal_lab.cli", "gimbal-device", *args]


def wait_for_line(proc, text, timeout_s=LIVENESS_S):
    """Read the subprocess's stdout until a line contains ``text``."""
    deadline = time.monotonic() + timeout_s
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if text in line:
            return line
    raise AssertionError(f"{text!r} never printed; output: {lines}, stderr: {proc.stderr.read() if proc.poll() is not None else ''}")


def slope(reports, joint, t0, t1):
    a = next(r for r in reports if abs(r.time_s - t0) < 1e-9)
    b = next(r for r in reports if abs(r.time_s - t1) < 1e-9)
    return (b.q_rad[joint] - a.q_rad[joint]) / (t1 - t0)


def test_rate_loops_settle_within_7_ms():
    """The premise of the rate tests' tolerance: every axis's closed rate loop has its slowest pole
    faster than 1/7 ms (python-control on the loop the mount runs)."""
    import control as ct

    from gimbal_lab.control import AxisPlant, RateLoop, closed_loop

    for axis in ("yaw", "roll", "pitch"):
        plant = AxisPlant.storm32(axis)
        loop = RateLoop(plant)
        T_ry, _ = closed_loop(plant, loop.gains, loop.pid.derivative_tau_s)
        assert -1.0 / max(ct.poles(T_ry).real) < 0.007


# ---------------------------------------------------------------------------------- encoding
def _hand_quaternion_30_minus_20():
    c15, s15, c10, s10 = math.cos(D(15)), math.sin(D(15)), math.cos(D(-10)), math.sin(D(-10))
    return np.array([c15 * c10, -s15 * s10, c15 * s10, s15 * c10])


@pytest.mark.parametrize("frame, flags", [("vehicle", ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME),
                                          ("earth", ROLL_LOCK | PITCH_LOCK | YAW_LOCK | YAW_IN_EARTH_FRAME)])
def test_set_attitude_encodes_yaw_30_pitch_minus_20(frame, flags):
    with sniffer() as sock, MavlinkGimbal(f"udpout:127.0.0.1:{sock.getsockname()[1]}", target=(1, 154),
                                          request_info=False) as gimbal:
        gimbal.send_attitude(D(30), D(-20), frame=frame)
        msg, raw = sniff(sock, "GIMBAL_DEVICE_SET_ATTITUDE")
    expected = _hand_quaternion_30_minus_20()
    assert np.abs(np.array(msg.q) - expected).max() < 6e-8
    assert msg.flags == flags
    assert all(math.isnan(v) for v in (msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z))
    assert (msg.target_system, msg.target_component) == (1, 154)
    assert (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 191)  # MAV_COMP_ID_ONBOARD_COMPUTER
    # MAVLink 2 framing, decoded by hand: magic 0xFD, payload length, flags, seq, sys, comp, 24-bit id 284
    magic, length, _, _, _, system, component = struct.unpack_from("<BBBBBBB", raw)
    message_id = int.from_bytes(raw[7:10], "little")
    assert (magic, system, component, message_id) == (0xFD, 1, 191, 284)
    # payload in the message set's wire order (largest types first): q[4], ωx, ωy, ωz (float),
    # flags (uint16), target system, target component (uint8); MAVLink 2 trims trailing zeros
    payload = raw[10:10 + length].ljust(32, b"\0")
    *q, wx, wy, wz, wire_flags, target_system, target_component = struct.unpack("<4f3fHBB", payload)
    assert np.abs(np.array(q) - expected).max() < 6e-8 and wire_flags == flags
    assert math.isnan(wx) and math.isnan(wy) and math.isnan(wz) and (target_system, target_component) == (1, 154)


def test_rate_commands_send_a_nan_quaternion():
    with sniffer() as sock, MavlinkGimbal(f"udpout:127.0.0.1:{sock.getsockname()[1]}", target=(1, 154),
                                          request_info=False) as gimbal:
        gimbal.send_rates([0.1, -0.2, 0.3], frame="earth")
        rates, _ = sniff(sock, "GIMBAL_DEVICE_SET_ATTITUDE")
        gimbal.send_joint_rates([0.5, 0.0, 0.0], q_rad=np.zeros(3))
        joint, _ = sniff(sock, "GIMBAL_DEVICE_SET_ATTITUDE")
        gimbal.send_camera_rates([0.0, 0.4, 0.0], q_rad=np.zeros(3))
        camera, _ = sniff(sock, "GIMBAL_DEVICE_SET_ATTITUDE")
    assert all(math.isnan(v) for v in rates.q)
    assert np.abs(np.array([rates.angular_velocity_x, rates.angular_velocity_y, rates.angular_velocity_z])
                  - (0.1, -0.2, 0.3)).max() < 6e-8
    assert rates.flags == ROLL_LOCK | PITCH_LOCK | YAW_LOCK | YAW_IN_EARTH_FRAME
    # the lab's yaw joint turning left at 0.5 rad/s is a yaw rate of −0.5 rad/s (z down) at home
    assert all(math.isnan(v) for v in joint.q) and joint.flags == ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME
    assert np.abs(np.array([joint.angular_velocity_x, joint.angular_velocity_y, joint.angular_velocity_z])
                  - (0.0, 0.0, -0.5)).max() < 6e-8
    # the camera turning about its own down axis pans right: +z
    assert np.abs(np.array([camera.angular_velocity_x, camera.angular_velocity_y, camera.angular_velocity_z])
                  - (0.0, 0.0, 0.4)).max() < 6e-8


def test_manager_pitch_yaw_and_heartbeat_encoding():
    with sniffer() as sock, MavlinkGimbal(f"udpout:127.0.0.1:{sock.getsockname()[1]}", target=(1, 154),
                                          request_info=False) as gimbal:
        heartbeat, raw = sniff(sock, "HEARTBEAT")
        gimbal.send_manager_pitch_yaw(pitch_rad=D(-20), yaw_rad=D(30))
        msg, _ = sniff(sock, "GIMBAL_MANAGER_SET_PITCHYAW")
    assert raw[0] == 0xFD and heartbeat.type == 18  # MAV_TYPE_ONBOARD_CONTROLLER
    assert (msg.target_system, msg.target_component, msg.gimbal_device_id) == (1, 1, 154)
    assert abs(msg.pitch - D(-20)) < 1e-7 and abs(msg.yaw - D(30)) < 1e-7
    assert math.isnan(msg.pitch_rate) and math.isnan(msg.yaw_rate)
    assert msg.flags == ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME


def test_bad_driver_input_is_named():
    with sniffer() as sock, MavlinkGimbal(f"udpout:127.0.0.1:{sock.getsockname()[1]}", target=(1, 154),
                                          request_info=False) as gimbal:
        with pytest.raises(ValueError, match="frame must be 'vehicle' or 'earth'"):
            gimbal.send_attitude(0.0, 0.0, frame="body")
        with pytest.raises(ValueError, match="omega_rad_s must be three finite numbers"):
            gimbal.send_rates([0.0, math.nan, 0.0])
        with pytest.raises(ValueError, match="q_rad is needed"):
            gimbal.send_joint_rates([0.1, 0.0, 0.0])
        with pytest.raises(GimbalCommandFailed, match="lockstep=True"):
            gimbal.step(0.1)
    with pytest.raises(ValueError, match="timeout_s must be a finite number > 0"):
        MavlinkGimbal("udpout:127.0.0.1:9", timeout_s=0)
    with pytest.raises(ValueError, match="udpin:HOST:PORT, udpout:HOST:PORT, a serial device path"):
        open_link("tcp:127.0.0.1:5760")
    with pytest.raises(ValueError, match="port of 'udpout:127.0.0.1:0' must be in 1..65535"):
        open_link("udpout:127.0.0.1:0")


def test_nobody_there_is_reported():
    port = free_udp_port()
    with pytest.raises(GimbalNotFound, match=f"no gimbal HEARTBEAT .* on udpout:127.0.0.1:{port} within 0.3 s"):
        MavlinkGimbal(f"udpout:127.0.0.1:{port}", discover_timeout_s=0.3)


# ---------------------------------------------------------------------------------- discovery and the stream
def test_discovery_and_information():
    with lockstep_pair() as (device, gimbal):
        info = gimbal.info
        assert gimbal.target == (1, 154)
        assert (info.vendor_name, info.firmware_version) == ("gimbal-lab", gimbal_lab.__version__)
        # the lab's limits (yaw ±170°, roll ±45°, pitch −90°..45°), yaw's sign turned, in float32
        assert np.allclose(info.yaw_limits_rad, (D(-170), D(170)), atol=1e-7)
        assert np.allclose(info.roll_limits_rad, (D(-45), D(45)), atol=1e-7)
        assert np.allclose(info.pitch_limits_rad, (D(-90), D(45)), atol=1e-7)
        assert np.allclose(info.joint_limits_rad, device.kinematics.joint_limits_rad, atol=1e-7)
        # HAS_NEUTRAL 2, ROLL_AXIS 4, ROLL_LOCK 16, PITCH_AXIS 32, PITCH_LOCK 128, YAW_AXIS 256,
        # YAW_FOLLOW 512, YAW_LOCK 1024, SUPPORTS_YAW_IN_EARTH_FRAME 4096; no roll/pitch follow
        assert info.cap_flags == 2 | 4 | 16 | 32 | 128 | 256 | 512 | 1024 | 4096


def test_information_turns_the_yaw_range():
    """A gimbal that yaws 100° right and 150° left: the protocol's yaw (positive right) spans
    −150°..100°."""
    kin = GimbalKinematics(joint_limits_rad=((D(-100), D(150)), (D(-30), D(40)), (D(-80), D(20))))
    with lockstep_pair(kinematics=kin) as (device, gimbal):
        info = gimbal.info
    assert np.allclose(info.yaw_limits_rad, (D(-150), D(100)), atol=1e-7)
    assert np.allclose(info.roll_limits_rad, (D(-30), D(40)), atol=1e-7)
    assert np.allclose(info.pitch_limits_rad, (D(-80), D(20)), atol=1e-7)
    assert np.allclose(info.joint_limits_rad, kin.joint_limits_rad, atol=1e-7)


@pytest.mark.parametrize("rate_hz", [50.0, 30.0])
def test_status_count_is_exact_in_lockstep(rate_hz):
    with lockstep_pair(status_rate_hz=rate_hz) as (device, gimbal):
        assert gimbal.step(1.0) == 1.0
        times_ms = [round(r.time_s * 1000) for r in gimbal.reports()]
    # a status every 1/rate s from one period after the start, at the first whole ms at or after it
    n = int(rate_hz)
    assert times_ms == [-(-k * 1000 // n) for k in range(1, n + 1)]


@pytest.mark.parametrize("omega, joint, joint_rate", [
    ((0.0, 0.0, 0.5), 0, -0.5),   # yawing right: the lab's yaw joint turns at −0.5 rad/s
    ((0.2, 0.0, 0.0), 1, 0.2),    # rolling right: roll joint +0.2 rad/s
    ((0.0, 0.3, 0.0), 2, 0.3),    # pitching up: pitch joint +0.3 rad/s
])
def test_rate_command_turns_its_joint_at_the_commanded_rate(omega, joint, joint_rate):
    with lockstep_pair(status_rate_hz=50.0) as (device, gimbal):
        gimbal.send_rates(omega)
        gimbal.step(1.0)
        reports = gimbal.reports()
    assert abs(slope(reports, joint, 0.5, 1.0) - joint_rate) < 1e-6
    others = [i for i in range(3) if i != joint]
    assert max(abs(r.q_rad[i]) for r in reports for i in others) < F32
    assert np.abs(reports[-1].angular_velocity_rad_s - omega).max() < 1e-6
    # the simulation's own joints agree with what the protocol carried
    assert abs(device.q_rad[joint] - reports[-1].q_rad[joint]) < F32


def test_attitude_command_converges():
    with lockstep_pair(status_rate_hz=50.0) as (device, gimbal):
        gimbal.send_attitude(D(30), D(-20))
        gimbal.step(1.0)
        report = gimbal.latest()
        assert np.abs(np.array(report.euler_rad) - (D(30), D(-20), 0.0)).max() < 1e-5
        # yaw 30° right is the lab's yaw joint at −30°; pitch −20° the pitch joint at −20°
        assert np.abs(report.q_rad - (D(-30), 0.0, D(-20))).max() < 1e-5
        assert np.abs(device.q_rad - report.q_rad).max() < 1e-5
        gimbal.send_neutral()
        gimbal.step(1.0)
        assert np.abs(gimbal.latest().q_rad).max() < 1e-5


def test_a_large_attitude_step_slews_at_the_rate_limit():
    with lockstep_pair(status_rate_hz=50.0, max_rate_rad_s=1.0) as (device, gimbal):
        gimbal.send_attitude(D(90), 0.0)  # 1.57 rad at 1 rad/s: still slewing from 0.2 s to 1.2 s
        gimbal.step(1.0)
        reports = gimbal.reports()
    assert abs(slope(reports, 0, 0.5, 1.0) + 1.0) < 1e-6


def test_earth_frame_on_a_turned_body():
    """The body faces 0.4 rad left of North (NED heading −0.4 rad): yaw 30° in the earth frame is
    30° + 0.4 rad right of the body's heading; in the vehicle frame it is 30° right of it."""
    with lockstep_pair(body=BodyMotion(yaw_rad=0.4)) as (device, gimbal):
        gimbal.send_attitude(D(30), D(-20), frame="earth")
        gimbal.step(1.0)
        report = gimbal.latest()
        assert report.frame == "vehicle" and report.flags & YAW_LOCK
        assert abs(report.delta_yaw_rad + 0.4) < 1e-7
        assert np.abs(np.array(report.euler_rad) - (D(30) + 0.4, D(-20), 0.0)).max() < 1e-5
        assert same_rotation(report.quaternion_in("earth"), _hand_quaternion_30_minus_20(), 1e-5)
        gimbal.send_attitude(D(30), D(-20), frame="vehicle")
        gimbal.step(1.0)
        assert np.abs(np.array(gimbal.latest().euler_rad) - (D(30), D(-20), 0.0)).max() < 1e-5


def same_rotation(a, b, tol):
    return min(np.abs(np.asarray(a) - b).max(), np.abs(np.asarray(a) + b).max()) < tol


def test_reports_on_a_swaying_body_are_the_camera_in_the_earth():
    """On a hovering body (sway and heading wander) the report, turned into the earth frame with
    its delta yaw, is the camera's true attitude: F·R_world_cam·R_cam_gimbal from the mount's own
    recorded joints and the body's pose (gimbal_lab.mount.camera_pose)."""
    F = np.diag([1.0, -1.0, -1.0])
    P = np.column_stack([(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
    with lockstep_pair(body=BodyMotion.hover(seed=2), duration_s=0.6, status_rate_hz=50.0) as (device, gimbal):
        gimbal.send_attitude(D(20), D(-10), frame="earth")
        gimbal.step(0.5)
        reports = gimbal.reports()
        camera_fn = device.mount.recorded_pose_fn(0.0, 0.5)
    headings = []
    for r in reports:
        _, T_world_cam = camera_fn(r.time_s)
        expected = frames.quaternion_from_matrix(F @ T_world_cam[:3, :3] @ P)
        assert same_rotation(r.quaternion_in("earth"), expected, 4 * F32)
        # delta yaw is the body's heading: its Z-Y-X yaw about up, with NED's sign (about down)
        R_world_body = device.body.T_world_body(r.time_s)[:3, :3]
        assert abs(r.delta_yaw_rad + math.atan2(R_world_body[1, 0], R_world_body[0, 0])) < 1e-7
        headings.append(r.delta_yaw_rad)
    assert np.ptp(headings) > 1e-3  # the heading did wander, so delta yaw was exercised


def test_joint_limit_stops_the_axis_and_is_flagged():
    with lockstep_pair(status_rate_hz=50.0) as (device, gimbal):
        gimbal.send_rates([0.0, 1.0, 0.0])  # pitch up at 1 rad/s towards +45°
        gimbal.step(2.0)
        reports = gimbal.reports()
    pitch = np.array([r.q_rad[2] for r in reports])
    assert pitch.max() <= D(45) + 1e-6
    assert D(45) - pitch[-1] < 1e-6
    assert reports[-1].failure_flags & AT_PITCH_LIMIT and not reports[0].failure_flags


# ---------------------------------------------------------------------------------- link effects
def test_latency_delays_statuses_and_commands():
    with lockstep_pair(status_rate_hz=50.0, latency_s=0.05) as (device, gimbal):
        gimbal.step(1.0)
        reports = gimbal.reports()
        # the sample of 0.94 s left at 0.99 s; that of 0.96 s leaves at 1.01 s
        assert len(reports) == 47 and reports[-1].time_s == 0.94
        gimbal.send_rates([0.0, 0.0, 0.5])  # sent at 1.00 s, takes effect at 1.05 s
        gimbal.step(0.5)
        reports = gimbal.reports()
    still = [r for r in reports if r.time_s <= 1.05]
    moving = [r for r in reports if r.time_s > 1.05]
    assert [r.time_s for r in still] == [0.96, 0.98, 1.0, 1.02, 1.04]
    # at rest the DH chain's cos(90°) offsets leave ~1e-16 rad; 10 ms of 0.5 rad/s is ~1e-3 rad
    assert all(abs(r.q_rad[0]) < 1e-12 for r in still)
    assert all(r.q_rad[0] < -1e-5 for r in moving)


def test_without_latency_the_command_acts_at_once():
    with lockstep_pair(status_rate_hz=50.0) as (device, gimbal):
        gimbal.step(1.0)
        gimbal.reports()
        gimbal.send_rates([0.0, 0.0, 0.5])
        gimbal.step(0.1)
        assert gimbal.reports()[0].q_rad[0] < -1e-5  # the sample at 1.02 s


def test_quantisation_of_reported_angles():
    quantum = D(0.1)

    def residues(reports):
        angles = np.array([r.euler_rad for r in reports])
        return np.abs(angles / quantum - np.round(angles / quantum)) * quantum

    with lockstep_pair(status_rate_hz=50.0, quantum_rad=quantum) as (device, gimbal):
        gimbal.send_rates([0.05, 0.3, 0.5])
        gimbal.step(1.0)
        coarse = residues(gimbal.reports())
    with lockstep_pair(status_rate_hz=50.0) as (device, gimbal):
        gimbal.send_rates([0.05, 0.3, 0.5])
        gimbal.step(1.0)
        fine = residues(gimbal.reports())
    assert coarse.max() < 1e-6  # on the 0.1° grid to float32 rounding
    assert fine.max() > 1e-4  # the exact angles are not


def _received_times(seed, loss, seconds=2.0):
    with lockstep_pair(status_rate_hz=50.0, loss=loss, seed=seed) as (device, gimbal):
        for _ in range(int(seconds / 0.2)):
            gimbal.step(0.2)
        reports = gimbal.reports()
        return [r.time_s for r in reports], [r.seq for r in reports], device.statuses_lost


def test_loss_is_seeded():
    times, seqs, lost = _received_times(seed=7, loss=0.3)
    again, _, _ = _received_times(seed=7, loss=0.3)
    other, _, _ = _received_times(seed=8, loss=0.3)
    # the n-th status is lost when the n-th draw of default_rng(seed).random() is below the loss
    draws = np.random.default_rng(7).random(100)
    expected = [round(0.02 * (n + 1), 2) for n in range(100) if draws[n] >= 0.3]
    assert [round(t, 2) for t in times] == expected and lost == 100 - len(expected)
    assert times == again and times != other
    # a lost status spends its sequence number: the receiver sees a gap of at least the losses
    sent = [round(0.02 * (n + 1), 2) for n in range(100)]
    for (t0, s0), (t1, s1) in zip(zip(times, seqs), zip(times[1:], seqs[1:])):
        lost_between = sent.index(round(t1, 2)) - sent.index(round(t0, 2)) - 1
        assert (s1 - s0) % 256 >= lost_between + 1


def test_commanded_only_reports_the_command():
    with lockstep_pair(status_rate_hz=50.0, commanded_only=True) as (device, gimbal):
        gimbal.send_attitude(D(30), D(-20))
        gimbal.step(0.02)
        report = gimbal.latest()
        # the commanded attitude at once, while the joints have hardly begun to move
        assert np.abs(np.array(report.euler_rad) - (D(30), D(-20), 0.0)).max() < F32
        assert abs(device.q_rad[0] - D(-30)) > D(20)
        assert np.all(np.isnan(report.angular_velocity_rad_s))
        gimbal.send_rates([0.0, 0.0, 0.5])
        gimbal.step(0.1)
        report = gimbal.latest()
        # the integral of the commanded rate from the commanded attitude: yaw 30° + 0.5·0.1 rad
        assert np.abs(np.array(report.euler_rad) - (D(30) + 0.05, D(-20), 0.0)).max() < F32
        assert np.abs(report.angular_velocity_rad_s - (0.0, 0.0, 0.5)).max() < 6e-8


def test_commanded_only_integrates_the_rate_up_to_each_status():
    """The commanded attitude is carried to the status's own step, however seldom the device
    re-maps its setpoint (here once a second): yaw 0.5 rad/s for 0.1 s is 0.05 rad at the status."""
    with lockstep_pair(status_rate_hz=50.0, commanded_only=True, control_period_s=1.0) as (_, gimbal):
        gimbal.send_rates([0.0, 0.0, 0.5])
        gimbal.step(0.1)
        report = gimbal.latest()
        assert report.time_s == pytest.approx(0.1, abs=1e-9)
        assert np.abs(np.array(report.euler_rad) - (0.05, 0.0, 0.0)).max() < F32


def test_lockstep_runs_are_identical():
    def run():
        with lockstep_pair(status_rate_hz=40.0, latency_s=0.013, loss=0.2, seed=3, quantum_rad=D(0.01)) as (_, gimbal):
            for k in range(10):
                gimbal.send_rates([0.1 * math.sin(k), 0.2, -0.3 * math.cos(k)])
                gimbal.step(0.05)
            gimbal.send_attitude(D(10), D(5))
            gimbal.step(0.3)
            return [(r.time_s, r.quaternion.tobytes(), r.angular_velocity_rad_s.tobytes()) for r in gimbal.reports()]

    first, second = run(), run()
    assert len(first) > 10 and first == second


def test_steps_past_the_end_or_in_real_time_are_refused():
    with lockstep_pair(duration_s=1.0) as (device, gimbal):
        assert gimbal.step(0.6) == 0.6
        with pytest.raises(GimbalCommandFailed, match="refused a step of 0.5 s .*DENIED.* clock is at 0.6 s"):
            gimbal.step(0.5)
        assert gimbal.step(0.4) == 1.0
    with running_device(lockstep=False) as (device, address, _):
        with MavlinkGimbal(address, lockstep=True) as gimbal:
            with pytest.raises(GimbalCommandFailed, match="DENIED"):
                gimbal.step(0.1)


# ---------------------------------------------------------------------------------- real time and liveness
def test_real_time_stream_and_a_stopped_device():
    with running_device(lockstep=False, status_rate_hz=20.0) as (device, address, stop):
        with MavlinkGimbal(address, timeout_s=0.5) as gimbal:
            first = gimbal.wait_report(timeout_s=LIVENESS_S)
            while gimbal.wait_report(timeout_s=LIVENESS_S).time_s < first.time_s + 0.5:
                pass
            times_ms = [round(r.time_s * 1000) for r in gimbal.reports()]
            # stamped on the simulated clock's grid: exactly every 50 ms, whatever the wall clock did
            assert len(times_ms) >= 10 and set(np.diff(times_ms)) == {50}
            stop.set()  # the device stops serving and falls silent
            with pytest.raises(GimbalLinkLost, match="is silent: no message from it for") as lost:
                while True:
                    gimbal.wait_report(timeout_s=LIVENESS_S)
            assert lost.value.silence_s > 0.5
            with pytest.raises(GimbalLinkLost):
                gimbal.latest()


def test_a_failing_link_is_reported():
    class Broken(Link):
        address = "broken"

        def read(self, timeout_s):
            raise OSError(5, "Input/output error")

        def write(self, data):
            pass

    gimbal = MavlinkGimbal(Broken(), target=(1, 154), request_info=False)
    try:
        with pytest.raises(GimbalLinkLost, match="the link broken failed: .*Input/output error"):
            gimbal.wait_report(timeout_s=LIVENESS_S)
    finally:
        gimbal.close()


def test_killed_device_process_is_noticed():
    port = free_udp_port()
    proc = subprocess.Popen(cli("--listen", f"udpin:127.0.0.1:{port}", "--status-rate-hz", "20"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_line(proc, "Ctrl-C stops")
        with MavlinkGimbal(f"udpout:127.0.0.1:{port}", discover_timeout_s=LIVENESS_S) as gimbal:
            gimbal.wait_report(timeout_s=LIVENESS_S)
            proc.kill()
            proc.wait(LIVENESS_S)
            killed = time.monotonic()
            with pytest.raises(GimbalLinkLost) as lost:
                while True:
                    gimbal.wait_report(timeout_s=LIVENESS_S)
            noticed = time.monotonic() - killed
        # the default timeout is 1 s of silence; this bound only guards against never noticing
        assert 1.0 < lost.value.silence_s and noticed < LIVENESS_S
    finally:
        proc.kill()
        proc.communicate()


def test_ctrl_c_exits_130_with_a_message():
    port = free_udp_port()
    proc = subprocess.Popen(cli("--listen", f"udpin:127.0.0.1:{port}"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_for_line(proc, "Ctrl-C stops")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=LIVENESS_S)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "gimbal-device: interrupted at" in out and "Traceback" not in err


@pytest.mark.parametrize("args, message", [
    (["--status-rate-hz", "0"], "--status-rate-hz must be in (0, 1000], got 0"),
    (["--status-rate-hz", "1e9"], "--status-rate-hz must be in (0, 1000], got 1e+09"),
    (["--loss", "1"], "--loss must be in [0, 1)"),
    (["--latency-s", "-0.1"], "--latency-s must be in [0, 10], got -0.1"),
    (["--latency-s", "1e12"], "--latency-s must be in [0, 10], got 1e+12"),
    (["--signing-key-file", "/no/such/key"], "--signing-key-file: signing key file /no/such/key: No such file"),
    (["--listen", "tcp:127.0.0.1:1"], "--listen: a link address must be udpin:HOST:PORT"),
    (["--listen", "/dev/no-such-port"], "--listen: cannot open serial port '/dev/no-such-port'"),
    (["--status-rate-hz", "fast"], "argument --status-rate-hz: invalid float value"),
])
def test_bad_arguments_give_one_line_and_exit_2(args, message, capsys):
    from gimbal_lab.cli import main

    with pytest.raises(SystemExit) as done:
        main(["gimbal-device", *args])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert done.value.code == 2 and len(lines) == 1, err
    assert message in lines[0] and lines[0].startswith("gimbal-lab gimbal-device: error:")


def test_without_the_extra_the_command_says_what_to_install(monkeypatch, capsys):
    from gimbal_lab.cli import main

    monkeypatch.setitem(sys.modules, "pymavlink", None)  # as if it were not installed
    assert main(["gimbal-device"]) == 1
    assert "needs pymavlink: pip install 'gimbal-lab[mavlink]'" in capsys.readouterr().err


def test_bad_argument_from_the_command_line():
    done = subprocess.run(cli("--loss", "2"), capture_output=True, text=True, timeout=LIVENESS_S)
    assert done.returncode == 2 and done.stderr.strip() == "gimbal-lab gimbal-device: error: --loss must be in [0, 1), got 2"


# ---------------------------------------------------------------------------------- serial links
def _pty_device():
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo or line editing before the device's pyserial takes the port
    proc = subprocess.Popen(cli("--listen", os.ttyname(slave), "--lockstep", "--status-rate-hz", "25"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return master, slave, proc


def test_serial_pseudo_terminal_lockstep():
    """The device command on the slave side of a pty pair (opened by pyserial as a serial port),
    the driver on the master side; Ctrl-C while the link is open stops the device with 130."""
    master, slave, proc = _pty_device()
    try:
        wait_for_line(proc, "Ctrl-C stops")
        with MavlinkGimbal(FdLink(master, address="pty"), lockstep=True, discover_timeout_s=LIVENESS_S) as gimbal:
            assert gimbal.target == (1, 154) and gimbal.info.model_name == "simulated yaw-roll-pitch"
            gimbal.send_rates([0.0, 0.3, 0.0])
            assert gimbal.step(1.0) == 1.0
            reports = gimbal.reports()
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=LIVENESS_S)
        assert [round(r.time_s * 1000) for r in reports] == list(range(40, 1001, 40))
        assert abs(slope(reports, 2, 0.6, 1.0) - 0.3) < 1e-6
    finally:
        proc.kill()
        os.close(slave)
    assert proc.returncode == 130 and "gimbal-device: interrupted at 1.000 s simulated" in out, (out, err)


def test_serial_pseudo_terminal_closed_by_the_controller():
    """When the controller closes its side of the pty the device says so and ends with 0
    (pyserial's "readiness to read but returned no data" is the hang-up, not an unexpected error)."""
    master, slave, proc = _pty_device()
    try:
        wait_for_line(proc, "Ctrl-C stops")
        with MavlinkGimbal(FdLink(master, address="pty"), lockstep=True, discover_timeout_s=LIVENESS_S) as gimbal:
            gimbal.send_rates([0.0, 0.3, 0.0])
            assert gimbal.step(0.2) == 0.2
        out, err = proc.communicate(timeout=LIVENESS_S)
    finally:
        proc.kill()
        os.close(slave)
    assert proc.returncode == 0 and "gimbal-device: link closed at 0.200 s simulated" in out, (out, err)
    assert err == ""


def test_loop_url_carries_a_packet_back():
    link = SerialLink("loop://")
    try:
        sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=154)
        packet = sender.gimbal_device_attitude_status_encode(0, 0, 1234, 44, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0,
                                                             0.0, 0.0, 0).pack(sender)
        link.write(packet)
        data = b""
        deadline = time.monotonic() + LIVENESS_S
        while len(data) < len(packet) and time.monotonic() < deadline:
            data += link.read(0.1)
        (msg,) = mavlink.MAVLink(None).parse_buffer(data)
        assert msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS" and msg.time_boot_ms == 1234
    finally:
        link.close()


# ---------------------------------------------------------------------------------- the device's parts
def test_device_parameters_are_checked():
    with pytest.raises(ValueError, match="status_rate_hz must be finite and > 0"):
        LinkEffects(status_rate_hz=0)
    with pytest.raises(ValueError, match="loss must be in"):
        LinkEffects(loss=1.0)
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        LinkEffects(seed=-1)
    with pytest.raises(ValueError, match="duration_s must be finite and > 0"):
        simulated_gimbal(duration_s=0)
    assert firmware_version_word("0.2.0") == 2 << 8 and firmware_version_word("1.2.3") == (3 << 16) | (2 << 8) | 1


# ---------------------------------------------------------------------------------- signing
def _stock_signer(key, *, system=1, component=191, timestamp=None):
    """A stock pymavlink sender signing with ``key`` (pymavlink's own signing is the oracle)."""
    from gimbal_lab.mavlink.signing import signing_timestamp

    sender = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    sender.signing.secret_key = key
    sender.signing.sign_outgoing = True
    sender.signing.timestamp = signing_timestamp() if timestamp is None else timestamp
    return sender


def _heartbeat_packet(sender):
    return sender.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(sender)


def _signed_receiver(key):
    from gimbal_lab.mavlink.protocol import new_mavlink
    from gimbal_lab.mavlink.signing import enable_signing

    receiver = new_mavlink(None, 1, 154)
    enable_signing(receiver, key)
    return receiver


def _kinds(receiver, packet):
    return [m.get_type() for m in receiver.parse_buffer(packet) or ()]


def test_signing_key_file_forms(tmp_path):
    from gimbal_lab.mavlink.signing import read_key

    key = bytes(range(32))
    (tmp_path / "raw").write_bytes(key)
    (tmp_path / "hex").write_text(key.hex().upper() + "\n")
    assert read_key(tmp_path / "raw") == key and read_key(tmp_path / "hex") == key
    for name, data, size in (("short", key[:31], 31), ("long", key + b"\n", 33), ("badhex", b"g" * 64, 64),
                             ("empty", b"", 0)):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match=rf"must hold 32 raw bytes or 64 hexadecimal characters, got {size} bytes"):
            read_key(tmp_path / name)
    with pytest.raises(ValueError, match="signing key file .*missing: No such file"):
        read_key(tmp_path / "missing")


def test_signing_refuses_unsigned_and_wrongly_signed_packets():
    """Accepted: signed with the key (by pymavlink's own signer). Refused and counted: unsigned
    MAVLink 2, MAVLink 1, another key, a replay of an accepted packet."""
    from gimbal_lab.mavlink.signing import refused_count

    key, other = bytes(range(32)), bytes(32 * [7])
    receiver = _signed_receiver(key)
    good = _heartbeat_packet(_stock_signer(key))
    assert _kinds(receiver, good) == ["HEARTBEAT"] and refused_count(receiver) == 0
    assert _kinds(receiver, good) == ["BAD_DATA"]  # the same packet again: a replay
    unsigned = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    assert _kinds(receiver, _heartbeat_packet(unsigned)) == ["BAD_DATA"]
    v1 = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    assert _kinds(receiver, v1.heartbeat_encode(6, 8, 0, 0, 0).pack(v1, force_mavlink1=True)) == ["BAD_DATA"]
    assert _kinds(receiver, _heartbeat_packet(_stock_signer(other))) == ["BAD_DATA"]
    assert refused_count(receiver) == 4
    # what this end sends is signed with the key: a stock receiver holding it accepts it
    stock = mavlink.MAVLink(None)
    stock.signing.secret_key = key
    reply = receiver.heartbeat_encode(26, 8, 0, 0, 4).pack(receiver)
    (msg,) = stock.parse_buffer(reply)
    assert msg.get_type() == "HEARTBEAT" and msg._signed


def test_a_forged_packet_cannot_block_the_real_sender():
    """A packet with a wrong signature but a time stamp far ahead does not move the stream's time
    stamp (pymavlink's own check records it first, and the real sender's packets would then be
    replays); the number of streams remembered is bounded."""
    from gimbal_lab.mavlink.signing import MAX_STREAMS, signing_timestamp

    key = bytes(range(32))
    receiver = _signed_receiver(key)
    now = signing_timestamp()
    forger = _stock_signer(bytes(32 * [9]), timestamp=now + 10**9)
    assert _kinds(receiver, _heartbeat_packet(forger)) == ["BAD_DATA"]
    assert _kinds(receiver, _heartbeat_packet(_stock_signer(key, timestamp=now + 1))) == ["HEARTBEAT"]
    for system in range(1, MAX_STREAMS + 20):
        assert _kinds(receiver, _heartbeat_packet(_stock_signer(key, system=system))) == ["HEARTBEAT"]
    assert len(receiver.signing.stream_timestamps) == MAX_STREAMS


def test_signed_device_answers_only_packets_signed_with_its_key():
    """Over loopback: with a key the device refuses (and counts) unsigned and wrongly signed
    requests, answers a signed one with packets signed with the key (checked by a stock pymavlink
    parser holding it), and only the signed sender becomes a client."""
    key = bytes(range(100, 132))
    with running_device(signing_key=key) as (device, address, _), sniffer() as sock:
        port = device.link.local_address[1]

        def request(sender):
            sock.sendto(sender.command_long_encode(1, 154, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 283, 0, 0, 0, 0, 0,
                                                   0).pack(sender), ("127.0.0.1", port))

        request(mavlink.MAVLink(None, srcSystem=1, srcComponent=191))
        request(_stock_signer(bytes(32)))
        deadline = time.monotonic() + LIVENESS_S
        while device.packets_refused < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert device.packets_refused == 2 and device.packets_dropped == 2 and device.clients == []
        request(_stock_signer(key))
        stock = mavlink.MAVLink(None)
        stock.signing.secret_key = key
        while True:
            data, _ = sock.recvfrom(65535)
            msgs = [m for m in stock.parse_buffer(data) or () if m.get_type() == "GIMBAL_DEVICE_INFORMATION"]
            if msgs:
                break
        assert msgs[0]._signed and device.clients == [sock.getsockname()]


def test_junk_from_another_socket_does_not_starve_the_client():
    """A real-time device streams 20 statuses a second to its client while another socket sends
    it a zero byte every 20 ms (before, each datagram's sender took the replies)."""
    with running_device(lockstep=False, status_rate_hz=20.0) as (device, address, _), sniffer() as sock, \
            sniffer() as junk:
        port = device.link.local_address[1]
        hello = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        sock.sendto(_heartbeat_packet(hello), ("127.0.0.1", port))
        parser, statuses = mavlink.MAVLink(None), 0
        sock.settimeout(0.02)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            junk.sendto(b"\x00", ("127.0.0.1", port))
            try:
                data = sock.recv(65535)
            except socket.timeout:
                continue
            statuses += sum(m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS" for m in parser.parse_buffer(data) or ())
        assert device.packets_dropped > 10 and device.clients == [sock.getsockname()]
    assert statuses >= 10  # 20 in the second; 10 leaves room for a slow machine


def test_clients_are_bounded():
    from gimbal_lab.mavlink.device import MAX_CLIENTS

    with running_device() as (device, address, _):
        port = device.link.local_address[1]
        socks = []
        try:
            for i in range(MAX_CLIENTS + 3):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
                socks.append(s)
                s.sendto(_heartbeat_packet(mavlink.MAVLink(None, srcSystem=2, srcComponent=191)), ("127.0.0.1", port))
                deadline = time.monotonic() + LIVENESS_S
                while s.getsockname() not in device.clients and time.monotonic() < deadline:
                    time.sleep(0.005)
            assert device.clients == [s.getsockname() for s in socks[-MAX_CLIENTS:]]
        finally:
            for s in socks:
                s.close()


def test_command_line_bounds_are_the_devices():
    from gimbal_lab.mavlink import cli as device_cli
    from gimbal_lab.mavlink.device import MAX_LATENCY_S, MAX_STATUS_RATE_HZ

    assert (device_cli._MAX_STATUS_RATE_HZ, device_cli._MAX_LATENCY_S) == (MAX_STATUS_RATE_HZ, MAX_LATENCY_S)
    with pytest.raises(ValueError, match=r"status_rate_hz must be finite and > 0 and <= 1000, got 1001"):
        LinkEffects(status_rate_hz=1001)
    with pytest.raises(ValueError, match=r"latency_s must be finite and >= 0 and <= 10, got 10.5"):
        LinkEffects(latency_s=10.5)
    done = subprocess.run(cli("--help"), capture_output=True, text=True, timeout=LIVENESS_S)
    text = " ".join(done.stdout.split())  # argparse wraps the help
    assert "status rate, Hz, in (0, 1000]" in text and "commands, s, in [0, 10]" in text


# ---------------------------------------------------------------------------------- limits and the seam
class _Recorder(Link):
    """A link that keeps the device's statuses, parsed by a fresh pymavlink parser."""

    def __init__(self):
        self.parser, self.statuses = mavlink.MAVLink(None), []

    def read(self, timeout_s):
        return b""

    def write(self, data):
        self.statuses += [m for m in self.parser.parse_buffer(data) or ()
                          if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]


def _in_process_device(duration_s, **kwargs):
    """A lock-step device driven by direct calls (no thread): (device, its recording link)."""
    link = _Recorder()
    return SimulatedGimbalDevice(link, simulated_gimbal(duration_s=duration_s), LinkEffects(status_rate_hz=100.0),
                                 lockstep=True, **kwargs), link


def _command_attitude(device, yaw_deg, pitch_deg=0.0, roll_deg=0.0, frame="vehicle"):
    """GIMBAL_DEVICE_SET_ATTITUDE of the Z-Y-X angles, as received off the wire."""
    sender = mavlink.MAVLink(None, srcSystem=200, srcComponent=191)
    flags = ROLL_LOCK | PITCH_LOCK | (YAW_IN_VEHICLE_FRAME if frame == "vehicle" else YAW_LOCK | YAW_IN_EARTH_FRAME)
    q = frames.quaternion_from_euler(D(yaw_deg), D(pitch_deg), D(roll_deg))
    packet = sender.gimbal_device_set_attitude_encode(1, 154, flags, [float(v) for v in q], math.nan, math.nan,
                                                      math.nan).pack(sender)
    (msg,) = mavlink.MAVLink(None).parse_buffer(packet)
    device.handle(msg)


def _run(device, seconds):
    """Advance ``seconds``; the yaw joint's path, rad, every 10 ms."""
    path = []
    for _ in range(int(round(seconds / 0.01))):
        device.advance_to(device._k + 10)
        path.append(device.q_rad[0])
    return np.array(path)


AT_YAW_LIMIT, AT_ROLL_LIMIT = 4, 1  # GIMBAL_DEVICE_ERROR_FLAGS


def settle_s(rate_rad_s=3.0):
    """The time the attitude law takes past its slew at the rate limit r: from the error r/k where
    the proportional law takes over down to 1e-5 rad, ln(r/(k·1e-5))/k (0.48 s at r = 3 rad/s and
    k = 20 /s), plus 0.05 s for the rate loops (time constants below 7 ms)."""
    return math.log(rate_rad_s / (20.0 * 1e-5)) / 20.0 + 0.05


SETTLE_S = settle_s()


def test_yaw_turns_the_way_inside_its_stops():
    """With ±170° yaw stops: the yaw joint from +170° to −170° turns back through 0 (340° at the
    3 rad/s limit, then the proportional tail) and arrives, never passing a stop and never flagged;
    from −170° to +90° it turns up through 0 (260°). (The protocol's yaw is the joint's, negated.)"""
    device, link = _in_process_device(8.0)
    _command_attitude(device, -170.0)  # joint +170°
    _run(device, 170 / math.degrees(3.0) + SETTLE_S)
    assert abs(device.q_rad[0] - D(170)) < 1e-5
    for target_deg, travel_deg in ((-170.0, 340.0), (90.0, 260.0)):
        start = len(link.statuses)
        _command_attitude(device, -target_deg)
        path = _run(device, travel_deg / math.degrees(3.0) + SETTLE_S)
        assert abs(device.q_rad[0] - D(target_deg)) < 1e-5, np.degrees(device.q_rad)
        assert np.all(np.abs(path) <= D(170) + 1e-9)
        steps = np.diff(path)
        assert np.all(steps * np.sign(D(target_deg) - path[0]) > -1e-9)  # one way, through 0
        assert not any(s.failure_flags & AT_YAW_LIMIT for s in link.statuses[start:])


@pytest.mark.parametrize("limits_deg", [{0: 170.0, 2: -90.0}, {0: -170.0, 2: 45.0}, {1: 45.0}, {1: -45.0}])
def test_targets_at_inside_and_beyond_each_limit(limits_deg):
    """Each joint's limits (yaw with pitch, roll alone): a target exactly at the limit is reached
    and not flagged; 0.1° inside, reached; 0.1° beyond, the joint goes to the limit (the nearest
    reachable attitude) and AT_*_LIMIT is reported while it is commanded. By hand, the Z-Y-X angles
    (yaw, pitch, 0) are the joints (−yaw, 0, pitch) and (0, 0, roll) the joints (0, roll, 0)."""
    flags = (AT_YAW_LIMIT, AT_ROLL_LIMIT, AT_PITCH_LIMIT)

    def command(offset_deg):
        joints = {j: limit + math.copysign(1.0, limit) * offset_deg for j, limit in limits_deg.items()}
        _command_attitude(device, -joints.get(0, 0.0), joints.get(2, 0.0), joints.get(1, 0.0))

    device, link = _in_process_device(4.0)
    command(0.0)
    _run(device, max(abs(v) for v in limits_deg.values()) / math.degrees(3.0) + SETTLE_S)
    for offset_deg in (0.0, -0.1, 0.1, 0.0):  # outward offsets are positive
        command(offset_deg)
        start = len(link.statuses)
        _run(device, SETTLE_S)
        expected = np.zeros(3)
        for j, limit in limits_deg.items():
            expected[j] = D(limit + math.copysign(1.0, limit) * min(offset_deg, 0.0))
        assert np.abs(device.q_rad - expected).max() < 1e-5, (offset_deg, np.degrees(device.q_rad))
        beyond = sum(flags[j] for j in limits_deg) if offset_deg > 0 else 0
        assert link.statuses[-1].failure_flags == beyond
        assert not any(s.failure_flags & ~beyond for s in link.statuses[start:])


_yaw_joint = st.floats(-170.0, 170.0)
_pitch_joint = st.floats(-90.0, 45.0)


@settings(max_examples=5, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(start=st.tuples(_yaw_joint, _pitch_joint), target=st.tuples(_yaw_joint, _pitch_joint))
def test_every_reachable_target_is_reached_in_the_time_its_rate_limit_implies(start, target):
    """From any reachable (yaw, pitch) joints to any other, the joints are within 1e-5 rad of the
    target after the largest joint travel at the rate limit plus settle_s (the slack: the
    proportional tail to 1e-5 rad and the rate loops' lag). Joints by hand as above. The rate limit
    is 6 rad/s here, to halve the simulated time."""
    rate = 6.0
    device, _ = _in_process_device(2 * (D(340) / rate + settle_s(rate)) + 0.1, max_rate_rad_s=rate)
    previous = np.zeros(3)
    for yaw_deg, pitch_deg in (start, target):
        goal = np.array([D(yaw_deg), 0.0, D(pitch_deg)])
        _command_attitude(device, -yaw_deg, pitch_deg)
        _run(device, np.abs(goal - previous).max() / rate + settle_s(rate))
        assert np.abs(device.q_rad - goal).max() < 1e-5, (np.degrees(device.q_rad), yaw_deg, pitch_deg)
        previous = goal


def test_reachable_joint_angle_by_hand():
    from gimbal_lab.mavlink.device import reachable_joint_angle as reach

    lo, hi = D(-170), D(170)
    assert reach(D(-170), D(170), lo, hi) == (D(-170), True)  # no turn of it lies across the stops
    assert reach(D(190), D(0), lo, hi) == (pytest.approx(D(-170)), True)  # 190° is −170°
    assert reach(D(175), D(0), lo, hi) == (hi, False) and reach(D(-175), D(0), lo, hi) == (lo, False)
    assert reach(D(180), D(100), lo, hi) == (hi, False) and reach(D(180), D(-100), lo, hi) == (lo, False)
    assert reach(D(170) + 5e-7, 0.0, lo, hi) == (hi, True)  # within float32's 2.4e-7 rad twice over
    assert reach(D(170) + 2e-6, 0.0, lo, hi) == (hi, False)
    # a joint with more than a turn of range: the turn nearest the joint now
    assert reach(D(10), D(300), D(-400), D(400)) == (pytest.approx(D(370)), True)
    assert reach(D(10), D(-300), -math.inf, math.inf) == (pytest.approx(D(-350)), True)


# ---------------------------------------------------------------------------------- the vehicle's attitude
def _autopilot_state(device, heading_deg, rate_rad_s=math.nan, *, feed_forward_rad_s=math.nan, delay_us=0, q=None):
    """AUTOPILOT_STATE_FOR_GIMBAL_DEVICE of a level vehicle heading ``heading_deg`` (right of North),
    as received off the wire."""
    sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    q = [math.cos(D(heading_deg) / 2), 0.0, 0.0, math.sin(D(heading_deg) / 2)] if q is None else q
    packet = sender.autopilot_state_for_gimbal_device_encode(
        1, 154, 0, q, delay_us, 0.0, 0.0, 0.0, 0, feed_forward_rad_s, 0, 0, rate_rad_s).pack(sender)
    (msg,) = mavlink.MAVLink(None).parse_buffer(packet)
    device.handle(msg)


@pytest.mark.parametrize("frame, joint_yaw_deg, earth_yaw_deg", [("earth", -50.0, 20.0), ("vehicle", -20.0, -10.0)])
def test_yaw_lock_holds_the_heading_and_follow_turns_with_the_vehicle(frame, joint_yaw_deg, earth_yaw_deg):
    """Yaw 20° right, pitch −10°; the autopilot reports the vehicle turning from North to −30° (at
    −60°/s, a state every 20 ms). Yaw lock (earth frame) holds the camera's heading at 20°: the yaw
    joint ends at −(20 − (−30)) = −50°. Follow (vehicle frame) keeps the joint at −20°: the heading
    turns with the vehicle to −10°. Reports: delta_yaw = −30°, earth yaw = reported yaw + delta_yaw."""
    device, link = _in_process_device(3.0)
    _autopilot_state(device, 0.0, 0.0)
    _command_attitude(device, 20.0, -10.0, frame=frame)
    _run(device, 1.0)
    assert abs(device.q_rad[0] - D(-20)) < 1e-5
    for i in range(1, 26):
        _autopilot_state(device, -30.0 * i / 25, D(-60) if i < 25 else 0.0)
        path = _run(device, 0.02)
        # the heading at the interval's end, carried forward with the rate: the joint tracks it
        # without lag (after the first state's 1.2° step has decayed at k = 20 /s) or holds still
        heading_deg = -30.0 * min(i + 1, 25) / 25
        ideal = D(heading_deg - 20.0) if frame == "earth" else D(-20.0)
        assert i < 15 or abs(path[-1] - ideal) < 1e-3, (i, np.degrees(path[-1]))
        assert frame == "earth" or np.abs(path - ideal).max() < 1e-6
    _run(device, 1.0)
    assert np.abs(device.q_rad - (D(joint_yaw_deg), 0.0, D(-10))).max() < 1e-5
    status = link.statuses[-1]
    yaw, pitch, _ = frames.euler_from_quaternion(status.q)
    assert abs(status.delta_yaw - D(-30)) < 1e-6 and abs(pitch - D(-10)) < 1e-5
    assert abs(yaw + status.delta_yaw - D(earth_yaw_deg)) < 1e-5
    assert device.autopilot_states_taken == 26


def test_an_attitude_and_an_angular_velocity_sent_together():
    """One AUTOPILOT_STATE_FOR_GIMBAL_DEVICE at t = 1 s: heading 10°, angular_velocity_z 0.5 rad/s,
    q_estimated_delay_us 20 ms. By hand the heading is 10° + 0.5·(t − 0.98 s) until 0.5 s after
    the sample (t = 1.48 s), then holds at 10° + 0.25 rad; delta_yaw_velocity is 0.5 then 0.
    With angular_velocity_z NaN the feed-forward rate is taken; a NaN attitude, a non-rotation or
    an infinite rate is refused."""
    from gimbal_lab.mavlink.device import AUTOPILOT_HORIZON_S

    device, link = _in_process_device(2.0)
    _run(device, 1.0)
    _autopilot_state(device, 10.0, 0.5, delay_us=20_000)
    start = len(link.statuses)
    _run(device, 0.8)
    checked = 0
    for status in link.statuses[start:]:
        t = status.time_boot_ms / 1000.0
        age = min(t - 0.98, AUTOPILOT_HORIZON_S)
        assert abs(status.delta_yaw - (D(10) + 0.5 * age)) < 1e-6, t
        assert status.delta_yaw_velocity == (0.5 if t - 0.98 < AUTOPILOT_HORIZON_S else 0.0)
        checked += 1
    assert checked == 80
    _autopilot_state(device, -5.0, feed_forward_rad_s=-0.3)
    _run(device, 0.1)
    assert abs(link.statuses[-1].delta_yaw - (D(-5) - 0.3 * 0.1)) < 1e-6
    for bad in (dict(q=[math.nan] * 4), dict(q=[3.0, 0.0, 0.0, 0.0]), dict(rate_rad_s=math.inf)):
        _autopilot_state(device, 0.0, **bad)
    assert (device.autopilot_states_taken, device.autopilot_states_rejected) == (2, 3)


def test_device_command_with_a_signing_key(tmp_path):
    """`gimbal-device --signing-key-file`: a key file of the wrong form is refused in one line
    (exit 2); with a good one the device refuses an unsigned request, answers a signed one and
    counts the refusal in its closing line (Ctrl-C, 130)."""
    bad = tmp_path / "bad.key"
    bad.write_text("g" * 64)
    done = subprocess.run(cli("--signing-key-file", str(bad)), capture_output=True, text=True, timeout=LIVENESS_S)
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        f"gimbal-lab gimbal-device: error: --signing-key-file: signing key file {bad} must hold 32 raw bytes or 64 "
        "hexadecimal characters, got 64 bytes"]
    key = bytes(range(7, 39))
    (tmp_path / "good.key").write_text(key.hex())
    port = free_udp_port()
    proc = subprocess.Popen(cli("--listen", f"udpin:127.0.0.1:{port}", "--lockstep", "--signing-key-file",
                                str(tmp_path / "good.key")), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert ", signed" in wait_for_line(proc, "Ctrl-C stops")
        with sniffer() as sock:
            for sender in (mavlink.MAVLink(None, srcSystem=1, srcComponent=191), _stock_signer(key)):
                sock.sendto(sender.command_long_encode(1, 154, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 283, 0, 0, 0, 0,
                                                       0, 0).pack(sender), ("127.0.0.1", port))
            info, _ = sniff(sock, "GIMBAL_DEVICE_INFORMATION")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=LIVENESS_S)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "1 packets dropped (1 refused for their signature)" in out, (out, err)
