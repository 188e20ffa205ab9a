"""Steering a MAVLink gimbal from a live camera's detections (``gimbal-lab track --gimbal``).

:class:`GimbalSteer` is the paper's active loop on a real gimbal: each frame's detection (the
target's pixel centre) goes into the paper's PI image loop (Ziegler–Nichols for the source's
frame rate and one frame of latency, :meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`), at
the joints of the gimbal's latest GIMBAL_DEVICE_ATTITUDE_STATUS (home before the first), and the
joint rates it gives are sent as GIMBAL_DEVICE_SET_ATTITUDE rates
(:meth:`gimbal_lab.mavlink.driver.MavlinkGimbal.send_joint_rates`). :func:`gimbal_lab.realworld.track`
calls :meth:`GimbalSteer.frame` once per frame and :meth:`GimbalSteer.close` at the end.

It writes ``gimbal.csv`` (columns :data:`GIMBAL_COLUMNS`), one row per frame, flushed as it is
written: the detection, the report the loop used and the command sent. Closing it (after Ctrl-C,
the end of the source, an error) sends zero rates; a device silent for ``timeout_s`` makes the
next :meth:`GimbalSteer.frame` write its row without a command and return False, with the
driver's :class:`~gimbal_lab.mavlink.driver.GimbalLinkLost` in :attr:`GimbalSteer.lost`.
"""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np

from ..outputs import deferred_interrupts
from .driver import GimbalLinkError, MavlinkGimbal

__all__ = ["GimbalSteer", "GIMBAL_COLUMNS"]

#: The columns of ``gimbal.csv``: the frame, the detection, the report the loop used (device
#: time, age on receipt, quaternion w x y z, joints) and the joint rates sent (rad/s).
GIMBAL_COLUMNS = ("frame", "t_s", "detected", "u_px", "v_px", "report_time_s", "report_age_s",
                  "report_qw", "report_qx", "report_qy", "report_qz",
                  "known_q_yaw_rad", "known_q_roll_rad", "known_q_pitch_rad",
                  "cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s")


class GimbalSteer:
    """The paper's image loop steering a MAVLink gimbal device, one call per frame.

    Parameters
    ----------
    address : str
        The device's link (``udpout:HOST:PORT``, ``udpin:HOST:PORT``, a serial port), as
        :class:`~gimbal_lab.mavlink.driver.MavlinkGimbal` takes it; the first gimbal heard is used.
    intrinsics : gimbal_lab.camera.Intrinsics
        The camera's (from its calibration).
    lens : BrownConrady, KannalaBrandt or None
        The lens the loop knows (the calibration's).
    out_dir : str or os.PathLike
        Where ``gimbal.csv`` is written (an existing folder).
    timeout_s : float
        Silence of the device after which the run stops, s (> 0).
    pace : bool
        Take frame n no earlier than n / fps after the first (a file is played at its frame rate;
        a camera delivers frames at its own). The frame rate is the source's, given with each
        frame (:meth:`frame`): the loop's sample rate and the rate its gains are tuned for.
    max_rate_rad_s : float
        The joint-rate limit of the loop, rad/s (the lab's gimbal's).
    discover_timeout_s : float
        How long to wait for the gimbal's first HEARTBEAT, s.
    """

    def __init__(self, address, intrinsics, lens, out_dir, *, timeout_s: float = 0.5, pace: bool = True,
                 max_rate_rad_s: float | None = None, discover_timeout_s: float = 5.0):
        from ..config import Gimbal

        gimbal = Gimbal()
        self.kinematics = gimbal.kinematics
        self.intrinsics, self.lens = intrinsics, lens
        self.max_rate_rad_s = gimbal.max_joint_rate_rad_s if max_rate_rad_s is None else float(max_rate_rad_s)
        self.loop = None
        self.dt_s = math.nan
        self.pace = bool(pace)
        self.path = Path(out_dir) / "gimbal.csv"
        self.driver = MavlinkGimbal(address, request_info=False, kinematics=self.kinematics, timeout_s=timeout_s,
                                    discover_timeout_s=discover_timeout_s)
        self._handle = open(self.path, "w", newline="")
        self._table = csv.writer(self._handle)
        self._table.writerow(GIMBAL_COLUMNS)
        self._handle.flush()
        self._start = None
        self.rows = 0
        self.stopped = False
        self.lost: GimbalLinkError | None = None

    def frame(self, n: int, uv_px, fps: float) -> bool:
        """Steer on frame ``n``'s detection ``uv_px`` (pixel centre, or None: hold) of a source
        delivering ``fps`` frames per second (the loop is tuned for it on the first call).

        Returns True when the command went out; False when the device has been silent for
        ``timeout_s`` (or the link failed): the frame's row is written without a command and
        :attr:`lost` says what happened. The caller stops taking frames then.
        """
        now = time.monotonic()
        if self.loop is None:
            from ..control import ImageLoop

            if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
                raise ValueError(f"fps must be a frame rate > 0, got {fps!r}")
            self.dt_s = 1.0 / float(fps)
            self.loop = ImageLoop.ziegler_nichols(self.intrinsics, float(fps), 1, distortion=self.lens,
                                                  max_rate_rad_s=self.max_rate_rad_s)
        if self._start is None:
            self._start = now
        detected, uv = _pixel(uv_px)
        report, sent = None, np.full(3, math.nan)
        try:
            if self.pace:
                due = self._start + n * self.dt_s
                if due > now:
                    time.sleep(due - now)
                    now = time.monotonic()
            report = self.driver.latest()
            known = report is not None and np.all(np.isfinite(report.q_rad))
            q = report.q_rad if known else np.zeros(3)
            J_cam = self.kinematics.angular_jacobian(q, frame="camera", check_limits=False)
            rate = np.asarray(self.loop.update(uv if detected else None, self.dt_s, J_cam, q), float)
            with deferred_interrupts():  # what went out is what the row says
                self.driver.send_joint_rates(rate, q)
                sent = rate
        except GimbalLinkError as exc:
            self.lost = exc
            self._write(n, now, detected, uv, report, sent)
            return False
        except KeyboardInterrupt:  # the frame's row (with the command if it went out), then stop
            if self.rows <= n:
                self._write(n, now, detected, uv, report, sent)
            raise
        self._write(n, now, detected, uv, report, sent)
        return True

    def unsteered(self, n: int, uv_px) -> None:
        """Log frame ``n``'s row without a command, unless it is logged already: for a frame whose
        :meth:`frame` call a Ctrl-C prevented (the caller had written the frame's own rows), so
        that ``gimbal.csv`` still has a row for every frame the caller kept."""
        if self.rows > n:
            return
        now = time.monotonic()
        if self._start is None:
            self._start = now
        self._write(n, now, *_pixel(uv_px), None, np.full(3, math.nan))

    def _write(self, n, now, detected, uv, report, rate) -> None:
        if report is None:
            time_s, age_s, quat, q = math.nan, math.nan, np.full(4, math.nan), np.full(3, math.nan)
        else:
            time_s, age_s, quat, q = report.time_s, now - report.received_s, report.quaternion, report.q_rad
        with deferred_interrupts():  # a row is whole and counted, or absent
            self._table.writerow((n, now - self._start, int(detected), *uv, time_s, age_s, *quat, *q, *rate))
            self._handle.flush()
            self.rows += 1

    def stop(self) -> bool:
        """Send zero rates (the gimbal holds where it is); False when the link is already lost."""
        try:
            self.driver.send_rates(np.zeros(3))
        except GimbalLinkError:
            return False
        self.stopped = True
        return True

    def close(self) -> None:
        """Stop the gimbal (zero rates, when the link still works), close the log and the link."""
        try:
            self.stop()
        finally:
            self._handle.close()
            self.driver.close()

    def __enter__(self) -> "GimbalSteer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _pixel(uv_px):
    """``(detected, uv)``: a frame's detection (pixel centre, or None) as the log records it."""
    detected = uv_px is not None
    return detected, (np.asarray(uv_px, float) if detected else np.full(2, math.nan))
