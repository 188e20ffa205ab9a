"""Target motions of the study (paper §4.1, Fig. 10), vectorised over time.

Both motions are periodic with period T and centred on c = (3.0, 0, 2.0) m in the Z-up world,
3 m in front of the gimbal's home camera at (0, 0, 2.0) m:

* circular: a vertical circle of radius R in the plane x = c_x, facing the camera,
  p(t) = c + R (0, cos φ, sin φ), φ = 2πt/T (starts at the camera's left, turns upwards);
* diagonal: a straight round trip through c, p(t) = c + A sin φ with A = (1.0, 0.8, 0.5) m,
  so depth runs from 2 to 4 m and the target passes the image centre twice per period;
* stationary: the target held still at c, on the home optical axis, p(t) = c (the moving drone's
  static-target arm, docs/design.md "The moving drone's gain, decomposed": the only image motion
  is the body's).

A third motion, :class:`ManoeuvringTarget`, is not periodic: seeded constant-velocity legs
joined by coordinated turns inside a box around c (docs/design.md, "Occlusion and manoeuvres").

The ArUco marker keeps one orientation, facing the home camera (its +z normal along world −x,
its x axis along world −y and its y axis up, as OpenCV's marker axes seen from the camera).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Trajectory", "ManoeuvringTarget", "R_WORLD_MARKER", "target_pose"]

#: Orientation of the marker in the world: columns are the marker's x, y, z axes.
R_WORLD_MARKER = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

_KINDS = ("circular", "diagonal", "stationary")


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
    kind : {"circular", "diagonal", "stationary"}
    period_s : float
        Time of one revolution (circular) or one round trip (diagonal), > 0; a stationary
        target's period only sets the run's length in revolutions.
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

    @classmethod
    def stationary(cls, period_s: float = 2.0, centre_m=(3.0, 0.0, 2.0)) -> "Trajectory":
        """The target held still at ``centre_m``, the circle's centre (docs/design.md, "The moving
        drone's gain, decomposed")."""
        return cls("stationary", period_s=period_s, centre_m=centre_m)

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
        elif self.kind == "stationary":
            offset = np.zeros(phi.shape + (3,))
        else:
            offset = np.sin(phi)[..., None] * np.asarray(self.amplitude_m)
        return c + offset

    def velocity(self, t_s) -> np.ndarray:
        """Target velocity in the world (m/s), same shapes as :meth:`position`."""
        t, phi = self._phase(t_s)
        w = 2.0 * np.pi / self.period_s
        if self.kind == "circular":
            return self.radius_m * w * np.stack((np.zeros_like(phi), -np.sin(phi), np.cos(phi)), axis=-1)
        if self.kind == "stationary":
            return np.zeros(phi.shape + (3,))
        return (w * np.cos(phi))[..., None] * np.asarray(self.amplitude_m)


#: Largest centripetal acceleration of the manoeuvring target (docs/design.md, "Occlusion and
#: manoeuvres").
MAX_TURN_ACCEL_M_S2 = 5.0


def _positive(name, value, upper=None) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    if upper is not None and v > upper:
        raise ValueError(f"{name} must be <= {upper:g}, got {value!r}")
    return v


@dataclass(frozen=True)
class ManoeuvringTarget:
    """A seeded target flying constant-velocity legs joined by coordinated turns, inside a box.

    The target keeps a constant speed. Each leg is a straight line; each turn rotates the velocity
    at the constant rate ω = a/v about an axis perpendicular to it (a coordinated turn of radius
    r = v²/a, centripetal acceleration a). Every leg ends at a random point at least 2r inside
    each face of the box, and the turn that follows heads for the next such point, so the target
    turns back before it reaches an edge and never leaves the box. The plan is drawn once, up to
    ``duration_s``. The defaults (1 m/s, 5 m/s², r = 0.2 m) fit the study's box around
    c = (3, 0, 2) m: ±0.5 m in depth (x), ±1 m across (y, z).

    Parameters
    ----------
    seed : int, numpy.random.SeedSequence or numpy.random.Generator
        Seed of the plan; the same integer seed (or sequence) gives the same path. A run passes its
        "plan" stream (:func:`gimbal_lab.config.seed_stream`).
    speed_m_s : float
        Constant speed v, m/s, > 0.
    turn_accel_m_s2 : float
        Centripetal acceleration a of every turn, m/s², in (0, 5] (docs/design.md); the turn rate
        is a/v (5 rad/s by default).
    min_leg_s, max_leg_s : float
        Bounds of a leg's duration, s (its length follows from the random point it heads for).
    min_turn_rad : float
        Smallest heading change of a turn, rad, in (0, π/2]; the largest is π.
    centre_m : (3,) floats
        Centre of the box in the world, metres (the study's c = (3, 0, 2) m).
    half_extent_m : (3,) floats
        Half-size of the box along world x, y, z, metres; each must exceed two turn radii.
    duration_s : float
        The path is defined on [0, duration_s].

    Notes
    -----
    On a turn that starts at time t₀ with position p₀ and velocity v₀ about the unit axis k,
    with w₀ = k × v₀ and τ = t − t₀:
    p = p₀ + v₀ sin(ωτ)/ω + w₀ (1 − cos ωτ)/ω, v = v₀ cos ωτ + w₀ sin ωτ,
    acceleration ω (w₀ cos ωτ − v₀ sin ωτ), of magnitude ω v = a. The acceleration jumps
    between 0 and a where legs and turns meet; position and velocity are continuous.
    The true acceleration is for evaluation only; a filter never sees it.

    Examples
    --------
    >>> target = ManoeuvringTarget(seed=3)
    >>> bool(np.allclose(np.linalg.norm(target.velocity([0.0, 7.5]), axis=1), 1.0))
    True
    """

    seed: object = 0
    speed_m_s: float = 1.0
    turn_accel_m_s2: float = 5.0
    min_leg_s: float = 0.4
    max_leg_s: float = 1.5
    min_turn_rad: float = math.radians(30.0)
    centre_m: tuple = (3.0, 0.0, 2.0)
    half_extent_m: tuple = (0.5, 1.0, 1.0)
    duration_s: float = 120.0
    _plan: dict = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        seed = self.seed
        if not isinstance(seed, (np.random.Generator, np.random.SeedSequence)):
            if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
                raise TypeError(f"seed must be an integer >= 0, a numpy SeedSequence or a numpy Generator, got {seed!r}")
            if seed < 0:
                raise ValueError(f"seed must be an integer >= 0, a numpy SeedSequence or a numpy Generator, got {seed!r}")
        object.__setattr__(self, "speed_m_s", _positive("speed_m_s", self.speed_m_s))
        object.__setattr__(self, "turn_accel_m_s2",
                           _positive("turn_accel_m_s2", self.turn_accel_m_s2, upper=MAX_TURN_ACCEL_M_S2))
        object.__setattr__(self, "min_leg_s", _positive("min_leg_s", self.min_leg_s))
        object.__setattr__(self, "max_leg_s", _positive("max_leg_s", self.max_leg_s))
        if self.max_leg_s < self.min_leg_s:
            raise ValueError(f"max_leg_s must be >= min_leg_s ({self.min_leg_s:g} s), got {self.max_leg_s!r}")
        object.__setattr__(self, "min_turn_rad", _positive("min_turn_rad", self.min_turn_rad, upper=math.pi / 2))
        object.__setattr__(self, "duration_s", _positive("duration_s", self.duration_s))
        object.__setattr__(self, "centre_m", _vec3("centre_m", self.centre_m))
        half = _vec3("half_extent_m", self.half_extent_m)
        if min(half) <= 2.0 * self.turn_radius_m:
            raise ValueError(f"half_extent_m must exceed two turn radii (2 v²/a = {2 * self.turn_radius_m:.3g} m) "
                             f"on every axis, got {self.half_extent_m!r}; lower speed_m_s or raise turn_accel_m_s2")
        object.__setattr__(self, "half_extent_m", half)
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(
            seed if isinstance(seed, np.random.SeedSequence) else int(seed))
        object.__setattr__(self, "_plan", self._draw_plan(rng))

    @property
    def turn_radius_m(self) -> float:
        """Radius v²/a of every turn, metres."""
        return self.speed_m_s**2 / self.turn_accel_m_s2

    @property
    def turn_rate_rad_s(self) -> float:
        """Rate ω = a/v at which the velocity turns, rad/s."""
        return self.turn_accel_m_s2 / self.speed_m_s

    @property
    def segment_start_s(self) -> np.ndarray:
        """Start times of the legs and turns, s (legs and turns alternate, a leg first)."""
        return self._plan["t0"].copy()

    # ------------------------------------------------------------------------------------------
    def _draw_plan(self, rng) -> dict:
        """Legs and turns up to ``duration_s``: start times, start states and turn rates.

        Every leg ends at a point q drawn uniformly from the box shrunk by two turn radii. A turn
        stays within 2r of where it starts (its circle has diameter 2r), so every turn lies in the
        box, and so does every leg, whose two ends do (the box is convex). The turn from (p, u)
        goes in the plane of u and q − p until the heading points at q, along the tangent from q
        to the turning circle; candidates q are redrawn until the turn and the leg after it are
        long enough.
        """
        v, w, r = self.speed_m_s, self.turn_rate_rad_s, self.turn_radius_m
        centre = np.asarray(self.centre_m)
        inner = np.asarray(self.half_extent_m) - 2.0 * r
        t0, p0, v0, w0, omega = [], [], [], [], []
        shortest, longest = v * self.min_leg_s, v * self.max_leg_s

        p = centre
        for _ in range(10_000):  # first leg: from the centre straight to a point q
            q = centre + rng.uniform(-1.0, 1.0, 3) * inner
            length = float(np.linalg.norm(q - p))
            if shortest <= length <= longest:
                break
        else:  # pragma: no cover - the shrunk box always holds points at a leg's length
            raise RuntimeError("ManoeuvringTarget: found no first leg")
        u = (q - p) / length
        t0.append(0.0), p0.append(p), v0.append(v * u), w0.append(np.zeros(3)), omega.append(0.0)
        t, p = length / v, p + length * u
        while t < self.duration_s:
            for _ in range(10_000):
                q = centre + rng.uniform(-1.0, 1.0, 3) * inner
                along = float((q - p) @ u)
                perp = q - p - along * u
                across = float(np.linalg.norm(perp))
                if across < 1e-9:
                    continue
                n = perp / across
                # q seen from the turn centre p + r·n, in the (u, n) plane
                dist = math.hypot(along, across - r)
                if dist <= r:
                    continue
                turn = (math.atan2(across - r, along) + math.asin(r / dist)) % (2.0 * math.pi)
                length = math.sqrt(dist * dist - r * r)
                if self.min_turn_rad <= turn <= math.pi and shortest <= length <= longest:
                    break
            else:  # pragma: no cover - points behind and far enough always exist
                raise RuntimeError(f"ManoeuvringTarget: found no turn at t = {t:.3f} s")
            t0.append(t), p0.append(p), v0.append(v * u), w0.append(v * n), omega.append(w)
            p = p + r * (math.sin(turn) * u + 2.0 * math.sin(turn / 2.0) ** 2 * n)
            u = math.cos(turn) * u + math.sin(turn) * n
            t += turn / w
            t0.append(t), p0.append(p), v0.append(v * u), w0.append(np.zeros(3)), omega.append(0.0)
            t, p = t + length / v, p + length * u
        return {"t0": np.array(t0), "p0": np.array(p0), "v0": np.array(v0), "w0": np.array(w0),
                "omega": np.array(omega)}

    def _local(self, t_s):
        t = np.asarray(t_s, dtype=float)
        if not np.all(np.isfinite(t)) or np.any(t < 0.0) or np.any(t > self.duration_s):
            raise ValueError(f"t_s must lie in [0, duration_s = {self.duration_s:g}] s")
        plan = self._plan
        i = np.searchsorted(plan["t0"], t, side="right") - 1
        tau = t - plan["t0"][i]
        om = plan["omega"][i]
        turning = om > 0.0
        return plan, i, tau, om, turning

    def turning(self, t_s) -> np.ndarray:
        """True where the target is in a turn (for evaluation), same shape as ``t_s``."""
        return self._local(t_s)[4]

    def _kinematics(self, t_s, order):
        plan, i, tau, om, turning = self._local(t_s)
        safe = np.where(turning, om, 1.0)
        phase = safe * tau
        s, c = np.sin(phase), np.cos(phase)
        v0, w0 = plan["v0"][i], plan["w0"][i]
        if order == 0:
            along = np.where(turning, s / safe, tau)[..., None]
            across = np.where(turning, 2.0 * np.sin(phase / 2) ** 2 / safe, 0.0)[..., None]
            return plan["p0"][i] + v0 * along + w0 * across
        if order == 1:
            return v0 * np.where(turning, c, 1.0)[..., None] + w0 * np.where(turning, s, 0.0)[..., None]
        return np.where(turning, om, 0.0)[..., None] * (w0 * c[..., None] - v0 * s[..., None])

    def position(self, t_s) -> np.ndarray:
        """Target centre in the world, metres: shape (3,) for a scalar ``t_s``, (N, 3) for (N,)."""
        return self._kinematics(t_s, 0)

    def velocity(self, t_s) -> np.ndarray:
        """Target velocity in the world, m/s, same shapes as :meth:`position`."""
        return self._kinematics(t_s, 1)

    def acceleration(self, t_s) -> np.ndarray:
        """True acceleration in the world, m/s² (for evaluation only), same shapes as :meth:`position`."""
        return self._kinematics(t_s, 2)


def target_pose(trajectory: Trajectory | ManoeuvringTarget, t_s: float) -> np.ndarray:
    """4 × 4 ``T_world_target`` at time ``t_s``: the trajectory's position, the fixed marker orientation."""
    T = np.eye(4)
    T[:3, :3] = R_WORLD_MARKER
    T[:3, 3] = trajectory.position(float(t_s))
    return T
