"""A gimbal device for tests: a thread of the test over loopback UDP, speaking through pymavlink's
generated code (not the lab's device, :mod:`gimbal_lab.mavlink.device`).

It answers whoever spoke to it last, sends a HEARTBEAT (MAV_TYPE_GIMBAL, component 154) every
0.1 s and a GIMBAL_DEVICE_ATTITUDE_STATUS every 0.02 s whose quaternion is :meth:`quaternion`'s
(None: no status, the heartbeats go on), and hands every message it parses to :meth:`received`,
which keeps each GIMBAL_DEVICE_SET_ATTITUDE in :attr:`commands`. Subclasses (the tests' gimbals
and vehicles) override those two and :meth:`tick` (more messages of their own, each loop turn).
With a signing ``key`` it signs what it sends with pymavlink's stock signing and refuses unsigned
or badly signed packets (counted in :attr:`refused`).
"""

from __future__ import annotations

import select
import socket
import threading
import time
from contextlib import contextmanager

from pymavlink.dialects.v20 import common as mavlink

#: How long a test waits for the thread to stop (a liveness bound, not a timing one).
LIVENESS_S = 60.0
EPOCH_2015_S = 1420070400.0  # the MAVLink signing time stamp counts 10 µs units from 2015-01-01 UTC


class LoopbackGimbal:
    """The device (module docstring); ``address`` is what a driver opens to reach it."""

    HEARTBEAT_S, STATUS_S = 0.1, 0.02

    def __init__(self, key: bytes | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address = f"udpout:127.0.0.1:{self.sock.getsockname()[1]}"
        self.peer, self.commands, self.stop = None, [], threading.Event()
        self.mav = mavlink.MAVLink(self, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_GIMBAL)
        if key is None:
            self.parser = mavlink.MAVLink(None)
        else:  # the sender's own object checks incoming signatures too
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.link_id = 0
            self.mav.signing.timestamp = int((time.time() - EPOCH_2015_S) * 1e5)
            self.mav.signing.allow_unsigned_callback = lambda mav, msg_id: False
            self.parser = self.mav
        self.parser.robust_parsing = True
        self.start_s = time.monotonic()

    def started(self):
        """Start the device's thread; returns the device."""
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        return self

    @property
    def refused(self) -> int:
        """Packets refused for their signature."""
        return self.mav.signing.reject_count

    def write(self, data: bytes) -> None:
        if self.peer is not None:
            self.sock.sendto(data, self.peer)

    def boot_ms(self, now: float) -> int:
        return int(1000 * (now - self.start_s))

    def received(self, msg) -> None:
        if msg.get_type() == "GIMBAL_DEVICE_SET_ATTITUDE":
            self.commands.append(msg)

    def quaternion(self):
        """The attitude the next status reports (w, x, y, z), or None for no status: level."""
        return (1.0, 0.0, 0.0, 0.0)

    def tick(self, now: float) -> None:
        """Called every turn of the loop after the device's own messages."""

    def _run(self) -> None:
        next_heartbeat = next_status = self.start_s
        while not self.stop.is_set():
            if select.select([self.sock], [], [], 0.005)[0]:
                data, self.peer = self.sock.recvfrom(65535)
                for msg in self.parser.parse_buffer(data) or ():
                    self.received(msg)
            now = time.monotonic()
            if now >= next_heartbeat:
                next_heartbeat = now + self.HEARTBEAT_S
                self.mav.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_AUTOPILOT_INVALID,
                                                                0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            if now >= next_status:
                next_status = now + self.STATUS_S
                q = self.quaternion()
                if q is not None:
                    self.mav.send(mavlink.MAVLink_gimbal_device_attitude_status_message(
                        0, 0, self.boot_ms(now), mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME,
                        [float(v) for v in q], 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0))
            self.tick(now)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(LIVENESS_S)
        self.sock.close()


@contextmanager
def running(device: LoopbackGimbal):
    """``device`` started, closed on the way out."""
    device.started()
    try:
        yield device
    finally:
        device.close()
