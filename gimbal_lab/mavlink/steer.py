"""Steering a MAVLink gimbal from a live camera's detections (``gimbal-lab track --gimbal``).

:class:`GimbalSteer` is the paper's active loop on a real gimbal: each frame's detection (the
target's pixel centre) goes into the paper's PI image loop (Ziegler–Nichols for the source's
frame rate and one frame of latency, :meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`), at
the joints of the gimbal's latest GIMBAL_DEVICE_ATTITUDE_STATUS, and the
joint rates it gives are sent as GIMBAL_DEVICE_SET_ATTITUDE rates
(:meth:`gimbal_lab.mavlink.driver.MavlinkGimbal.send_joint_rates`). :func:`gimbal_lab.realworld.track`
calls :meth:`GimbalSteer.frame` once per frame and :meth:`GimbalSteer.close` at the end.

It never steers blind. It waits for the gimbal's first attitude status before the first frame,
and each frame checks the status it is about to use: a quaternion that is not finite or not of
unit norm (all zero included), an earth-frame attitude without the vehicle's heading, or a status
older than ``max_age_s`` (heartbeats alone do not keep it fresh) sends zero rates and stops
steering (:meth:`GimbalSteer.frame` returns False, :class:`UnusableAttitude` in
:attr:`GimbalSteer.failure`). A device silent for ``timeout_s`` does the same without the zero
rates (there is no link to send them on), with the driver's
:class:`~gimbal_lab.mavlink.driver.GimbalLinkLost`.

It writes ``gimbal.csv`` (columns :data:`GIMBAL_COLUMNS`), one row per frame, flushed as it is
written under a temporary name beside it and renamed into place on :meth:`GimbalSteer.close`
(kept after the end of the source, a stop or Ctrl-C; dropped after an error, when an earlier
run's file stays as it was): the detection, the report the loop used (its age at the moment it
was read, never negative) and the command sent. Closing it sends zero rates.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import time
from pathlib import Path

import numpy as np

from ..outputs import deferred_interrupts, temporary_name
from .driver import AttitudeReport, GimbalLinkError, GimbalNotFound, MavlinkGimbal

__all__ = ["GimbalSteer", "GIMBAL_COLUMNS", "UnusableAttitude", "attitude_problem", "MAX_AGE_S",
           "UNIT_NORM_TOLERANCE"]

#: The default oldest status the loop steers on, s: above the status period of a 5 Hz gimbal
#: (0.2 s, the slowest link of the link study) and below the default silence timeout (0.5 s).
MAX_AGE_S = 0.25
#: How far from 1 a status quaternion's norm may be (float32 rounding of a unit quaternion is
#: about 1e-7; a device that sends more is not sending an attitude).
UNIT_NORM_TOLERANCE = 1e-3

#: The columns of ``gimbal.csv``: the frame, the detection, the report the loop used (device
#: time, age on receipt, quaternion w x y z, joints) and the joint rates sent (rad/s).
GIMBAL_COLUMNS = ("frame", "t_s", "detected", "u_px", "v_px", "report_time_s", "report_age_s",
                  "report_qw", "report_qx", "report_qy", "report_qz",
                  "known_q_yaw_rad", "known_q_roll_rad", "known_q_pitch_rad",
                  "cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s")


class UnusableAttitude(GimbalLinkError):
    """The gimbal's attitude status cannot be steered on (not finite, not a unit quaternion, no
    heading for an earth-frame attitude, or too old); ``str()`` is one line saying which."""


def attitude_problem(report: AttitudeReport | None, read_s: float, max_age_s: float) -> str | None:
    """Why ``report``, read at ``read_s`` (``time.monotonic()``, s), cannot be steered on; None
    when it can.

    It cannot when there is none, when its quaternion as received is not finite or its norm is
    more than :data:`UNIT_NORM_TOLERANCE` from 1 (an all-zero quaternion included), when it gives
    no joint angles (an earth-frame attitude without the vehicle's heading), or when it was
    received more than ``max_age_s`` before ``read_s``.
    """
    if report is None:
        return "no attitude status has arrived"
    norm = report.quaternion_norm
    if not math.isfinite(norm):
        return "its attitude quaternion is not finite"
    if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
        return f"its attitude quaternion is not a unit quaternion (norm {norm:.6g})"
    if not np.all(np.isfinite(report.q_rad)):
        return "its attitude is in the earth frame and its heading (delta_yaw) is unknown"
    age_s = read_s - report.received_s
    if age_s > max_age_s:
        return f"its latest attitude status is {age_s:.2f} s old (at most {max_age_s:g} s)"
    return None


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
        How long to wait for the gimbal's first HEARTBEAT, and then for its first attitude
        status, s.
    max_age_s : float
        The oldest attitude status the loop steers on, s (> 0; :data:`MAX_AGE_S`): its age is
        the time since this process received it.
    say : callable, optional
        Called with a line of text while connecting: that it waits for a gimbal, and when the
        gimbal is found (the command line prints them).
    signing_key_file : str or os.PathLike, optional
        MAVLink 2 signing key for the link (:class:`~gimbal_lab.mavlink.driver.MavlinkGimbal`);
        None: no signing.
    via_manager : bool
        Steer through a gimbal manager (the device's own or an autopilot's) instead of the device:
        find it, take primary control (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE) before the first
        frame, send each frame's joint rates as GIMBAL_MANAGER_SET_PITCHYAW pitch and yaw rates
        (:meth:`~gimbal_lab.mavlink.driver.MavlinkGimbal.send_manager_joint_rates`; the manager
        holds roll), and release control on :meth:`close`. The attitude is still the device's
        status.

    Raises
    ------
    GimbalNotFound
        No gimbal heard, or no attitude status from it, within ``discover_timeout_s``.
    """

    def __init__(self, address, intrinsics, lens, out_dir, *, timeout_s: float = 0.5, pace: bool = True,
                 max_rate_rad_s: float | None = None, discover_timeout_s: float = 5.0, max_age_s: float = MAX_AGE_S,
                 say=None, signing_key_file=None, via_manager: bool = False):
        from ..config import Gimbal

        if isinstance(max_age_s, bool) or not isinstance(max_age_s, (int, float)) or not (
                max_age_s > 0 and math.isfinite(max_age_s)):
            raise ValueError(f"max_age_s must be a finite time > 0 s, got {max_age_s!r}")
        gimbal = Gimbal()
        self.kinematics = gimbal.kinematics
        self.intrinsics, self.lens = intrinsics, lens
        self.max_rate_rad_s = gimbal.max_joint_rate_rad_s if max_rate_rad_s is None else float(max_rate_rad_s)
        self.max_age_s = float(max_age_s)
        self.loop = None
        self.dt_s = math.nan
        self.pace = bool(pace)
        self.via_manager = bool(via_manager)
        self.path = Path(out_dir) / "gimbal.csv"
        say = say or (lambda line: None)
        say(f"waiting up to {discover_timeout_s:g} s for a gimbal on {address} ...")
        start = time.monotonic()
        self.driver = MavlinkGimbal(address, request_info=False, kinematics=self.kinematics, timeout_s=timeout_s,
                                    discover_timeout_s=discover_timeout_s, signing_key_file=signing_key_file)
        try:
            system, component = self.driver.target
            say(f"gimbal {system}/{component} found on {self.driver.address} after {time.monotonic() - start:.1f} s")
            try:
                self.driver.wait_report(discover_timeout_s)
            except TimeoutError:
                raise GimbalNotFound(f"gimbal {system}/{component} on {self.driver.address} sent no attitude status "
                                     f"(GIMBAL_DEVICE_ATTITUDE_STATUS) within {discover_timeout_s:g} s: it cannot be "
                                     f"steered without one{self.driver.refusals_note()}") from None
            if self.via_manager:
                manager = self.driver.find_manager(discover_timeout_s)
                self.driver.take_manager_control()
                say(f"gimbal manager {manager[0]}/{manager[1]} found; this driver is its primary control")
            self._tmp = temporary_name(self.path)
            self._handle = open(self._tmp, "w", newline="")
        except BaseException:
            self.driver.close()
            raise
        self._table = csv.writer(self._handle)
        self._table.writerow(GIMBAL_COLUMNS)
        self._handle.flush()
        self._start = None
        self.rows = 0
        self.stopped = False
        self.failure: GimbalLinkError | None = None

    @property
    def partial_path(self) -> Path:
        """The temporary name ``gimbal.csv`` is written under until :meth:`close`."""
        return self._tmp

    def frame(self, n: int, uv_px, fps: float) -> bool:
        """Steer on frame ``n``'s detection ``uv_px`` (pixel centre, or None: hold) of a source
        delivering ``fps`` frames per second (the loop is tuned for it on the first call).

        Returns True when the command went out; False when steering has stopped, with the
        reason in :attr:`failure`: the status to be used cannot be steered on
        (:func:`attitude_problem`; zero rates are sent and logged as the frame's command), or
        the device has been silent for ``timeout_s`` or the link failed (the frame's row has no
        command). The caller stops taking frames then.
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
        report, read_s, sent = None, now, np.full(3, math.nan)
        try:
            if self.pace:
                due = self._start + n * self.dt_s
                if due > now:
                    time.sleep(due - now)
                    now = time.monotonic()
            report = self.driver.latest()
            read_s = time.monotonic()
            problem = attitude_problem(report, read_s, self.max_age_s)
            if problem is not None:
                with deferred_interrupts():  # the zero rates and their record are one step
                    self._send_zero_rates()
                    self.stopped, sent = True, np.zeros(3)
                    system, component = self.driver.target
                    self.failure = UnusableAttitude(f"gimbal {system}/{component} on {self.driver.address}: {problem}; "
                                                    "zero rates sent")
                    self._write(n, now, detected, uv, report, read_s, sent)
                return False
            q = report.q_rad
            J_cam = self.kinematics.angular_jacobian(q, frame="camera", check_limits=False)
            rate = np.asarray(self.loop.update(uv if detected else None, self.dt_s, J_cam, q), float)
            with deferred_interrupts():  # what went out is what the row says
                if self.via_manager:
                    self.driver.send_manager_joint_rates(rate, q)
                else:
                    self.driver.send_joint_rates(rate, q)
                sent = rate
        except GimbalLinkError as exc:
            self.failure = exc
            self._write(n, now, detected, uv, report, read_s, sent)
            return False
        except KeyboardInterrupt:  # the frame's row (with the command if it went out), then stop
            if self.rows <= n:
                self._write(n, now, detected, uv, report, read_s, sent)
            raise
        self._write(n, now, detected, uv, report, read_s, sent)
        return True

    def unsteered(self, n: int, uv_px) -> None:
        """Stop the gimbal and log frame ``n``'s row with the zero rates as its command, unless
        the frame is logged already: for a frame whose :meth:`frame` call a Ctrl-C prevented (the
        caller had written the frame's own rows), so that ``gimbal.csv`` still has a row for every
        frame the caller kept. The row carries the latest status; without a link, no command."""
        if self.rows > n:
            return
        now = time.monotonic()
        if self._start is None:
            self._start = now
        with deferred_interrupts():
            try:
                report = self.driver.latest()
            except GimbalLinkError:
                report = None
            read_s = time.monotonic()
            sent = np.zeros(3) if self.stop() else np.full(3, math.nan)
            self._write(n, now, *_pixel(uv_px), report, read_s, sent)

    def _write(self, n, now, detected, uv, report, read_s, rate) -> None:
        if report is None:
            time_s, age_s, quat, q = math.nan, math.nan, np.full(4, math.nan), np.full(3, math.nan)
        else:
            time_s, age_s, quat, q = report.time_s, read_s - report.received_s, report.quaternion, report.q_rad
        with deferred_interrupts():  # a row is whole and counted, or absent
            self._table.writerow((n, now - self._start, int(detected), *uv, time_s, age_s, *quat, *q, *rate))
            self._handle.flush()
            self.rows += 1

    def _send_zero_rates(self) -> None:
        if self.via_manager:
            self.driver.send_manager_pitch_yaw(pitch_rate_rad_s=0.0, yaw_rate_rad_s=0.0)
        else:
            self.driver.send_rates(np.zeros(3))

    def stop(self) -> bool:
        """Send zero rates (the gimbal holds where it is); False when the link is already lost."""
        try:
            self._send_zero_rates()
        except GimbalLinkError:
            return False
        self.stopped = True
        return True

    def close(self, keep: bool = True) -> None:
        """Stop the gimbal (zero rates, when the link still works) and close the link; rename the
        log to ``gimbal.csv`` (``keep``), or delete it and leave an earlier ``gimbal.csv`` as it
        was (``keep=False``: the run failed, as ``track`` keeps its earlier files then)."""
        if self._handle.closed:
            return
        try:
            if self.stop() and self.via_manager:
                with contextlib.suppress(GimbalLinkError):  # a manager that does not answer keeps no one waiting
                    self.driver.release_manager_control(timeout_s=0.5, attempts=1)
        finally:
            self._handle.close()
            self.driver.close()
            with deferred_interrupts():
                if keep:
                    os.replace(self._tmp, self.path)
                else:
                    with contextlib.suppress(FileNotFoundError):
                        self._tmp.unlink()

    def __enter__(self) -> "GimbalSteer":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self.close(keep=kind is None or issubclass(kind, KeyboardInterrupt))


def _pixel(uv_px):
    """``(detected, uv)``: a frame's detection (pixel centre, or None) as the log records it."""
    detected = uv_px is not None
    return detected, (np.asarray(uv_px, float) if detected else np.full(2, math.nan))
