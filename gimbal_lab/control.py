"""Gimbal control: the motor-axis plant, discrete PID, ultimate gain, Ziegler–Nichols, loops.

The paper's control structure (§3.2.3, Fig. 5) has two loops:

* an **inner rate loop** per joint (yaw, roll, pitch): a PID on the angular rate measured by the
  gyro, tuned with the Ziegler–Nichols ultimate-gain rules;
* an **outer image loop**: the target's pixel offset from the image centre,
  e_u = u_ref − u, e_v = v_ref − v with (u_ref, v_ref) = (cx, cy), becomes a camera angular-rate
  reference, mapped to joint-rate references through the gimbal's angular Jacobian.

One gimbal axis (``AxisPlant``) is modelled as

    torque command u --[saturation ±torque_limit]--> 1/(tau_m s + 1)   (motor / current loop)
        --> applied torque T;   J dω/dt = T − b ω + d                 (inertia J, damping b)
        --> gyro 1/(tau_g s + 1) --> delay e^{−s L} --> measured rate

so the linear part, torque command → measured rate, is

    G(s) = e^{−s L} / ((tau_m s + 1) (J s + b) (tau_g s + 1)),

which has a finite ultimate gain Ku (the lags and the delay add the phase that the
inertia's −90° lacks to reach −180°). ``GimbalAxis`` integrates this plant one fixed step at a
time (exact discretisation of the linear part under a zero-order hold), and is the integrator
used by ``simulate_axis``, ``relay_experiment`` and the closed-loop study.

Conventions
-----------
* SI units and radians; torques in N·m, rates in rad/s.
* ``delay_s`` is the *total* sample-and-compute delay of the discrete loop, *including* the
  zero-order hold's half sample: a controller at step dt_s holding its output for one step acts
  like a delay of dt_s/2, so ``GimbalAxis`` adds a transport delay of ``delay_s − dt_s/2`` to the
  gyro signal. The continuous model ``AxisPlant.transfer_function`` and the discrete simulation
  then describe the same loop, and ``delay_s >= dt_s/2`` is required.
* Camera frame: OpenCV's (x right, y down, z forward).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import control as ct
import numpy as np
import scipy.linalg

from .camera import Intrinsics, backproject

__all__ = [
    "AxisPlant",
    "GimbalAxis",
    "PIDGains",
    "PID",
    "RateLoop",
    "ImageLoop",
    "AxisSimulation",
    "RelayExperiment",
    "ultimate_gain",
    "relay_experiment",
    "relay_ultimate_gain",
    "ziegler_nichols",
    "pid_transfer_function",
    "closed_loop",
    "simulate_axis",
    "step_metrics",
    "compare_tunings",
    "PointingSimulation",
    "simulate_pointing",
    "outer_loop_plant",
    "outer_loop_delay_s",
    "outer_loop_gains",
    "AXES",
]

AXES = ("yaw", "roll", "pitch")
"""Gimbal joints in kinematic order, UAV body → camera (§3.2.4)."""


# ----------------------------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------------------------
def _check_real(name: str, value, *, low=None, high=None, low_open=False, allow_inf=False):
    """Return ``float(value)`` or raise a ValueError naming ``name`` and the allowed range."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    lo_txt = "" if low is None else (f"> {low}" if low_open else f">= {low}")
    hi_txt = "" if high is None else f"<= {high}"
    rng = " and ".join(t for t in (lo_txt, hi_txt) if t) or "finite"
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name} must be a finite number ({rng}), got {value!r}")
    if low is not None and (v <= low if low_open else v < low):
        raise ValueError(f"{name} must be {rng}, got {value!r}")
    if high is not None and v > high:
        raise ValueError(f"{name} must be {rng}, got {value!r}")
    return v


# ----------------------------------------------------------------------------------------------
# the plant
# ----------------------------------------------------------------------------------------------
# STorM32-scale defaults, one set per joint. The payload about each joint grows from the camera
# outwards: pitch turns the camera alone (a ~60 g camera, ~5 cm across), roll turns the camera
# plus the pitch motor and bracket, yaw turns everything below the body (camera, pitch and roll
# motors, arms). Inertias are those of the rigid bodies (I = m (a² + b²)/12 plus arm offsets);
# damping is the back-EMF of a high-resistance gimbal motor (Kt²/R ≈ 0.04²/10 Ω ≈ 1.6e-4 N·m·s);
# torque limits are those of 22xx-size gimbal motors on a 3S STorM32 board; the motor lag is the
# winding's L/R with the PWM filter, the gyro lag an MPU-6050 low-pass near 160 Hz, and the delay
# one 1 kHz sample of computation plus the zero-order hold's half sample.
_STORM32 = {
    "pitch": dict(inertia_kgm2=4.0e-5, damping_Nms_per_rad=1.5e-4, torque_limit_Nm=0.04),
    "roll": dict(inertia_kgm2=9.0e-5, damping_Nms_per_rad=1.5e-4, torque_limit_Nm=0.05),
    "yaw": dict(inertia_kgm2=1.6e-4, damping_Nms_per_rad=2.0e-4, torque_limit_Nm=0.06),
}
_STORM32_COMMON = dict(motor_tau_s=5.0e-4, gyro_tau_s=1.0e-3, delay_s=1.5e-3)


@dataclass(frozen=True)
class AxisPlant:
    """One brushless gimbal axis: torque command → measured angular rate.

    Parameters
    ----------
    inertia_kgm2 : float
        Moment of inertia J of everything the joint turns, kg·m², > 0.
    damping_Nms_per_rad : float
        Viscous damping b (bearing friction, motor back-EMF), N·m·s/rad, >= 0. It acts on the
        rate relative to the base, so a base rotating at ω_b drags the axis with a torque
        b·ω_b (see ``base_rate_torque_Nm``).
    torque_limit_Nm : float
        Symmetric saturation of the torque command, N·m, > 0 (``math.inf`` for a linear axis).
    motor_tau_s : float
        Time constant of the motor / current loop (first-order lag), s, > 0.
    gyro_tau_s : float
        Time constant of the gyro's low-pass filter (first-order lag), s, > 0.
    delay_s : float
        Total sample-and-compute delay of the discrete loop including the zero-order hold's half
        sample, s, >= 0.

    Notes
    -----
    Linear part (paper §3.2.3, the "3-DoF Gimbal" block of Fig. 5, one axis):
    G(s) = e^{−sL} / ((τ_m s + 1)(J s + b)(τ_g s + 1)).

    Examples
    --------
    >>> plant = AxisPlant.storm32("pitch")
    >>> Ku, Tu = ultimate_gain(plant.transfer_function())
    >>> 0.0 < Tu < 0.05
    True
    """

    inertia_kgm2: float
    damping_Nms_per_rad: float
    torque_limit_Nm: float
    motor_tau_s: float
    gyro_tau_s: float
    delay_s: float

    def __post_init__(self):
        _check_real("inertia_kgm2", self.inertia_kgm2, low=0.0, low_open=True)
        _check_real("damping_Nms_per_rad", self.damping_Nms_per_rad, low=0.0)
        _check_real("torque_limit_Nm", self.torque_limit_Nm, low=0.0, low_open=True, allow_inf=True)
        _check_real("motor_tau_s", self.motor_tau_s, low=0.0, low_open=True)
        _check_real("gyro_tau_s", self.gyro_tau_s, low=0.0, low_open=True)
        _check_real("delay_s", self.delay_s, low=0.0)

    @classmethod
    def storm32(cls, axis: str = "pitch", **overrides) -> "AxisPlant":
        """STorM32-scale defaults for one joint, ``axis`` in ("yaw", "roll", "pitch").

        ========  ========  ===========  ==========  =======  =======  =======
        axis      J kg·m²   b N·m·s/rad  limit N·m   τ_m s    τ_g s    L s
        ========  ========  ===========  ==========  =======  =======  =======
        pitch     4.0e-5    1.5e-4       0.04        5e-4     1e-3     1.5e-3
        roll      9.0e-5    1.5e-4       0.05        5e-4     1e-3     1.5e-3
        yaw       1.6e-4    2.0e-4       0.06        5e-4     1e-3     1.5e-3
        ========  ========  ===========  ==========  =======  =======  =======

        Pitch turns a ~60 g camera; roll adds the pitch motor and bracket; yaw turns the whole
        stabilised assembly. Keyword ``overrides`` replace single fields.
        """
        if axis not in _STORM32:
            raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
        params = {**_STORM32[axis], **_STORM32_COMMON, **overrides}
        return cls(**params)

    def transfer_function(self, pade_order: int = 6) -> ct.TransferFunction:
        """Linear plant, torque command (N·m) → measured rate (rad/s), delay as a Padé approximant.

        Parameters
        ----------
        pade_order : int
            Order of the Padé approximation of e^{−s·delay_s}, >= 1 (ignored when delay_s = 0).

        Returns
        -------
        control.TransferFunction
            G(s) = pade(delay_s) / ((τ_m s + 1)(J s + b)(τ_g s + 1)).
        """
        if isinstance(pade_order, bool) or not isinstance(pade_order, (int, np.integer)) or pade_order < 1:
            raise ValueError(f"pade_order must be an integer >= 1, got {pade_order!r}")
        motor = ct.tf([1.0], [self.motor_tau_s, 1.0])
        body = ct.tf([1.0], [self.inertia_kgm2, self.damping_Nms_per_rad])
        gyro = ct.tf([1.0], [self.gyro_tau_s, 1.0])
        plant = motor * body * gyro
        if self.delay_s > 0.0:
            num, den = ct.pade(self.delay_s, int(pade_order))
            plant = plant * ct.tf(num, den)
        return plant

    def base_rate_torque_Nm(self, base_rate_rad_s):
        """Torque b·ω_b with which a base turning at ``base_rate_rad_s`` drags the axis, N·m.

        The damping acts on the axis rate relative to the base, J dω/dt = T − b (ω − ω_b), so a
        base rotation enters the axis model as the disturbance torque b·ω_b.
        """
        return self.damping_Nms_per_rad * np.asarray(base_rate_rad_s, dtype=float)


class GimbalAxis:
    """Discrete simulation of one nonlinear gimbal axis at a fixed step.

    Per step the torque command is saturated at ±``torque_limit_Nm`` and held (zero-order hold);
    the linear chain motor lag → inertia + damping → gyro low-pass (plus the angle) is advanced
    with its exact discretisation (matrix exponential, computed once); the gyro signal then
    passes a transport delay of ``delay_s − dt_s/2`` (linear interpolation between samples).

    Parameters
    ----------
    plant : AxisPlant
    dt_s : float
        Fixed step, s, > 0 and <= 2·delay_s.

    Attributes
    ----------
    rate_rad_s : float
        True (inertial) angular rate of the axis, rad/s.
    angle_rad : float
        Integrated angle, rad.
    measured_rate_rad_s : float
        Delayed, filtered gyro reading, rad/s — what a controller sees.
    torque_Nm : float
        Torque the motor currently applies (after its lag), N·m.
    saturated : bool
        Whether the last torque command reached or exceeded the limit.

    Notes
    -----
    The step methods work on plain Python floats so that they are cheap at 1 kHz.
    """

    def __init__(self, plant: AxisPlant, dt_s: float = 1e-3):
        if not isinstance(plant, AxisPlant):
            raise TypeError(f"plant must be an AxisPlant, got {type(plant).__name__}")
        dt_s = _check_real("dt_s", dt_s, low=0.0, low_open=True)
        if plant.delay_s < 0.5 * dt_s - 1e-15:
            raise ValueError(
                f"plant.delay_s ({plant.delay_s}) must be >= dt_s/2 ({0.5 * dt_s}): the "
                "zero-order hold alone delays the loop by half a step"
            )
        self.plant = plant
        self.dt_s = dt_s
        J, b = plant.inertia_kgm2, plant.damping_Nms_per_rad
        tm, tg = plant.motor_tau_s, plant.gyro_tau_s
        # state x = (applied torque, rate, gyro rate, angle); inputs (torque command, disturbance)
        A = np.array(
            [
                [-1.0 / tm, 0.0, 0.0, 0.0],
                [1.0 / J, -b / J, 0.0, 0.0],
                [0.0, 1.0 / tg, -1.0 / tg, 0.0],
                [0.0, 1.0, 0.0, 0.0],
            ]
        )
        B = np.array([[1.0 / tm, 0.0], [0.0, 1.0 / J], [0.0, 0.0], [0.0, 0.0]])
        M = np.zeros((6, 6))
        M[:4, :4] = A
        M[:4, 4:] = B
        E = scipy.linalg.expm(M * dt_s)
        self._Ad = tuple(tuple(float(v) for v in row) for row in E[:4, :4])
        self._Bd = tuple(tuple(float(v) for v in row) for row in E[:4, 4:])
        self._limit = float(plant.torque_limit_Nm)
        transport = max(plant.delay_s - 0.5 * dt_s, 0.0) / dt_s
        self._n_delay = int(math.floor(transport + 1e-9))
        self._frac = transport - self._n_delay
        if self._frac < 1e-9:
            self._frac = 0.0
        self.reset()

    def reset(self, angle_rad: float = 0.0, rate_rad_s: float = 0.0) -> None:
        """Restart at rest torque-wise, at ``angle_rad`` and a steady ``rate_rad_s``."""
        angle_rad = _check_real("angle_rad", angle_rad)
        rate_rad_s = _check_real("rate_rad_s", rate_rad_s)
        self.torque_Nm = 0.0
        self.rate_rad_s = rate_rad_s
        self._gyro = rate_rad_s
        self.angle_rad = angle_rad
        self.saturated = False
        # ring buffer of past gyro samples, newest last; measured = sample delayed by n + frac
        self._buffer = [rate_rad_s] * (self._n_delay + 2)
        self._head = 0  # index of the oldest entry
        self.measured_rate_rad_s = rate_rad_s

    def step(self, torque_cmd_Nm: float, disturbance_Nm: float = 0.0) -> float:
        """Advance one step with ``torque_cmd_Nm`` held; return the new measured rate, rad/s."""
        u = torque_cmd_Nm
        lim = self._limit
        if u >= lim:
            u = lim
            self.saturated = True
        elif u <= -lim:
            u = -lim
            self.saturated = True
        else:
            self.saturated = u != u  # a NaN command is flagged (and propagates)
        d = disturbance_Nm
        x0, x1, x2, x3 = self.torque_Nm, self.rate_rad_s, self._gyro, self.angle_rad
        A, B = self._Ad, self._Bd
        r0, r1, r2, r3 = A
        b0, b1, b2, b3 = B
        self.torque_Nm = r0[0] * x0 + b0[0] * u + b0[1] * d
        self.rate_rad_s = r1[0] * x0 + r1[1] * x1 + b1[0] * u + b1[1] * d
        self._gyro = r2[0] * x0 + r2[1] * x1 + r2[2] * x2 + b2[0] * u + b2[1] * d
        self.angle_rad = r3[0] * x0 + r3[1] * x1 + x3 + b3[0] * u + b3[1] * d
        # delay line: overwrite the oldest sample with the newest gyro value
        buf = self._buffer
        n = len(buf)
        buf[self._head] = self._gyro
        self._head = (self._head + 1) % n
        newest = self._head - 1  # index of the sample just written (may be -1: wraps)
        k = self._n_delay
        a = buf[(newest - k) % n]
        if self._frac:
            a = (1.0 - self._frac) * a + self._frac * buf[(newest - k - 1) % n]
        self.measured_rate_rad_s = a
        return a

    def stop(self, angle_rad: float, rate_rad_s: float) -> None:
        """The axis meets a mechanical stop: its angle becomes ``angle_rad`` and its rate
        ``rate_rad_s`` (the stop's own: zero on a still base), an inelastic contact; the motor's
        torque, the gyro's filter and its delay line keep their states and follow from there."""
        self.angle_rad = angle_rad
        self.rate_rad_s = rate_rad_s


# ----------------------------------------------------------------------------------------------
# ultimate gain
# ----------------------------------------------------------------------------------------------
def ultimate_gain(system) -> tuple[float, float]:
    """Ultimate gain and period of a loop closed with a proportional gain, from ``control.margin``.

    Parameters
    ----------
    system : control.LTI or AxisPlant
        Open-loop plant (an ``AxisPlant`` is converted with its default Padé order).

    Returns
    -------
    Ku : float
        Gain margin: the proportional gain at which the loop oscillates steadily.
    Tu : float
        Period of that oscillation, 2π/ω_pc with ω_pc the phase-crossover frequency, s.

    Raises
    ------
    ValueError
        If the phase never crosses −180° (infinite gain margin: no finite Ku).

    Notes
    -----
    ``control.margin`` reports a single gain margin and prefers one above 1; a plant in
    physical units (torque → rate) is often already unstable under unit feedback (Ku < 1),
    and the Padé delay adds further −180° crossings at high frequency. The ultimate gain of
    an open-loop-stable plant is the *smallest* gain margin over all phase crossovers, so the
    margins are taken from ``control.stability_margins(..., returnall=True)``, which
    ``control.margin`` calls, and the smallest is kept.

    Examples
    --------
    >>> import control as ct
    >>> Ku, Tu = ultimate_gain(ct.tf([1], [1, 3, 3, 1]))   # 1/(s+1)^3
    >>> round(Ku, 6), round(Tu, 6)
    (8.0, 3.627599)
    """
    if isinstance(system, AxisPlant):
        system = system.transfer_function()
    gms, _pms, _sms, w_pcs, _w_gcs, _w_sms = ct.stability_margins(system, returnall=True)
    gms, w_pcs = np.atleast_1d(np.asarray(gms, float)), np.atleast_1d(np.asarray(w_pcs, float))
    ok = np.isfinite(gms) & np.isfinite(w_pcs) & (w_pcs > 0.0) & (gms > 0.0)
    if not np.any(ok):
        raise ValueError(
            "system has no phase crossover (infinite gain margin): Ku is undefined; "
            "add lags or a delay to the plant"
        )
    i = int(np.argmin(np.where(ok, gms, np.inf)))
    return float(gms[i]), 2.0 * math.pi / float(w_pcs[i])


@dataclass(frozen=True)
class RelayExperiment:
    """Trace and result of an Åström–Hägglund relay experiment (see ``relay_experiment``).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time, s.
    measured_rate : ndarray, shape (N,)
        Gyro reading the relay switched on, rad/s.
    torque_cmd : ndarray, shape (N,)
        Relay output, N·m.
    Ku, Tu : float
        Ultimate gain 4d/(πa) (N·m·s/rad) and period (s) estimated from the settled part.
    amplitude_rad_s : float
        Half the peak-to-peak rate a over the settled part, rad/s.
    t_settled_s : float
        Start of the part of the trace used for the estimate, s.
    """

    t: np.ndarray
    measured_rate: np.ndarray
    torque_cmd: np.ndarray
    Ku: float
    Tu: float
    amplitude_rad_s: float
    t_settled_s: float


def relay_experiment(
    plant: AxisPlant,
    relay_amplitude_Nm: float,
    dt_s: float = 1e-3,
    duration_s: float = 0.5,
    *,
    settle_fraction: float = 0.5,
    kick_rad_s: float = 1e-3,
) -> RelayExperiment:
    """Run an Åström–Hägglund relay experiment on the simulated nonlinear axis.

    The rate loop is closed with an ideal relay, u = d·sign(0 − y): the axis settles into a limit
    cycle at the phase-crossover frequency. The describing function of the relay, 4d/(πa),
    then estimates Ku, and the cycle's period estimates Tu.

    Parameters
    ----------
    plant : AxisPlant
    relay_amplitude_Nm : float
        Relay amplitude d, N·m, > 0 (keep it below the torque limit to stay linear).
    dt_s : float
        Step of the discrete loop, s.
    duration_s : float
        Length of the experiment, s; the last ``settle_fraction`` of it is analysed.
    settle_fraction : float
        Fraction of the trace (at its end) used for the estimate, in (0, 1].
    kick_rad_s : float
        Initial rate that starts the oscillation, rad/s.

    Returns
    -------
    RelayExperiment

    Notes
    -----
    K. J. Åström and T. Hägglund, "Automatic tuning of simple regulators with specifications on
    phase and amplitude margins", Automatica 20(5), 1984. Tu is the mean spacing of the upward
    zero crossings (interpolated between samples); a is half the peak-to-peak rate.
    """
    d = _check_real("relay_amplitude_Nm", relay_amplitude_Nm, low=0.0, low_open=True)
    duration_s = _check_real("duration_s", duration_s, low=0.0, low_open=True)
    settle_fraction = _check_real("settle_fraction", settle_fraction, low=0.0, high=1.0, low_open=True)
    axis = GimbalAxis(plant, dt_s)
    axis.reset(rate_rad_s=_check_real("kick_rad_s", kick_rad_s))
    n = int(round(duration_s / axis.dt_s))
    t = np.arange(n) * axis.dt_s
    y = np.empty(n)
    u = np.empty(n)
    meas = axis.measured_rate_rad_s
    for k in range(n):
        cmd = -d if meas > 0.0 else d
        y[k] = meas
        u[k] = cmd
        meas = axis.step(cmd)
    start = int(n * (1.0 - settle_fraction))
    ys, ts = y[start:], t[start:]
    up = np.nonzero((ys[:-1] < 0.0) & (ys[1:] >= 0.0))[0]
    if len(up) < 3:
        raise ValueError(
            "relay experiment did not reach a limit cycle: increase duration_s or relay_amplitude_Nm"
        )
    crossings = ts[up] - ys[up] * (ts[up + 1] - ts[up]) / (ys[up + 1] - ys[up])
    Tu = float(np.mean(np.diff(crossings)))
    seg = ys[up[0] : up[-1] + 1]  # whole periods only
    a = 0.5 * float(seg.max() - seg.min())
    Ku = 4.0 * d / (math.pi * a)
    return RelayExperiment(t, y, u, Ku, Tu, a, float(t[start]))


def relay_ultimate_gain(
    plant: AxisPlant,
    relay_amplitude_Nm: float,
    dt_s: float = 1e-3,
    duration_s: float = 0.5,
    **kwargs,
) -> tuple[float, float]:
    """(Ku, Tu) from a relay experiment on the simulated axis; see ``relay_experiment``."""
    exp = relay_experiment(plant, relay_amplitude_Nm, dt_s, duration_s, **kwargs)
    return exp.Ku, exp.Tu


# ----------------------------------------------------------------------------------------------
# Ziegler–Nichols and PID
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PIDGains:
    """Parallel PID gains, u = kp·e + ki·∫e dt − kd·dy/dt.

    Parameters
    ----------
    kp : float
        Proportional gain (output units per error unit), >= 0.
    ki : float
        Integral gain, per second, >= 0.
    kd : float
        Derivative gain, seconds, >= 0.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0

    def __post_init__(self):
        for name in ("kp", "ki", "kd"):
            _check_real(name, getattr(self, name), low=0.0)

    def scaled(self, kp: float = 1.0, ki: float = 1.0, kd: float = 1.0) -> "PIDGains":
        """Return the gains multiplied term by term by the given factors."""
        return PIDGains(self.kp * kp, self.ki * ki, self.kd * kd)


# Ziegler & Nichols (1942), ultimate-gain ("closed-loop") table: Kp, Ti, Td in units of Ku, Tu.
_ZN_TABLE = {
    "P": (0.5, math.inf, 0.0),
    "PI": (0.45, 1.0 / 1.2, 0.0),
    "PID": (0.6, 0.5, 0.125),
}


def ziegler_nichols(Ku: float, Tu: float, kind: str = "PID") -> PIDGains:
    """Ziegler–Nichols gains from the ultimate gain and period.

    ====  ========  ========  ========
    kind  Kp        Ti        Td
    ====  ========  ========  ========
    P     0.5 Ku    —         —
    PI    0.45 Ku   Tu / 1.2  —
    PID   0.6 Ku    Tu / 2    Tu / 8
    ====  ========  ========  ========

    with ki = Kp/Ti and kd = Kp·Td.

    Parameters
    ----------
    Ku : float
        Ultimate gain, > 0.
    Tu : float
        Ultimate period, s, > 0.
    kind : {"PID", "PI", "P"}

    Returns
    -------
    PIDGains

    Notes
    -----
    J. G. Ziegler and N. B. Nichols, "Optimum settings for automatic controllers", Trans. ASME 64,
    759–768, 1942. The paper tunes its inner loop this way (§3.2.3, ref. [31]).
    """
    Ku = _check_real("Ku", Ku, low=0.0, low_open=True)
    Tu = _check_real("Tu", Tu, low=0.0, low_open=True)
    if kind not in _ZN_TABLE:
        raise ValueError(f"kind must be one of {tuple(_ZN_TABLE)}, got {kind!r}")
    kp_factor, ti_factor, td_factor = _ZN_TABLE[kind]
    kp = kp_factor * Ku
    ki = kp / (ti_factor * Tu) if math.isfinite(ti_factor) else 0.0
    kd = kp * td_factor * Tu
    return PIDGains(kp, ki, kd)


_ANTI_WINDUP = ("back_calculation", "clamp", "none")
_DERIVATIVE_N = 10.0  # default derivative filter: tau_d = Td / N


class PID:
    """Discrete PID with derivative on measurement, a filtered derivative and anti-windup.

    Continuous-time law (``pid_transfer_function`` gives the same as a transfer function)::

        u = kp·e + ki·∫e dt − kd·s/(τ_d s + 1)·y,     e = r − y,

    discretised with a forward-Euler integral (the integral state is used, then advanced) and a
    backward-Euler filtered derivative, and clipped to ``output_limits``.

    Parameters
    ----------
    gains : PIDGains
    dt_s : float
        Fixed step, s, > 0.
    output_limits : tuple of float
        (lo, hi) output limits, lo < hi; default unbounded.
    derivative_tau_s : float or None
        Derivative filter time constant τ_d, s, >= 0. ``None``: Td/10 with Td = kd/kp (or dt_s
        when kp = 0).
    anti_windup : {"back_calculation", "clamp", "none"}
        ``"back_calculation"``: the integral is corrected by (u_sat − u)/T_t with the tracking
        time T_t = √(Ti·Td) for a PID and Ti for a PI (Åström & Hägglund, *Advanced PID
        Control*, 2006, §3.5). ``"clamp"``: conditional integration — the integral is frozen
        while the output is saturated and the error drives it further into saturation.
        ``"none"``: the integral winds up.
    tracking_time_s : float or None
        Override T_t for back-calculation, s, > 0.

    Examples
    --------
    >>> pid = PID(PIDGains(2.0, 1.0, 0.0), dt_s=0.01)
    >>> pid.update(1.0, 0.0)
    2.0
    """

    def __init__(
        self,
        gains: PIDGains,
        dt_s: float,
        output_limits: tuple[float, float] = (-math.inf, math.inf),
        derivative_tau_s: float | None = None,
        anti_windup: str = "back_calculation",
        tracking_time_s: float | None = None,
    ):
        if not isinstance(gains, PIDGains):
            raise TypeError(f"gains must be PIDGains, got {type(gains).__name__}")
        self.gains = gains
        self.dt_s = _check_real("dt_s", dt_s, low=0.0, low_open=True)
        if len(output_limits) != 2:
            raise ValueError(f"output_limits must be (lo, hi), got {output_limits!r}")
        lo = _check_real("output_limits[0]", output_limits[0], allow_inf=True)
        hi = _check_real("output_limits[1]", output_limits[1], allow_inf=True)
        if not lo < hi:
            raise ValueError(f"output_limits must satisfy lo < hi, got {output_limits!r}")
        self.output_limits = (lo, hi)
        if derivative_tau_s is None:
            derivative_tau_s = gains.kd / gains.kp / _DERIVATIVE_N if gains.kp > 0 else self.dt_s
        self.derivative_tau_s = _check_real("derivative_tau_s", derivative_tau_s, low=0.0)
        if anti_windup not in _ANTI_WINDUP:
            raise ValueError(f"anti_windup must be one of {_ANTI_WINDUP}, got {anti_windup!r}")
        self.anti_windup = anti_windup
        if tracking_time_s is None:
            if gains.ki > 0 and gains.kp > 0:
                ti = gains.kp / gains.ki
                td = gains.kd / gains.kp
                tracking_time_s = math.sqrt(ti * td) if td > 0 else ti
            else:
                tracking_time_s = math.inf
        self.tracking_time_s = _check_real(
            "tracking_time_s", tracking_time_s, low=0.0, low_open=True, allow_inf=True
        )
        # precomputed coefficients (plain floats for a cheap update)
        tau, dt = self.derivative_tau_s, self.dt_s
        self._d_decay = tau / (tau + dt)
        self._d_gain = gains.kd / (tau + dt)
        self._bc = dt / self.tracking_time_s if anti_windup == "back_calculation" else 0.0
        self.reset()

    def reset(self) -> None:
        """Clear the integral, the derivative filter and the previous measurement."""
        self.integral = 0.0
        self.derivative = 0.0
        self._y_prev = None
        self.output = 0.0
        self.saturated = False

    def update(self, setpoint: float, measurement: float, hold_integral: bool = False) -> float:
        """One controller step: return the (limited) output for this sample.

        ``hold_integral`` leaves the integral as it is for this sample (conditional integration
        decided by the caller, e.g. while the plant sits against a mechanical stop).
        """
        g = self.gains
        e = setpoint - measurement
        y_prev = self._y_prev
        if y_prev is None:
            y_prev = measurement  # no derivative kick on the first sample
        self._y_prev = measurement
        self.derivative = self._d_decay * self.derivative - self._d_gain * (measurement - y_prev)
        v = g.kp * e + self.integral + self.derivative
        lo, hi = self.output_limits
        u = hi if v > hi else lo if v < lo else v
        self.saturated = u != v
        step = g.ki * e * self.dt_s
        if self.anti_windup == "back_calculation":
            step += self._bc * (u - v)
        elif self.anti_windup == "clamp" and self.saturated and (v - u) * e > 0.0:
            step = 0.0
        if hold_integral:
            step = 0.0
        self.integral += step
        self.output = u
        return u


def pid_transfer_function(gains: PIDGains, derivative_tau_s: float | None = None):
    """Continuous transfer functions of the PID law, split as used in ``closed_loop``.

    Returns
    -------
    C_e : control.TransferFunction
        Error path kp + ki/s.
    C_y : control.TransferFunction
        Measurement path kd·s/(τ_d s + 1) (entering with a minus sign).
    """
    if derivative_tau_s is None:
        derivative_tau_s = gains.kd / gains.kp / _DERIVATIVE_N if gains.kp > 0 else 0.0
    s = ct.tf("s")
    C_e = gains.kp + gains.ki / s if gains.ki > 0 else ct.tf([gains.kp], [1.0])
    C_y = ct.tf([gains.kd, 0.0], [derivative_tau_s, 1.0]) if gains.kd > 0 else ct.tf([0.0], [1.0])
    return C_e, C_y


def closed_loop(plant, gains: PIDGains, derivative_tau_s: float | None = None, pade_order: int = 6):
    """Continuous closed rate loop of the PID around ``plant`` (the loop ``RateLoop`` runs).

    Parameters
    ----------
    plant : AxisPlant or control.LTI
        An ``AxisPlant`` is built from its blocks (motor lag → inertia with the disturbance
        torque added → gyro lag → Padé delay); any other system is used as is, the disturbance
        then entering at its input.
    gains : PIDGains
    derivative_tau_s : float or None
        As in ``PID``.
    pade_order : int
        Padé order of the delay.

    Returns
    -------
    T_ry : control.StateSpace
        Reference → measured rate, C_e·G / (1 + G (C_e + C_y)).
    T_dy : control.StateSpace
        Disturbance torque → measured rate.

    Notes
    -----
    Both are the two input channels of one interconnected state-space loop
    (``control.interconnect``), so each has exactly the loop's poles; a high-order Padé delay
    in polynomial (transfer-function) form would be too ill-conditioned to simulate.
    """
    C_e, C_y = pid_transfer_function(gains, derivative_tau_s)
    blocks = [
        ct.ss(C_e, inputs="e", outputs="u_e", name="C_e"),
        ct.ss(C_y, inputs="y", outputs="u_y", name="C_y"),
        ct.summing_junction(["r", "-y"], "e", name="error"),
        ct.summing_junction(["u_e", "-u_y"], "u", name="pid"),
    ]
    if isinstance(plant, AxisPlant):
        blocks += [
            ct.ss(ct.tf([1.0], [plant.motor_tau_s, 1.0]), inputs="u", outputs="T", name="motor"),
            ct.summing_junction(["T", "d"], "T_d", name="torque"),
            ct.ss(
                ct.tf([1.0], [plant.inertia_kgm2, plant.damping_Nms_per_rad]),
                inputs="T_d",
                outputs="w",
                name="body",
            ),
            ct.ss(ct.tf([1.0], [plant.gyro_tau_s, 1.0]), inputs="w", outputs="w_g", name="gyro"),
        ]
        if plant.delay_s > 0.0:
            plant.transfer_function(pade_order)  # validates pade_order
            pade = ct.tf(*ct.pade(plant.delay_s, int(pade_order)))
            blocks.append(ct.ss(pade, inputs="w_g", outputs="y", name="delay"))
        else:
            blocks.append(ct.ss([], [], [], 1.0, inputs="w_g", outputs="y", name="delay"))
    else:
        blocks += [
            ct.summing_junction(["u", "d"], "u_d", name="torque"),
            ct.ss(plant, inputs="u_d", outputs="y", name="plant"),
        ]
    loop = ct.interconnect(blocks, inputs=["r", "d"], outputs="y")
    return loop[0, 0], loop[0, 1]


# ----------------------------------------------------------------------------------------------
# the loops of Fig. 5
# ----------------------------------------------------------------------------------------------
class RateLoop:
    """Inner loop of one joint: PID on the gyro rate, torque command out (paper §3.2.3).

    Parameters
    ----------
    plant : AxisPlant
        The axis; gives the torque limit and, when ``gains`` is None, the ZN tuning.
    gains : PIDGains or None
        ``None``: Ziegler–Nichols PID from ``ultimate_gain(plant.transfer_function())``.
    dt_s : float
        Loop step, s (1 kHz default, as on a STorM32 board).
    anti_windup : str
        Passed to ``PID``; back-calculation by default.
    derivative_tau_s : float or None
        Passed to ``PID``.

    Attributes
    ----------
    pid : PID
    Ku, Tu : float or None
        The ultimate gain and period used for the default tuning (None with explicit gains).
    """

    def __init__(
        self,
        plant: AxisPlant,
        gains: PIDGains | None = None,
        dt_s: float = 1e-3,
        anti_windup: str = "back_calculation",
        derivative_tau_s: float | None = None,
    ):
        if not isinstance(plant, AxisPlant):
            raise TypeError(f"plant must be an AxisPlant, got {type(plant).__name__}")
        self.plant = plant
        self.Ku = self.Tu = None
        if gains is None:
            self.Ku, self.Tu = ultimate_gain(plant.transfer_function())
            gains = ziegler_nichols(self.Ku, self.Tu, "PID")
        lim = plant.torque_limit_Nm
        self.pid = PID(gains, dt_s, (-lim, lim), derivative_tau_s, anti_windup)
        self.gains = gains
        self.dt_s = self.pid.dt_s

    def update(self, rate_ref_rad_s: float, rate_meas_rad_s: float, hold_integral: bool = False) -> float:
        """Return the torque command, N·m, for this 1-step sample (``hold_integral``: see :meth:`PID.update`)."""
        return self.pid.update(rate_ref_rad_s, rate_meas_rad_s, hold_integral)

    def reset(self) -> None:
        """Reset the PID state."""
        self.pid.reset()


def outer_loop_delay_s(fps: float, latency_frames: int) -> float:
    """Delay of the outer (image) loop, s: L = (latency_frames + ½) / fps.

    A detection made on frame k reaches the outer loop ``latency_frames`` frames later, and the
    rate reference it produces is held for one frame (a zero-order hold, worth half a frame).
    """
    fps = _check_real("fps", fps, low=0.0, low_open=True)
    if isinstance(latency_frames, bool) or not float(latency_frames).is_integer() or latency_frames < 0:
        raise ValueError(f"latency_frames must be an integer >= 0, got {latency_frames!r}")
    return (int(latency_frames) + 0.5) / fps


def outer_loop_plant(fps: float = 30.0, latency_frames: int = 1, pade_order: int = 6):
    """The plant the outer loop sees: camera rate reference → angle of the target's line of sight.

    With the inner rate loops closed (their bandwidth, tens of Hz, is far above the outer loop's),
    the camera turns at the commanded rate, so the angle is the integral of the reference; the
    image reaches the loop after the vision delay L (:func:`outer_loop_delay_s`):

        P(s) = e^{−sL} / s.

    Parameters
    ----------
    fps : float
        Camera frame rate, 1/s.
    latency_frames : int
        Frames between taking an image and its detection reaching the loop, >= 0.
    pade_order : int
        Order of the Padé approximant of the delay.

    Returns
    -------
    control.TransferFunction

    Notes
    -----
    Paper §3.2.3, Fig. 5 (outer loop). The phase of e^{−sL}/s reaches −180° at ω = π/(2L), where
    |P| = 2L/π: Ku = π/(2L) and Tu = 4L (a hand derivation the tests check).
    """
    L = outer_loop_delay_s(fps, latency_frames)
    integrator = ct.tf([1.0], [1.0, 0.0])
    return integrator * ct.tf(*ct.pade(L, int(pade_order)))


def outer_loop_gains(fps: float = 30.0, latency_frames: int = 1, kind: str = "PI") -> PIDGains:
    """Ziegler–Nichols gains of the outer image loop from its own plant (:func:`outer_loop_plant`).

    Ku and Tu come from :func:`ultimate_gain`; the rule is the ultimate-gain table of
    :func:`ziegler_nichols` (PI by default: kp = 0.45 Ku, Ti = Tu/1.2). Nothing about the target's
    motion enters. kp is in rad/s of camera rate per rad of angular error (1/s), ki in 1/s².

    Examples
    --------
    >>> g = outer_loop_gains(30.0, 1)       # L = 1.5 frames = 50 ms: Ku = 10π /s, Tu = 0.2 s
    >>> round(g.kp, 3), round(g.ki, 2)
    (14.137, 84.82)
    """
    Ku, Tu = ultimate_gain(outer_loop_plant(fps, latency_frames))
    return ziegler_nichols(Ku, Tu, kind)


class ImageLoop:
    """Outer loop: target pixel → joint-rate references (paper §3.2.3, Fig. 5).

    Per call:

    1. pixel error e = (u_ref − u, v_ref − v) with (u_ref, v_ref) = (cx, cy);
    2. the target's normalised ray (x, y, 1) (through ``camera.backproject``, so lens distortion
       is removed when a model is given) becomes the camera rotation that brings it onto the
       optical axis. In the OpenCV camera frame the optical axis z turns towards the ray about
       z × (x, y, 1) = (−y, x, 0): a target right of centre (x > 0) needs a positive rotation
       about +y (down), a target below centre (y > 0) a negative rotation about +x. With
       ``exact_angles`` the rotation vector is atan(ρ)·(−y, x, 0)/ρ, ρ = √(x² + y²) (the
       geodesic rotation); otherwise the small-angle (−y, x, 0). No rotation about the optical
       axis is requested: pointing needs two degrees of freedom only;
    3. camera angular-rate reference ω = kp·θ + ki·∫θ dt (PI on the angular error);
    4. joint rates q̇ from J_cam: the two pointing rows (J_cam[0] q̇ = ω_x, J_cam[1] q̇ = ω_y) plus
       a **roll-levelling** row that fixes the roll joint's rate to −roll_gain·q_roll, so the
       free rotation about the optical axis is spent on driving the roll joint back to zero.
       When the 3×3 system is singular (roll joint parallel to the pointing plane), the
       least-squares solution of J_cam q̇ = (ω_x, ω_y, 0) is used instead;
    5. the joint rates are scaled down together so that none exceeds ``max_rate_rad_s``; the
       integral is frozen while that limit is active (anti-windup).

    When the target is lost (``uv_px`` None), the integral is frozen and the loop first coasts:
    for ``coast_s`` after the loss (the updates whose interval of one ``dt_s`` ends by then) it
    repeats its last joint-rate command, so the camera keeps turning as it did; 0 (the default)
    skips this. Then the joints hold (zero rate) until ``lost_hold_s`` after the loss; after that,
    with ``return_home`` the joints return to q = 0 with rate −home_gain·q (limited) and the
    integral is cleared; without it they keep holding. A new detection resumes tracking at once.

    Parameters
    ----------
    intrinsics : Intrinsics
    kp_per_s : float
        Proportional gain, rad/s of rate per rad of angular error, > 0.
    ki_per_s2 : float
        Integral gain, >= 0 (removes the lag on a target moving at constant rate).
    max_rate_rad_s : float
        Largest joint-rate reference, rad/s, > 0.
    lost_hold_s : float
        Hold time after the target is lost, s, >= 0.
    return_home : bool
        Return to the home pose after the hold.
    exact_angles : bool
        Geodesic (atan) angle instead of the small-angle approximation.
    roll_gain_per_s : float
        Gain of the roll-levelling row, 1/s, >= 0.
    home_gain_per_s : float
        Gain of the return to home, 1/s, > 0.
    distortion : BrownConrady or None
        Lens model of the pixels passed in (None: pinhole).
    coast_s : float
        How long after losing the target the last command is repeated, s, >= 0 (0: hold at once).
        The occlusion study's blind fallback (docs/design.md, "When does a gimbal pay off?",
        Repairs) uses the target filters' coasting time, 1.5 s.

    Examples
    --------
    A target right of centre, then lost: the loop repeats its last command for ``coast_s``, then
    holds.

    >>> K = Intrinsics.default()
    >>> J = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    >>> loop = ImageLoop(K, kp_per_s=2.0, coast_s=0.1)
    >>> last = loop.update((K.cx + 50.0, K.cy), 0.05, J, np.zeros(3))
    >>> [bool(np.array_equal(loop.update(None, 0.05, J, np.zeros(3)), last)) for _ in range(3)]
    [True, True, False]
    >>> loop.state
    'hold'
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        kp_per_s: float = 4.0,
        ki_per_s2: float = 0.0,
        max_rate_rad_s: float = 3.0,
        lost_hold_s: float = 1.0,
        return_home: bool = False,
        exact_angles: bool = True,
        roll_gain_per_s: float = 2.0,
        home_gain_per_s: float = 1.0,
        distortion=None,
        coast_s: float = 0.0,
    ):
        self.intrinsics = intrinsics
        self.kp_per_s = _check_real("kp_per_s", kp_per_s, low=0.0, low_open=True)
        self.ki_per_s2 = _check_real("ki_per_s2", ki_per_s2, low=0.0)
        self.max_rate_rad_s = _check_real("max_rate_rad_s", max_rate_rad_s, low=0.0, low_open=True)
        self.lost_hold_s = _check_real("lost_hold_s", lost_hold_s, low=0.0)
        self.return_home = bool(return_home)
        self.exact_angles = bool(exact_angles)
        self.roll_gain_per_s = _check_real("roll_gain_per_s", roll_gain_per_s, low=0.0)
        self.home_gain_per_s = _check_real("home_gain_per_s", home_gain_per_s, low=0.0, low_open=True)
        self.distortion = distortion
        self.coast_s = _check_real("coast_s", coast_s, low=0.0)
        self.reset()

    @classmethod
    def ziegler_nichols(cls, intrinsics: Intrinsics, fps: float = 30.0, latency_frames: int = 1, **kwargs) -> "ImageLoop":
        """The paper's outer loop with Ziegler–Nichols PI gains from :func:`outer_loop_gains`.

        ``kwargs`` set the other parameters (limits, lost-target behaviour, lens).
        """
        gains = outer_loop_gains(fps, latency_frames, "PI")
        return cls(intrinsics, kp_per_s=gains.kp, ki_per_s2=gains.ki, **kwargs)

    def reset(self) -> None:
        """Clear the integral, the lost-target timer and the last command."""
        self.integral = np.zeros(2)
        self.lost_time_s = 0.0
        self._lost_updates = 0
        self.last_command = np.zeros(3)
        self.state = "tracking"
        self.error_px = np.full(2, np.nan)
        self.angle_error_rad = np.full(2, np.nan)

    def camera_angle_error(self, uv_px) -> np.ndarray:
        """Rotation (ω-direction, rad) about camera x and y that centres the pixel ``uv_px``.

        Returns
        -------
        ndarray, shape (2,)
            (θ_x, θ_y): rotation about the camera's x (right) and y (down) axes, rad.
        """
        ray = backproject(np.asarray(uv_px, dtype=float).reshape(1, 2), self.intrinsics, self.distortion)[0]
        x, y = ray[0] / ray[2], ray[1] / ray[2]
        theta = np.array([-y, x])
        if self.exact_angles:
            rho = math.hypot(x, y)
            if rho > 0.0:
                theta *= math.atan(rho) / rho
        return theta

    def update(self, uv_px, dt_s: float, J_cam, q_rad) -> np.ndarray:
        """Joint-rate references (yaw, roll, pitch), rad/s, for this frame.

        Parameters
        ----------
        uv_px : array_like, shape (2,), or None
            Detected target centre, px; None when nothing was detected.
        dt_s : float
            Time since the previous call, s, > 0.
        J_cam : array_like, shape (3, 3)
            Angular Jacobian in the camera frame: camera angular velocity = J_cam @ q̇.
        q_rad : array_like, shape (3,)
            Joint angles (yaw, roll, pitch), rad.

        Returns
        -------
        ndarray, shape (3,)
        """
        dt_s = _check_real("dt_s", dt_s, low=0.0, low_open=True)
        J = np.asarray(J_cam, dtype=float)
        q = np.asarray(q_rad, dtype=float)
        if J.shape != (3, 3) or q.shape != (3,):
            raise ValueError(f"J_cam must have shape (3, 3) and q_rad (3,), got {J.shape} and {q.shape}")
        if uv_px is None:
            return self._lost(dt_s, q)
        uv = np.asarray(uv_px, dtype=float)
        if uv.shape != (2,) or not np.all(np.isfinite(uv)):
            raise ValueError(f"uv_px must be a finite (2,) pixel or None, got {uv_px!r}")
        self.state = "tracking"
        self.lost_time_s = 0.0
        self._lost_updates = 0
        cx, cy = self.intrinsics.cx, self.intrinsics.cy
        self.error_px = np.array([cx - uv[0], cy - uv[1]])
        theta = self.camera_angle_error(uv)
        self.angle_error_rad = theta
        omega_xy = self.kp_per_s * theta + self.ki_per_s2 * self.integral
        qdot = self._joint_rates(J, omega_xy, -self.roll_gain_per_s * q[1])
        qdot, limited = self._limit(qdot)
        if not limited:
            self.integral = self.integral + theta * dt_s
        self.last_command = qdot
        return qdot

    def _joint_rates(self, J, omega_xy, roll_rate):
        A = np.vstack([J[:2], [0.0, 1.0, 0.0]])
        b = np.array([omega_xy[0], omega_xy[1], roll_rate])
        if np.linalg.cond(A) < 1e8:
            return np.linalg.solve(A, b)
        return np.linalg.lstsq(J, np.array([omega_xy[0], omega_xy[1], 0.0]), rcond=None)[0]

    def _limit(self, qdot):
        peak = float(np.max(np.abs(qdot)))
        if peak > self.max_rate_rad_s:
            return qdot * (self.max_rate_rad_s / peak), True
        return qdot, False

    def _lost(self, dt_s, q):
        self.lost_time_s += dt_s
        self._lost_updates += 1
        self.error_px = np.full(2, np.nan)
        self.angle_error_rad = np.full(2, np.nan)
        # the lost time is a sum of steps: allow its rounding, at most n·ε·sum after n additions
        # (1.5 s of 1/30 s steps sums to 1.5 + 1.3e-15)
        rounding_s = self._lost_updates * np.finfo(float).eps * self.lost_time_s
        if self.lost_time_s <= self.coast_s + rounding_s:
            self.state = "coast"
            return self.last_command.copy()
        if self.lost_time_s <= self.lost_hold_s or not self.return_home:
            self.state = "hold"
            return np.zeros(3)
        self.state = "home"
        self.integral = np.zeros(2)
        return self._limit(-self.home_gain_per_s * q)[0]


# ----------------------------------------------------------------------------------------------
# simulation
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AxisSimulation:
    """Result of ``simulate_axis``; all arrays have shape (N,), sampled at the step times.

    Attributes
    ----------
    t : time, s.
    rate : true axis rate, rad/s.
    measured_rate : gyro reading the controller saw, rad/s.
    angle : axis angle, rad.
    torque : torque command (before saturation), N·m.
    saturated : whether the command exceeded the torque limit.
    reference : rate reference, rad/s.
    disturbance : disturbance torque, N·m.
    """

    t: np.ndarray
    rate: np.ndarray
    measured_rate: np.ndarray
    angle: np.ndarray
    torque: np.ndarray
    saturated: np.ndarray
    reference: np.ndarray
    disturbance: np.ndarray
    extra: dict = field(default_factory=dict)


def _signal(name: str, value, t: np.ndarray) -> np.ndarray:
    if value is None:
        return np.zeros_like(t)
    if callable(value):
        out = np.asarray([value(tk) for tk in t], dtype=float)
    else:
        out = np.broadcast_to(np.asarray(value, dtype=float), t.shape).copy()
    if out.shape != t.shape:
        raise ValueError(f"{name} must be a scalar, a callable of t or an array of shape {t.shape}")
    return out


def simulate_axis(
    plant: AxisPlant,
    controller,
    reference: float | Callable | np.ndarray = 0.0,
    disturbance: float | Callable | np.ndarray | None = None,
    t: np.ndarray | None = None,
    *,
    duration_s: float = 1.0,
    dt_s: float = 1e-3,
) -> AxisSimulation:
    """Simulate one axis in closed loop at a fixed step (``GimbalAxis`` integrator).

    At step k the controller sees the gyro reading y_k and the reference r_k and returns the
    torque command u_k, which ``GimbalAxis`` holds over [t_k, t_k + dt).

    Parameters
    ----------
    plant : AxisPlant
    controller : object with ``update(reference, measurement) -> torque`` and ``reset()``
        (``RateLoop``, ``PID``), or None for an open loop (zero torque). It is reset first.
    reference : float, callable t -> float, or ndarray shape (N,)
        Rate reference, rad/s.
    disturbance : float, callable, ndarray shape (N,) or None
        Disturbance torque at the inertia, N·m.
    t : ndarray, shape (N,), or None
        Uniformly spaced times, s; default ``np.arange(0, duration_s, dt_s)``.

    Returns
    -------
    AxisSimulation
    """
    if t is None:
        duration_s = _check_real("duration_s", duration_s, low=0.0, low_open=True)
        dt_s = _check_real("dt_s", dt_s, low=0.0, low_open=True)
        t = np.arange(int(round(duration_s / dt_s))) * dt_s
    else:
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError("t must be a 1-D array of at least 2 times")
        steps = np.diff(t)
        dt_s = float(steps[0])
        if dt_s <= 0 or not np.allclose(steps, dt_s, rtol=1e-6, atol=1e-12):
            raise ValueError("t must be uniformly spaced and increasing (fixed-step simulation)")
    r = _signal("reference", reference, t)
    d = _signal("disturbance", disturbance, t)
    axis = GimbalAxis(plant, dt_s)
    if controller is not None:
        controller.reset()
    n = t.size
    rate = np.empty(n)
    meas = np.empty(n)
    angle = np.empty(n)
    torque = np.empty(n)
    sat = np.zeros(n, dtype=bool)
    r_list, d_list = r.tolist(), d.tolist()
    y = axis.measured_rate_rad_s
    for k in range(n):
        u = controller.update(r_list[k], y) if controller is not None else 0.0
        rate[k] = axis.rate_rad_s
        angle[k] = axis.angle_rad
        meas[k] = y
        torque[k] = u
        y = axis.step(u, d_list[k])
        sat[k] = axis.saturated
    return AxisSimulation(t, rate, meas, angle, torque, sat, r, d)


def step_metrics(t, y, final_value: float | None = None, settling_threshold: float = 0.02) -> dict:
    """Overshoot (%), settling time (s), rise time (s) and peak of a step response.

    Thin wrapper of ``control.step_info`` on sampled data.
    """
    info = ct.step_info(
        np.asarray(y, dtype=float),
        timepts=np.asarray(t, dtype=float),
        final_output=final_value,
        SettlingTimeThreshold=settling_threshold,
    )
    return {
        "overshoot_pct": float(info["Overshoot"]),
        "settling_time_s": float(info["SettlingTime"]),
        "rise_time_s": float(info["RiseTime"]),
        "peak": float(info["Peak"]),
    }


def compare_tunings(
    plant: AxisPlant,
    gains_by_label: dict,
    reference: float = 1.0,
    duration_s: float = 0.1,
    dt_s: float = 1e-3,
    anti_windup: str = "back_calculation",
):
    """Rate-step responses of several tunings of one axis and their step metrics.

    Parameters
    ----------
    plant : AxisPlant
    gains_by_label : dict of str -> PIDGains
    reference : float
        Rate step, rad/s (small enough to stay linear by default).
    duration_s, dt_s : float
        Simulation length and step, s.

    Returns
    -------
    table : pandas.DataFrame
        One row per label: kp, ki, kd, overshoot_pct, settling_time_s (2 %), rise_time_s and
        the final value (of the true rate; a P loop keeps a steady-state error).
    sims : dict of str -> AxisSimulation
    """
    import pandas as pd

    rows, sims = [], {}
    for label, gains in gains_by_label.items():
        sim = simulate_axis(
            plant, RateLoop(plant, gains, dt_s, anti_windup), reference, None, duration_s=duration_s, dt_s=dt_s
        )
        sims[label] = sim
        metrics = step_metrics(sim.t, sim.rate)
        rows.append(dict(label=label, kp=gains.kp, ki=gains.ki, kd=gains.kd, **metrics, final=float(sim.rate[-1])))
    return pd.DataFrame(rows).set_index("label"), sims


@dataclass(frozen=True)
class PointingSimulation:
    """Result of ``simulate_pointing``; N frames.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Frame times, s.
    uv_px : ndarray, shape (N, 2)
        Target pixel seen in each frame (NaN when outside the image or lost).
    error_px : ndarray, shape (N, 2)
        (u − cx, v − cy), px — the offset from the image centre (the loop's e with the sign flipped).
    q_rad : ndarray, shape (N, 3)
        Joint angles at each frame, rad.
    qdot_rad_s : ndarray, shape (N, 3)
        Joint-rate references produced at each frame, rad/s.
    """

    t: np.ndarray
    uv_px: np.ndarray
    error_px: np.ndarray
    q_rad: np.ndarray
    qdot_rad_s: np.ndarray


def simulate_pointing(
    image_loop: ImageLoop,
    camera_pose: Callable,
    target_world: Callable,
    duration_s: float,
    fps: float = 30.0,
    q0_rad=(0.0, 0.0, 0.0),
    visible: Callable | None = None,
    latency_frames: int = 0,
) -> PointingSimulation:
    """Outer loop alone: the joints follow the rate references exactly (ideal inner loop).

    Each frame the target point is projected with the pinhole camera (``camera.project``), the
    loop turns its pixel into joint rates, and the joint angles integrate them over the frame.

    Parameters
    ----------
    image_loop : ImageLoop
        Reset first.
    camera_pose : callable q -> (T_world_cam (4, 4), J_cam (3, 3))
        Camera pose and camera-frame angular Jacobian at joint angles q, e.g. from
        ``kinematics.GimbalKinematics``.
    target_world : callable t -> ndarray, shape (3,)
        Target position in the world, m.
    duration_s, fps : float
        Length, s, and frame rate, 1/s.
    q0_rad : array_like, shape (3,)
        Initial joint angles, rad.
    visible : callable t -> bool, optional
        False makes the frame a "no detection" (e.g. an occlusion).
    latency_frames : int
        Frames between taking an image and its pixel reaching the loop, >= 0 (the study: 1).
    """
    from .camera import project

    image_loop.reset()
    fps = _check_real("fps", fps, low=0.0, low_open=True)
    n = int(round(_check_real("duration_s", duration_s, low=0.0, low_open=True) * fps))
    dt = 1.0 / fps
    K = image_loop.intrinsics
    q = np.asarray(q0_rad, dtype=float).copy()
    t = np.arange(n) * dt
    outer_loop_delay_s(fps, latency_frames)  # validates latency_frames
    pending = []
    uvs, qs, qds = np.full((n, 2), np.nan), np.empty((n, 3)), np.empty((n, 3))
    for k in range(n):
        T_world_cam, J_cam = camera_pose(q)
        T_world_cam = np.asarray(T_world_cam, dtype=float)
        p_cam = T_world_cam[:3, :3].T @ (np.asarray(target_world(t[k]), float) - T_world_cam[:3, 3])
        uv = project(p_cam[None, :], K, image_loop.distortion)[0]
        inside = bool(np.all(np.isfinite(uv))) and 0 <= uv[0] <= K.width - 1 and 0 <= uv[1] <= K.height - 1
        if visible is not None and not visible(t[k]):
            inside = False
        if inside:
            uvs[k] = uv
        qs[k] = q
        pending.append(uv if inside else None)
        seen = pending.pop(0) if len(pending) > latency_frames else None
        qdot = image_loop.update(seen, dt, J_cam, q)
        qds[k] = qdot
        q = q + dt * qdot
    error = uvs - np.array([K.cx, K.cy])
    return PointingSimulation(t, uvs, error, qs, qds)
