"""MAVLink 2 message signing for the lab's driver and device: the key file and the parser's setup.

With a key set, a link end signs every packet it sends and accepts only packets signed with the
same key whose time stamp moves forward on their stream; unsigned packets (MAVLink 1 frames
included: they cannot be signed) and wrongly signed ones are refused and counted
(:func:`refused_count`). The signature is the MAVLink 2 one: the first 6 bytes of
SHA-256(key ‖ header ‖ payload ‖ CRC ‖ link id ‖ time stamp), the time stamp in 10 µs units since
2015-01-01 00:00:00 UTC.

Two things differ from pymavlink's own check, both to bound what a stranger on the link can do:

* the signature is checked **before** the time stamp is recorded, so a forged packet cannot move
  a stream's time stamp forward (which would make the real sender's next packets look like
  replays);
* at most :data:`MAX_STREAMS` streams (link id, system, component) are remembered; a new one
  beyond that replaces the one heard from longest ago.

Signing authenticates the sender and stops replays; it does not hide the traffic.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import struct
import time
from collections import OrderedDict

__all__ = ["KEY_BYTES", "MAX_STREAMS", "read_key", "enable_signing", "refused_count", "signing_timestamp"]

#: A MAVLink 2 signing key is 32 bytes.
KEY_BYTES = 32
#: Streams whose last time stamp is remembered (bounded state per sender).
MAX_STREAMS = 64
_EPOCH_2015_S = 1420070400.0  # 2015-01-01 00:00:00 UTC
_NEW_STREAM_SLACK = 6_000_000  # 60 s in 10 µs units: how far behind a new stream may start
_SIGNATURE_BLOCK = 13  # link id (1), time stamp (6), signature (6)
_READ_LIMIT = 4096


def read_key(path) -> bytes:
    """The 32-byte signing key in file ``path``: 32 raw bytes, or 64 hexadecimal characters
    (surrounding whitespace, e.g. a final newline, allowed).

    Raises
    ------
    ValueError
        In one line naming the file, when it cannot be read or holds anything else.
    """
    try:
        with open(os.fspath(path), "rb") as f:
            data = f.read(_READ_LIMIT + 1)
    except OSError as exc:
        raise ValueError(f"signing key file {os.fspath(path)!s}: {exc.strerror or exc}") from None
    if len(data) == KEY_BYTES:
        return data
    text = data.strip()
    if len(text) == 2 * KEY_BYTES:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    size = f"more than {_READ_LIMIT}" if len(data) > _READ_LIMIT else str(len(data))
    raise ValueError(f"signing key file {os.fspath(path)!s} must hold 32 raw bytes or 64 hexadecimal characters, "
                     f"got {size} bytes")


def signing_timestamp(now_s: float | None = None) -> int:
    """MAVLink 2 signing time stamp of Unix time ``now_s`` (default: now): 10 µs units since 2015-01-01 UTC."""
    now_s = time.time() if now_s is None else float(now_s)
    return max(0, int((now_s - _EPOCH_2015_S) * 1e5))


def enable_signing(mav, key: bytes, *, link_id: int = 0) -> None:
    """Sign everything ``mav`` sends with ``key`` and refuse every packet it parses that is not
    signed with it (module docstring).

    Parameters
    ----------
    mav : pymavlink MAVLink object (MAVLink 2)
    key : bytes
        32 bytes (:func:`read_key`).
    link_id : int
        The link id written into this end's signatures, 0..255.
    """
    if not isinstance(key, (bytes, bytearray)) or len(key) != KEY_BYTES:
        raise ValueError(f"key must be {KEY_BYTES} bytes, got {type(key).__name__} of length "
                         f"{len(key) if hasattr(key, '__len__') else '?'}")
    if isinstance(link_id, bool) or not isinstance(link_id, int) or not 0 <= link_id <= 255:
        raise ValueError(f"link_id must be an integer in 0..255, got {link_id!r}")
    signing = mav.signing
    signing.secret_key = bytes(key)
    signing.link_id = link_id
    signing.timestamp = signing_timestamp()
    signing.sign_outgoing = True
    signing.allow_unsigned_callback = _refuse  # every refusal then passes through reject_count
    signing.stream_timestamps = OrderedDict()
    mav.check_signature = _checker(mav)


def refused_count(mav) -> int:
    """Packets ``mav`` refused for their signature (unsigned or wrongly signed) since signing was enabled."""
    return int(mav.signing.reject_count)


def _refuse(mav, msg_id: int) -> bool:
    return False


def _checker(mav):
    signing = mav.signing
    unpack_stamp = struct.Struct("<IH").unpack

    def check_signature(msgbuf, src_system: int, src_component: int) -> bool:
        if len(msgbuf) < _SIGNATURE_BLOCK:
            return False
        expected = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
            return False
        low, high = unpack_stamp(bytes(msgbuf[-12:-6]))
        stamp = low + (high << 32)
        stream = (msgbuf[-13], src_system, src_component)
        streams = signing.stream_timestamps
        last = streams.get(stream)
        if last is not None:
            if stamp <= last:
                return False  # a replay, or packets out of order
        elif stamp + _NEW_STREAM_SLACK < signing.timestamp:
            return False  # a new stream starting more than a minute in the past
        streams[stream] = stamp
        streams.move_to_end(stream)
        while len(streams) > MAX_STREAMS:
            streams.popitem(last=False)
        signing.timestamp = max(signing.timestamp, stamp)
        return True

    return check_signature
