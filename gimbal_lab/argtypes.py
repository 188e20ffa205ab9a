"""Argument types of the command line (argparse ``type=`` functions), shared by every command.

They live below everything else so that a command module at any layer can use them without
importing :mod:`gimbal_lab.cli`, the top of the package.
"""

from __future__ import annotations

import argparse

__all__ = ["positive_int", "nonnegative_int", "int_at_least", "length_m"]


def _int_at_least(text: str, low: int) -> int:
    """``text`` as an integer >= ``low``; otherwise an ArgumentTypeError saying so."""
    try:
        value = int(text)
    except ValueError:
        value = low - 1
    if value < low:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(text, 1)


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(text, 0)


def int_at_least(low: int):
    """argparse type: an integer >= ``low`` (its message names ``low``, not 1)."""

    def parse(text: str) -> int:
        return _int_at_least(text, low)

    parse.__name__ = f"int_at_least_{low}"
    return parse


def length_m(text: str) -> float:
    """argparse type: a finite length > 0, metres (``nan``, ``inf``, 0 and negatives refused)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a length in metres > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite length in metres > 0, got {text!r}")
    return value
