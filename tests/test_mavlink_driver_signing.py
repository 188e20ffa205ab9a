"""MAVLink 2 signing on the driver's side (MavlinkGimbal(signing_key_file=...), track --signing-key-file).

The device is a small one in the test that signs and checks with pymavlink's own signing code
(its stock signature check, an implementation independent of gimbal_lab.mavlink.signing), over
loopback UDP: with the driver's key it is found and commanded; with another key, or none, the
driver refuses its packets and it refuses the driver's, and nothing the driver sends is executed.
Time bounds are liveness bounds, not speed measurements.
"""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402
from _loopback_gimbal import LoopbackGimbal, running  # noqa: E402  (tests/_loopback_gimbal.py)

from gimbal_lab.mavlink.driver import GimbalNotFound, MavlinkGimbal  # noqa: E402

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
LIVENESS_S = 60.0


class SignedFakeGimbal(LoopbackGimbal):
    """A gimbal device on a thread over loopback UDP, pymavlink's generated code and its stock
    signing (``key`` None: unsigned, accepting anything): HEARTBEAT every 0.1 s, a level attitude
    status every 0.02 s, each GIMBAL_DEVICE_SET_ATTITUDE it accepts kept in :attr:`commands`;
    packets refused for their signature counted in :attr:`refused` (tests/_loopback_gimbal.py)."""


def signed_fake(key):
    return running(SignedFakeGimbal(key))


def key_file(tmp_path, key: bytes, name: str = "key.hex"):
    path = tmp_path / name
    path.write_text(key.hex() + "\n")
    return path


def test_with_the_same_key_the_driver_finds_the_device_and_its_signed_commands_are_executed(tmp_path):
    """Same key both ends: found, a status read, a command accepted by pymavlink's stock check (so
    it was signed with the key), nothing refused on either side."""
    with signed_fake(KEY) as fake:
        with MavlinkGimbal(fake.address, request_info=False, discover_timeout_s=LIVENESS_S,
                           signing_key_file=key_file(tmp_path, KEY)) as gimbal:
            assert gimbal.target == (1, mavlink.MAV_COMP_ID_GIMBAL) and gimbal.signed
            report = gimbal.wait_report(LIVENESS_S)
            np.testing.assert_allclose(report.quaternion, [1, 0, 0, 0], rtol=0, atol=1e-7)
            gimbal.send_rates([0.0, 0.1, 0.2])
            deadline = time.monotonic() + LIVENESS_S
            while not fake.commands and time.monotonic() < deadline:
                time.sleep(0.01)
            assert gimbal.refused_packets == 0
        assert fake.refused == 0 and fake.mav.signing.goodsig_count > 0
    command = fake.commands[0]
    assert command._signed  # pymavlink's flag: the packet carried a signature its check accepted
    np.testing.assert_allclose([command.angular_velocity_y, command.angular_velocity_z], [0.1, 0.2], rtol=1e-6)


@pytest.mark.parametrize("device_key, driver_key", [(KEY, OTHER_KEY), (None, KEY)],
                         ids=["another key", "an unsigned device"])
def test_a_driver_whose_key_is_not_the_devices_is_refused_both_ways(tmp_path, device_key, driver_key):
    """A device with another key, or an unsigned one: the driver refuses every packet it hears,
    finds no gimbal and says that packets were refused for their signature; a keyed device
    refuses the driver's packets (its heartbeats) and executes nothing."""
    with signed_fake(device_key) as fake:
        with pytest.raises(GimbalNotFound) as caught:
            MavlinkGimbal(fake.address, request_info=False, discover_timeout_s=1.5,
                          signing_key_file=key_file(tmp_path, driver_key))
        refused_by_device = fake.refused
        assert not fake.commands
    message = str(caught.value)
    assert "no gimbal HEARTBEAT" in message and "refused for their signature" in message, message
    assert int(message.split("; ")[-1].split()[0]) >= 10  # 1.5 s of 10 Hz heartbeats and 50 Hz statuses
    if device_key is not None:
        assert refused_by_device >= 1  # the driver's first HEARTBEAT at least


def test_an_unkeyed_driver_is_refused_by_a_keyed_device(tmp_path):
    """No key on the driver: it reads the signed device without a check (it has nothing to check
    with), but every command it sends is unsigned and the device refuses it."""
    with signed_fake(KEY) as fake:
        with MavlinkGimbal(fake.address, request_info=False, discover_timeout_s=LIVENESS_S) as gimbal:
            assert not gimbal.signed and gimbal.refused_packets == 0
            gimbal.wait_report(LIVENESS_S)
            before = fake.refused
            gimbal.send_rates([0.0, 0.1, 0.2])
            deadline = time.monotonic() + LIVENESS_S
            while fake.refused == before and time.monotonic() < deadline:
                time.sleep(0.01)
        assert fake.refused > before and not fake.commands


def test_a_bad_key_file_is_refused_in_one_line(tmp_path):
    short = tmp_path / "short.key"
    short.write_bytes(b"\x00" * 31)
    with pytest.raises(ValueError, match=r"^signing key file .*short.key must hold 32 raw bytes or 64 hexadecimal"):
        MavlinkGimbal("udpout:127.0.0.1:9", request_info=False, signing_key_file=short)
    with pytest.raises(ValueError, match=r"^signing key file .*missing.key: "):
        MavlinkGimbal("udpout:127.0.0.1:9", request_info=False, signing_key_file=tmp_path / "missing.key")


def test_track_gimbal_signs_with_its_key_file_and_a_wrong_key_is_refused(tmp_path, capsys):
    """``track --gimbal --signing-key-file``: GimbalSteer steers a keyed device with the same key
    (its commands pass the device's stock check); the command line with another key finds no
    gimbal and exits 2 in one line naming the refused packets, before any frame is read; the
    option without --gimbal is refused."""
    from gimbal_lab import cli
    from gimbal_lab.calibration import save_calibration
    from gimbal_lab.camera import Intrinsics
    from gimbal_lab.mavlink.steer import GimbalSteer
    from gimbal_lab.realworld import Calibration

    cam = Intrinsics.default()
    with signed_fake(KEY) as fake:
        steer = GimbalSteer(fake.address, cam, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S,
                            max_age_s=2.0, signing_key_file=key_file(tmp_path, KEY))
        try:
            assert all(steer.frame(n, (400.0, 300.0), 30.0) for n in range(3))
        finally:
            steer.close()
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert len(fake.commands) == 4 and all(m._signed for m in fake.commands) and fake.refused == 0

    yaml = save_calibration(tmp_path / "cam.yaml", Calibration(cam, None))
    argv = ["track", str(tmp_path / "never-read.mp4"), "--target", "sphere", "--calibration", str(yaml),
            "--out", str(tmp_path / "out"), "--no-progress", "--gimbal-wait", "1.5",
            "--signing-key-file", str(key_file(tmp_path, OTHER_KEY, "other.key"))]
    with signed_fake(KEY) as fake, pytest.raises(SystemExit) as exit_:
        cli.main(argv + ["--gimbal", fake.address])
    assert exit_.value.code == 2 and not fake.commands
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "no gimbal HEARTBEAT" in error and "refused for their signature" in error, error
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2 and "--signing-key-file needs --gimbal" in capsys.readouterr().err


def test_the_lab_device_with_a_key_is_steered_with_it_and_refuses_a_wrongly_keyed_driver(tmp_path):
    """``gimbal-lab gimbal-device --signing-key-file`` in its own process. A driver with its key
    finds it and turns it to yaw +0.5 rad. A driver with another key finds nothing (the device
    does not take it as a client), and its attitude commands to yaw −0.5 rad, sent to the device's
    address regardless, are not executed: the keyed driver still sees yaw +0.5 rad."""
    import subprocess
    import sys

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"udpout:127.0.0.1:{port}"
    process = subprocess.Popen([sys.executable, "-m", "gimbal_lab.cli", "gimbal-device", "--listen",
                                f"udpin:127.0.0.1:{port}", "--status-rate-hz", "50", "--signing-key-file",
                                str(key_file(tmp_path, KEY))], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    yaw_rad = 0.5
    try:
        # the right key first: its interpreter takes seconds to start on a busy machine
        with MavlinkGimbal(address, request_info=True, discover_timeout_s=LIVENESS_S, timeout_s=5.0,
                           signing_key_file=key_file(tmp_path, KEY)) as gimbal:
            assert gimbal.info is not None and gimbal.info.component_id == mavlink.MAV_COMP_ID_GIMBAL
            gimbal.send_attitude(yaw_rad, 0.0)
            deadline = time.monotonic() + LIVENESS_S
            while abs(gimbal.wait_report(LIVENESS_S).euler_rad[0] - yaw_rad) > 1e-3:
                assert time.monotonic() < deadline
            with pytest.raises(GimbalNotFound, match="no gimbal HEARTBEAT"):
                MavlinkGimbal(address, request_info=False, discover_timeout_s=1.0, component_id=192,
                              signing_key_file=key_file(tmp_path, OTHER_KEY, "other.key"))
            # another sender (component 192: two senders with one identity would be one signing stream)
            with MavlinkGimbal(address, target=gimbal.target, request_info=False, timeout_s=LIVENESS_S,
                               component_id=192, signing_key_file=key_file(tmp_path, OTHER_KEY, "other.key")) as stranger:
                for _ in range(10):
                    stranger.send_attitude(-yaw_rad, 0.0)
                    time.sleep(0.05)
            time.sleep(0.5)  # the device turns 1 rad in well under 0.5 s when it obeys (20 /s gain)
            report = gimbal.wait_report(LIVENESS_S)
            assert abs(report.euler_rad[0] - yaw_rad) < 1e-3, report.euler_rad
            assert gimbal.refused_packets == 0
        assert process.poll() is None  # the device is still up
    finally:
        process.kill()
        process.wait(LIVENESS_S)
