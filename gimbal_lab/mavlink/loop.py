"""The closed loop's gimbal behind a MAVLink link: the lab's device in lock-step, driven through the driver.

:class:`LinkedGimbal` is what :func:`gimbal_lab.simulation.connect` gives the closed loop when a
run's ``pointing.link`` is set (:class:`gimbal_lab.config.GimbalLink`). It runs the run's own
gimbal (the :class:`gimbal_lab.mount.GimbalMount` that :meth:`gimbal_lab.config.Gimbal.mount`
builds from the config's Gimbal and Platform parts and seed, exactly as in-process) inside a
:class:`~gimbal_lab.mavlink.device.SimulatedGimbalDevice` served by a thread of this process on
``udpin:127.0.0.1:<free port>``, in lock-step, and talks to it through a
:class:`~gimbal_lab.mavlink.driver.MavlinkGimbal` over loopback UDP: every byte between the loop
and the gimbal is a MAVLink 2 packet of the real protocol.

What the loop knows and does (docs/design.md, "The link"):

* **joints**: those of the latest GIMBAL_DEVICE_ATTITUDE_STATUS received when a frame starts
  (:attr:`AttitudeReport.q_rad`), stale until the next status arrives, quantised and delayed as
  the link makes them; before the first status, the home pose (where the gimbal starts);
* **the frame's pose**: the camera pose of those joints on the body (whose pose the loop knows):
  the detection goes to the world through it, the truth through the mount's own pose;
* with ``pointing.link.attitude = "propagated"``, both carried from the status's time stamp to the
  instant they are used by the status's angular velocity (the rates last commanded when it has
  none): q + A(q)⁻¹·ω·age;
* **commands**: the outer loop's joint rates, sent once per frame as the angular velocity they
  give at the known joints (GIMBAL_DEVICE_SET_ATTITUDE, vehicle frame); the device maps them
  back to joint references on arrival and holds them until the next command (its
  ``control_period_s`` is the run's length), as the in-process loop holds its references. Then
  the driver steps the device by the frame's inner steps.

With a status every inner step and every effect off, a run equals the in-process run up to the
float32 fields of the messages: the same detections, and joints within :func:`equality_bound`,
until the first frame on which a multisample at the target's edge falls the other way (the joints
then differ by about 1e-8 rad, the target's image by 1e-5 px); from there on the two are the same
closed loop with another sub-pixel history (docs/design.md, "The link").
"""

from __future__ import annotations

import socket
import threading

import numpy as np

from ..mount import camera_pose
from .device import LinkEffects, SimulatedGimbalDevice
from .driver import MavlinkGimbal
from .frames import angular_velocity_to_joint_rates

__all__ = ["LinkedGimbal", "link_effects", "equality_bound", "F32_ANGLE_RAD"]

#: A joint angle carried by a float32 quaternion is good to this, rad (tests/test_mavlink.py).
F32_ANGLE_RAD = 2.4e-7

#: How long the driver waits for the device's answer to a step before it counts it lost, s of
#: wall time (a step of a frame takes milliseconds; the device reports progress every 0.25 s).
STEP_TIMEOUT_S = 10.0
#: The device's own joint-rate limit here, rad/s: none that binds (the in-process mount has none;
#: the outer loops limit their references themselves, 3 or 6 rad/s).
DEVICE_MAX_RATE_RAD_S = 1000.0


def equality_bound(q_rad, t_s, roll_gain_per_s: float = 2.0) -> np.ndarray:
    """How far the joints of a run through an effect-free link (a status every inner step) may
    drift from the in-process run's while both detect the same, rad, per frame and joint.

    With the same detections the outer loop's state is the same, and the two runs differ only
    where the joints enter it: the image loop's Jacobian at the known joints (off by a float32
    quaternion, :data:`F32_ANGLE_RAD`: the joint rates it gives are off by at most 2·F32 of
    themselves for the gimbal's near-orthonormal Jacobian), its roll levelling (``roll_gain_per_s``
    × F32, absolute), the float32 angular velocity on the wire (2⁻²⁴ relative) and the device's
    mapping back at the true joints (F32 relative again). Nothing feeds back while the detections
    agree, so the drift is at most these rates integrated, (2⁻²³ + 4·F32)·(the joint's path length
    so far) + roll_gain·F32·t, plus F32 for the reported joints themselves (twice each estimate).

    Parameters
    ----------
    q_rad : array_like, shape (n, 3)
        The in-process run's joint angles per frame, rad.
    t_s : array_like, shape (n,)
        The frames' instants from the run's start, s.

    Returns
    -------
    ndarray, shape (n, 3)
    """
    q = np.asarray(q_rad, dtype=float)
    path = np.vstack([np.zeros((1, 3)), np.cumsum(np.abs(np.diff(q, axis=0)), axis=0)])
    return (2.0 ** -23 + 4 * F32_ANGLE_RAD) * path + roll_gain_per_s * F32_ANGLE_RAD * np.asarray(t_s, float)[:, None] \
        + F32_ANGLE_RAD


def link_effects(config) -> LinkEffects:
    """The device's :class:`LinkEffects` of a run: its ``pointing.link`` with the losses seeded from
    stream 4 of the run's seed (:meth:`gimbal_lab.config.GimbalLink.effects_seed`)."""
    link = config.pointing.link
    return LinkEffects(status_rate_hz=link.status_rate_hz, latency_s=link.latency_s, quantum_rad=link.quantum_rad,
                       loss=link.loss, seed=link.effects_seed(config.seed), commanded_only=link.commanded_only)


class LinkedGimbal:
    """The outer loop's side of a gimbal behind a MAVLink link (module docstring); the same four
    calls as :class:`gimbal_lab.simulation.DirectGimbal`.

    Parameters
    ----------
    config : TrackingConfig
        The run; ``config.pointing.link`` gives the link's effects.
    mount : GimbalMount
        The run's gimbal, "active", not yet stepped: the device runs it, and it stays the truth.

    Attributes
    ----------
    device : SimulatedGimbalDevice
    driver : MavlinkGimbal
    """

    def __init__(self, config, mount):
        self.kinematics = mount.kinematics
        self.body = mount.body
        self.dt_s = mount.dt_s
        run_s = mount.n_steps * mount.dt_s
        self.device = SimulatedGimbalDevice("udpin:127.0.0.1:0", mount, link_effects(config), lockstep=True,
                                            max_rate_rad_s=DEVICE_MAX_RATE_RAD_S,
                                            control_period_s=max(run_s, self.dt_s))
        self._stop = threading.Event()
        self._errors: list[BaseException] = []
        self._thread = threading.Thread(target=self._serve, name="simulated gimbal device", daemon=True)
        self._thread.start()
        try:
            port = self.device.link.local_address[1]
            self.driver = MavlinkGimbal(f"udpout:127.0.0.1:{port}", target=(self.device.system_id,
                                                                              self.device.component_id),
                                        request_info=False, kinematics=self.kinematics, lockstep=True,
                                        timeout_s=STEP_TIMEOUT_S)
        except BaseException:
            self._shutdown()
            raise
        self._report = None
        self._home = np.zeros(3)
        self._propagate = config.pointing.link.attitude == "propagated"
        self._commanded = np.zeros(3)  # the joint rates last sent, rad/s

    def _serve(self) -> None:
        try:
            self.device.run(self._stop)
        except BaseException as exc:  # raised again by close()
            self._errors.append(exc)

    # ------------------------------------------------------------------ the loop's four calls
    def joint_rates(self, report) -> np.ndarray:
        """The joint rates a status implies, rad/s: its angular velocity (vehicle frame) through the
        gimbal's rates matrix at its joints, A(q)⁻¹·ω; the rates last commanded when it reports no
        angular velocity (NaN), is in the earth frame, or sits at the roll singularity."""
        omega = report.angular_velocity_rad_s
        if report.frame == "vehicle" and np.all(np.isfinite(omega)):
            try:
                return angular_velocity_to_joint_rates(self.kinematics, report.q_rad, omega)
            except ValueError:
                pass
        return self._commanded.copy()

    def _known(self, t_s: float) -> np.ndarray:
        """The joints the loop takes for the instant ``t_s``: the latest status's (home before the
        first); with ``attitude="propagated"`` carried forward to ``t_s`` by its joint rates times
        its age (never backward: a status from after ``t_s`` is used as it is)."""
        if self._report is None:
            return self._home.copy()
        q = self._report.q_rad.copy()
        age = t_s - self._report.time_s
        if self._propagate and age > 0:
            q = q + self.joint_rates(self._report) * age
        return q

    def joints(self, t_s: float) -> np.ndarray:
        """The joints of the latest status received when the frame at ``t_s`` starts (home before the
        first; propagated to ``t_s`` when the link says so), rad; the status is kept as the frame's
        knowledge for :meth:`frame_pose`."""
        report = self.driver.latest()
        self._report = report if report is not None and np.all(np.isfinite(report.q_rad)) else None
        return self._known(t_s)

    def frame_pose(self, t_s: float, q_truth, T_world_cam_truth):
        """``(q, T_world_cam, age_s)`` the loop maps the frame's detection with: the known joints on the
        body at the truth instant ``t_s`` (propagated to it when the link says so), and the status's
        age then (NaN before the first status)."""
        q = self._known(t_s)
        age = np.nan if self._report is None else t_s - self._report.time_s
        return q, camera_pose(self.kinematics, self.body, q, t_s), float(age)

    def drive(self, n_steps: int, rate_ref, q_known) -> None:
        """Send ``rate_ref`` (joint rates, rad/s) at the known joints ``q_known``, then step the device
        ``n_steps`` inner steps (lock-step: its statuses of the step arrive before it returns)."""
        self.driver.send_joint_rates(rate_ref, q_known)
        self._commanded = np.asarray(rate_ref, dtype=float).copy()
        self.driver.step(n_steps * self.dt_s)

    def close(self) -> None:
        """Stop the device's thread and close both ends; raise what the device's thread raised."""
        self._shutdown()
        if self._errors:
            raise RuntimeError(f"the simulated gimbal device failed: {self._errors[0]!r}") from self._errors[0]

    def _shutdown(self) -> None:
        self._stop.set()
        driver = getattr(self, "driver", None)
        if driver is not None:
            driver.close()
        # an empty datagram wakes the device's thread from its read at once (it polls every 50 ms)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as wake:
            wake.sendto(b"", ("127.0.0.1", self.device.link.local_address[1]))
        self._thread.join(5.0)
        self.device.close()
