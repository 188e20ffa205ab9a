"""The UAV body's motion: hover sway, blade-pass vibration and a waypoint flight (seeded).

The paper's study keeps the drone still; its abstract and §4.1.3 argue that a gimbal pays off on
a *moving, vibrating* drone, which its simulator could not show (§5 leaves it to future work).
This module gives the body pose T_world_body(t) and the body's angular rate, continuous in time,
so a renderer can sample them anywhere inside an exposure.

Conventions: world Z-up; body axes x forward, y left, z up (the study's body faces world +x);
attitude as Z-Y-X Euler angles (yaw ψ, pitch θ, roll φ), R = Rz(ψ)·Ry(θ)·Rx(φ); angles in
radians; ``T_world_body`` maps body points to the world.

Shaped noise
------------
Each sway component is a second-order shaped noise: white noise through
H(s) = ωn²/(s² + 2ζωn s + ωn²), scaled to a stated RMS. It is synthesised as a sum of many
sinusoids at jittered frequencies with random phases, whose amplitudes follow |H(j2πf)|²: the
process is exactly continuous and differentiable at any t, evaluating it costs one vectorised
sum, and the same seed gives the same motion. (An SDE integrated on a grid would need an
interpolant between samples, whose own error would show inside an exposure.)

Notes
-----
Paper abstract and §4.1.3 (motion blur of a moving, vibrating drone), §5 (a drone flying between
waypoints while tracking). Parameters fixed in docs/design.md ("Moving drone").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ShapedNoise", "HoverSway", "Vibration", "WaypointFlight", "BodyMotion", "euler_to_matrix",
           "body_rates_from_euler", "GRAVITY_M_S2"]

GRAVITY_M_S2 = 9.80665
_BLOCK = 32  # instants per block of ShapedNoise's angle-addition stepping
_GRID_MIN = 16  # fewer instants are evaluated directly


def _number(name, value, low=None, low_open=False):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if low is not None and (v <= low if low_open else v < low):
        raise ValueError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {value!r}")
    return v


def _rng(seed):
    """A Generator from an integer seed >= 0, a numpy SeedSequence (a replicate's named stream,
    :func:`gimbal_lab.config.seed_stream`) or a Generator (used as it is)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, a numpy SeedSequence or a numpy Generator, got {seed!r}")
    return np.random.default_rng(int(seed))


class ShapedNoise:
    """One scalar second-order shaped noise, continuous in time.

    Parameters
    ----------
    rms : float
        Standard deviation of the process, >= 0 (in the caller's unit).
    natural_hz : float
        Natural frequency fn of the shaping filter, Hz, > 0.
    damping : float
        Damping ratio ζ, > 0.
    rng : numpy.random.Generator, numpy.random.SeedSequence or int
    n_components : int
        Sinusoids in the sum (frequencies spread over [0, 10·fn]).

    Notes
    -----
    x(t) = Σ a_k cos(2π f_k t + φ_k) with f_k = (k + u_k)·Δf, u_k ~ U(0, 1), φ_k ~ U(0, 2π) and
    a_k ∝ |H(j2πf_k)| √Δf, scaled so that Σ a_k²/2 = rms² exactly.
    """

    def __init__(self, rms: float, natural_hz: float, damping: float, rng, n_components: int = 600):
        self.rms = _number("rms", rms, low=0.0)
        self.natural_hz = _number("natural_hz", natural_hz, low=0.0, low_open=True)
        self.damping = _number("damping", damping, low=0.0, low_open=True)
        rng = _rng(rng)
        f_max = 10.0 * self.natural_hz
        df = f_max / n_components
        self.freq_hz = (np.arange(n_components) + rng.uniform(0.0, 1.0, n_components)) * df
        self.phase = rng.uniform(0.0, 2.0 * np.pi, n_components)
        r = self.freq_hz / self.natural_hz
        power = 1.0 / ((1.0 - r * r) ** 2 + (2.0 * self.damping * r) ** 2)
        amp = np.sqrt(2.0 * power * df)
        scale = self.rms / math.sqrt(0.5 * float(np.sum(amp * amp))) if self.rms > 0 else 0.0
        self.amplitude = amp * scale
        self._omega = 2.0 * np.pi * self.freq_hz
        self._sin_phase = np.sin(self.phase)
        self._last = None  # (times as bytes, their four sums): see _grid_sums
        self._coefficients = None  # (n_components, 4) complex: a, a·ω, a/ω, a·ω²
        self._steps = None  # (spacing, exp(iω·j·spacing) for j < _BLOCK)

    def psd(self, f_hz) -> np.ndarray:
        """One-sided power spectral density of the process, unit²/Hz (analytic, for checks).

        rms² · |H(j2πf)|² / ∫₀^{10 fn} |H|² df: the filter's shape, normalised to the variance.
        """
        f = np.asarray(f_hz, dtype=float)
        shape = lambda x: 1.0 / ((1.0 - (x / self.natural_hz) ** 2) ** 2 + (2.0 * self.damping * x / self.natural_hz) ** 2)
        grid = np.linspace(0.0, 10.0 * self.natural_hz, 20001)
        return self.rms**2 * shape(f) / np.trapezoid(shape(grid), grid)

    def integral(self, t_s):
        """∫₀ᵗ x(τ) dτ, same shape as ``t_s`` (term by term: a (sin(ωt + φ) − sin φ)/ω)."""
        return self._eval(t_s, -1)

    def _eval(self, t_s, derivative: int) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        flat = t.reshape(-1)
        out = np.empty_like(flat)
        for start in range(0, flat.size, 4096):  # chunks keep the (times × components) matrix small
            chunk = flat[start:start + 4096]
            sums = self._grid_sums(chunk)
            if sums is not None:  # columns: Σ a·e^{iθ}, Σ aω·e^{iθ}, Σ (a/ω)·e^{iθ}, Σ aω²·e^{iθ}
                if derivative == -1:
                    out[start:start + 4096] = sums[:, 2].imag - self._sin_phase @ (self.amplitude / self._omega)
                elif derivative == 0:
                    out[start:start + 4096] = sums[:, 0].real
                elif derivative == 1:
                    out[start:start + 4096] = -sums[:, 1].imag
                else:
                    out[start:start + 4096] = -sums[:, 3].real
                continue
            # a few instants: the one trigonometric function needed
            arg = np.outer(chunk, self._omega) + self.phase
            cos = np.cos(arg) if derivative in (0, 2) else None
            sin = np.sin(arg) if derivative in (-1, 1) else None
            if derivative == -1:
                out[start:start + 4096] = (sin - self._sin_phase) @ (self.amplitude / self._omega)
            elif derivative == 0:
                out[start:start + 4096] = cos @ self.amplitude
            elif derivative == 1:
                out[start:start + 4096] = -sin @ (self.amplitude * self._omega)
            else:
                out[start:start + 4096] = -cos @ (self.amplitude * self._omega**2)
        return out.reshape(t.shape)

    def _grid_sums(self, t: np.ndarray):
        """Σ_k c_k·exp(i(ω_k t + φ_k)) for the four coefficient sets c = a, a·ω, a/ω, a·ω² (value,
        rate, integral, second derivative), (len(t), 4) complex, when ``t`` holds at least
        ``_GRID_MIN`` evenly spaced instants (the 1 kHz inner loop, an exposure's knots); else None.

        Each block of ``_BLOCK`` instants starts from its first instant, evaluated directly, and
        steps by angle addition, exp(i(ω(t_b + jΔ) + φ)) = exp(i(ωt_b + φ))·exp(iωjΔ), from one
        table of exp(iωjΔ) per spacing: a complex product instead of a sine and a cosine per
        instant and component, about 8 times faster for 1,000 instants. The rounding (≈ 1e-14
        of the amplitude) is that of forming ωt + φ directly for t of a few seconds. The last
        result is kept: the value, rate and integral at the same instants share it.
        """
        n = t.size
        if n < _GRID_MIN:
            return None
        key = t.tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        dt = (t[-1] - t[0]) / (n - 1)
        if not dt > 0 or np.any(np.abs(t - (t[0] + dt * np.arange(n))) > 1e-13 * max(1.0, abs(t[-1]))):
            return None
        if self._steps is None or abs(self._steps[0] - dt) > 1e-13 * dt:
            self._steps = (dt, np.exp(1j * np.outer(dt * np.arange(_BLOCK), self._omega)))
        table = self._steps[1]
        if self._coefficients is None:
            a, w = self.amplitude, self._omega
            self._coefficients = np.column_stack((a, a * w, a / w, a * w * w)).astype(complex)
        sums = np.empty((n, 4), dtype=complex)
        starts = np.exp(1j * (np.outer(t[::_BLOCK], self._omega) + self.phase))
        for i, b in enumerate(range(0, n, _BLOCK)):
            m = min(_BLOCK, n - b)
            sums[b:b + m] = (starts[i] * table[:m]) @ self._coefficients
        self._last = (key, sums)
        return sums

    def value(self, t_s):
        """x(t), same shape as ``t_s``."""
        return self._eval(t_s, 0)

    def rate(self, t_s):
        """dx/dt, same shape as ``t_s``."""
        return self._eval(t_s, 1)


@dataclass(frozen=True)
class HoverSway:
    """Hover sway of attitude and position (docs/design.md "Moving drone").

    Parameters
    ----------
    roll_pitch_rms_rad, yaw_rms_rad : float
        RMS of roll and pitch (2°) and of yaw (1°), each a shaped noise at ``attitude_hz``.
    attitude_hz, damping : float
        Natural frequency (1.5 Hz) and damping ratio (0.7) of the attitude shaping filters.
    position_rms_m, position_hz : float
        RMS per world axis (0.05 m) and natural frequency (0.5 Hz, damping ``damping``).
    """

    roll_pitch_rms_rad: float = math.radians(2.0)
    yaw_rms_rad: float = math.radians(1.0)
    attitude_hz: float = 1.5
    damping: float = 0.7
    position_rms_m: float = 0.05
    position_hz: float = 0.5

    def __post_init__(self):
        for name in ("roll_pitch_rms_rad", "yaw_rms_rad", "position_rms_m"):
            object.__setattr__(self, name, _number(name, getattr(self, name), low=0.0))
        for name in ("attitude_hz", "damping", "position_hz"):
            object.__setattr__(self, name, _number(name, getattr(self, name), low=0.0, low_open=True))


@dataclass(frozen=True)
class Vibration:
    """Blade-pass vibration: a sinusoid per axis at ``frequency_hz`` whose frequency wanders by up to
    ±``jitter`` (a smooth random drift), with RMS ``rms_rad`` per axis (0.3° at 120 Hz ± 10 %)."""

    rms_rad: float = math.radians(0.3)
    frequency_hz: float = 120.0
    jitter: float = 0.10

    def __post_init__(self):
        object.__setattr__(self, "rms_rad", _number("rms_rad", self.rms_rad, low=0.0))
        object.__setattr__(self, "frequency_hz", _number("frequency_hz", self.frequency_hz, low=0.0, low_open=True))
        jitter = _number("jitter", self.jitter, low=0.0)
        if jitter >= 1.0:
            raise ValueError(f"jitter must be < 1, got {self.jitter!r}")
        object.__setattr__(self, "jitter", jitter)


@dataclass(frozen=True)
class WaypointFlight:
    """A straight pass from ``start_m`` to ``end_m`` and back, repeated, at ``speed_m_s`` cruise.

    Each leg accelerates with a(t) = a_max·sin²(π t/T_a), T_a = 2·v/a_max (peak ``accel_m_s2``,
    1 m/s² by default), cruises, and brakes the same way; the body banks by atan(a/g) towards the
    acceleration, as a quadrotor must (its thrust axis parallel to a + g·z), and keeps facing world +x.
    """

    start_m: tuple = (0.0, -1.5, 2.0)
    end_m: tuple = (0.0, 1.5, 2.0)
    speed_m_s: float = 1.0
    accel_m_s2: float = 1.0

    def __post_init__(self):
        for name in ("start_m", "end_m"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be three finite numbers (metres), got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        object.__setattr__(self, "speed_m_s", _number("speed_m_s", self.speed_m_s, low=0.0, low_open=True))
        object.__setattr__(self, "accel_m_s2", _number("accel_m_s2", self.accel_m_s2, low=0.0, low_open=True))
        if self.cruise_m < 0:
            raise ValueError(f"the leg ({self.length_m:g} m) is too short to reach {self.speed_m_s:g} m/s and stop "
                             f"at {self.accel_m_s2:g} m/s² (needs {2 * self.ramp_m:g} m)")

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end_m, self.start_m)))

    @property
    def ramp_s(self) -> float:
        return 2.0 * self.speed_m_s / self.accel_m_s2

    @property
    def ramp_m(self) -> float:
        return self.accel_m_s2 * self.ramp_s**2 / 4.0

    @property
    def cruise_m(self) -> float:
        return self.length_m - 2.0 * self.ramp_m

    @property
    def leg_s(self) -> float:
        return 2.0 * self.ramp_s + self.cruise_m / self.speed_m_s

    @property
    def period_s(self) -> float:
        return 2.0 * self.leg_s

    def _leg(self, tau):
        """Distance along the leg, speed, acceleration and jerk at leg time ``tau`` (arrays)."""
        a, ta, v = self.accel_m_s2, self.ramp_s, self.speed_m_s
        t_cruise_end = ta + self.cruise_m / v
        s = np.empty_like(tau)
        sd, sdd, sddd = np.empty_like(tau), np.empty_like(tau), np.empty_like(tau)
        w = np.pi / ta
        up = tau < ta
        x = tau[up]
        s[up] = a * (x * x / 4.0 + (np.cos(2 * w * x) - 1.0) / (8.0 * w * w))
        sd[up] = a * (x / 2.0 - np.sin(2 * w * x) / (4.0 * w))
        sdd[up] = a * np.sin(w * x) ** 2
        sddd[up] = a * w * np.sin(2 * w * x)
        mid = (tau >= ta) & (tau < t_cruise_end)
        s[mid] = self.ramp_m + v * (tau[mid] - ta)
        sd[mid], sdd[mid], sddd[mid] = v, 0.0, 0.0
        down = tau >= t_cruise_end
        x = tau[down] - t_cruise_end
        s[down] = self.ramp_m + self.cruise_m + v * x - a * (x * x / 4.0 + (np.cos(2 * w * x) - 1.0) / (8.0 * w * w))
        sd[down] = v - a * (x / 2.0 - np.sin(2 * w * x) / (4.0 * w))
        sdd[down] = -a * np.sin(w * x) ** 2
        sddd[down] = -a * w * np.sin(2 * w * x)
        return s, sd, sdd, sddd

    def kinematics(self, t_s):
        """Position, velocity, acceleration and jerk in the world at ``t_s``: each (N, 3)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        phase = np.mod(t, self.period_s)
        back = phase >= self.leg_s
        tau = np.where(back, phase - self.leg_s, phase)
        s, sd, sdd, sddd = self._leg(tau)
        start, end = np.asarray(self.start_m), np.asarray(self.end_m)
        u = (end - start) / self.length_m
        sign = np.where(back, -1.0, 1.0)
        origin = np.where(back[:, None], end, start)
        return (origin + (sign * s)[:, None] * u, (sign * sd)[:, None] * u, (sign * sdd)[:, None] * u,
                (sign * sddd)[:, None] * u)


def euler_to_matrix(yaw, pitch, roll) -> np.ndarray:
    """R = Rz(yaw)·Ry(pitch)·Rx(roll), vectorised: (..., 3, 3)."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    R = np.empty(np.broadcast(cy, cp, cr).shape + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def body_rates_from_euler(pitch, roll, yaw_rate, pitch_rate, roll_rate) -> np.ndarray:
    """Body-frame angular rate (p, q, r) from Z-Y-X Euler angles and their rates: (..., 3)."""
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    p = roll_rate - sp * yaw_rate
    q = cr * pitch_rate + sr * cp * yaw_rate
    r = -sr * pitch_rate + cr * cp * yaw_rate
    return np.stack(np.broadcast_arrays(p, q, r), axis=-1)


@dataclass(frozen=True)
class BodyMotion:
    """The UAV body's motion: a base pose plus optional sway, vibration and flight.

    Parameters
    ----------
    position_m : (3,) floats
        Where the body hovers (the flight's own path replaces it when ``flight`` is given).
    yaw_rad : float
        Heading (0: facing world +x).
    sway : HoverSway or None
    vibration : Vibration or None
    flight : WaypointFlight or None
    seed : int or numpy.random.SeedSequence
        Seed of every random draw (same seed → same motion); a run passes its "body" stream
        (:meth:`gimbal_lab.config.Platform.body`).
    time_offset_s : float
        The motion at time t is the unshifted motion's at t + ``time_offset_s`` (replicates of a
        flight start at different points of the pass).

    Examples
    --------
    >>> still = BodyMotion.static()
    >>> still.T_world_body(1.0)[:3, 3]
    array([0., 0., 2.])
    """

    position_m: tuple = (0.0, 0.0, 2.0)
    yaw_rad: float = 0.0
    sway: HoverSway | None = None
    vibration: Vibration | None = None
    flight: WaypointFlight | None = None
    seed: int = 0
    time_offset_s: float = 0.0
    _parts: dict = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        v = np.asarray(self.position_m, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"position_m must be three finite numbers (metres), got {self.position_m!r}")
        object.__setattr__(self, "position_m", tuple(float(x) for x in v))
        object.__setattr__(self, "yaw_rad", _number("yaw_rad", self.yaw_rad))
        object.__setattr__(self, "time_offset_s", _number("time_offset_s", self.time_offset_s))
        for name, kind in (("sway", HoverSway), ("vibration", Vibration), ("flight", WaypointFlight)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise TypeError(f"{name} must be a {kind.__name__} or None, got {type(value).__name__}")
        rng = _rng(self.seed)
        parts = {}
        if self.sway is not None:
            s = self.sway
            parts["roll"] = [ShapedNoise(s.roll_pitch_rms_rad, s.attitude_hz, s.damping, rng)]
            parts["pitch"] = [ShapedNoise(s.roll_pitch_rms_rad, s.attitude_hz, s.damping, rng)]
            parts["yaw"] = [ShapedNoise(s.yaw_rms_rad, s.attitude_hz, s.damping, rng)]
            parts["position"] = [ShapedNoise(s.position_rms_m, s.position_hz, s.damping, rng) for _ in range(3)]
        if self.vibration is not None:
            vib = self.vibration
            # frequency drift: a slow shaped noise (0.2 Hz) of RMS jitter/3 (within ±jitter 99.7 % of the time)
            parts["vibration"] = [(ShapedNoise(vib.jitter / 3.0, 0.2, 0.7, rng), rng.uniform(0, 2 * np.pi))
                                  for _ in range(3)]
        object.__setattr__(self, "_parts", parts)

    @classmethod
    def static(cls, position_m=(0.0, 0.0, 2.0)) -> "BodyMotion":
        """The paper's still body: level, facing +x, at ``position_m``."""
        return cls(position_m=position_m)

    @classmethod
    def hover(cls, seed: int = 0, vibration: bool = False, position_m=(0.0, 0.0, 2.0)) -> "BodyMotion":
        """Hover sway (and blade-pass vibration) with the fixed parameters."""
        return cls(position_m=position_m, sway=HoverSway(), vibration=Vibration() if vibration else None, seed=seed)

    @classmethod
    def flying(cls, seed: int = 0) -> "BodyMotion":
        """The waypoint pass with hover sway on top."""
        return cls(sway=HoverSway(), flight=WaypointFlight(), seed=seed)

    # ------------------------------------------------------------------------------------------
    def _vibration(self, t, with_rates: bool):
        """Per-axis vibration angles at times ``t`` and, ``with_rates``, their rates (else empty).

        angle = √2·rms·sin(2π f0 (t + ∫₀ᵗ j dτ) + φ0), with j(t) the frequency drift: a slow
        (0.2 Hz) shaped noise of RMS jitter/3, so the instantaneous frequency f0 (1 + j) stays
        within ±jitter 99.7 % of the time; its rate is the exact derivative.
        """
        vib = self.vibration
        amp = math.sqrt(2.0) * vib.rms_rad
        angles, rates = [], []
        for drift, phase0 in self._parts["vibration"]:
            arg = 2.0 * np.pi * vib.frequency_hz * (t + drift.integral(t)) + phase0
            angles.append(amp * np.sin(arg))
            if with_rates:
                omega = 2.0 * np.pi * vib.frequency_hz * (1.0 + drift.value(t))
                rates.append(amp * omega * np.cos(arg))
        return angles, rates

    def attitude(self, t_s):
        """(yaw, pitch, roll) and their time derivatives at ``t_s``: two arrays of shape (N, 3)."""
        return self._attitude(t_s, with_rates=True)

    def _attitude(self, t_s, with_rates: bool):
        """:meth:`attitude`; the rates are None unless ``with_rates`` (a pose needs the angles only)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float)) + self.time_offset_s
        if not np.all(np.isfinite(t)):
            raise ValueError("t_s must be finite")
        angles = np.zeros((t.size, 3))
        rates = np.zeros((t.size, 3)) if with_rates else None
        angles[:, 0] = self.yaw_rad
        if self.sway is not None:
            for i, name in enumerate(("yaw", "pitch", "roll")):
                noise = self._parts[name][0]
                angles[:, i] += noise.value(t)
                if with_rates:
                    rates[:, i] += noise.rate(t)
        if self.vibration is not None:
            values, derivs = self._vibration(t, with_rates)
            for i in range(3):
                angles[:, i] += values[i]
                if with_rates:
                    rates[:, i] += derivs[i]
        if self.flight is not None:
            _, _, acc, jerk = self.flight.kinematics(t)
            # Bank so that the thrust axis R·z_b is parallel to a + g·z (exactly, at yaw 0):
            # pitch θ = atan2(a_x, g + a_z), roll φ = atan2(−a_y, N), N = √(a_x² + (g + a_z)²).
            ax, ay, jx, jy, jz = acc[:, 0], acc[:, 1], jerk[:, 0], jerk[:, 1], jerk[:, 2]
            gz = GRAVITY_M_S2 + acc[:, 2]
            norm = np.sqrt(ax * ax + gz * gz)
            angles[:, 1] += np.arctan2(ax, gz)
            angles[:, 2] += np.arctan2(-ay, norm)
            if with_rates:
                rates[:, 1] += (jx * gz - ax * jz) / (norm * norm)
                # d/dt atan(u), u = −a_y/N, dN/dt = (a_x j_x + (g + a_z) j_z)/N
                u = -ay / norm
                du = (-jy * norm + ay * (ax * jx + gz * jz) / norm) / (norm * norm)
                rates[:, 2] += du / (1.0 + u * u)
        return angles, rates

    def position(self, t_s):
        """Body origin in the world at ``t_s``: (N, 3)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float)) + self.time_offset_s
        p = np.tile(np.asarray(self.position_m), (t.size, 1))
        if self.flight is not None:
            p = self.flight.kinematics(t)[0]
        if self.sway is not None:
            p = p + np.column_stack([n.value(t) for n in self._parts["position"]])
        return p

    def T_world_body(self, t_s) -> np.ndarray:
        """4 × 4 pose at a scalar ``t_s``, or (N, 4, 4) for an array of times."""
        scalar = np.ndim(t_s) == 0
        angles, _ = self._attitude(t_s, with_rates=False)
        T = np.tile(np.eye(4), (angles.shape[0], 1, 1))
        T[:, :3, :3] = euler_to_matrix(angles[:, 0], angles[:, 1], angles[:, 2])
        T[:, :3, 3] = self.position(t_s)
        return T[0] if scalar else T

    def angular_rate_body(self, t_s) -> np.ndarray:
        """The body's angular velocity in the body frame, rad/s: (3,) or (N, 3)."""
        scalar = np.ndim(t_s) == 0
        angles, rates = self.attitude(t_s)
        w = body_rates_from_euler(angles[:, 1], angles[:, 2], rates[:, 0], rates[:, 1], rates[:, 2])
        return w[0] if scalar else w

