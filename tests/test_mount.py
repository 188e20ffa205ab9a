"""The camera mount on a moving body (gimbal_lab.mount) against python-control, scipy and geometry."""

import math

import numpy as np
import pytest
import scipy.signal
import scipy.spatial.transform

from gimbal_lab.control import AxisPlant
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.mount import (GYRO_NOISE_RAD_S_RTHZ, GimbalMount, attitude_error_rad, camera_pose, exposure_pose_fn,
                              stabilised_attitude_transfer)
from gimbal_lab.platform import BodyMotion

KIN = GimbalKinematics.default()
DT = 1e-3


def _run(mount, body, seconds, every=5, rate_ref=None, **kwargs):
    """Step a mount; sample the camera's world attitude error, the axis angles and b every ``every`` steps."""
    n = int(round(seconds / DT))
    m = GimbalMount(KIN, body, mount, DT, n, **kwargs)
    t, err, axis_angle, body_angle = [], [], [], np.zeros(3)
    body_angles = []
    for k in range(0, n, every):
        for j in range(every):
            body_angle = body_angle + m._base_rates(m.q, k + j) * DT
            m.advance(1, rate_ref)
        t.append(m.t_s)
        err.append(attitude_error_rad(m.T_world_cam(m.q, m.t_s)[:3, :3], m.R_world_home))
        axis_angle.append([a.angle_rad for a in m.axes])
        body_angles.append(body_angle)
    return m, np.array(t), np.array(err), np.array(axis_angle), np.array(body_angles)


@pytest.fixture(scope="module")
def hover_stabilised():
    # 16 s: 8 s compared between the transient and the wrap-around (measured: the axis ratios
    # 1.011, total 1.027, correlation 0.9986, as over 24 s: 1.010, 1.028, 0.9986)
    return _run("stabilised", BodyMotion.hover(seed=3), 16.0, every=1)


def test_stabilised_mount_attenuates_sway_as_the_loops_sensitivity_predicts(hover_stabilised):
    """Camera attitude error = body rotation (in the joint basis) through the closed loop's transfer.

    The prediction filters the body's own rotation about each joint axis with
    stabilised_attitude_transfer (python-control, Padé delay) in the frequency domain; the run is
    the nonlinear discrete loop with the exact kinematics. Bounds: each axis within 5 %, the camera's
    total world attitude error within 10 % (the issue's bound), correlation > 0.99 on the pitch axis.
    """
    m, t, err, axis_angle, body_angle = hover_stabilised
    keep = (t > 4.0) & (t < t[-1] - 4.0)  # the start's transient and the FFT's wrap-around
    predicted = np.empty_like(axis_angle)
    for i, name in enumerate(("yaw", "roll", "pitch")):
        T = stabilised_attitude_transfer(AxisPlant.storm32(name), DT)
        x = body_angle[:, i] - np.linspace(body_angle[0, i], body_angle[-1, i], len(t))
        f = np.fft.rfftfreq(len(t), t[1] - t[0])
        predicted[:, i] = np.fft.irfft(np.fft.rfft(x) * T(2j * np.pi * f), len(t))
        ratio = axis_angle[keep, i].std() / predicted[keep, i].std()
        assert abs(ratio - 1) < 0.05, (name, ratio)
    # camera axes at home: x right = pitch axis, y down = yaw axis, z forward = roll axis
    measured_total = np.sqrt(np.sum(err[keep].var(axis=0)))
    predicted_total = np.sqrt(np.sum(predicted[keep].var(axis=0)))
    assert abs(measured_total / predicted_total - 1) < 0.10, (measured_total, predicted_total)
    assert abs(np.corrcoef(err[keep, 0], predicted[keep, 2])[0, 1]) > 0.99
    # and the sway itself was 2° / 1° RMS: the mount removes all but a few thousandths of a degree
    assert math.degrees(measured_total) < 0.005


def test_the_loop_transfer_matches_a_single_axis_driven_by_a_sinusoid():
    """stabilised_attitude_transfer's gain against the discrete axis at 1.5 and 5 Hz, within 3 %."""
    from gimbal_lab.control import GimbalAxis, RateLoop

    plant = AxisPlant.storm32("pitch")
    T = stabilised_attitude_transfer(plant, DT)
    for f in (1.5, 5.0):
        axis, loop, estimate, amp = GimbalAxis(plant, DT), RateLoop(plant, dt_s=DT), 0.0, 0.01
        out, ts = [], []
        for k in range(int(6 / DT)):
            b = amp * 2 * math.pi * f * math.cos(2 * math.pi * f * (k + 0.5) * DT)
            measured = axis.measured_rate_rad_s
            r, estimate = -20.0 * estimate, estimate + measured * DT
            axis.step(loop.update(r, measured), plant.damping_Nms_per_rad * b)
            out.append(axis.angle_rad)
            ts.append((k + 1) * DT)
        ts, out = np.array(ts), np.array(out)
        keep = ts > 2
        X = np.column_stack([np.sin(2 * np.pi * f * ts), np.cos(2 * np.pi * f * ts)])[keep]
        gain = np.hypot(*np.linalg.lstsq(X, out[keep], rcond=None)[0]) / amp
        assert gain == pytest.approx(abs(T(2j * np.pi * f)), rel=0.03)


def test_base_rates_solve_the_joint_basis_system():
    # b = (R_body_base·J(q))⁻¹·ω_body by Cramer's rule against numpy's LU solve, on a tilted mount
    # (R_body_base not the identity) and joint angles across their ranges; within 1e-13 rad/s
    T = np.eye(4)
    T[:3, :3] = scipy.spatial.transform.Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    kin = GimbalKinematics(T_body_base=T)
    m = GimbalMount(kin, BodyMotion.flying(seed=3), "active", DT, 400)
    rng = np.random.default_rng(1)
    for k in range(0, 400, 7):
        q = rng.uniform([-2.9, -0.7, -1.5], [2.9, 0.7, 0.7])
        J = T[:3, :3] @ kin.angular_jacobian(q, "base", check_limits=False)
        expected = np.linalg.solve(J, m._w_body[k])
        assert np.allclose(m._base_rates(q, k), expected, rtol=0.0, atol=1e-13)
        assert np.abs(expected).max() > 1e-3  # the body turns: a test of the solve, not of zeros


def test_fixed_mount_moves_rigidly_with_the_body():
    body = BodyMotion.hover(seed=1, vibration=True)
    m = GimbalMount(KIN, body, "fixed", DT, 200)
    m.advance(137)
    T = m.T_world_cam(m.q, m.t_s)
    expected = body.T_world_body(0.137) @ KIN.T_body_base @ KIN.forward(np.zeros(3))
    np.testing.assert_allclose(T, expected, atol=1e-12)
    assert np.all(m.q == 0) and np.all(m.qd == 0)


def test_joint_angles_follow_the_body_so_that_an_inertially_still_camera_stays_still():
    """With the axes forced to zero inertial rate, q = −∫b keeps the camera's world attitude fixed.

    Exact kinematics check: a flight (bank up to 5.8°) with sway; the camera may not turn by more than
    2e-6 rad over 3 s although the body turns by degrees.
    """
    body = BodyMotion.flying(seed=2)
    n = 3000
    m = GimbalMount(KIN, body, "active", DT, n)
    for axis in m.axes:  # infinitely stiff axes: freeze their inertial state
        axis.step = lambda torque, disturbance=0.0: None
    R0 = m.T_world_cam(m.q, 0.0)[:3, :3]
    worst, body_turn = 0.0, 0.0
    for k in range(0, n, 50):
        m.advance(50)
        R = m.T_world_cam(m.q, m.t_s)[:3, :3]
        worst = max(worst, np.linalg.norm(attitude_error_rad(R, R0)))
        body_turn = max(body_turn, np.linalg.norm(attitude_error_rad(body.T_world_body(m.t_s)[:3, :3],
                                                                     body.T_world_body(0.0)[:3, :3])))
    assert body_turn > math.radians(2.0)
    assert worst < 2e-6


def test_exposure_pose_fn_matches_the_stepped_mount_within_an_exposure():
    """The in-exposure pose (mean w held, body exact) against the mount stepped at 1 kHz.

    Bound 0.02° (0.19 px at the study's 554 px focal length): what the extrapolation leaves out is
    the axes' residual answer to the 120 Hz vibration (±0.1 rad/s, ±1.3e-4 rad), against a body that
    turns by tenths of a degree within the same 17 ms.
    """
    body = BodyMotion.hover(seed=5, vibration=True)
    m = GimbalMount(KIN, body, "stabilised", DT, 2000)
    m.advance(1000)
    camera_fn = m.exposure_pose_fn(m.t_s, m.t_s + 0.017)
    t0 = m.t_s
    m.advance(17)
    q_fn, T_fn = camera_fn(t0 + 0.017)
    angle = np.linalg.norm(attitude_error_rad(T_fn[:3, :3], m.T_world_cam(m.q, m.t_s)[:3, :3]))
    assert math.degrees(angle) < 0.02
    # while the body itself turned by far more within those 17 ms (vibration at 120 Hz)
    turn = np.linalg.norm(attitude_error_rad(body.T_world_body(t0)[:3, :3], body.T_world_body(t0 + 0.017)[:3, :3]))
    assert math.degrees(turn) > 0.05


@pytest.mark.parametrize("motion", ["still", "vibration"])
def test_recorded_pose_is_the_path_the_mount_stepped_through(motion):
    """An active mount given a new rate reference as a frame starts (as the image loop does every
    frame): the recorded path reproduces the joint angles of every inner step (1e-12 rad), runs
    on from the present state past the last step, and is the camera of ``camera_pose``. Holding
    the rate of the frame's start instead misses the stepped mount by milliradians within 17 ms."""
    body = BodyMotion.static() if motion == "still" else BodyMotion.hover(seed=2, vibration=True)
    m = GimbalMount(KIN, body, "active", DT, 200)
    m.advance(100, np.array([0.3, -0.2, 0.5]))
    t0, q_start, w_start = m.t_s, m.q, m.smooth_axis_rates
    stepped = []
    for _ in range(33):
        m.advance(1, np.array([-0.5, 0.4, -0.3]))
        stepped.append(m.q)
    camera_fn = m.recorded_pose_fn(t0, t0 + 0.030)
    for j, q in enumerate(stepped, start=1):
        np.testing.assert_allclose(camera_fn(t0 + j * DT)[0], q, atol=1e-12, rtol=0)
    q_many, T_many = camera_fn.many(t0 + DT * np.arange(1, 34))
    np.testing.assert_allclose(q_many, stepped, atol=1e-12, rtol=0)
    t = t0 + 0.0125  # between steps
    np.testing.assert_allclose(camera_fn(t)[1], camera_pose(KIN, body, camera_fn(t)[0], t), atol=1e-15)
    # past the last step: the present state run on as exposure_pose_fn does, continuously
    tail = exposure_pose_fn(KIN, body, "active", m.q, m.smooth_axis_rates, m.t_s, t0 + 0.030)
    for t in (m.t_s + 1e-4, m.t_s + 0.003):
        np.testing.assert_allclose(camera_fn(t)[0], tail(t)[0], atol=1e-15, rtol=0)
    np.testing.assert_allclose(camera_fn(m.t_s)[0], stepped[-1], atol=1e-12, rtol=0)
    held = exposure_pose_fn(KIN, body, "active", q_start, w_start, t0, t0 + 0.030)
    assert np.linalg.norm(held(t0 + 0.017)[0] - stepped[16]) > 2e-3


def test_still_body_reduces_to_the_paper_axes_exactly():
    body = BodyMotion.static()
    a = GimbalMount(KIN, body, "active", DT, 500)
    from gimbal_lab.control import GimbalAxis, RateLoop

    plants = [AxisPlant.storm32(x) for x in ("yaw", "roll", "pitch")]
    axes = [GimbalAxis(p, DT) for p in plants]
    loops = [RateLoop(p, dt_s=DT) for p in plants]
    ref = np.array([0.3, -0.2, 0.5])
    a.advance(500, ref)
    for _ in range(500):
        for i in range(3):
            axes[i].step(loops[i].update(ref[i], axes[i].measured_rate_rad_s))
    assert np.array_equal(a.q, [x.angle_rad for x in axes])


def test_gyro_noise_has_the_stated_density_through_the_low_pass():
    """Welch PSD of the noise the stabilised loop sees, below the 160 Hz corner, within 10 % of 0.005 °/s/√Hz."""
    rng = np.random.default_rng(0)
    m = GimbalMount(KIN, BodyMotion.static(), "stabilised", DT, 60_000, GYRO_NOISE_RAD_S_RTHZ, rng)
    f, P = scipy.signal.welch(m._noise[:, 1], fs=1 / DT, nperseg=4096)
    band = (f > 5) & (f < 30)
    density = math.sqrt(np.mean(P[band]))
    assert density == pytest.approx(GYRO_NOISE_RAD_S_RTHZ, rel=0.10)
    # above the corner: the gyro's low-pass, discretised exactly at 1 kHz (scipy's freqz as the oracle)
    a = math.exp(-DT / AxisPlant.storm32("roll").gyro_tau_s)
    high = (f > 250) & (f < 450)
    _, h = scipy.signal.freqz([1 - a], [1, -a], worN=f[high], fs=1 / DT)
    ratio = np.mean(P[high]) / np.mean(GYRO_NOISE_RAD_S_RTHZ**2 * np.abs(h) ** 2)
    assert ratio == pytest.approx(1.0, rel=0.10)
    assert np.mean(P[high]) < 0.6 * GYRO_NOISE_RAD_S_RTHZ**2  # the low-pass is there


def test_bad_inputs_are_refused():
    body = BodyMotion.static()
    with pytest.raises(ValueError, match="mount"):
        GimbalMount(KIN, body, "gimbal", DT, 10)
    with pytest.raises(TypeError, match="BodyMotion"):
        GimbalMount(KIN, "still", "fixed", DT, 10)
    with pytest.raises(ValueError, match="rng"):
        GimbalMount(KIN, body, "stabilised", DT, 10, gyro_noise_rad_s_rthz=1e-4)
    with pytest.raises(ValueError, match="gyro_noise"):
        GimbalMount(KIN, body, "stabilised", DT, 10, gyro_noise_rad_s_rthz=-1.0)
    m = GimbalMount(KIN, body, "active", DT, 10)
    with pytest.raises(ValueError, match="steps"):
        m.advance(11)
    assert exposure_pose_fn(KIN, body, "fixed", [0.1, 0.2, 0.3], [1, 1, 1], 0.0, 0.01)(0.005)[0].tolist() == [0, 0, 0]


MOTIONS = {
    "still": BodyMotion.static(),
    "hover": BodyMotion.hover(seed=4),
    "vibration": BodyMotion.hover(seed=4, vibration=True),
    "flight": BodyMotion.flying(seed=4),
}


@pytest.mark.parametrize("motion", sorted(MOTIONS))
@pytest.mark.parametrize("mount", ["fixed", "stabilised", "active"])
def test_exposure_pose_many_is_the_scalar_pose_at_each_instant(mount, motion, monkeypatch):
    """camera_fn.many(times) against camera_fn(t) one instant at a time, 1e-12 (rad and m; the body's
    sums of sinusoids differ by round-off between one and many instants), with the body evaluated
    once; instants span the exposure, its margins and beyond (where the joint angles hold)."""
    body = MOTIONS[motion]
    q0, w, t0, t1 = np.array([0.05, -0.03, 0.1]), np.array([0.4, -0.2, 0.3]), 1.3, 1.3 + 0.037
    camera_fn = exposure_pose_fn(KIN, body, mount, q0, w, t0, t1)
    times = np.linspace(t0 - 0.02, t1 + 0.02, 37)
    single = [camera_fn(t) for t in times]
    assert single[0][0].shape == (3,) and single[0][1].shape == (4, 4)
    calls, T_world_body = [], BodyMotion.T_world_body

    def counted(self, t_s):
        calls.append(np.shape(t_s))
        return T_world_body(self, t_s)

    monkeypatch.setattr(BodyMotion, "T_world_body", counted)
    q, T = camera_fn.many(times)
    assert calls == [(37,)] and q.shape == (37, 3) and T.shape == (37, 4, 4)
    np.testing.assert_allclose(q, [s[0] for s in single], rtol=0, atol=1e-12)
    np.testing.assert_allclose(T, [s[1] for s in single], rtol=0, atol=1e-12)
    if mount == "fixed":
        assert np.all(q == 0)
    else:  # q = q0 + w·(t − t0) − ∫b: at t0 the state itself
        np.testing.assert_allclose(camera_fn(t0)[0], q0, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------
# joint stops
# ----------------------------------------------------------------------------------------------
def _rate_to_axis_mean_delay_s(plant, gains) -> float:
    """Mean delay (−T'(0)/T(0)) from a rate reference to the axis's true rate, from
    python-control's continuous closed rate loop: the loop to the gyro's delayed reading, less
    the gyro's lag τ_g and the delay L behind the axis (mean delays of a cascade add)."""
    from gimbal_lab.control import closed_loop

    T = closed_loop(plant, gains)[0]
    A, B, C, D = (np.asarray(x) for x in (T.A, T.B, T.C, T.D))
    dc = (D - C @ np.linalg.solve(A, B)).item()
    tau = (C @ np.linalg.solve(A, np.linalg.solve(A, B))).item() / dc  # −T'(0)/T(0), T'(0) = −C A⁻² B
    return tau - plant.gyro_tau_s - plant.delay_s


def test_a_joint_driven_into_its_stop_reaches_it_on_time_and_stays():
    """Still body, a constant pitch-rate reference r = 0.5 rad/s from q0 = 0: once the rate loop
    has settled the joint follows r·(t − τ), τ the loop's mean delay (python-control), so it
    reaches the default +45° stop at t = (limit − q0)/r + τ (1.569 s), to within one and a half
    inner steps (the stop is found at the end of the step that crosses it, and the held torque
    puts the discrete loop within half a step of the continuous one; measured 0.65 ms). Until then
    the joint moves exactly as a joint without limits; from then on it stays at the limit, is
    reported at it, and its rate loop's integral does not move (measured: no torque saturation,
    so the linear loop's delay applies)."""
    from gimbal_lab.control import RateLoop

    rate, n = 0.5, 2600
    hi = KIN.joint_limits_rad[2][1]
    free_kin = GimbalKinematics(joint_limits_rad=((-math.inf, math.inf),) * 3)
    runs = {}
    for name, kin in (("stopped", KIN), ("free", free_kin)):
        m = GimbalMount(kin, BodyMotion.static(), "active", DT, n)
        q, at, integral, saturated = [], [], [], False
        for _ in range(n):
            m.advance(1, (0.0, 0.0, rate))
            q.append(m.q[2])
            at.append(m.at_limit)
            integral.append(m.rate_loops[2].pid.integral)
            saturated |= m.axes[2].saturated
        runs[name] = np.array(q), np.array(at), np.array(integral)
        assert not saturated
    q, at, integral = runs["stopped"]
    k = int(np.argmax(at[:, 2]))  # first step ending at the stop
    t_stop = (k + 1) * DT
    plant = AxisPlant.storm32("pitch")
    tau = _rate_to_axis_mean_delay_s(plant, RateLoop(plant, dt_s=DT).gains)
    assert abs(t_stop - (hi / rate + tau)) <= 1.5 * DT, (t_stop, hi / rate + tau)
    np.testing.assert_array_equal(q[:k], runs["free"][0][:k])  # untouched before the stop
    assert runs["free"][0][k] > hi  # the free joint goes on
    assert np.all(q[k:] == hi) and at[k:, 2].all() and not at[:k, 2].any()
    assert not at[:, :2].any()  # yaw and roll stay free
    assert np.all(integral[k:] == integral[k])  # held: no windup against the stop


def test_a_joint_leaves_its_stop_as_soon_as_the_reference_reverses():
    """After 1 s against the stop the reference reverses: with the integral held at the stop the
    joint leaves it within 2 inner steps and then follows −r (0.3 s later it has come back
    r·0.3 = 0.15 rad, within 2 mrad). A rate loop integrating against the stop (measured: its
    integral winds up to 0.034 N·m, near the torque limit) holds the joint there for 15 steps and
    lags by 9 mrad."""
    rate = 0.5
    hi = KIN.joint_limits_rad[2][1]
    m = GimbalMount(KIN, BodyMotion.static(), "active", DT, 3000)
    m.advance(2600, (0.0, 0.0, rate))
    assert m.at_limit == (False, False, True) and m.q[2] == hi
    at = []
    for _ in range(300):
        m.advance(1, (0.0, 0.0, -rate))
        at.append(m.at_limit[2])
    assert not any(at[2:])
    assert abs((hi - m.q[2]) - rate * 0.3) < 2e-3


def test_a_joint_at_its_stop_on_a_swaying_body_stays_at_the_limit():
    """The stop holds the joint angle, not the camera: on a hovering body the pitch joint driven
    into its lower stop stays at −90° (to rounding of the base-angle bookkeeping) while the body,
    and so the camera, keep moving."""
    body = BodyMotion.hover(seed=2)
    lo = KIN.joint_limits_rad[2][0]
    m = GimbalMount(KIN, body, "active", DT, 4000)
    m.advance(3200, (0.0, 0.0, -1.0))  # 1.57 rad at 1 rad/s: at the stop after about 1.6 s
    q, turn = [], []
    R0 = m.T_world_cam(m.q, m.t_s)[:3, :3]
    for _ in range(800):
        m.advance(1, (0.0, 0.0, -1.0))
        q.append(m.q[2])
        turn.append(np.linalg.norm(attitude_error_rad(m.T_world_cam(m.q, m.t_s)[:3, :3], R0)))
        assert m.at_limit[2]
    np.testing.assert_allclose(q, lo, rtol=0, atol=1e-12)
    assert max(turn) > math.radians(0.5)  # the camera moves with the body meanwhile


def test_the_fixed_mount_is_never_at_a_stop():
    m = GimbalMount(KIN, BodyMotion.hover(seed=1), "fixed", DT, 100)
    m.advance(100, (0.0, 0.0, 5.0))
    assert m.at_limit == (False, False, False)
