"""The UAV body's motion against independent oracles.

- Shaped noise: variance and band powers of a long sample (scipy.signal.welch) against the
  shaping filter's |H(j2πf)|² (scipy.signal.freqs), and rates against central differences.
- Vibration: RMS per axis and the spectral peak at the blade-pass frequency.
- Body rates: the Euler-rate map against Rᵀ·dR/dt from finite differences of the rotation.
- Flight: the waypoint profile (speeds, accelerations, leg times) by hand, and the bank making the
  thrust axis parallel to a + g·z.
- Same seed, same motion; named errors on bad input.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as ss

from gimbal_lab.platform import (
    GRAVITY_M_S2,
    BodyMotion,
    HoverSway,
    ShapedNoise,
    Vibration,
    WaypointFlight,
    body_rates_from_euler,
    euler_to_matrix,
)


def _band_powers(x, fs, edges, nperseg):
    f, psd = ss.welch(x, fs=fs, nperseg=nperseg)
    df = f[1] - f[0]
    return [psd[(f >= a) & (f < b)].sum() * df for a, b in zip(edges[:-1], edges[1:])]


def _filter_band_powers(rms, fn, zeta, edges):
    """Band powers of white noise through H(s) = ωn²/(s² + 2ζωn s + ωn²), normalised to rms²
    over [0, 10 fn] (where the process puts its power), from scipy.signal.freqs."""
    wn = 2 * np.pi * fn
    fine = np.linspace(0.0, 10.0 * fn, 200001)
    _, h = ss.freqs([wn * wn], [1.0, 2 * zeta * wn, wn * wn], worN=2 * np.pi * fine)
    h2 = np.abs(h) ** 2
    total = np.trapezoid(h2, fine)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = (fine >= a) & (fine <= b)
        out.append(rms**2 * np.trapezoid(h2[m], fine[m]) / total)
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_shaped_noise_variance_and_spectrum_follow_the_filter(seed):
    rms, fn, zeta = 2.0, 1.5, 0.7
    noise = ShapedNoise(rms, fn, zeta, np.random.default_rng(seed))
    fs = 50.0
    x = noise.value(np.arange(0.0, 2000.0, 1.0 / fs))
    assert x.std() == pytest.approx(rms, rel=0.03)  # 2000 s ≫ the 40 s a line spacing of 0.025 Hz needs
    # Bands from 0.5 Hz up (0.1 Hz Welch bins hold several lines each; below 0.5 Hz the 10 s
    # segments cannot resolve the spectrum). 10 %: the sample's own scatter is ~8 % at 1.5 Hz.
    edges = [0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 15.0]
    got = _band_powers(x, fs, edges, nperseg=500)
    want = _filter_band_powers(rms, fn, zeta, edges)
    np.testing.assert_allclose(got, want, rtol=0.10)
    # The analytic psd() integrates to rms² over the synthesised band.
    f = np.linspace(0.0, 10 * fn, 20001)
    assert np.trapezoid(noise.psd(f), f) == pytest.approx(rms**2, rel=1e-6)
    np.testing.assert_allclose([np.trapezoid(noise.psd(np.linspace(a, b, 2001)), np.linspace(a, b, 2001))
                                for a, b in zip(edges[:-1], edges[1:])], want, rtol=1e-3)


def test_shaped_noise_rate_and_integral_are_exact_derivatives():
    noise = ShapedNoise(0.05, 0.5, 0.7, 3)
    t = np.linspace(0.0, 30.0, 301)
    h = 1e-5
    fd = (noise.value(t + h) - noise.value(t - h)) / (2 * h)
    np.testing.assert_allclose(noise.rate(t), fd, atol=1e-8)
    fd_int = (noise.integral(t + h) - noise.integral(t - h)) / (2 * h)
    np.testing.assert_allclose(fd_int, noise.value(t), atol=1e-8)
    assert noise.integral(0.0) == 0.0


@pytest.mark.parametrize("n, spacing_s, t0_s", [(16, 1e-3, 0.0), (33, 5.2e-4, 3.7), (1001, 1e-3, 12.345), (40, 0.0, 1.0)])
def test_shaped_noise_on_even_grids_is_the_direct_sum(n, spacing_s, t0_s):
    """Oracle: the sum Σ a_k cos(ω_k t + φ_k) (and its derivative and integral) with numpy's own
    sine and cosine at every instant. Even grids are stepped by angle addition; they must agree
    within 1e-12 of the RMS (of the rate's RMS for rates) — round-off, far below any effect —
    and a grid that is not even (a jittered one, a repeated instant) is evaluated directly."""
    noise = ShapedNoise(0.03, 1.5, 0.7, np.random.default_rng(4))
    grids = [t0_s + spacing_s * np.arange(n)]
    grids.append(grids[0] + np.random.default_rng(1).uniform(0.0, 1e-6, n))  # not even
    for t in grids:
        arg = np.outer(t, noise._omega) + noise.phase
        rate_rms = noise.rms * noise._omega.max()
        np.testing.assert_allclose(noise.value(t), np.cos(arg) @ noise.amplitude, rtol=0, atol=1e-12 * noise.rms)
        np.testing.assert_allclose(noise.rate(t), -np.sin(arg) @ (noise.amplitude * noise._omega), rtol=0,
                                   atol=1e-12 * rate_rms)
        np.testing.assert_allclose(noise.integral(t), (np.sin(arg) - np.sin(noise.phase)) @ (noise.amplitude / noise._omega),
                                   rtol=0, atol=1e-12 * noise.rms)
        np.testing.assert_array_equal(noise.value(t), noise.value(t.copy()))  # the kept result


def test_zero_rms_noise_is_silent():
    noise = ShapedNoise(0.0, 1.0, 0.7, 0)
    assert np.all(noise.value(np.linspace(0, 5, 11)) == 0.0)


@pytest.mark.parametrize("seed", [0, 4])
def test_vibration_rms_and_peak_at_blade_pass(seed):
    vib = Vibration()
    motion = BodyMotion(vibration=vib, seed=seed)
    fs = 1000.0  # Nyquist 500 Hz, well above the 132 Hz jitter edge
    t = np.arange(0.0, 20.0, 1.0 / fs)
    angles, _ = motion.attitude(t)
    for axis in range(3):
        a = angles[:, axis] - (motion.yaw_rad if axis == 0 else 0.0)
        assert a.std() == pytest.approx(vib.rms_rad, rel=0.02)
        f, psd = ss.welch(a, fs=fs, nperseg=4096)
        peak = f[np.argmax(psd)]
        assert abs(peak - 120.0) < 0.10 * 120.0
        # Nearly all the power lies within the ±10 % jitter band.
        band = (f > 108.0 * 0.97) & (f < 132.0 * 1.03)
        assert psd[band].sum() / psd.sum() > 0.95


def test_euler_matrix_matches_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    ypr = rng.uniform(-1.2, 1.2, size=(50, 3))
    want = Rotation.from_euler("ZYX", ypr).as_matrix()
    np.testing.assert_allclose(euler_to_matrix(ypr[:, 0], ypr[:, 1], ypr[:, 2]), want, atol=1e-14)


@pytest.mark.parametrize("motion", [
    BodyMotion.hover(seed=1, vibration=True),
    BodyMotion.flying(seed=2),
    BodyMotion(flight=WaypointFlight(start_m=(-1.0, -1.0, 2.0), end_m=(1.5, 1.0, 2.5))),  # pitch, roll and climb at once
], ids=["hover+vibration", "flight", "diagonal-climb"])
def test_body_rate_is_the_rotation_derivative(motion):
    """ω× = Rᵀ·dR/dt, from central differences of T_world_body (independent of the Euler map)."""
    t = np.linspace(0.1, 7.0, 40)
    h = 1e-6
    R = motion.T_world_body(t)[:, :3, :3]
    dR = (motion.T_world_body(t + h)[:, :3, :3] - motion.T_world_body(t - h)[:, :3, :3]) / (2 * h)
    W = np.einsum("nji,njk->nik", R, dR)
    fd = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    w = motion.angular_rate_body(t)
    scale = np.abs(w).max()
    np.testing.assert_allclose(w, fd, atol=1e-6 * max(scale, 1.0))
    np.testing.assert_allclose(motion.angular_rate_body(t[3]), w[3])


def test_body_rates_from_euler_hand_cases():
    # pure yaw rate at level attitude: r = ψ̇; pure roll rate: p = φ̇
    np.testing.assert_allclose(body_rates_from_euler(0.0, 0.0, 0.3, 0.0, 0.0), [0, 0, 0.3])
    np.testing.assert_allclose(body_rates_from_euler(0.0, 0.0, 0.0, 0.0, 0.2), [0.2, 0, 0])
    # yaw rate with the body pitched 90° shows up as a negative roll rate
    np.testing.assert_allclose(body_rates_from_euler(math.pi / 2, 0.0, 0.5, 0.0, 0.0), [-0.5, 0, 0], atol=1e-15)


def test_waypoint_profile_by_hand():
    fl = WaypointFlight()
    # ramp: T_a = 2 v / a = 2 s covering a·T_a²/4 = 1 m; cruise 3 - 2 = 1 m at 1 m/s
    assert (fl.ramp_s, fl.ramp_m, fl.cruise_m, fl.leg_s, fl.period_s) == pytest.approx((2.0, 1.0, 1.0, 5.0, 10.0))
    # s(t) = a (t²/4 + (cos 2wt − 1)/(8w²)), w = π/T_a: s(1) = 1/4 − 1/π²
    p, v, a, j = fl.kinematics(np.array([0.0, 1.0, 2.0, 2.5, 5.0, 7.5, 10.0]))
    np.testing.assert_allclose(p[:, 1], [-1.5, -1.5 + 0.25 - 1 / math.pi**2, -0.5, 0.0, 1.5, 0.0, -1.5], atol=1e-12)
    np.testing.assert_allclose(v[:, 1], [0.0, 0.5, 1.0, 1.0, 0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(a[:, 1], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], atol=1e-12)
    assert np.all(p[:, [0, 2]] == [0.0, 2.0])
    # velocity and acceleration are the derivatives of position and velocity
    t = np.linspace(0.0, 20.0, 2001)
    h = 1e-6
    pp, vv, aa, jj = fl.kinematics(t)
    np.testing.assert_allclose((fl.kinematics(t + h)[0] - fl.kinematics(t - h)[0]) / (2 * h), vv, atol=1e-6)
    np.testing.assert_allclose((fl.kinematics(t + h)[1] - fl.kinematics(t - h)[1]) / (2 * h), aa, atol=1e-6)
    assert np.abs(aa).max() == pytest.approx(1.0, rel=1e-4) and np.abs(vv).max() == pytest.approx(1.0)


@pytest.mark.parametrize("start, end", [((0.0, -1.5, 2.0), (0.0, 1.5, 2.0)), ((-1.0, -1.0, 2.0), (1.5, 1.0, 2.5))])
def test_flight_bank_points_thrust_along_acceleration_plus_gravity(start, end):
    motion = BodyMotion(flight=WaypointFlight(start_m=start, end_m=end))
    t = np.linspace(0.0, 2 * motion.flight.period_s, 400)
    R = motion.T_world_body(t)[:, :3, :3]
    _, _, acc, _ = motion.flight.kinematics(t)
    need = acc + np.array([0.0, 0.0, GRAVITY_M_S2])
    need /= np.linalg.norm(need, axis=1, keepdims=True)
    np.testing.assert_allclose(R[:, :, 2], need, atol=1e-12)
    if start[2] == end[2]:  # level flight: the largest tilt is atan(1 m/s² / g) = 5.82°
        tilt = np.degrees(np.arccos(R[:, 2, 2]))
        assert tilt.max() == pytest.approx(math.degrees(math.atan(1.0 / GRAVITY_M_S2)), rel=1e-3)


def test_hover_sway_rms_matches_the_design():
    motion = BodyMotion.hover(seed=7)
    t = np.arange(0.0, 1500.0, 0.1)  # ≫ the 40–120 s the line spacings need; aliasing keeps the variance
    angles, _ = motion.attitude(t)
    pos = motion.position(t)
    assert np.degrees(angles[:, 2].std()) == pytest.approx(2.0, rel=0.05)  # roll
    assert np.degrees(angles[:, 1].std()) == pytest.approx(2.0, rel=0.05)  # pitch
    assert np.degrees(angles[:, 0].std()) == pytest.approx(1.0, rel=0.05)  # yaw
    np.testing.assert_allclose(pos.std(axis=0), 0.05, rtol=0.08)  # 0.5 Hz: fewer independent samples
    np.testing.assert_allclose(pos.mean(axis=0), [0.0, 0.0, 2.0], atol=0.01)


def test_same_seed_same_motion_other_seed_other_motion():
    t = np.linspace(0.0, 3.0, 50)
    a = BodyMotion.hover(seed=3, vibration=True).T_world_body(t)
    b = BodyMotion.hover(seed=3, vibration=True).T_world_body(t)
    c = BodyMotion.hover(seed=4, vibration=True).T_world_body(t)
    assert np.array_equal(a, b) and not np.allclose(a, c)


def test_static_body_is_the_papers_still_mount():
    still = BodyMotion.static()
    np.testing.assert_array_equal(still.T_world_body(2.0), np.array(
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2.0], [0, 0, 0, 1]], dtype=float))
    assert np.all(still.angular_rate_body(np.linspace(0, 1, 5)) == 0.0)


@pytest.mark.parametrize("make, message", [
    (lambda: ShapedNoise(-1.0, 1.0, 0.7, 0), "rms must be >= 0"),
    (lambda: ShapedNoise(1.0, 0.0, 0.7, 0), "natural_hz must be > 0"),
    (lambda: ShapedNoise(1.0, 1.0, float("nan"), 0), "damping must be finite"),
    (lambda: ShapedNoise("1", 1.0, 0.7, 0), "rms must be a number"),
    (lambda: ShapedNoise(1.0, 1.0, 0.7, -3), "seed must be an integer >= 0"),
    (lambda: Vibration(jitter=1.0), "jitter must be < 1"),
    (lambda: HoverSway(attitude_hz=-1.0), "attitude_hz must be > 0"),
    (lambda: WaypointFlight(end_m=(0.0, 0.0)), "end_m must be three finite numbers"),
    (lambda: WaypointFlight(end_m=(0.0, -1.0, 2.0)), "too short"),
    (lambda: BodyMotion(position_m=(0, 0, float("inf"))), "position_m must be three finite numbers"),
    (lambda: BodyMotion(sway="yes"), "sway must be a HoverSway or None"),
    (lambda: BodyMotion.hover().T_world_body(float("nan")), "t_s must be finite"),
])
def test_bad_input_is_named(make, message):
    with pytest.raises((ValueError, TypeError), match=message):
        make()


@pytest.mark.parametrize("motion", [
    BodyMotion.static(),
    BodyMotion.hover(seed=1, vibration=True),
    BodyMotion(sway=HoverSway(), vibration=Vibration(), flight=WaypointFlight(), seed=3, time_offset_s=2.5),
], ids=["still", "hover+vibration", "flight+vibration, offset"])
def test_pose_of_many_instants_is_the_pose_of_each(motion):
    """T_world_body of an array of times against one call per time (1e-12: the sums of sinusoids
    round differently as matrix-vector products), and its rotation and origin are attitude()'s
    angles through euler_to_matrix and position() (exactly: the pose skips the rates)."""
    t = np.linspace(0.2, 6.0, 29)
    T = motion.T_world_body(t)
    np.testing.assert_allclose(T, [motion.T_world_body(x) for x in t], rtol=0, atol=1e-12)
    angles, _ = motion.attitude(t)
    np.testing.assert_array_equal(T[:, :3, :3], euler_to_matrix(*angles.T))
    np.testing.assert_array_equal(T[:, :3, 3], motion.position(t))
    np.testing.assert_array_equal(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
