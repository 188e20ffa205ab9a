"""Target motions of the study (paper §4.1, Fig. 10), vectorised over time.

Both motions are periodic with period T and centred on c = (3.0, 0, 2.0) m in the Z-up world,
3 m in front of the gimbal's home camera at (0, 0, 2.0) m:

* circular: a vertical circle of radius R in the plane x = c_x, facing the camera,
  p(t) = c + R (0, cos φ, sin φ), φ = 2πt/T (starts at the camera's left, turns upwards);
* diagonal: a straight round trip through c, p(t) = c + A sin φ with A = (1.0, 0.8, 0.5) m,
  so depth runs from 2 to 4 m and the target passes the image centre twice per period.

The ArUco marker keeps one orientation, facing the home camera (its +z normal along world −x,
its x axis along world −y and its y axis up, as OpenCV's marker axes seen from the camera).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Trajectory", "R_WORLD_MARKER", "target_pose"]

#: Orientation of the marker in the world: columns are the marker's x, y, z axes.
R_WORLD_MARKER = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

_KINDS = ("circular", "diagonal")


def _vec3(name, value) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be three finite numbers (metres), got {value!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Trajectory:
    """A periodic target motion.

    Parameters
    ----------
    kind : {"circular", "diagonal"}
    period_s : float
        Time of one revolution (circular) or one round trip (diagonal), > 0.
    centre_m : (3,) floats
        Centre of the motion in the world, metres.
    radius_m : float
        Circle radius (circular only), > 0.
    amplitude_m : (3,) floats
        Half-extent of the straight motion along world x, y, z (diagonal only).

    Examples
    --------
    >>> Trajectory.circular().position(0.0)
    array([3., 1., 2.])
    """

    kind: str = "circular"
    period_s: float = 2.0
    centre_m: tuple = (3.0, 0.0, 2.0)
    radius_m: float = 1.0
    amplitude_m: tuple = field(default=(1.0, 0.8, 0.5))

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"kind must be one of {_KINDS}, got {self.kind!r}")
        period = float(self.period_s)
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period_s must be > 0 s, got {self.period_s!r}")
        radius = float(self.radius_m)
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"radius_m must be > 0 m, got {self.radius_m!r}")
        object.__setattr__(self, "period_s", period)
        object.__setattr__(self, "radius_m", radius)
        object.__setattr__(self, "centre_m", _vec3("centre_m", self.centre_m))
        object.__setattr__(self, "amplitude_m", _vec3("amplitude_m", self.amplitude_m))

    @classmethod
    def circular(cls, period_s: float = 2.0, radius_m: float = 1.0, centre_m=(3.0, 0.0, 2.0)) -> "Trajectory":
        """The study's vertical circle (docs/design.md)."""
        return cls("circular", period_s=period_s, centre_m=centre_m, radius_m=radius_m)

    @classmethod
    def diagonal(cls, period_s: float = 2.0, amplitude_m=(1.0, 0.8, 0.5), centre_m=(3.0, 0.0, 2.0)) -> "Trajectory":
        """The study's straight round trip through the centre (docs/design.md)."""
        return cls("diagonal", period_s=period_s, centre_m=centre_m, amplitude_m=amplitude_m)

    def _phase(self, t_s):
        t = np.asarray(t_s, dtype=float)
        if not np.all(np.isfinite(t)):
            raise ValueError("t_s must be finite")
        return t, 2.0 * np.pi * t / self.period_s

    def position(self, t_s) -> np.ndarray:
        """Target centre in the world at time(s) ``t_s``: shape (3,) for a scalar, (N, 3) for (N,)."""
        t, phi = self._phase(t_s)
        c = np.asarray(self.centre_m)
        if self.kind == "circular":
            offset = self.radius_m * np.stack((np.zeros_like(phi), np.cos(phi), np.sin(phi)), axis=-1)
        else:
            offset = np.sin(phi)[..., None] * np.asarray(self.amplitude_m)
        return c + offset

    def velocity(self, t_s) -> np.ndarray:
        """Target velocity in the world (m/s), same shapes as :meth:`position`."""
        t, phi = self._phase(t_s)
        w = 2.0 * np.pi / self.period_s
        if self.kind == "circular":
            return self.radius_m * w * np.stack((np.zeros_like(phi), -np.sin(phi), np.cos(phi)), axis=-1)
        return (w * np.cos(phi))[..., None] * np.asarray(self.amplitude_m)


def target_pose(trajectory: Trajectory, t_s: float) -> np.ndarray:
    """4 × 4 ``T_world_target`` at time ``t_s``: the trajectory's position, the fixed marker orientation."""
    T = np.eye(4)
    T[:3, :3] = R_WORLD_MARKER
    T[:3, 3] = trajectory.position(float(t_s))
    return T
