"""Kalman-type filters that track the target's 3-D world position (docs/design.md, "Occlusion and
manoeuvres").

The detector measures the target centre in the world, z = p + noise, with a covariance R given
at each update (the range error grows with distance, so R changes from frame to frame). Three
filters share one interface:

* :class:`ConstantVelocity`: state (p, v), white acceleration;
* :class:`ConstantAcceleration`: state (p, v, a), white jerk;
* :class:`IMM`: an interacting multiple model of a constant-velocity model and a 3-D
  coordinated-turn model on the common state (p, v, a).

Interface
---------
``update(t_s, z_m, R_m2)`` fuses a measurement taken at ``t_s`` and returns whether it was
accepted; ``z_m=None`` is a missed frame (nothing changes: the track coasts). A measurement
whose normalised innovation squared (NIS) exceeds the χ² quantile of the gate probability with
3 degrees of freedom is rejected and counted (``n_rejected``); the NIS of the last measurement
offered is ``nis``. After ``restart_after`` rejections in a row the track is taken as lost and
restarts from the last measurement (``n_restarts``). ``predict(t_s)`` returns the mean and
covariance of (p, v) at any time from the last accepted update on, without changing the filter;
``position(t_s)`` and ``velocity(t_s)`` are its parts, for pointing. A coasting filter's
covariance grows with the time since its last update.

Initialisation (one point): the first measurement starts the track with p = z, P_pp = R, zero
velocity with standard deviation ``velocity_std_m_s`` per axis and, where the state has one,
zero acceleration with standard deviation ``accel_std_m_s2`` per axis (the target class's
limits). The first update returns True and leaves ``nis`` undefined (NaN). The gate applies
once the track holds as many measurements as the state has kinematic orders (two for CV, three
for CA and the IMM): before, velocity (and acceleration) are not yet observed, and a target
whose true velocity lies in the prior's tail would be rejected for ever, its NIS staying near
(v/σ_v)² however long the track coasts. The same trap can close later (an acceleration error in
the prior's tail, a lost track), hence the restart.

Process noise is continuous-time white noise (acceleration for CV, jerk for CA and the turn
model), discretised exactly over the actual interval: the filter predicts to arbitrary times
(frame timestamps, missed frames, pointing between frames), and for these models predicting over
t₁ then t₂ gives the same covariance as predicting over t₁ + t₂, which the per-step discrete
models (DWNA, DWPA) do not.

State vectors are ordered (px, py, pz, vx, vy, vz[, ax, ay, az]) in the Z-up world, in m, m/s,
m/s²; covariances in the squares of those units.

Notes
-----
Beyond the paper: its §5 asks for a Bayesian filter to keep tracking through occlusion, and its
related work tracks manoeuvring targets with an IMM. Models and the IMM recursion follow
Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation* (2001),
chapters 6 (kinematic models, consistency tests) and 11 (IMM); the 3-D turn model is the
constant-speed turn ȧ = −ω² v surveyed by Li & Jilkov, *Survey of maneuvering target tracking,
Part I: dynamic models* (IEEE TAES, 2003).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

__all__ = ["ConstantVelocity", "ConstantAcceleration", "IMM", "nees", "chi2_bounds"]

_I3 = np.eye(3)
#: Intervals whose IMM models are kept (an occluded track predicts over many multiples of a frame).
_MODEL_CACHE_SIZE = 128
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(8)


def _per_axis(M) -> np.ndarray:
    """M ⊗ I₃: a per-axis matrix applied to x, y and z alike (what np.kron does, without its overhead)."""
    n = len(M)
    out = np.zeros((n, 3, n, 3))
    for axis in range(3):
        out[:, axis, :, axis] = M
    return out.reshape(3 * n, 3 * n)


# ----------------------------------------------------------------------------------------------
# checks

def _number(name, value, low=0.0, high=None, low_open=True) -> float:
    """A finite float above ``low`` (or at it, if not ``low_open``) and at most ``high``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if v < low or (low_open and v == low):
        raise ValueError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {value!r}")
    if high is not None and v > high:
        raise ValueError(f"{name} must be <= {high:g}, got {value!r}")
    return v


def _measurement(z_m, R_m2) -> tuple[np.ndarray, np.ndarray]:
    z = np.asarray(z_m, dtype=float)
    if z.shape != (3,) or not np.all(np.isfinite(z)):
        raise ValueError(f"z_m must be three finite numbers (a world position, m), got {z_m!r}")
    if R_m2 is None:
        raise ValueError("R_m2 must be given with a measurement: its 3 × 3 covariance, m²")
    R = np.asarray(R_m2, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"R_m2 must be a finite 3 × 3 covariance (m²), got shape {R.shape}")
    if not np.allclose(R, R.T, rtol=1e-9, atol=1e-15):
        raise ValueError("R_m2 must be symmetric")
    try:
        np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        raise ValueError("R_m2 must be positive definite") from None
    return z, 0.5 * (R + R.T)


# ----------------------------------------------------------------------------------------------
# evaluation helpers

def nees(x_true, x_est, P) -> np.ndarray:
    """Normalised estimation error squared, e P⁻¹ e with e = x_true − x_est.

    Parameters
    ----------
    x_true, x_est : ndarray, shape (..., n)
    P : ndarray, shape (..., n, n)
        Covariance the filter claims for ``x_est``.

    Returns
    -------
    ndarray, shape (...)
        χ²(n)-distributed when the filter is consistent.
    """
    xt, xe, P = np.asarray(x_true, float), np.asarray(x_est, float), np.asarray(P, float)
    if xt.shape != xe.shape or xt.ndim < 1:
        raise ValueError(f"x_true and x_est must have the same shape (..., n), got {xt.shape} and {xe.shape}")
    n = xt.shape[-1]
    if P.shape[-2:] != (n, n):
        raise ValueError(f"P must have shape (..., {n}, {n}), got {P.shape}")
    e = xt - xe
    return np.sum(e * np.linalg.solve(P, e[..., None])[..., 0], axis=-1)


def chi2_bounds(dof: int, n_runs: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided interval of the average of ``n_runs`` independent χ²(dof) values.

    n·ε̄ ~ χ²(dof·n), so the interval is χ²⁻¹((1 ∓ p)/2; dof·n)/n.

    Parameters
    ----------
    dof : int
        Degrees of freedom of one value (state dimension for NEES, 3 for NIS), ≥ 1.
    n_runs : int
        Independent values averaged (Monte Carlo runs at one time step), ≥ 1.
    p : float
        Probability inside the interval, in (0, 1).

    Examples
    --------
    >>> lo, hi = chi2_bounds(3, 50)
    >>> round(lo, 2), round(hi, 2)
    (2.36, 3.72)
    """
    for name, value in (("dof", dof), ("n_runs", n_runs)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    p = _number("p", p)
    if p >= 1.0:
        raise ValueError(f"p must be < 1, got {p!r}")
    k = int(dof) * int(n_runs)
    return float(chi2.ppf(0.5 * (1.0 - p), k) / n_runs), float(chi2.ppf(0.5 * (1.0 + p), k) / n_runs)


# ----------------------------------------------------------------------------------------------
# motion models: transition F(dt) and process noise Q(dt) on (p, v) or (p, v, a)

def _cv_model(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant velocity, white acceleration of spectral density q (m²/s³)."""
    F = _per_axis(np.array([[1.0, dt], [0.0, 1.0]]))
    Q = q * _per_axis(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    return F, Q


def _ca_model(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant acceleration, white jerk of spectral density q (m²/s⁵)."""
    F = _per_axis(np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]]))
    Q = q * _per_axis(np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6],
                                [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                                [dt**3 / 6, dt**2 / 2, dt]]))
    return F, Q


def _turn_transition_1d(dt, w) -> np.ndarray:
    """Per-axis transition of ṗ = v, v̇ = a, ȧ = −ω² v over ``dt`` (array-valued dt allowed)."""
    x = w * np.asarray(dt, dtype=float)
    s, c, one_minus_c = np.sin(x), np.cos(x), 2.0 * np.sin(x / 2.0) ** 2
    zero, one = np.zeros_like(x), np.ones_like(x)
    return np.stack([np.stack([one, s / w, one_minus_c / w**2], -1),
                     np.stack([zero, c, s / w], -1),
                     np.stack([zero, -w * s, c], -1)], -2)


def _turn_model(dt: float, q: float, w: float) -> tuple[np.ndarray, np.ndarray]:
    """3-D coordinated turn at known rate ω (rad/s), white jerk of spectral density q (m²/s⁵).

    ȧ = −ω² v keeps the speed and turns the velocity at rate ω in the plane of v and a, for any
    plane; the plane and sense of the turn live in the state. Q = q ∫₀^dt φ(τ) φ(τ)ᵀ dτ with
    φ(τ) = e^{Aτ}(0, 0, 1)ᵀ per axis, by 8-point Gauss–Legendre on pieces of at most 0.25/ω s
    (the integrand is a trigonometric polynomial of frequency ≤ 2ω: the rule is exact to
    rounding there, and also as ω → 0, where the model becomes constant acceleration).
    """
    F1 = _turn_transition_1d(dt, w)
    Q1 = np.zeros((3, 3))
    if dt > 0.0:
        pieces = max(1, math.ceil(4.0 * w * dt))
        edges = np.linspace(0.0, dt, pieces + 1)
        half = 0.5 * (edges[1:] - edges[:-1])
        tau = (edges[:-1] + half)[:, None] + half[:, None] * _GAUSS_NODES[None, :]
        weights = (half[:, None] * _GAUSS_WEIGHTS[None, :]).ravel()
        phi = _turn_transition_1d(tau.ravel(), w)[:, :, 2]
        Q1 = q * (phi.T * weights) @ phi
    return _per_axis(F1), _per_axis(0.5 * (Q1 + Q1.T))


def _kalman_correct(x, P, z, R):
    """Kalman update of (x, P) with z = x[:3] + noise(R); Joseph form. Returns x, P, y, S."""
    y = z - x[:3]
    S = P[:3, :3] + R
    K = np.linalg.solve(S, P[:3, :]).T
    I_KH = np.eye(len(x))
    I_KH[:, :3] -= K
    P = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x + K @ y, 0.5 * (P + P.T), y, S


# ----------------------------------------------------------------------------------------------
# filters

class _Tracker:
    """What every filter shares: time keeping, gating, coasting and the public interface."""

    dim_x = 6

    def __init__(self, velocity_std_m_s: float, gate_probability: float, restart_after: int | None):
        self.velocity_std_m_s = _number("velocity_std_m_s", velocity_std_m_s)
        self.gate_probability = _number("gate_probability", gate_probability, 0.0, 1.0)
        self.gate_nis = math.inf if self.gate_probability == 1.0 else float(chi2.ppf(self.gate_probability, 3))
        if restart_after is not None and (isinstance(restart_after, (bool, np.bool_))
                                          or not isinstance(restart_after, (int, np.integer)) or restart_after < 1):
            raise ValueError(f"restart_after must be an integer >= 1 or None, got {restart_after!r}")
        self.restart_after = restart_after
        self.reset()

    def reset(self) -> None:
        """Forget the track (counters included)."""
        self.t_s = None
        self.nis = math.nan
        self.n_accepted = 0
        self.n_rejected = 0
        self.n_restarts = 0
        self._in_track = 0  # measurements fused since the track (re)started
        self._rejected_in_a_row = 0
        self._reset_state()

    @property
    def initialised(self) -> bool:
        """True once a measurement has started the track."""
        return self.t_s is not None

    def _dt(self, t_s) -> float:
        t = _number("t_s", t_s, low=-math.inf)
        if not self.initialised:
            raise RuntimeError("the filter has no measurement yet (call update first)")
        if t < self.t_s:
            raise ValueError(f"t_s must not precede the last update ({self.t_s:g} s), got {t_s!r}")
        return t - self.t_s

    def _initial_covariance(self, R) -> np.ndarray:
        P = np.zeros((self.dim_x, self.dim_x))
        P[:3, :3] = R
        P[3:6, 3:6] = self.velocity_std_m_s**2 * _I3
        if self.dim_x == 9:
            P[6:, 6:] = self.accel_std_m_s2**2 * _I3
        return P

    def update(self, t_s: float, z_m, R_m2=None) -> bool:
        """Fuse the position ``z_m`` measured at ``t_s`` with covariance ``R_m2``.

        Parameters
        ----------
        t_s : float
            Time of the measurement, s; not before the last accepted update.
        z_m : (3,) floats or None
            Measured world position, m; None for a frame without a detection (the track coasts).
        R_m2 : ndarray, shape (3, 3)
            Covariance of the measurement, m², symmetric positive definite.

        Returns
        -------
        bool
            True if the measurement started (or restarted) the track or passed the gate and was
            fused; False for a missed frame or a rejected measurement.
        """
        if z_m is None:
            if self.initialised:
                self._dt(t_s)
            return False
        z, R = _measurement(z_m, R_m2)
        if not self.initialised:
            return self._restart(_number("t_s", t_s, low=-math.inf), z, R)
        prior = self._prior(self._dt(t_s))
        x, P = self._combine(prior)
        y = z - x[:3]
        self.nis = float(y @ np.linalg.solve(P[:3, :3] + R, y))
        if self._in_track >= self.dim_x // 3 and self._gate_test(prior, z, R) > self.gate_nis:
            self.n_rejected += 1
            self._rejected_in_a_row += 1
            if self.restart_after is not None and self._rejected_in_a_row >= self.restart_after:
                self.n_restarts += 1
                return self._restart(float(t_s), z, R)
            return False
        self._correct(prior, z, R)
        self.t_s = float(t_s)
        self.n_accepted += 1
        self._in_track += 1
        self._rejected_in_a_row = 0
        return True

    def _restart(self, t_s: float, z, R) -> bool:
        self._reset_state()
        self._start(z, R)
        self.t_s, self.nis = t_s, math.nan
        self.n_accepted += 1
        self._in_track, self._rejected_in_a_row = 1, 0
        return True

    def predict(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean, shape (6,), and covariance, shape (6, 6), of (p, v) at ``t_s``; the filter is unchanged."""
        x, P = self._combine(self._prior(self._dt(t_s)))
        return x[:6].copy(), P[:6, :6].copy()

    def position(self, t_s: float) -> np.ndarray:
        """Predicted world position at ``t_s``, m, shape (3,)."""
        return self.predict(t_s)[0][:3]

    def velocity(self, t_s: float) -> np.ndarray:
        """Predicted world velocity at ``t_s``, m/s, shape (3,)."""
        return self.predict(t_s)[0][3:6]

    @property
    def x(self) -> np.ndarray:
        """Full state estimate at ``t_s`` (after the last accepted update), shape (dim_x,)."""
        return self._combine(self._prior(0.0))[0] if self.initialised else None

    @property
    def P(self) -> np.ndarray:
        """Covariance of :attr:`x`, shape (dim_x, dim_x)."""
        return self._combine(self._prior(0.0))[1] if self.initialised else None


class _SingleModel(_Tracker):
    def _reset_state(self):
        self._x = self._P = None

    def _start(self, z, R):
        self._x = np.zeros(self.dim_x)
        self._x[:3] = z
        self._P = self._initial_covariance(R)

    def _prior(self, dt):
        F, Q = self._model(dt)
        return F @ self._x, F @ self._P @ F.T + Q

    @staticmethod
    def _combine(prior):
        return prior

    def _gate_test(self, prior, z, R):
        return self.nis

    def _correct(self, prior, z, R):
        self._x, self._P, _, _ = _kalman_correct(prior[0], prior[1], z, R)


class ConstantVelocity(_SingleModel):
    """Constant-velocity Kalman filter on the target's world position.

    State (p, v); the acceleration is white noise of spectral density ``q_accel_m2_s3`` per axis
    (continuous white-noise acceleration model): over dt,
    F = [[I, dt·I], [0, I]], Q = q [[dt³/3, dt²/2], [dt²/2, dt]] ⊗ I.

    Parameters
    ----------
    q_accel_m2_s3 : float
        Spectral density of the white acceleration, m²/s³, > 0 (q·T is the velocity variance
        gained over T seconds).
    velocity_std_m_s : float
        Standard deviation per axis of the velocity when a track starts, m/s.
    gate_probability : float
        Probability that a measurement of the modelled target passes the gate, in (0, 1]
        (1 switches the gate off).
    restart_after : int or None
        Consecutive rejected measurements after which the track restarts from the last one
        (None: never).

    Examples
    --------
    >>> f = ConstantVelocity(q_accel_m2_s3=0.5)
    >>> R = 1e-4 * np.eye(3)
    >>> f.update(0.0, [3.0, 0.0, 2.0], R), f.update(0.1, [3.0, 0.1, 2.0], R)
    (True, True)
    >>> bool(f.velocity(0.1)[1] > 0.5)
    True
    """

    dim_x = 6

    def __init__(self, q_accel_m2_s3: float = 1.0, velocity_std_m_s: float = 2.0, gate_probability: float = 0.99,
                 restart_after: int | None = 10):
        self.q_accel_m2_s3 = _number("q_accel_m2_s3", q_accel_m2_s3)
        super().__init__(velocity_std_m_s, gate_probability, restart_after)

    def _model(self, dt):
        return _cv_model(dt, self.q_accel_m2_s3)


class ConstantAcceleration(_SingleModel):
    """Constant-acceleration Kalman filter on the target's world position.

    State (p, v, a); the jerk is white noise of spectral density ``q_jerk_m2_s5`` per axis
    (continuous Wiener-process acceleration model): over dt,
    F = [[1, dt, dt²/2], [0, 1, dt], [0, 0, 1]] ⊗ I and
    Q = q [[dt⁵/20, dt⁴/8, dt³/6], [dt⁴/8, dt³/3, dt²/2], [dt³/6, dt²/2, dt]] ⊗ I.

    Parameters
    ----------
    q_jerk_m2_s5 : float
        Spectral density of the white jerk, m²/s⁵, > 0.
    velocity_std_m_s, accel_std_m_s2 : float
        Standard deviations per axis of the velocity and acceleration when a track starts.
    gate_probability, restart_after
        As for :class:`ConstantVelocity`.
    """

    dim_x = 9

    def __init__(self, q_jerk_m2_s5: float = 10.0, velocity_std_m_s: float = 2.0, accel_std_m_s2: float = 5.0,
                 gate_probability: float = 0.99, restart_after: int | None = 10):
        self.q_jerk_m2_s5 = _number("q_jerk_m2_s5", q_jerk_m2_s5)
        self.accel_std_m_s2 = _number("accel_std_m_s2", accel_std_m_s2)
        super().__init__(velocity_std_m_s, gate_probability, restart_after)

    def _model(self, dt):
        return _ca_model(dt, self.q_jerk_m2_s5)


class IMM(_Tracker):
    """Interacting multiple model: constant velocity + 3-D coordinated turn.

    Both models act on the state (p, v, a):

    * CV: p' = p + v dt, v' = v, a' = 0, white acceleration of density ``q_accel_m2_s3``
      (its acceleration is zero with zero variance after a prediction);
    * CT: ȧ = −ω² v with the known turn rate ω = ``turn_rate_rad_s`` and white jerk of density
      ``q_jerk_m2_s5``. A coordinated turn at speed v has a ⊥ v and |a| = ω v; the model turns
      the velocity at rate ω in the plane of v and a, whatever that plane, so one linear model
      covers every turn of a target whose turns share one rate.

    Why this turn model: the target's turns are 3-D (any plane) and, for the study's target,
    all at one rate a/v; a known-rate linear turn model lets both modes share a state and be
    mixed exactly, and keeps each mode a plain Kalman filter (no linearisation). A turn rate far
    from ω is absorbed, less well, by the jerk noise; an unknown rate would need the nonlinear
    turn model (ω = |v × a|/|v|²) with an extended filter.

    Mode switching is a continuous-time Markov chain with mean sojourn times ``sojourn_s``
    (CV, CT): over dt, Π = I + (1 − e^{−(λ₁+λ₂)dt})/(λ₁+λ₂)·G with G = [[−λ₁, λ₁], [λ₂, −λ₂]] and
    λᵢ = 1/sojournᵢ; Π[i, j] is the probability of going from mode i to mode j. The track starts
    with the chain's stationary probabilities. One IMM cycle (mix, predict each mode, update each
    mode, reweight by likelihood, combine) runs per accepted measurement over the whole interval
    since the last one. ``nis`` uses the moment-matched prior; the gate keeps a measurement that
    passes the gate of either mode (a gate on the moment-matched prior, dominated by the CV mode
    on a leg, rejected the first frames of every turn and lost the track).

    Parameters
    ----------
    q_accel_m2_s3 : float
        Spectral density of the CV mode's white acceleration, m²/s³, > 0 (default: the velocity
        wanders by √(0.05 · 1 s) ≈ 0.2 m/s per second).
    q_jerk_m2_s5 : float
        Spectral density of the CT mode's white jerk, m²/s⁵, > 0. The study's target starts a
        turn abruptly (its acceleration jumps from 0 to 5 m/s²), so the default lets the CT mode
        take up that whole acceleration within one 1/30 s frame: (5 m/s²)² · 30 /s = 750.
    turn_rate_rad_s : float
        Turn rate ω of the CT mode, rad/s, > 0 (the study's target: 5 m/s² at 1 m/s, 5 rad/s).
    sojourn_s : (float, float)
        Mean time spent in the CV and CT modes, s, > 0.
    velocity_std_m_s, accel_std_m_s2 : float
        Standard deviations per axis of the velocity and (CT mode) acceleration at track start.
    gate_probability, restart_after
        As for :class:`ConstantVelocity`.

    Attributes
    ----------
    mode_probability : ndarray, shape (2,)
        Posterior probabilities of (CV, CT) after the last accepted update.

    Notes
    -----
    Measured consistency (tests/test_filters.py): on a motion drawn from its own switching
    model the (p, v) NEES and the NIS lie inside their 95 % χ² intervals. On the study's
    manoeuvring target it is conservative on legs (average NEES about 3 for 6 degrees of freedom:
    the legs are exact straight lines, which no filter with process noise matches) and not
    consistent in turns (over-confident at a turn's onset, conservative later).
    """

    dim_x = 9
    MODES = ("CV", "CT")

    def __init__(self, q_accel_m2_s3: float = 0.05, q_jerk_m2_s5: float = 750.0, turn_rate_rad_s: float = 5.0,
                 sojourn_s=(1.0, 0.4), velocity_std_m_s: float = 2.0, accel_std_m_s2: float = 5.0,
                 gate_probability: float = 0.99, restart_after: int | None = 10):
        self.q_accel_m2_s3 = _number("q_accel_m2_s3", q_accel_m2_s3)
        self.q_jerk_m2_s5 = _number("q_jerk_m2_s5", q_jerk_m2_s5)
        self.turn_rate_rad_s = _number("turn_rate_rad_s", turn_rate_rad_s)
        self.accel_std_m_s2 = _number("accel_std_m_s2", accel_std_m_s2)
        if isinstance(sojourn_s, (str, bytes)) or np.ndim(sojourn_s) != 1 or len(sojourn_s) != 2:
            raise ValueError(f"sojourn_s must be two times (CV, CT) in s, got {sojourn_s!r}")
        self.sojourn_s = tuple(_number("sojourn_s", s) for s in sojourn_s)
        self._cached_models = {}
        super().__init__(velocity_std_m_s, gate_probability, restart_after)

    def _reset_state(self):
        self._xs = self._Ps = None
        rates = 1.0 / np.asarray(self.sojourn_s)
        self.mode_probability = rates[::-1] / rates.sum()

    def transition_matrix(self, dt_s: float) -> np.ndarray:
        """Mode transition probabilities over ``dt_s``: Π[i, j] = P(mode j at t + dt | mode i at t)."""
        dt = _number("dt_s", dt_s, low=0.0, low_open=False)
        l1, l2 = 1.0 / self.sojourn_s[0], 1.0 / self.sojourn_s[1]
        s = -math.expm1(-(l1 + l2) * dt) / (l1 + l2)
        return np.array([[1.0 - l1 * s, l1 * s], [l2 * s, 1.0 - l2 * s]])

    def models(self, dt_s: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """(F, Q) of the CV and CT modes over ``dt_s``, each 9 × 9."""
        dt = _number("dt_s", dt_s, low=0.0, low_open=False)
        return [(F.copy(), Q.copy()) for F, Q in self._models(dt)]

    def _models(self, dt: float):
        models = self._cached_models.get(dt)
        if models is None:  # frames at a steady rate reuse a few intervals (updates, predictions between)
            F_cv, Q_cv = _cv_model(dt, self.q_accel_m2_s3)
            F, Q = np.zeros((9, 9)), np.zeros((9, 9))
            F[:6, :6], Q[:6, :6] = F_cv, Q_cv
            models = [(F, Q), _turn_model(dt, self.q_jerk_m2_s5, self.turn_rate_rad_s)]
            if len(self._cached_models) >= _MODEL_CACHE_SIZE:
                self._cached_models.pop(next(iter(self._cached_models)))
            self._cached_models[dt] = models
        return models

    def _start(self, z, R):
        x = np.zeros(9)
        x[:3] = z
        P = self._initial_covariance(R)
        P_cv = P.copy()
        P_cv[6:, 6:] = 0.0  # the CV mode's acceleration is zero
        self._xs, self._Ps = [x.copy(), x.copy()], [P_cv, P]

    def _prior(self, dt):
        """Mix, then predict each mode over dt: (predicted mode probabilities, means, covariances)."""
        Pi = self.transition_matrix(dt)
        mu = self.mode_probability
        cbar = mu @ Pi
        mix = Pi * mu[:, None] / cbar[None, :]  # mix[i, j]: weight of mode i in mode j's start
        xs, Ps = [], []
        for j, (F, Q) in enumerate(self._models(dt)):
            x0 = sum(mix[i, j] * self._xs[i] for i in range(2))
            P0 = sum(mix[i, j] * (self._Ps[i] + np.outer(self._xs[i] - x0, self._xs[i] - x0)) for i in range(2))
            xs.append(F @ x0)
            Ps.append(F @ P0 @ F.T + Q)
        return cbar, xs, Ps

    @staticmethod
    def _combine(prior):
        weights, xs, Ps = prior
        x = sum(w * xi for w, xi in zip(weights, xs))
        P = sum(w * (Pi + np.outer(xi - x, xi - x)) for w, xi, Pi in zip(weights, xs, Ps))
        return x, P

    def _gate_test(self, prior, z, R):
        """The smallest NIS over the modes: a measurement is kept if any mode could have made it."""
        _, xs, Ps = prior
        return min(float((z - x[:3]) @ np.linalg.solve(P[:3, :3] + R, z - x[:3])) for x, P in zip(xs, Ps))

    def _correct(self, prior, z, R):
        cbar, xs, Ps = prior
        log_like = np.empty(2)
        for j in range(2):
            xs[j], Ps[j], y, S = _kalman_correct(xs[j], Ps[j], z, R)
            _, logdet = np.linalg.slogdet(2.0 * np.pi * S)
            log_like[j] = -0.5 * (y @ np.linalg.solve(S, y) + logdet)
        w = np.log(cbar) + log_like
        w = np.maximum(np.exp(w - w.max()), 1e-300)  # no mode is ever ruled out entirely
        self.mode_probability = w / w.sum()
        self._xs, self._Ps = xs, Ps

    @property
    def x(self) -> np.ndarray:
        """Combined state estimate at ``t_s``, shape (9,)."""
        return self._combine((self.mode_probability, self._xs, self._Ps))[0] if self.initialised else None

    @property
    def P(self) -> np.ndarray:
        """Covariance of :attr:`x`, shape (9, 9)."""
        return self._combine((self.mode_probability, self._xs, self._Ps))[1] if self.initialised else None
