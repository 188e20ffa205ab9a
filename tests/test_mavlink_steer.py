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

from _loopback_gimbal import LoopbackGimbal, running  # noqa: E402  (tests/_loopback_gimbal.py)
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


class Sent(list):
    """The GIMBAL_DEVICE_SET_ATTITUDE messages the device was sent, in order; ``to_manager``: the
    GIMBAL_MANAGER_SET_PITCHYAW ones."""

    def __init__(self):
        super().__init__()
        self.to_manager = []


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
    sent, stop = Sent(), threading.Event()
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
                        elif msg.get_type() == "GIMBAL_MANAGER_SET_PITCHYAW":
                            sent.to_manager.append(msg)
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
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S, max_age_s=2.0)
        try:
            df = rw.track(video, tmp_path, "sphere", rw.Calibration(CAM, None), max_frames=20, progress=False,
                          video=False, gimbal=steer)
        finally:
            steer.close()
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert steer.stopped and steer.failure is None
        assert len(sent) == 21 and is_zero_rate(sent[-1])  # a command per frame, then the zero rates of close()
        assert not any(is_zero_rate(m) for m in sent[:-1])
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert list(log.columns) == list(GIMBAL_COLUMNS)
    assert log["frame"].tolist() == list(range(20)) == sorted(df["frame"].unique())
    assert log["detected"].all()
    np.testing.assert_allclose(log[["u_px", "v_px"]].to_numpy(), df[["u_px", "v_px"]].to_numpy(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(log[["u_px", "v_px"]].to_numpy(), np.tile(uv_true, (20, 1)), rtol=0, atol=1.0)
    assert log["report_time_s"].notna().all()  # the first status was awaited before the first frame
    assert (log["report_age_s"] >= 0).all()
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
    track kept, none of NaN: the last one has the status then and the zero rates that stopped
    the gimbal in the first case, the command that was sent in the second."""
    interrupt_at = 10
    with device_process() as (_, address, sent):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S, pace=False,
                            max_age_s=2.0)
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
    assert log[["report_time_s", "report_age_s", "report_qw", "known_q_yaw_rad"]].notna().all().all()
    assert (log["report_age_s"] >= 0).all()
    if lands == "before the frame is steered":
        np.testing.assert_array_equal(commands[interrupt_at], np.zeros(3))
        assert log["detected"].iloc[interrupt_at] == 1 and is_zero_rate(sent[-1])
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
    """SIGINT to ``gimbal-lab track --gimbal``: it said it was waiting, then that it found the
    gimbal; it exits 130 after sending zero rates (the last command the device was sent), with a
    gimbal.csv row for every frame of track.csv (written under a temporary name, then renamed)."""
    yaml = save_calibration(tmp_path / "cam.yaml", rw.Calibration(CAM, None))
    out = tmp_path / "out"
    with device_process() as (_, address, sent):
        child = subprocess.Popen([sys.executable, "-c", _TRACK, "track", str(video), "--target", "sphere",
                                  "--calibration", str(yaml), "--out", str(out), "--gimbal", address, "--gimbal-wait", str(LIVENESS_S), "--no-progress",
                                  "--no-video", "--gimbal-max-age", "2", "--gimbal-timeout", "2"], stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + LIVENESS_S

            def rows_so_far():
                partial = list(out.glob(".gimbal.partial-*.csv"))
                return len(partial[0].read_text().splitlines()) - 1 if partial else 0

            while rows_so_far() < 10:
                assert child.poll() is None and time.monotonic() < deadline, child.communicate()
                assert not (out / "gimbal.csv").exists()  # renamed into place only at the end
                time.sleep(0.05)
            moving = len(sent)
            child.send_signal(signal.SIGINT)
            stdout, stderr = child.communicate(timeout=LIVENESS_S)
        finally:
            if child.poll() is None:
                child.kill()
        assert child.returncode == 130, stderr
        assert "stopped (zero rates sent)" in stdout, stdout
        lines = stdout.splitlines()
        assert lines[0].startswith(f"waiting up to {LIVENESS_S:g} s for a gimbal on {address}"), stdout
        assert lines[1].startswith(f"gimbal 1/154 found on {address} after "), stdout
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert len(sent) > moving and is_zero_rate(sent[-1])
        assert not any(is_zero_rate(m) for m in sent[:-1])
    log = pd.read_csv(out / "gimbal.csv")
    frames = pd.read_csv(out / "track.csv")["frame"].unique()
    assert 10 <= len(log) and set(frames) <= set(log["frame"])
    assert log["frame"].tolist() == list(range(len(log)))
    assert not list(out.glob(".gimbal.partial-*"))


def test_a_killed_device_stops_tracking_with_a_message_and_no_row_lost(tmp_path, video):
    """The device process is killed mid-run: the next frames find it silent (0.5 s), track stops
    and keeps its frames, gimbal.csv holds a row for each (the last without a command), and the
    lost link names the silence."""
    killed_at = []
    with device_process() as (device, address, _):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=0.5, discover_timeout_s=LIVENESS_S,
                            max_age_s=5.0)  # the silence, not the status's age, stops it here

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
    assert isinstance(steer.failure, GimbalLinkLost) and "silent" in str(steer.failure)
    assert steer.failure.silence_s > 0.5
    assert df.attrs["interrupted"] and not steer.stopped
    assert stopped_at - killed_at[0] < 5.0  # liveness (expected: 0.5 s of silence plus a frame or two)
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert log["frame"].tolist() == list(range(df.attrs["frames"]))
    assert log.iloc[-1][["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].isna().all()
    assert log.iloc[:-1][["cmd_yaw_rad_s", "cmd_pitch_rad_s"]].notna().all().all()
    assert df.attrs["frames"] < 600


# ----------------------------------------------------------------------------------------------
# never steering blind: unusable attitudes, from a fake device and from the lab's
# ----------------------------------------------------------------------------------------------
GOOD_Q = frames.quaternion_from_euler(0.2, -0.1, 0.0)  # yaw right 0.2 rad, pitch down 0.1 rad
BAD_ATTITUDES = {  # the quaternion a device sends, and what the stop must say
    "nan": ((math.nan, 0.0, 0.0, 0.0), "not finite"),
    "inf": ((1.0, math.inf, 0.0, 0.0), "not finite"),
    "all zero": ((0.0, 0.0, 0.0, 0.0), "not a unit quaternion (norm 0)"),
    "norm 2": (tuple(2.0 * GOOD_Q), "not a unit quaternion (norm 2)"),
}


class FakeGimbal(LoopbackGimbal):
    """A gimbal device on a thread of the test, over loopback UDP (tests/_loopback_gimbal.py):
    its GIMBAL_DEVICE_ATTITUDE_STATUS every 0.02 s reports ``attitude(k)`` once k
    GIMBAL_DEVICE_SET_ATTITUDE commands have arrived (None: no status, the heartbeats go on)."""

    def __init__(self, attitude):
        super().__init__()
        self.attitude = attitude

    def quaternion(self):
        return self.attitude(len(self.commands))


def fake_gimbal(attitude):
    return running(FakeGimbal(attitude))


def test_attitude_problem_at_each_seam():
    """The checks of one report, at and either side of each limit: the norm within 1e-3 of 1 (the
    float32 quaternion of a real attitude is within 1e-7), the age up to max_age_s."""
    from gimbal_lab.mavlink.driver import AttitudeReport
    from gimbal_lab.mavlink.steer import UNIT_NORM_TOLERANCE, attitude_problem

    def report(norm, q_rad=(0.1, 0.0, -0.2), received_s=10.0):
        return AttitudeReport(time_s=1.0, received_s=received_s, quaternion=GOOD_Q, quaternion_norm=norm,
                              frame="vehicle", angular_velocity_rad_s=np.zeros(3), flags=0, failure_flags=0,
                              delta_yaw_rad=math.nan, delta_yaw_rate_rad_s=math.nan, seq=0, q_rad=np.array(q_rad))

    assert UNIT_NORM_TOLERANCE == 1e-3
    for norm in (1.0, 1.0 + 0.9e-3, 1.0 - 0.9e-3):
        assert attitude_problem(report(norm), 10.0, 0.25) is None, norm
    for norm in (1.0 + 1.1e-3, 1.0 - 1.1e-3, 0.0, 2.0):
        assert "not a unit quaternion" in attitude_problem(report(norm), 10.0, 0.25), norm
    for norm in (math.nan, math.inf):
        assert "not finite" in attitude_problem(report(norm), 10.0, 0.25)
    assert attitude_problem(report(1.0), 10.25, 0.25) is None  # exactly max_age_s old
    assert "0.26 s old (at most 0.25 s)" in attitude_problem(report(1.0), 10.26, 0.25)
    assert "heading" in attitude_problem(report(1.0, q_rad=(math.nan,) * 3), 10.0, 0.25)
    assert "no attitude status" in attitude_problem(None, 10.0, 0.25)


def steer_until_stopped(steer, frames_at_most=90):
    """Call ``steer.frame`` with a fixed detection until it returns False; how many returned True."""
    for n in range(frames_at_most):
        if not steer.frame(n, (400.0, 300.0), 30.0):
            return n
    raise AssertionError(f"still steering after {frames_at_most} frames")


def steer_until_stopped_then_close(steer, fake):
    """:func:`steer_until_stopped`, then the commands the device had got before ``steer`` closed
    (which sends zero rates of its own); steer is closed either way."""
    try:
        steered = steer_until_stopped(steer)
        time.sleep(0.2)  # the last datagram is on its way over loopback
        return steered, list(fake.commands)
    finally:
        steer.close()


def check_stopped_with_zero_rates(commands, log, steered):
    """The device got a command for each steered frame, then the stop's zero rates, before the
    loop closed; the log's rows agree, the last with the zero rates; no age is negative."""
    zero = [is_zero_rate(m) for m in commands]
    assert zero == [False] * steered + [True], zero
    assert len(log) == steered + 1 and log["frame"].tolist() == list(range(steered + 1))
    commands = log[["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].to_numpy()
    np.testing.assert_array_equal(commands[-1], np.zeros(3))
    assert np.isfinite(commands[:-1]).all() and (np.abs(commands[:-1]).max(axis=1) > 0).all()
    assert (log["report_age_s"] >= 0).all()
    # every steered frame used a good status: its quaternion as the fake sent it (float32)
    np.testing.assert_allclose(log[["report_qw", "report_qx", "report_qy", "report_qz"]].to_numpy()[:-1],
                               np.tile(GOOD_Q, (steered, 1)), rtol=0, atol=1e-6)


@pytest.mark.parametrize("case", sorted(BAD_ATTITUDES))
def test_a_bad_attitude_stops_steering_after_zero_rates(tmp_path, case):
    """The fake device's status turns bad after 5 commands: the loop steers on good statuses only,
    then sends zero rates and stops, saying what was wrong; gimbal.csv's last row holds the zero
    rates."""
    from gimbal_lab.mavlink.steer import UnusableAttitude

    bad_q, says = BAD_ATTITUDES[case]
    with fake_gimbal(lambda k: GOOD_Q if k < 5 else bad_q) as fake:
        steer = GimbalSteer(fake.address, CAM, None, tmp_path, timeout_s=5.0, discover_timeout_s=LIVENESS_S,
                            max_age_s=5.0)  # wide: only the bad quaternion may stop it, on a loaded machine too
        steered, commands = steer_until_stopped_then_close(steer, fake)
        assert steered >= 5 and steer.stopped
        assert isinstance(steer.failure, UnusableAttitude) and says in str(steer.failure), steer.failure
        assert str(steer.failure).endswith("zero rates sent") and "\n" not in str(steer.failure)
        log = pd.read_csv(tmp_path / "gimbal.csv")
        check_stopped_with_zero_rates(commands, log, steered)
    if case != "norm 2":  # a non-unit quaternion is logged normalised, the others as NaN
        assert log[["report_qw", "known_q_yaw_rad"]].iloc[-1].isna().all()


def test_statuses_that_stop_while_heartbeats_go_on_stop_steering_at_the_stated_age(tmp_path):
    """The fake device stops its statuses after 5 commands but keeps its heartbeats (so the link is
    not silent): the loop stops once its status is older than the default 0.25 s, with zero rates,
    and no later (within two frames of 1/30 s, plus scheduling)."""
    from gimbal_lab.mavlink.steer import MAX_AGE_S, UnusableAttitude

    with fake_gimbal(lambda k: GOOD_Q if k < 5 else None) as fake:
        steer = GimbalSteer(fake.address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S)
        steered, commands = steer_until_stopped_then_close(steer, fake)
        assert steered >= 5 and MAX_AGE_S == 0.25 and steer.max_age_s == MAX_AGE_S
        assert isinstance(steer.failure, UnusableAttitude) and "s old (at most 0.25 s)" in str(steer.failure)
        log = pd.read_csv(tmp_path / "gimbal.csv")
        check_stopped_with_zero_rates(commands, log, steered)
    ages = log["report_age_s"].to_numpy()
    assert ages[-1] > MAX_AGE_S and (ages[:-1] <= MAX_AGE_S).all()


def test_the_lab_device_reporting_at_2_hz_is_too_slow_for_a_max_age_of_0_1_s(tmp_path):
    """The lab's simulated device with a status every 0.5 s, against --gimbal-max-age 0.1 s: the
    loop steers on fresh statuses and stops, with zero rates, once the status is older than 0.1 s
    (within a status period of the first frame)."""
    from gimbal_lab.mavlink.steer import UnusableAttitude

    with device_process("--status-rate-hz", "2") as (_, address, sent):
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S,
                            max_age_s=0.1)
        try:
            steered = steer_until_stopped(steer, frames_at_most=30)
        finally:
            steer.close()
        time.sleep(0.2)
        assert isinstance(steer.failure, UnusableAttitude) and "(at most 0.1 s)" in str(steer.failure)
        assert sent and is_zero_rate(sent[-1]) and not any(is_zero_rate(m) for m in sent[:steered])
    log = pd.read_csv(tmp_path / "gimbal.csv")
    assert len(log) == steered + 1 and log["report_age_s"].iloc[-1] > 0.1
    assert (log["report_age_s"].iloc[:-1] <= 0.1).all() and (log["report_age_s"] >= 0).all()
    np.testing.assert_array_equal(log[["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].iloc[-1], 0.0)


def test_track_gimbal_stops_on_a_nan_attitude_with_exit_1_and_a_failed_rerun_keeps_gimbal_csv(tmp_path, video,
                                                                                              capsys):
    """``gimbal-lab track --gimbal`` against the fake device whose statuses turn NaN after 5
    commands: it says it waits, then that it found the gimbal, stops with one line naming the bad
    attitude (exit 1) and keeps gimbal.csv with a row per frame of track.csv. A rerun that fails
    (a calibration of another image size: exit 2) leaves that gimbal.csv and track.csv as they were,
    with no temporary file left."""
    from gimbal_lab import cli

    out = tmp_path / "out"
    yaml = save_calibration(tmp_path / "cam.yaml", rw.Calibration(CAM, None))
    argv = ["track", str(video), "--target", "sphere", "--out", str(out), "--no-progress", "--no-video",
            "--gimbal-wait", str(LIVENESS_S), "--gimbal-timeout", "5", "--gimbal-max-age", "5"]
    with fake_gimbal(lambda k: GOOD_Q if k < 5 else (math.nan,) * 4) as fake:
        assert cli.main(argv + ["--calibration", str(yaml), "--gimbal", fake.address]) == 1
    stdout, stderr = capsys.readouterr()
    lines = stdout.splitlines()
    assert lines[0] == f"waiting up to {LIVENESS_S:g} s for a gimbal on {fake.address} ...", stdout
    assert lines[1].startswith(f"gimbal 1/154 found on {fake.address} after "), stdout
    error = stderr.strip().splitlines()[-1]
    assert error.startswith("gimbal-lab track: error: steering stopped after frame ")
    assert "its attitude quaternion is not finite; zero rates sent" in error, stderr
    log, table = pd.read_csv(out / "gimbal.csv"), pd.read_csv(out / "track.csv")
    assert log["frame"].tolist() == sorted(table["frame"].unique()) and len(log) >= 6
    before = {name: (out / name).read_bytes() for name in ("gimbal.csv", "track.csv")}

    other = Intrinsics(CAM.fx / 2, CAM.fy / 2, CAM.cx / 2, CAM.cy / 2, CAM.width // 2, CAM.height // 2)
    small = save_calibration(tmp_path / "small.yaml", rw.Calibration(other, None))
    with fake_gimbal(lambda k: GOOD_Q) as fake, pytest.raises(SystemExit) as exit_:
        cli.main(argv + ["--calibration", str(small), "--gimbal", fake.address])
    assert exit_.value.code == 2 and "calibrate this camera at this resolution" in capsys.readouterr().err
    assert {name: (out / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in out.iterdir()) == ["gimbal.csv", "track.csv"]


def test_track_via_the_devices_own_manager_turns_the_gimbal_towards_the_target(tmp_path, video):
    """``--via-manager`` against the lab's device and its built-in manager (its own process): the
    driver takes control of manager 1/154, every frame's command goes out as
    GIMBAL_MANAGER_SET_PITCHYAW rates towards the ball (yaw right, pitch down), none as a device
    command, closing sends zero rates; the device's reported attitude turns right and down."""
    with device_process() as (_, address, sent):
        lines = []
        steer = GimbalSteer(address, CAM, None, tmp_path, timeout_s=2.0, discover_timeout_s=LIVENESS_S,
                            max_age_s=2.0, via_manager=True, say=lines.append)
        try:
            rw.track(video, tmp_path, "sphere", rw.Calibration(CAM, None), max_frames=15, progress=False,
                     video=False, gimbal=steer)
        finally:
            steer.close()
        time.sleep(0.2)  # the last datagram is on its way over loopback
        assert steer.failure is None and steer.stopped
        assert lines[-1] == "gimbal manager 1/154 found; this driver is its primary control"
        assert not sent and len(sent.to_manager) == 16
        *steering, last = sent.to_manager
        assert all(m.yaw_rate > 0 and m.pitch_rate < 0 and math.isnan(m.yaw) and math.isnan(m.pitch)
                   for m in steering)
        assert (last.yaw_rate, last.pitch_rate) == (0.0, 0.0)
    log = pd.read_csv(tmp_path / "gimbal.csv")
    first, final = (frames.euler_from_quaternion(log[["report_qw", "report_qx", "report_qy", "report_qz"]].iloc[k])
                    for k in (0, -1))
    assert final[0] > first[0] + 0.01 and final[1] < first[1] - 0.01, (first, final)  # yaw right, pitch down (rad)
