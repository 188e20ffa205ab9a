"""Byte links for MAVLink: UDP (``udpin:``/``udpout:``), serial ports, pyserial URLs, file descriptors.

A link moves raw bytes; framing and parsing are pymavlink's. The address strings follow the
MAVLink tools' usage:

* ``udpin:HOST:PORT`` – bind HOST:PORT and answer whoever sent the last datagram (a device waiting
  for its controller; nothing is sent until a first datagram arrives);
* ``udpout:HOST:PORT`` – send to HOST:PORT from an ephemeral port and read the answers there;
* a device path (``/dev/ttyUSB0``, ``/dev/pts/3``) – a serial port at ``baud``;
* a pyserial URL (``loop://``, ``socket://HOST:PORT``, ...) – through ``serial.serial_for_url``;
* :class:`FdLink` – an open file descriptor, e.g. the master side of ``os.openpty()``.
"""

from __future__ import annotations

import errno
import os
import select
import socket

__all__ = ["Link", "LinkClosed", "UdpLink", "SerialLink", "FdLink", "open_link", "parse_udp_address"]

_MAX_DATAGRAM = 65535


class LinkClosed(OSError):
    """The other side of a serial link went away (a pty whose master was closed, a USB adapter unplugged)."""


class Link:
    """A bidirectional byte link: :meth:`read` with a timeout, :meth:`write`, :meth:`close`."""

    #: The address it was opened with, for messages.
    address: str = ""

    def read(self, timeout_s: float) -> bytes:
        """Bytes received within ``timeout_s`` seconds (b"" when none arrived)."""
        raise NotImplementedError

    def write(self, data: bytes) -> None:
        """Send ``data`` (a whole MAVLink packet on a datagram link)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the link (idempotent)."""


def parse_udp_address(address: str) -> tuple[str, str, int]:
    """``("udpin" | "udpout", host, port)`` of ``udpin:HOST:PORT`` or ``udpout:HOST:PORT``.

    Port 0 is allowed for ``udpin`` (bind to a free port: :attr:`UdpLink.local_address` tells which).

    Raises
    ------
    ValueError
        When the address is not of that form or the port is not in 1..65535 (0..65535 for udpin).
    """
    kind, _, rest = address.partition(":")
    host, sep, port_text = rest.rpartition(":")
    if kind not in ("udpin", "udpout") or not sep or not host:
        raise ValueError(f"a UDP address must be udpin:HOST:PORT or udpout:HOST:PORT, got {address!r}")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"the port of {address!r} must be an integer in 1..65535, got {port_text!r}") from None
    if not (0 if kind == "udpin" else 1) <= port <= 65535:
        raise ValueError(f"the port of {address!r} must be in {'0' if kind == 'udpin' else '1'}..65535, got {port}")
    return kind, host, port


class UdpLink(Link):
    """MAVLink over UDP datagrams (one or more whole packets per datagram).

    Parameters
    ----------
    address : str
        ``udpin:HOST:PORT`` (bind there; reply to the last sender) or ``udpout:HOST:PORT`` (send
        there; accept datagrams from that address only).
    """

    def __init__(self, address: str):
        kind, host, port = parse_udp_address(address)
        self.address = address
        self.kind = kind
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if kind == "udpin":
                self._sock.bind((host, port))
                self.peer = None
            else:
                self.peer = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4]
                self._sock.bind(("127.0.0.1" if self.peer[0].startswith("127.") else "0.0.0.0", 0))
        except OSError as exc:
            self._sock.close()
            raise OSError(exc.errno, f"cannot open {address}: {exc.strerror}") from None

    @property
    def local_address(self) -> tuple[str, int]:
        """(host, port) the socket is bound to."""
        return self._sock.getsockname()

    def read(self, timeout_s: float) -> bytes:
        self._sock.settimeout(max(float(timeout_s), 0.0))
        try:
            data, sender = self._sock.recvfrom(_MAX_DATAGRAM)
        except (socket.timeout, BlockingIOError):
            return b""
        except ConnectionRefusedError:  # an ICMP "port unreachable" for an earlier datagram
            return b""
        if self.kind == "udpin":
            self.peer = sender
        elif sender != self.peer:
            return b""
        return data

    def write(self, data: bytes) -> None:
        if self.peer is None:  # udpin before anyone has spoken: nowhere to send
            return
        try:
            self._sock.sendto(data, self.peer)
        except ConnectionRefusedError:  # nobody listens there (yet); UDP loses it, as on a real link
            pass

    def close(self) -> None:
        self._sock.close()


class SerialLink(Link):
    """MAVLink over a serial port or a pyserial URL (``loop://`` loops writes back to reads).

    Parameters
    ----------
    address : str
        A device path or a pyserial URL.
    baud : int
        Bits per second (ignored by pseudo-terminals and ``loop://``).
    """

    def __init__(self, address: str, baud: int = 115200):
        import serial

        if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        self.address = address
        self._serial_error = serial.SerialException
        try:
            self._port = serial.serial_for_url(address, baudrate=baud, timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise OSError(errno.ENODEV, f"cannot open serial port {address!r}: {exc}") from None

    def read(self, timeout_s: float) -> bytes:
        port = self._port
        timeout_s = max(float(timeout_s), 0.0)
        if port.timeout != timeout_s:  # setting it reconfigures the port
            port.timeout = timeout_s
        try:
            first = port.read(1)
        except self._serial_error as exc:  # pyserial: "readiness to read but returned no data"
            raise LinkClosed(errno.EIO, f"{self.address}: the other side went away ({exc})") from None
        if not first:
            return b""
        waiting = port.in_waiting
        return first + (port.read(waiting) if waiting else b"")

    def write(self, data: bytes) -> None:
        self._port.write(data)

    def close(self) -> None:
        self._port.close()


class FdLink(Link):
    """MAVLink over an open file descriptor (e.g. the master side of ``os.openpty()``).

    The descriptor is switched to non-blocking; :meth:`close` closes it unless ``owns`` is False.
    A pseudo-terminal whose other side is closed reads as empty (not as an error).
    """

    def __init__(self, fd: int, owns: bool = True, address: str | None = None):
        if isinstance(fd, bool) or not isinstance(fd, int) or fd < 0:
            raise ValueError(f"fd must be an open file descriptor (int >= 0), got {fd!r}")
        os.set_blocking(fd, False)
        self._fd = fd
        self._owns = owns
        self._closed = False
        self.address = address or f"fd {fd}"

    def read(self, timeout_s: float) -> bytes:
        ready, _, _ = select.select([self._fd], [], [], max(float(timeout_s), 0.0))
        if not ready:
            return b""
        try:
            return os.read(self._fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # a pty master whose slave side is closed
                return b""
            raise

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                select.select([], [self._fd], [], 0.1)
                continue
            view = view[n:]

    def close(self) -> None:
        if self._owns and not self._closed:
            self._closed = True
            os.close(self._fd)


def open_link(address, baud: int = 115200) -> Link:
    """Open ``address`` (module docstring) or return it unchanged when it is already a :class:`Link`.

    Raises
    ------
    ValueError
        When the address is of none of the accepted forms.
    OSError
        When the socket or port cannot be opened.
    """
    if isinstance(address, Link):
        return address
    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"a link address must be a non-empty string, got {address!r}")
    if address.startswith(("udpin:", "udpout:")):
        return UdpLink(address)
    if "://" in address or address.startswith("/") or address.startswith("COM"):
        return SerialLink(address, baud)
    raise ValueError(f"a link address must be udpin:HOST:PORT, udpout:HOST:PORT, a serial device path "
                     f"or a pyserial URL (loop://), got {address!r}")
