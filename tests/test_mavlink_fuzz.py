"""The simulated gimbal device under hostile input, over loopback UDP only: no packet ends it.

A lock-step device serves in a thread on 127.0.0.1; a plain UDP socket throws at it random bytes,
truncated frames, every message the device reads with NaN, ±inf, float32's largest values and
random integers in each field (MAVLink 2, and MAVLink 1 for the messages with ids below 256), and
checks after every batch that the device still answers a request, that its joints stay within
their limits, and that no handling failed (``handler_errors == 0``). Packets are built with
pymavlink's own encoder (the oracle of the wire format); every draw is seeded.

Cost: about 2,400 datagrams and 40 lock-step steps of 10 ms, a few seconds of CPU.
"""

import math
import socket
import threading
import time
from contextlib import contextmanager

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from gimbal_lab.mavlink.device import LinkEffects, SimulatedGimbalDevice, simulated_gimbal
from gimbal_lab.mavlink.protocol import STEP_COMMAND

LIVENESS_S = 30.0  # generous bound for an answer that must merely arrive
SYSTEM, COMPONENT = 1, mavlink.MAV_COMP_ID_GIMBAL
#: Messages the device reads.
READ = ("GIMBAL_DEVICE_SET_ATTITUDE", "COMMAND_LONG", "COMMAND_INT", "GIMBAL_MANAGER_SET_ATTITUDE",
        "GIMBAL_MANAGER_SET_PITCHYAW", "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE")
HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e-45, -0.0, 1e9)
INT_RANGES = {"uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535), "int16_t": (-32768, 32767),
              "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1), "uint64_t": (0, 2**64 - 1),
              "int64_t": (-2**63, 2**63 - 1)}


@contextmanager
def device_on_loopback(**kwargs):
    """A lock-step device on udpin:127.0.0.1:<free port> served by a thread; yields (device, a
    client socket connected to it)."""
    device = SimulatedGimbalDevice("udpin:127.0.0.1:0", simulated_gimbal(duration_s=30.0), LinkEffects(),
                                   lockstep=True, **kwargs)
    stop, errors = threading.Event(), []

    def serve():
        try:
            device.run(stop)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.connect(("127.0.0.1", device.link.local_address[1]))
    try:
        yield device, sock
    finally:
        stop.set()
        thread.join(LIVENESS_S)
        sock.close()
        device.close()
    assert not errors, errors


def client(system=200, component=mavlink.MAV_COMP_ID_ONBOARD_COMPUTER):
    return mavlink.MAVLink(None, srcSystem=system, srcComponent=component)


def wait_for(sock, predicate, timeout_s=LIVENESS_S):
    """The first message from the device for which ``predicate`` holds (AssertionError on timeout)."""
    parser = mavlink.MAVLink(None)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        sock.settimeout(max(deadline - time.monotonic(), 0.001))
        try:
            data = sock.recv(65535)
        except socket.timeout:
            break
        for msg in parser.parse_buffer(data) or ():
            if msg.get_type() != "BAD_DATA" and predicate(msg):
                return msg
    raise AssertionError("the device did not answer")


def ack_of(sock, command):
    return wait_for(sock, lambda m: m.get_type() == "COMMAND_ACK" and m.command == command
                    and m.result != mavlink.MAV_RESULT_IN_PROGRESS)


def request_information(sock, mav):
    sock.send(mav.command_long_encode(SYSTEM, COMPONENT, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                      mavlink.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, 0, 0, 0, 0, 0, 0).pack(mav))
    return wait_for(sock, lambda m: m.get_type() == "GIMBAL_DEVICE_INFORMATION")


def step(sock, mav, duration_s):
    sock.send(mav.command_long_encode(SYSTEM, COMPONENT, STEP_COMMAND, 0, duration_s, 0, 0, 0, 0, 0, 0).pack(mav))
    return ack_of(sock, STEP_COMMAND)


def assert_alive(device, sock, mav):
    """The device answers, its joints are within their limits and nothing it handled failed."""
    assert request_information(sock, mav).model_name == "simulated yaw-roll-pitch"
    assert step(sock, mav, 0.01).result == mavlink.MAV_RESULT_ACCEPTED
    q = device.q_rad
    lo = np.array([a for a, _ in device.kinematics.joint_limits_rad])
    hi = np.array([b for _, b in device.kinematics.joint_limits_rad])
    assert np.all(np.isfinite(q)) and np.all(q >= lo) and np.all(q <= hi), np.degrees(q)
    assert device.handler_errors == 0


def hostile_message(name, rng, *, addressed=True):
    """A message of type ``name`` with every field drawn from hostile values (seeded)."""
    cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
    types = dict(zip(cls.fieldnames, cls.fieldtypes))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    values = []
    for field in cls.fieldnames:
        kind, n = types[field], lengths[field]

        def one():
            if kind in ("float", "double"):
                return float(rng.choice(HOSTILE_FLOATS))
            if kind == "char":
                return bytes(rng.integers(0, 256, 1, dtype=np.uint8))
            lo, hi = INT_RANGES[kind]
            picks = [lo, hi, 0, int(rng.integers(lo, hi, endpoint=True, dtype=np.int64)) if hi < 2**63 else hi // 3]
            return picks[int(rng.integers(len(picks)))]  # an index: numpy would turn 2**64 - 1 into a float
        values.append([one() for _ in range(n)] if n else one())
    msg = cls(*values)
    if addressed and hasattr(msg, "target_system"):
        msg.target_system, msg.target_component = SYSTEM, int(rng.choice([0, COMPONENT]))
    if name in ("COMMAND_LONG", "COMMAND_INT") and rng.random() < 0.5:  # the commands the device knows
        msg.command = int(rng.choice([mavlink.MAV_CMD_REQUEST_MESSAGE, STEP_COMMAND,
                                      mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                                      mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE]))
    if hasattr(msg, "gimbal_device_id") and rng.random() < 0.7:  # mostly this gimbal (or all)
        msg.gimbal_device_id = int(rng.choice([0, COMPONENT]))
    return msg


def test_random_bytes_and_truncated_frames_do_not_stop_the_device():
    rng = np.random.default_rng(41)
    mav = client()
    valid = [mav.command_long_encode(SYSTEM, COMPONENT, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 283, 0, 0, 0, 0, 0,
                                     0).pack(mav),
             mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [1, 0, 0, 0], 0, 0, 0).pack(mav)]
    with device_on_loopback() as (device, sock):
        for batch in range(10):
            for _ in range(40):
                sock.send(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes())
            for _ in range(40):  # a frame's start (v2 or v1 marker) and random bytes
                marker = bytes([int(rng.choice([0xFD, 0xFE]))])
                sock.send(marker + rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes())
            for _ in range(40):  # a valid packet cut short, or with one byte flipped
                packet = bytearray(valid[int(rng.integers(len(valid)))])
                if rng.random() < 0.5:
                    packet = packet[:int(rng.integers(1, len(packet)))]
                else:
                    packet[int(rng.integers(len(packet)))] ^= 1 << int(rng.integers(8))
                sock.send(bytes(packet))
            assert_alive(device, sock, mav)
        assert device.packets_dropped > 100


@pytest.mark.parametrize("wire", ["mavlink2", "mavlink1"])
def test_every_message_the_device_reads_with_hostile_fields(wire):
    """NaN, ±inf, ±3.4e38 in every float field, extremes in every integer field, addressed to the
    device: each is refused or acted on, never fatal, and the joints stay within their limits."""
    rng = np.random.default_rng(42 if wire == "mavlink2" else 43)
    mav = client()
    names = [n for n in READ if wire == "mavlink2" or getattr(mavlink, f"MAVLINK_MSG_ID_{n}") < 256]
    with device_on_loopback() as (device, sock):
        for batch in range(15):
            for name in names:
                for _ in range(10):
                    msg = hostile_message(name, rng)
                    if msg.get_type() in ("COMMAND_LONG", "COMMAND_INT") and msg.command == STEP_COMMAND:
                        msg.param1 = float(rng.choice([math.nan, math.inf, -1.0, 3.4e38, 0.0, 0.003]))
                    sock.send(msg.pack(mav, force_mavlink1=wire == "mavlink1"))
            assert_alive(device, sock, mav)
        if wire == "mavlink2":
            assert device.commands_rejected > 0


def test_nan_quaternion_and_infinite_rates_are_refused():
    """The packets that once ended the device (issue 41): a NaN quaternion with two infinite rates,
    and REQUEST_MESSAGE with param1 NaN or inf (acknowledged DENIED)."""
    mav = client()
    nan, inf = math.nan, math.inf
    with device_on_loopback() as (device, sock):
        sock.send(mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [nan] * 4, inf, -inf, 0.0).pack(mav))
        sock.send(mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [inf, 0, 0, 0], nan, nan, nan).pack(mav))
        sock.send(mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [nan] * 4, 0.0, 101.0, 0.0).pack(mav))
        for param in (nan, inf, -1.0, 283.5):
            sock.send(mav.command_long_encode(SYSTEM, COMPONENT, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, param, 0, 0, 0,
                                              0, 0, 0).pack(mav))
            assert ack_of(sock, mavlink.MAV_CMD_REQUEST_MESSAGE).result == mavlink.MAV_RESULT_DENIED
        assert_alive(device, sock, mav)
        assert device.commands_rejected == 3 and device.commands_applied == 0
        # a rate just within the bound is taken
        sock.send(mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [nan] * 4, 0.0, 99.0, 0.0).pack(mav))
        assert_alive(device, sock, mav)
        assert device.commands_applied == 1


def test_a_torn_datagram_does_not_swallow_the_next_request():
    """A datagram holding only the start of a long frame (0xFD, length 255) is dropped whole: the
    next datagram's request is answered (a stream parser would wait for 255 more bytes)."""
    mav = client()
    with device_on_loopback() as (device, sock):
        for junk in (b"\xfd\xff", b"\xfe\xff\x00", b"\xfd"):
            sock.send(junk)
            assert request_information(sock, mav).get_type() == "GIMBAL_DEVICE_INFORMATION"
        assert device.packets_dropped == 3


def test_unknown_commands_are_acknowledged_unsupported():
    mav = client()
    with device_on_loopback() as (device, sock):
        sock.send(mav.command_long_encode(SYSTEM, COMPONENT, mavlink.MAV_CMD_DO_SET_SERVO, 0, 1, 2, 0, 0, 0, 0,
                                          0).pack(mav))
        assert ack_of(sock, mavlink.MAV_CMD_DO_SET_SERVO).result == mavlink.MAV_RESULT_UNSUPPORTED
        sock.send(mav.command_int_encode(SYSTEM, COMPONENT, 0, mavlink.MAV_CMD_DO_SET_SERVO, 0, 0, 1, 2, 0, 0, 0, 0,
                                         0).pack(mav))
        ack = ack_of(sock, mavlink.MAV_CMD_DO_SET_SERVO)
        assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED and (ack.target_system, ack.target_component) == (
            200, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)
        # the step command is a COMMAND_LONG only
        sock.send(mav.command_int_encode(SYSTEM, COMPONENT, 0, STEP_COMMAND, 0, 0, 0.01, 0, 0, 0, 0, 0, 0).pack(mav))
        assert ack_of(sock, STEP_COMMAND).result == mavlink.MAV_RESULT_UNSUPPORTED
        assert device.t_s == 0.0


def test_pending_commands_are_bounded():
    """With a latency, attitude commands wait in a queue; beyond MAX_PENDING_COMMANDS they are refused."""
    from gimbal_lab.mavlink.device import MAX_PENDING_COMMANDS

    device = SimulatedGimbalDevice("loop://", simulated_gimbal(duration_s=1.0), LinkEffects(latency_s=0.5),
                                   lockstep=True)
    try:
        mav = client()
        msg = mav.gimbal_device_set_attitude_encode(SYSTEM, COMPONENT, 0, [1, 0, 0, 0], 0, 0, 0)
        msg.pack(mav)
        for _ in range(MAX_PENDING_COMMANDS + 5):
            device.handle(msg)
        assert device.commands_rejected == 5 and len(device._incoming) == MAX_PENDING_COMMANDS
    finally:
        device.close()
