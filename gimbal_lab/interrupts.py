"""Whether a Ctrl-C came during a command, for the commands to stop on even if it was swallowed.

The command line's SIGINT handler (:mod:`gimbal_lab.cli`) raises KeyboardInterrupt and notes here
that it did. A library may catch that exception on its way out (trimesh's optional imports catch
every exception) and let the command go on; a command calls :func:`stop_if_interrupted` after
such imports, so it stops there instead of running to its end. It lives below everything else so
that a command module at any layer can call it without importing :mod:`gimbal_lab.cli`.
"""

from __future__ import annotations

__all__ = ["note_interrupt", "clear", "received", "stop_if_interrupted"]

_received = False


def note_interrupt() -> None:
    """Called by the SIGINT handler: a Ctrl-C came."""
    global _received
    _received = True


def clear() -> None:
    """Forget any earlier Ctrl-C (a command starts)."""
    global _received
    _received = False


def received() -> bool:
    """Whether a Ctrl-C came since the command started."""
    return _received


def stop_if_interrupted() -> None:
    """Raise KeyboardInterrupt when a Ctrl-C came and something swallowed its exception."""
    if _received:
        raise KeyboardInterrupt
