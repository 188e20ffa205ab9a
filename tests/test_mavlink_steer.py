"""Steering a MAVLink gimbal from track's detections (gimbal_lab.mavlink.steer, track --gimbal).

The gimbal is the lab's simulated device in real time (on a thread over loopback UDP, or as its
own process, ``gimbal-lab gimbal-device``); the video a still red ball right of and below the
image centre, written with realworld's helpers. Oracles: the ball's pixel position by projection,
the camera's turn by the kinematics (a command must move the ball's image towards the centre), the
device's own state (the last command it applied), and the rows of track.csv and gimbal.csv.

Time bounds here are liveness bounds (a process that never stops), not speed measurements: the
driver's silence timeout is 0.5 s and the stop is expected within about a second.
"""

from __future__ import annotations

import contextlib
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("pymavlink")

from gimbal_lab import realworld as rw  # noqa: E402
from gimbal_lab.camera import Intrinsics, project  # noqa: E402
from gimbal_lab.calibration import save_calibration  # noqa: E402
from gimbal_lab.mavlink import frames  # noqa: E402
from gimbal_lab.mavlink.driver import GimbalLinkLost, MavlinkGimbal  # noqa: E402
from gimbal_lab.mavlink.steer import GIMBAL_COLUMNS, GimbalSteer  # noqa: E402

CAM = Intrinsics.default()
BALL_M = np.array([0.4, 0.25, 3.0])  # camera frame: right of and below the optical axis
RADIUS_M = 0.10
LIVENESS_S = 60.0


def ball_frame():
    image = rw.sphere_photo(CAM, BALL_M, RADIUS_M, (0.2, 0.2, 0.2), colour=(0.6, 0.02, 0.02))
    effects = rw.PhotoEffects(paper=1.0, ink=0.0, uneven_light=0.0, vignetting=0.0, defocus_px=0.5, noise_std=0.0,
                              jpeg_quality=0)
    return effects.apply(image, np.random.default_rng(0))


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 20 s, 30 frames/s video of the still ball (long enough to be stopped)."""
    folder = tmp_path_factory.mktemp("steer")
    frame = ball_frame()
    return rw.write_video(folder / "ball.mp4", (frame for _ in range(600)), fps=30.0)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def device_process(*extra):
    """``gimbal-lab gimbal-device`` in real time as its own process (its own interpreter: a thread
    of this one falls behind real time on a loaded machine), behind a relay that reads every
    packet the driver sends with pymavlink's parser. Yields (process, the driver's address, the
    GIMBAL_DEVICE_SET_ATTITUDE messages the device was sent, in order)."""
    from pymavlink.dialects.v20 import common as mavlink

    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "gimbal_lab.cli", "gimbal-device", "--listen",
                                f"udpin:127.0.0.1:{port}", "--status-rate-hz", "50", *extra],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    front.bind(("127.0.0.1", 0))
    back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    back.bind(("127.0.0.1", 0))
    sent, stop = [], threading.Event()
    parser = mavlink.MAVLink(None)

    def relay():
        import select

        driver = None
        while not stop.is_set():
            ready, _, _ = select.select([front, back], [], [], 0.05)
            for sock in ready:
                try:
                    data, source = sock.recvfrom(65535)
                except ConnectionRefusedError:  # a datagram forwarded to a driver that has gone
                    continue
                if sock is front:
                    driver = source
                    for msg in parser.parse_buffer(data) or ():
                        if msg.get_type() == "GIMBAL_DEVICE_SET_ATTITUDE":
                            sent.append(msg)
                    back.sendto(data, ("127.0.0.1", port))
                elif driver is not None:
                    with contextlib.suppress(OSError):
                        front.sendto(data, driver)

    thread = threading.Thread(target=relay, daemon=True)
    thread.start()
    try:
        # the device is up once it answers (its interpreter takes seconds to start on a busy machine)
        MavlinkGimbal(f"udpout:127.0.0.1:{front.getsockname()[1]}", request_info=False,
                      discover_timeout_s=LIVENESS_S).close()
        yield process, f"udpout:127.0.0.1:{front.getsockname()[1]}", sent
    finally:
        stop.set()
        thread.join(LIVENESS_S)
        front.close()
        back.close()
        if process.poll() is None:
            process.kill()
        process.wait(LIVENESS_S)


def is_zero_rate(msg) -> bool:
    """A rate command (quaternion NaN) of zero angular velocity."""
    return (all(math.isnan(v) for v in msg.q)
            and (msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z) == (0.0, 0.0, 0.0))


def test_track_steers_the_gimbal_towards_the_target_and_logs_every_frame(tmp_path, video):
    """20 frames: a row per frame in gimbal.csv beside track.csv's, the detections the same, each
    command turns the camera so that the ball's image moves towards the centre, one command per
    frame went out, and closing sent zero rates."""
    uv_true = project(BALL_M[None], CAM)[0]
    with device_process() as (_, address, sent):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S)
        try:
            df = rw.track(video, tmp_path, "sphere", rw.Calibration(CAM, None), max_frames=20, progress=False,
                          video=False, gimbal=steer)
        finally:
            steer.close()
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert steer.stopped and steer.lost is None
        assert len(sent) == 21 and is_zero_rate(sent[-1])  # a command per frame, then the zero rates of close()
        assert not any(is_zero_rate(m) for m in sent[:-1])
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert list(log.columns) == list(GIMBAL_COLUMNS)
    assert log["frame"].tolist() == list(range(20)) == sorted(df["frame"].unique())
    assert log["detected"].all()
    np.testing.assert_allclose(log[["u_px", "v_px"]].to_numpy(), df[["u_px", "v_px"]].to_numpy(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(log[["u_px", "v_px"]].to_numpy(), np.tile(uv_true, (20, 1)), rtol=0, atol=1.0)
    assert log["report_time_s"].notna().iloc[5:].all()  # statuses at 50 Hz arrive from the start
    kin = steer.kinematics
    direction = BALL_M / np.linalg.norm(BALL_M)
    for row, msg in zip(log.itertuples(), sent):
        q = np.array([row.known_q_yaw_rad, row.known_q_roll_rad, row.known_q_pitch_rad])
        q = np.where(np.isfinite(q), q, 0.0)
        rate = np.array([row.cmd_yaw_rad_s, row.cmd_roll_rad_s, row.cmd_pitch_rad_s])
        # what went out is the logged command at the logged joints (float32 on the wire)
        omega = frames.joint_rates_to_angular_velocity(kin, q, rate)
        wire = np.array([msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z])
        np.testing.assert_allclose(wire, omega, rtol=2.0 ** -23, atol=1e-12)
        omega_cam = kin.angular_jacobian(q, frame="camera", check_limits=False) @ rate
        # the camera turned by ω dt: a fixed direction d is seen as d − (ω × d) dt
        seen = direction - np.cross(omega_cam, direction) * 0.01
        before = np.hypot(*(direction[:2] / direction[2]))
        after = np.hypot(*(seen[:2] / seen[2]))
        assert after < before, (row.frame, omega_cam)


@pytest.mark.parametrize("lands", ["before the frame is steered", "after its command went out"])
def test_ctrl_c_at_any_point_of_a_frame_keeps_a_gimbal_row_for_every_tracked_frame(tmp_path, video, monkeypatch,
                                                                                lands):
    """Ctrl-C lands at frame 10: just before ``frame`` runs (as when it arrives while track writes the
    frame's rows, and is raised as that block ends), or as the frame's command goes out (SIGINT
    itself, delivered inside the driver's send). Either way gimbal.csv has a row for every frame
    track kept, the last one without a command in the first case and with the command that was
    sent in the second."""
    interrupt_at = 10
    with device_process() as (_, address, sent):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S, pace=False)
        if lands == "before the frame is steered":
            steer_frame = steer.frame

            def frame(n, uv_px, fps):
                if n == interrupt_at:
                    raise KeyboardInterrupt
                return steer_frame(n, uv_px, fps)

            monkeypatch.setattr(steer, "frame", frame)
        else:
            send, calls = steer.driver.send_joint_rates, []

            def send_then_interrupt(rate, q):
                send(rate, q)
                calls.append(np.array(rate, float))
                if len(calls) == interrupt_at + 1:
                    signal.raise_signal(signal.SIGINT)  # Ctrl-C, as the datagram leaves

            monkeypatch.setattr(steer.driver, "send_joint_rates", send_then_interrupt)
        try:
            df = rw.track(video, tmp_path, "sphere", rw.Calibration(CAM, None), max_frames=30, progress=False,
                          video=False, gimbal=steer)
        finally:
            steer.close()
    assert df.attrs["interrupted"] and df.attrs["frames"] == interrupt_at + 1
    log = pd.read_csv(tmp_path / "gimbal.csv")
    kept = sorted(pd.read_csv(tmp_path / "track.csv")["frame"].unique())
    assert log["frame"].tolist() == kept == list(range(interrupt_at + 1))
    commands = log[["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].to_numpy()
    assert np.isfinite(commands[:interrupt_at]).all()
    if lands == "before the frame is steered":
        assert np.isnan(commands[interrupt_at]).all() and log["detected"].iloc[interrupt_at] == 1
        np.testing.assert_allclose(log[["u_px", "v_px"]].iloc[interrupt_at], df[["u_px", "v_px"]].iloc[-1],
                                   rtol=0, atol=1e-9)
    else:
        np.testing.assert_array_equal(commands[interrupt_at], calls[-1])


_TRACK = """
import sys
from gimbal_lab import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def test_ctrl_c_stops_the_gimbal_before_track_exits(tmp_path, video):
    """SIGINT to ``gimbal-lab track --gimbal``: it exits 130 after sending zero rates (the last
    command the device was sent), with a gimbal.csv row for every frame of track.csv."""
    yaml = save_calibration(tmp_path / "cam.yaml", rw.Calibration(CAM, None))
    out = tmp_path / "out"
    with device_process() as (_, address, sent):
        child = subprocess.Popen([sys.executable, "-c", _TRACK, "track", str(video), "--target", "sphere",
                                  "--calibration", str(yaml), "--out", str(out), "--gimbal", address, "--gimbal-wait", str(LIVENESS_S), "--no-progress",
                                  "--no-video"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + LIVENESS_S
            while not ((out / "gimbal.csv").exists() and len((out / "gimbal.csv").read_text().splitlines()) > 10):
                assert child.poll() is None and time.monotonic() < deadline, child.communicate()
                time.sleep(0.05)
            moving = len(sent)
            child.send_signal(signal.SIGINT)
            stdout, stderr = child.communicate(timeout=LIVENESS_S)
        finally:
            if child.poll() is None:
                child.kill()
        assert child.returncode == 130, stderr
        assert "stopped (zero rates sent)" in stdout, stdout
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert len(sent) > moving and is_zero_rate(sent[-1])
        assert not any(is_zero_rate(m) for m in sent[:-1])
    log = pd.read_csv(out / "gimbal.csv")
    frames = pd.read_csv(out / "track.csv")["frame"].unique()
    assert 10 <= len(log) and set(frames) <= set(log["frame"])
    assert log["frame"].tolist() == list(range(len(log)))


def test_a_killed_device_stops_tracking_with_a_message_and_no_row_lost(tmp_path, video):
    """The device process is killed mid-run: the next frames find it silent (0.5 s), track stops
    and keeps its frames, gimbal.csv holds a row for each (the last without a command), and the
    lost link names the silence."""
    killed_at = []
    with device_process() as (device, address, _):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=0.5, discover_timeout_s=LIVENESS_S)

        def kill_when_moving():
            deadline = time.monotonic() + LIVENESS_S
            while steer.rows < 15 and time.monotonic() < deadline:
                time.sleep(0.01)
            device.send_signal(signal.SIGKILL)
            killed_at.append(time.monotonic())

        killer = threading.Thread(target=kill_when_moving, daemon=True)
        killer.start()
        try:
            df = rw.track(video, tmp_path, "sphere", rw.Calibration(CAM, None), progress=False, video=False,
                          gimbal=steer)
            stopped_at = time.monotonic()
        finally:
            steer.close()
        killer.join(LIVENESS_S)
    assert isinstance(steer.lost, GimbalLinkLost) and "silent" in str(steer.lost)
    assert steer.lost.silence_s > 0.5
    assert df.attrs["interrupted"] and not steer.stopped
    assert stopped_at - killed_at[0] < 5.0  # liveness (expected: 0.5 s of silence plus a frame or two)
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert log["frame"].tolist() == list(range(df.attrs["frames"]))
    assert log.iloc[-1][["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].isna().all()
    assert log.iloc[:-1][["cmd_yaw_rad_s", "cmd_pitch_rad_s"]].notna().all().all()
    assert df.attrs["frames"] < 600
