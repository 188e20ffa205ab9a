"""Tests of gimbal_lab.control against python-control and hand derivations."""

import math

import control as ct
import numpy as np
import pytest

from gimbal_lab.camera import Intrinsics, project
from gimbal_lab.control import (
    AXES,
    PID,
    AxisPlant,
    GimbalAxis,
    ImageLoop,
    PIDGains,
    RateLoop,
    closed_loop,
    relay_experiment,
    relay_ultimate_gain,
    simulate_axis,
    simulate_pointing,
    step_metrics,
    ultimate_gain,
    ziegler_nichols,
)


# ----------------------------------------------------------------------------------------------
# ultimate gain and Ziegler–Nichols
# ----------------------------------------------------------------------------------------------
def test_ultimate_gain_of_triple_lag():
    # 1/(s+1)^3: phase −180° where 3·atan(ω) = π -> ω = √3, |G| = 1/(1+3)^{3/2} = 1/8.
    Ku, Tu = ultimate_gain(ct.tf([1.0], [1.0, 3.0, 3.0, 1.0]))
    assert Ku == pytest.approx(8.0, abs=1e-6)
    assert Tu == pytest.approx(2.0 * math.pi / math.sqrt(3.0), abs=1e-6)


def test_ultimate_gain_rejects_plant_without_phase_crossover():
    with pytest.raises(ValueError, match="Ku is undefined"):
        ultimate_gain(ct.tf([1.0], [1.0, 1.0]))


@pytest.mark.parametrize("axis", AXES)
def test_plant_ultimate_gain_is_the_first_instability(axis):
    # Hand check of the phase crossover: at ω_pc the phase of G is −180° and K = 1/|G(jω_pc)|.
    plant = AxisPlant.storm32(axis)
    Ku, Tu = ultimate_gain(plant)
    w = 2.0 * math.pi / Tu
    J, b = plant.inertia_kgm2, plant.damping_Nms_per_rad
    phase = -(
        math.atan(w * plant.motor_tau_s) + math.atan2(w * J, b) + math.atan(w * plant.gyro_tau_s)
        + w * plant.delay_s
    )
    mag = 1.0 / (
        math.hypot(1, w * plant.motor_tau_s) * math.hypot(b, w * J) * math.hypot(1, w * plant.gyro_tau_s)
    )
    # the order-6 Padé is accurate to ~1e-9 rad at ω·L ≈ 0.8
    assert phase == pytest.approx(-math.pi, abs=1e-6)
    assert Ku == pytest.approx(1.0 / mag, rel=1e-6)
    # P control just below Ku is stable, just above unstable (closed-loop poles)
    G = plant.transfer_function()
    assert np.all(ct.feedback(0.98 * Ku * G).poles().real < 0)
    assert np.any(ct.feedback(1.02 * Ku * G).poles().real > 0)


def test_ziegler_nichols_table():
    # hand-evaluated table for Ku = 10, Tu = 2 s: ki = kp/Ti, kd = kp·Td
    assert ziegler_nichols(10.0, 2.0, "P") == PIDGains(5.0, 0.0, 0.0)
    pi = ziegler_nichols(10.0, 2.0, "PI")
    assert (pi.kp, pi.ki, pi.kd) == pytest.approx((4.5, 4.5 / (2.0 / 1.2), 0.0), rel=1e-12)
    pid = ziegler_nichols(10.0, 2.0, "PID")
    assert (pid.kp, pid.ki, pid.kd) == pytest.approx((6.0, 6.0, 1.5), rel=1e-12)


@pytest.mark.parametrize("Ku, Tu", [(0.0, 1.0), (-1.0, 1.0), (float("nan"), 1.0), (1.0, 0.0), (1.0, math.inf)])
def test_ziegler_nichols_rejects_bad_ultimate_values(Ku, Tu):
    with pytest.raises(ValueError, match="Ku|Tu"):
        ziegler_nichols(Ku, Tu)


def test_ziegler_nichols_rejects_unknown_kind():
    with pytest.raises(ValueError, match="kind"):
        ziegler_nichols(1.0, 1.0, "PD")


@pytest.mark.parametrize("axis", AXES)
def test_relay_matches_margin_on_linear_axis(axis):
    # relay amplitude well below the torque limit: the axis stays linear. The describing
    # function ignores the harmonics of the square wave (they make the peak amplitude larger),
    # the tolerance is 10 % on Ku and 5 % on Tu (1 kHz: the period is quantised).
    plant = AxisPlant.storm32(axis)
    Ku, Tu = ultimate_gain(plant)
    Ku_r, Tu_r = relay_ultimate_gain(plant, 0.25 * plant.torque_limit_Nm, dt_s=1e-3, duration_s=0.4)
    assert Ku_r == pytest.approx(Ku, rel=0.10)
    assert Tu_r == pytest.approx(Tu, rel=0.05)


def test_relay_experiment_trace_is_a_relay():
    plant = AxisPlant.storm32("pitch")
    exp = relay_experiment(plant, 0.01, dt_s=1e-3, duration_s=0.3)
    assert set(np.unique(exp.torque_cmd)) == {-0.01, 0.01}
    assert np.all(np.sign(exp.torque_cmd[exp.measured_rate != 0]) == -np.sign(exp.measured_rate[exp.measured_rate != 0]))
    assert exp.Ku == pytest.approx(4 * 0.01 / (math.pi * exp.amplitude_rad_s))


# ----------------------------------------------------------------------------------------------
# the plant integrator
# ----------------------------------------------------------------------------------------------
def test_gimbal_axis_matches_continuous_step_response():
    # Under a zero-order hold a step command is exact; with dt = 1 ms and delay 1.5 ms the
    # transport delay delay − dt/2 is exactly one sample, so the measured rate at t_k equals
    # the continuous delay-free step response at t_k − 1 ms (python-control, to solver accuracy).
    plant = AxisPlant.storm32("roll")
    axis = GimbalAxis(plant, 1e-3)
    u = 0.2 * plant.torque_limit_Nm
    n = 200
    meas = np.array([axis.step(u) for _ in range(n)])
    t = np.arange(1, n + 1) * 1e-3
    G0 = AxisPlant.storm32("roll", delay_s=0.0).transfer_function()
    y = ct.step_response(u * G0, T=t - 1e-3).outputs
    assert np.max(np.abs(meas - y)) < 1e-9 * np.max(np.abs(y))
    # angle is the integral of the rate: compare with the integral of the delay-free response
    t_fine = np.linspace(0, 0.2, 20001)
    body = ct.tf([plant.motor_tau_s * 0 + 1.0], [plant.motor_tau_s, 1.0]) * ct.tf([1.0], [plant.inertia_kgm2, plant.damping_Nms_per_rad, 0.0])
    angle = ct.step_response(u * body, T=t_fine).outputs[-1]
    assert axis.angle_rad == pytest.approx(angle, rel=1e-6)


def test_gimbal_axis_saturates():
    plant = AxisPlant.storm32("pitch")
    axis = GimbalAxis(plant, 1e-3)
    axis.step(10.0)
    assert axis.saturated
    for _ in range(200):
        axis.step(10.0)
    # at the limit the steady rate is limit/b (reached from below)
    assert axis.rate_rad_s < plant.torque_limit_Nm / plant.damping_Nms_per_rad
    axis.step(0.5 * plant.torque_limit_Nm)
    assert not axis.saturated


@pytest.mark.parametrize(
    "field, value",
    [
        ("inertia_kgm2", -1e-4),
        ("inertia_kgm2", 0.0),
        ("damping_Nms_per_rad", -1.0),
        ("torque_limit_Nm", 0.0),
        ("motor_tau_s", float("nan")),
        ("gyro_tau_s", 0.0),
        ("delay_s", -1e-3),
    ],
)
def test_plant_rejects_bad_fields(field, value):
    with pytest.raises(ValueError, match=field):
        AxisPlant.storm32("yaw", **{field: value})


def test_axis_rejects_step_longer_than_twice_the_delay():
    with pytest.raises(ValueError, match="delay_s"):
        GimbalAxis(AxisPlant.storm32("yaw"), dt_s=5e-3)
    with pytest.raises(ValueError, match="axis"):
        AxisPlant.storm32("tilt")


# ----------------------------------------------------------------------------------------------
# PID and the rate loop
# ----------------------------------------------------------------------------------------------
def test_discrete_pid_matches_continuous_closed_loop():
    # A 10 µs step makes the discretisation (forward-Euler integral, backward-Euler derivative,
    # zero-order hold) negligible next to the 1 % RMS tolerance of the issue; the plant's delay
    # is exact in the simulation and an order-6 Padé in python-control.
    plant = AxisPlant.storm32("pitch")
    gains = ziegler_nichols(*ultimate_gain(plant), "PID")
    dt = 1e-5
    pid = PID(gains, dt)
    sim = simulate_axis(plant, pid, 1.0, None, duration_s=0.08, dt_s=dt)
    T_ry, _ = closed_loop(plant, gains, pade_order=6)
    y = ct.step_response(T_ry, T=sim.t).outputs
    rms = np.sqrt(np.mean((sim.measured_rate - y) ** 2))
    assert rms < 0.01


@pytest.mark.parametrize("axis", AXES)
def test_zn_rate_loop_is_stable_and_rejects_torque_step(axis):
    plant = AxisPlant.storm32(axis)
    loop = RateLoop(plant)
    T_ry, T_dy = closed_loop(plant, loop.gains)
    assert np.all(T_ry.poles().real < 0)
    # discrete loop at 1 kHz: a step torque disturbance (25 % of the limit) is rejected.
    d = 0.25 * plant.torque_limit_Nm
    sim = simulate_axis(plant, loop, 0.0, lambda t: d if t >= 0.01 else 0.0, duration_s=0.3)
    peak = np.max(np.abs(sim.rate))
    open_loop = d / plant.damping_Nms_per_rad  # steady rate without control
    assert peak < 0.05 * open_loop
    assert np.max(np.abs(sim.rate[sim.t > 0.2])) < 0.01 * peak  # integral action: back to zero
    # the 1 kHz response follows the continuous model's disturbance response (same loop)
    y = ct.forced_response(T_dy, T=sim.t, U=sim.disturbance).outputs
    assert np.max(np.abs(sim.measured_rate - y)) < 0.2 * peak


def test_anti_windup_reduces_overshoot_under_saturation():
    plant = AxisPlant.storm32("pitch")
    gains = ziegler_nichols(*ultimate_gain(plant), "PID")
    ref = 30.0  # rad/s: needs ~30 ms at the torque limit, the integral winds up meanwhile
    overshoot = {}
    for mode in ("none", "clamp", "back_calculation"):
        sim = simulate_axis(plant, RateLoop(plant, gains, anti_windup=mode), ref, None, duration_s=0.3)
        assert sim.saturated[:10].all()
        overshoot[mode] = sim.rate.max() / ref - 1.0
        assert abs(sim.rate[-1] - ref) < 1e-3 * ref
    assert overshoot["back_calculation"] < 0.5 * overshoot["none"]
    assert overshoot["clamp"] < 0.5 * overshoot["none"]


def test_pid_terms_by_hand():
    pid = PID(PIDGains(2.0, 10.0, 0.5), dt_s=0.1, derivative_tau_s=0.0)
    assert pid.update(1.0, 0.0) == pytest.approx(2.0)  # P only: no derivative kick, I starts at 0
    # second sample: e = 0.5, integral = 10·1·0.1 = 1, derivative = −0.5·(0.5 − 0)/0.1 = −2.5
    assert pid.update(1.0, 0.5) == pytest.approx(2.0 * 0.5 + 1.0 - 2.5)
    pid.reset()
    assert pid.integral == 0.0 and pid.update(0.0, 0.0) == 0.0


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(dt_s=0.0), "dt_s"),
        (dict(dt_s=1e-3, output_limits=(1.0, -1.0)), "output_limits"),
        (dict(dt_s=1e-3, anti_windup="reset"), "anti_windup"),
        (dict(dt_s=1e-3, derivative_tau_s=-1.0), "derivative_tau_s"),
    ],
)
def test_pid_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        PID(PIDGains(1.0, 1.0, 0.1), **kwargs)
    with pytest.raises(ValueError, match="kp"):
        PIDGains(-1.0)


def test_step_metrics_wraps_step_info():
    sys = ct.tf([1.0], [1.0, 0.6, 1.0])
    t = np.linspace(0, 30, 3001)
    y = ct.step_response(sys, T=t).outputs
    m = step_metrics(t, y, 1.0)
    zeta = 0.3  # second-order overshoot exp(−ζπ/√(1−ζ²)) by hand
    assert m["overshoot_pct"] == pytest.approx(100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), rel=1e-3)


# ----------------------------------------------------------------------------------------------
# the outer image loop on a yaw–roll–pitch gimbal built here by hand
# ----------------------------------------------------------------------------------------------
def _rot(axis, a):
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# camera axes in the body frame (x forward, y left, z up): x_cam = −y, y_cam = −z, z_cam = x
R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _gimbal(q):
    """R_world_cam and the camera-frame angular Jacobian of a yaw→roll→pitch gimbal."""
    Rz, Rx, Ry = _rot("z", q[0]), _rot("x", q[1]), _rot("y", q[2])
    R = Rz @ Rx @ Ry @ R_BODY_CAM
    axes_world = np.column_stack([[0, 0, 1], Rz @ [1, 0, 0], Rz @ Rx @ [0, 1, 0]])
    return R, R.T @ axes_world


def _camera_pose(q):
    R, J = _gimbal(q)
    T = np.eye(4)
    T[:3, :3] = R
    return T, J


def _run(loop, target, K, duration_s, fps=30.0):
    # the joints integrate the rate references exactly (ideal inner loop)
    sim = simulate_pointing(loop, _camera_pose, target, duration_s, fps)
    return sim.error_px, sim.q_rad


def test_simulate_pointing_projects_like_camera_project():
    K = Intrinsics.default()
    target = np.array([3.0, -0.65, -0.3])
    sim = simulate_pointing(ImageLoop(K), _camera_pose, lambda t: target, 0.5)
    R, _ = _gimbal(sim.q_rad[7])
    assert sim.uv_px[7] == pytest.approx(project((R.T @ target)[None, :], K)[0], abs=1e-9)


def test_image_loop_signs():
    K = Intrinsics.default()
    loop = ImageLoop(K, kp_per_s=2.0)
    _, J = _gimbal(np.zeros(3))
    right = loop.update(np.array([K.cx + 100.0, K.cy]), 0.03, J, np.zeros(3))
    w = J @ right
    assert w[1] > 0 and abs(w[0]) < 1e-12  # turn about camera +y (down) to look right
    below = loop.update(np.array([K.cx, K.cy + 100.0]), 0.03, J, np.zeros(3))
    w = J @ below
    assert w[0] < 0 and abs(w[1]) < 1e-12  # turn about camera −x to look down
    # exact angle: ω_y = kp·atan(100/fx)
    assert (J @ right)[1] == pytest.approx(2.0 * math.atan(100.0 / K.fx), rel=1e-12)
    assert loop.error_px == pytest.approx([0.0, -100.0])


def test_image_loop_centres_a_static_target():
    K = Intrinsics.default()
    # a point 3 m away, ~12° right and ~6° below the optical axis
    target = np.array([3.0, -0.65, -0.3])
    errors, qs = _run(ImageLoop(K, kp_per_s=4.0), lambda t: target, K, duration_s=4.0)
    assert np.linalg.norm(errors[0]) > 100.0
    assert np.linalg.norm(errors[-1]) < 0.01  # e^{-4·4} of ~140 px
    assert np.max(np.abs(qs[:, 1])) < 1e-6  # roll kept at zero (levelling row)


def test_image_loop_bounded_lag_for_constant_rate_target():
    K = Intrinsics.default()
    omega, kp = 0.5, 4.0  # rad/s target rate around the gimbal, outer gain

    def circling(t):
        return 3.0 * np.array([math.cos(omega * t), math.sin(omega * t), 0.0])

    errors, _ = _run(ImageLoop(K, kp_per_s=kp, max_rate_rad_s=5.0), circling, K, duration_s=5.0)
    # discrete P loop on an integrator: e_{k+1} = e_k + ω·dt − kp·dt·e_k -> steady e = ω/kp;
    # the target is left of centre (it leads the camera), by fx·tan(ω/kp) px
    lag_px = -K.fx * math.tan(omega / kp)
    assert errors[-1, 0] == pytest.approx(lag_px, rel=1e-6)
    assert abs(errors[-1, 1]) < 1e-6
    # PI removes the lag
    errors, _ = _run(ImageLoop(K, kp_per_s=kp, ki_per_s2=4.0, max_rate_rad_s=5.0), circling, K, duration_s=8.0)
    assert abs(errors[-1, 0]) < 0.05


def test_image_loop_lost_target_holds_then_returns_home():
    K = Intrinsics.default()
    q = np.array([0.3, 0.05, -0.2])
    _, J = _gimbal(q)
    hold = ImageLoop(K, lost_hold_s=0.5, return_home=False)
    home = ImageLoop(K, lost_hold_s=0.5, return_home=True, home_gain_per_s=1.0, max_rate_rad_s=3.0)
    for k in range(15):  # 0.5 s at 30 Hz: hold
        assert np.all(hold.update(None, 1 / 30, J, q) == 0.0)
        assert np.all(home.update(None, 1 / 30, J, q) == 0.0)
        assert home.state == "hold"
    for k in range(5):
        assert np.all(hold.update(None, 1 / 30, J, q) == 0.0)
        rates = home.update(None, 1 / 30, J, q)
    assert home.state == "home"
    assert rates == pytest.approx(-q)
    # a new detection resumes tracking
    home.update(np.array([K.cx, K.cy]), 1 / 30, J, q)
    assert home.state == "tracking"


def test_image_loop_coasts_on_its_last_command_then_holds_by_hand():
    # J maps (yaw, roll, pitch) rates to camera (x, y, z): camera x ← yaw, y ← pitch, z ← roll, so
    # the loop's 3 × 3 system is solved by hand: q̇ = (ω_x, −roll_gain·q_roll, ω_y)
    K = Intrinsics.default()
    J = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    q = np.array([0.0, 0.1, 0.0])
    dt, kp, ki = 1 / 30, 2.0, 3.0
    loop = ImageLoop(K, kp_per_s=kp, ki_per_s2=ki, coast_s=1.5, roll_gain_per_s=2.0)
    # target 100 px right of centre: θ = (0, atan(100/fx)); after two frames the integral is 2·dt·θ_y
    theta_y = math.atan(100.0 / K.fx)
    loop.update((K.cx + 100.0, K.cy), dt, J, q)
    last = loop.update((K.cx + 100.0, K.cy), dt, J, q)
    expected = np.array([0.0, -2.0 * 0.1, kp * theta_y + ki * dt * theta_y])  # the integral lags one frame
    assert last == pytest.approx(expected, rel=1e-12, abs=1e-15)
    # lost for 1.5 s = 45 frames at 30 frames/s: the last command 45 times (whatever the pose now),
    # then zero rate; the integral stays frozen throughout
    integral = loop.integral.copy()
    coasting = [loop.update(None, dt, J, q + 0.01 * k) for k in range(45)]
    assert all(np.array_equal(c, last) for c in coasting) and loop.state == "coast"
    assert np.all(loop.update(None, dt, J, q) == 0.0) and loop.state == "hold"
    assert np.array_equal(loop.integral, integral)
    # a detection resumes tracking with the frozen integral; a new loss coasts on the new command
    resumed = loop.update((K.cx, K.cy - 50.0), dt, J, np.zeros(3))
    theta_x = math.atan(50.0 / K.fy)  # target above centre: θ_x = −y = +atan(50/fy)
    assert resumed == pytest.approx([kp * theta_x, 0.0, ki * integral[1]], rel=1e-12)
    assert np.array_equal(loop.update(None, dt, J, np.zeros(3)), resumed)
    # the default holds at once, as the paper's loop always did
    hold = ImageLoop(K, kp_per_s=kp)
    hold.update((K.cx + 100.0, K.cy), dt, J, q)
    assert np.all(hold.update(None, dt, J, q) == 0.0) and hold.state == "hold"


def test_image_loop_rate_limit():
    K = Intrinsics.default()
    loop = ImageLoop(K, kp_per_s=50.0, max_rate_rad_s=1.0)
    _, J = _gimbal(np.zeros(3))
    rates = loop.update(np.array([600.0, 400.0]), 0.03, J, np.zeros(3))
    assert np.max(np.abs(rates)) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kwargs, name",
    [(dict(kp_per_s=0.0), "kp_per_s"), (dict(ki_per_s2=-1.0), "ki_per_s2"), (dict(max_rate_rad_s=float("nan")), "max_rate_rad_s"), (dict(lost_hold_s=-1.0), "lost_hold_s"),
     (dict(coast_s=-0.1), "coast_s"), (dict(coast_s=math.inf), "coast_s")],
)
def test_image_loop_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ImageLoop(Intrinsics.default(), **kwargs)


def test_image_loop_centres_a_target_with_the_project_kinematics():
    # the Jacobian convention of gimbal_lab.kinematics (camera frame, joint order yaw, roll, pitch)
    from gimbal_lab.kinematics import GimbalKinematics

    kin = GimbalKinematics.default()
    K = Intrinsics.default()
    T_home = kin.forward(np.zeros(3))
    target = T_home[:3, :3] @ np.array([-0.5, -0.4, 3.0]) + T_home[:3, 3]  # left of and above the axis
    sim = simulate_pointing(
        ImageLoop(K, kp_per_s=4.0), lambda q: (kin.forward(q), kin.angular_jacobian(q, frame="camera")),
        lambda t: target, 4.0,
    )
    assert sim.error_px[0, 0] < -80 and sim.error_px[0, 1] < -60  # ≈ fx·(−0.5, −0.4)/3
    assert np.linalg.norm(sim.error_px[-1]) < 0.01
    assert np.max(np.abs(sim.q_rad[:, 1])) < 1e-3  # roll stays level


# --- the outer loop's own Ziegler–Nichols tuning -------------------------------------------------
from gimbal_lab.control import outer_loop_delay_s, outer_loop_gains, outer_loop_plant  # noqa: E402


@pytest.mark.parametrize("fps, latency", [(30.0, 0), (30.0, 1), (30.0, 2), (60.0, 1)])
def test_outer_loop_ultimate_gain_matches_the_hand_derivation(fps, latency):
    """e^{−sL}/s: phase −π/2 − ωL = −π at ω = π/(2L), |P| = 1/ω there, so Ku = π/(2L), Tu = 4L."""
    L = (latency + 0.5) / fps
    assert outer_loop_delay_s(fps, latency) == pytest.approx(L, rel=1e-15)
    Ku, Tu = ultimate_gain(outer_loop_plant(fps, latency))
    assert Ku == pytest.approx(math.pi / (2 * L), rel=1e-8)  # 6th-order Padé: 4e-11 measured
    assert Tu == pytest.approx(4 * L, rel=1e-8)


def test_outer_loop_gains_are_the_zn_pi_rule():
    g = outer_loop_gains(30.0, 1)
    L = 1.5 / 30.0
    assert g.kp == pytest.approx(0.45 * math.pi / (2 * L), rel=1e-8)  # 14.14 /s
    assert g.ki == pytest.approx(g.kp / (4 * L / 1.2), rel=1e-8)  # 84.8 /s²
    assert g.kd == 0.0
    loop = ImageLoop.ziegler_nichols(Intrinsics.default(), 30.0, 1, max_rate_rad_s=2.0)
    assert (loop.kp_per_s, loop.ki_per_s2, loop.max_rate_rad_s) == (g.kp, g.ki, 2.0)
    with pytest.raises(ValueError, match="latency_frames"):
        outer_loop_gains(30.0, -1)
    with pytest.raises(ValueError, match="fps"):
        outer_loop_gains(0.0, 1)


def test_simulate_pointing_delays_the_pixel_by_the_latency():
    """With one frame of latency the loop sees frame k's pixel at frame k+1: the first command is 0."""
    K = Intrinsics.default()
    target = np.array([3.0, -0.65, -0.3])
    fresh = simulate_pointing(ImageLoop(K), _camera_pose, lambda t: target, 0.2)
    late = simulate_pointing(ImageLoop(K), _camera_pose, lambda t: target, 0.2, latency_frames=1)
    assert np.all(late.qdot_rad_s[0] == 0) and np.any(fresh.qdot_rad_s[0] != 0)
    assert late.qdot_rad_s[1] == pytest.approx(fresh.qdot_rad_s[0], abs=1e-12)  # same pixel, one frame later


def test_pid_holds_its_integral_when_told_and_only_then():
    """hold_integral freezes the integral for that sample; the output is the same law either way
    (kp·e + integral − derivative), and the next free sample integrates again (ki·e·dt)."""
    pid = PID(PIDGains(2.0, 3.0, 0.0), dt_s=0.01)
    pid.update(1.0, 0.0)
    before = pid.integral
    assert before == pytest.approx(3.0 * 1.0 * 0.01, rel=1e-15)
    u = pid.update(1.0, 0.5, hold_integral=True)
    assert pid.integral == before and u == pytest.approx(2.0 * 0.5 + before, rel=1e-15)
    pid.update(1.0, 0.5)
    assert pid.integral == pytest.approx(before + 3.0 * 0.5 * 0.01, rel=1e-15)
