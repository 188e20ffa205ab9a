"""The closed loop with its gimbal behind the MAVLink link (gimbal_lab.mavlink.loop, simulation.connect).

Oracles: the in-process run of the same config (the link must add nothing but float32 rounding
when it reports every inner step without effects), the device's status schedule worked out by
hand (which status a frame knows, and how old it is), and the camera pose of the known joints
recomputed from the frame table with the kinematics (the world estimate goes through it).

Tolerances: a float32 quaternion gives a joint angle to F32 = 2.4e-7 rad (tests/test_mavlink.py);
a float32 angular velocity is good to 2⁻²⁴ of itself; the equality bound is derived in
:func:`gimbal_lab.mavlink.loop.equality_bound` from both.
"""

import math

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from gimbal_lab.config import GimbalLink  # noqa: E402
from gimbal_lab.mavlink.device import LinkEffects  # noqa: E402
from gimbal_lab.mavlink.loop import equality_bound, link_effects  # noqa: E402
from gimbal_lab.mount import camera_pose  # noqa: E402
from gimbal_lab.simulation import DirectGimbal, connect, make_renderer, simulate  # noqa: E402
from gimbal_lab.studies.paper import PaperStudy  # noqa: E402

F32 = 2.4e-7  # rad: a joint angle carried by a float32 quaternion
JOINTS = ["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]
KNOWN = ["known_q_yaw_rad", "known_q_roll_rad", "known_q_pitch_rad"]
START = ["q0_yaw_rad", "q0_roll_rad", "q0_pitch_rad"]
DETECTION = ["u_px", "v_px"]


def cell(target="sphere", seed=0, revolutions=1.0):
    """The link study's cell: the paper's distorted circle, active."""
    config = PaperStudy().config(target, "distorted", "circular", "active", seed)
    return config.replace(revolutions=revolutions)


@pytest.fixture(scope="module")
def renderers():
    cache = {}

    def get(config):
        key = config.renderer_key
        if key not in cache:
            cache[key] = make_renderer(config)
        return cache[key]

    yield get
    for r in cache.values():
        r.close()


def first_difference(direct, linked):
    """Index of the first frame whose detection (detected, u, v) differs, or the frame count."""
    a = direct[["detected"] + DETECTION].to_numpy(float)
    b = linked[["detected"] + DETECTION].to_numpy(float)
    differs = ~np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
    return int(np.argmax(differs)) if differs.any() else len(direct)


@pytest.mark.parametrize("target, seed", [("sphere", 0), ("sphere", 6), ("aruco", 0)])
def test_an_effect_free_link_equals_the_in_process_run(target, seed, renderers):
    """Done-when of issue 30: a run through the device in lock-step equals the in-process run when
    every link effect is off, within :func:`gimbal_lab.mavlink.loop.equality_bound` (1e-6 to 3e-6 rad
    over these runs; measured 1e-8 to 2e-8). The joints stay within it on every frame up to and
    including the first whose detection differs: a detection may differ only because a pose within
    the bound moved a multisample at the target's edge (the sphere of seed 6 at frame 93 and the
    marker of seed 0 are such runs, scripts/link_equality.py), never because the link moved it
    more. The world estimate follows the joints (range × bound + F32), and the known joints are the
    frame's own status."""
    config = cell(target, seed, revolutions=2.0)
    direct = simulate(config, renderers(config)).frames
    linked = simulate(config.with_(pointing__link=GimbalLink(status_rate_hz=1000.0)), renderers(config)).frames
    first = first_difference(direct, linked)
    upto = min(first + 1, len(direct))
    d, lk = direct.iloc[:upto], linked.iloc[:upto]
    dq = np.abs(lk[JOINTS].to_numpy() - d[JOINTS].to_numpy())
    bound = equality_bound(direct[JOINTS].to_numpy(), direct["t_mid_s"].to_numpy())[:upto]
    worst = np.unravel_index(np.argmax(dq / bound), dq.shape)
    assert np.all(dq <= bound), f"frame {worst[0]}, {JOINTS[worst[1]]}: {dq[worst]:.3g} rad > {bound[worst]:.3g}"
    same = d["detected"].to_numpy() & lk["detected"].to_numpy()
    if first < len(direct):
        same[first] = False  # the frame that differs has another estimate
    est = ["est_x_m", "est_y_m", "est_z_m"]
    dest = np.abs(lk.loc[same, est].to_numpy() - d.loc[same, est].to_numpy())
    assert np.all(dest <= d.loc[same, ["d_true_m"]].to_numpy() * (bound[same].max(axis=1, keepdims=True) + 2 * F32))
    # what the loop knew: the status of the frame's own step, off by float32 only
    np.testing.assert_allclose(linked[KNOWN].to_numpy(), linked[START].to_numpy(), rtol=0, atol=F32)
    age = linked["known_age_s"].to_numpy()
    assert math.isnan(age[0])  # the first status comes one step after the first frame: home is assumed
    assert np.all(np.abs(age[1:]) <= 0.5e-3 + 1e-12)  # a frame starts within half a step of a status


def test_in_process_the_loop_knows_the_truth(renderers):
    config = cell("sphere", revolutions=0.5)
    f = simulate(config, renderers(config)).frames
    np.testing.assert_array_equal(f[KNOWN].to_numpy(), f[JOINTS].to_numpy())
    assert (f["known_age_s"] == 0).all()
    assert np.abs(f[["cmd_yaw_rad_s", "cmd_pitch_rad_s"]].to_numpy()).max() > 0.1  # the loop commands


@pytest.mark.parametrize("rate_hz, latency_s, loss", [(10.0, 0.02, 0.0), (10.0, 0.0, 0.0), (5.0, 0.06, 0.0),
                                                     (50.0, 0.02, 0.3)])
def test_a_frame_knows_the_latest_status_that_has_arrived(rate_hz, latency_s, loss, renderers):
    """By hand: status n is sampled at inner step n·1000/rate (n >= 1), lost when the n-th draw of
    default_rng(stream 4 of the seed) is below the loss, and arrives latency_s later; a frame
    starting at inner step round(1000·k/30) knows the latest status that arrived by then (none:
    home, age NaN). Every third frame starts on a multiple of 100 steps, so a status sampled there
    is the state of that frame's start (its q0 columns), to float32."""
    config = cell("sphere", revolutions=1.0).with_(pointing__link=GimbalLink(status_rate_hz=rate_hz,
                                                                             latency_s=latency_s, loss=loss))
    f = simulate(config, renderers(config)).frames
    period = int(round(1000 / rate_hz))
    lag = int(round(1000 * latency_s))
    start_step = np.round(1000 * f["frame"].to_numpy() / 30).astype(int)
    n_max = start_step[-1] // period + 1
    draws = np.random.default_rng(GimbalLink.effects_seed(config.seed)).random(n_max + 1)
    kept = [n for n in range(1, n_max + 1) if not (loss > 0 and draws[n - 1] < loss)]
    q0_at_step = dict(zip(start_step, f[START].to_numpy()))
    checked = 0
    for k, step in enumerate(start_step):
        arrived = [n for n in kept if n * period + lag <= step]
        if not arrived:
            np.testing.assert_array_equal(f.loc[k, KNOWN].to_numpy(float), np.zeros(3))
            assert math.isnan(f.loc[k, "known_age_s"])
            continue
        sample = arrived[-1] * period
        assert f.loc[k, "known_age_s"] == pytest.approx(f.loc[k, "t_mid_s"] - sample / 1000, abs=1e-12), k
        if sample in q0_at_step:
            np.testing.assert_allclose(f.loc[k, KNOWN].to_numpy(float), q0_at_step[sample], rtol=0, atol=F32)
            checked += 1
    assert checked > 0.2 * len(f)
    if loss:
        assert len(kept) < 0.85 * n_max  # the draws lose statuses, and the frames saw it


def test_the_detection_goes_to_the_world_through_the_known_pose(renderers):
    """At 5 Hz the known pose lags the camera: est = T(known joints)·est_cam exactly, and it differs
    from the true pose's mapping by centimetres while the camera turns."""
    config = cell("sphere", revolutions=1.0).with_(pointing__link=GimbalLink(status_rate_hz=5.0))
    f = simulate(config, renderers(config)).frames
    f = f[f["detected"]]
    kin, body = config.gimbal.kinematics, config.body
    est, true_mapped = [], []
    for _, row in f.iterrows():
        p_cam = row[["est_cam_x_m", "est_cam_y_m", "est_cam_z_m"]].to_numpy(float)
        for pose, out in ((camera_pose(kin, body, row[KNOWN].to_numpy(float), row["t_mid_s"]), est),
                          (camera_pose(kin, body, row[JOINTS].to_numpy(float), row["t_mid_s"]), true_mapped)):
            out.append(pose[:3, :3] @ p_cam + pose[:3, 3])
    np.testing.assert_allclose(f[["est_x_m", "est_y_m", "est_z_m"]].to_numpy(), np.array(est), rtol=0, atol=1e-12)
    assert np.max(np.linalg.norm(np.array(est) - np.array(true_mapped), axis=1)) > 0.05


def test_a_run_through_a_lossy_link_is_reproducible(renderers):
    """Lock-step and seeded losses: the same config gives bit-identical frame tables; the device's
    losses come from stream 4 of the run's seed."""
    link = GimbalLink(status_rate_hz=50.0, latency_s=0.02, quantum_rad=math.radians(0.1), loss=0.3)
    config = cell("sphere", revolutions=0.5).with_(pointing__link=link)
    a = simulate(config, renderers(config)).frames
    b = simulate(config, renderers(config)).frames
    assert a.equals(b)
    assert link_effects(config) == LinkEffects(status_rate_hz=50.0, latency_s=0.02, quantum_rad=math.radians(0.1),
                                               loss=0.3, seed=GimbalLink.effects_seed(0))
    assert GimbalLink.effects_seed(0) != GimbalLink.effects_seed(1)


def test_commanded_only_reports_the_commands_not_the_axes(renderers):
    """Without feedback the gimbal reports its commanded attitude: the rate commands' angular
    velocities, each held over its frame, integrated from neutral (R ← exp(ω Δt)·R, by hand with
    scipy's Rotation), not the axes. The oracle takes each frame's ω from the frame's known joints
    and command as the driver does; the known joints must give that attitude to float32 (a
    quaternion's 2.4e-7 rad per angle, three angles, plus 2⁻²³ of each frame's turn on the wire),
    and they differ from the axes where the axes lag and where a held angular velocity is not a
    held joint rate."""
    from scipy.spatial.transform import Rotation

    from gimbal_lab.mavlink import frames

    config = cell("sphere", revolutions=1.0).with_(pointing__link=GimbalLink(status_rate_hz=1000.0,
                                                                             commanded_only=True))
    f = simulate(config, renderers(config)).frames
    kin = config.gimbal.kinematics
    cmd = f[["cmd_yaw_rad_s", "cmd_roll_rad_s", "cmd_pitch_rad_s"]].to_numpy()
    known = f[KNOWN].to_numpy()
    dt = np.diff(np.round(1000 * np.arange(len(f) + 1) / 30)) / 1000
    R = np.eye(3)
    turned = 0.0
    worst = 0.0
    for k in range(len(f) - 1):
        omega = frames.joint_rates_to_angular_velocity(kin, known[k], cmd[k])
        R = Rotation.from_rotvec(omega * dt[k]).as_matrix() @ R
        turned += float(np.linalg.norm(omega)) * dt[k]
        R_known = frames.gimbal_attitude_matrix(kin, known[k + 1])
        worst = max(worst, np.linalg.norm(Rotation.from_matrix(R_known @ R.T).as_rotvec()))
    assert worst <= 3 * F32 + 2.0 ** -23 * turned, worst
    assert turned > 0.5  # the commands turned the camera
    assert np.max(np.abs(known - f[START].to_numpy())) > 5e-3


def test_connect_gives_the_in_process_gimbal_without_a_link():
    config = cell("sphere", revolutions=0.1)
    mount = config.gimbal.mount(config.body, "active", 100, 0)
    assert isinstance(connect(config, mount), DirectGimbal)


def test_a_propagated_status_is_carried_forward_by_its_own_rates():
    """By hand: a status at joints q with angular velocity ω = A(q)·q̇ (the device's report of joint
    rates q̇), used `age` later, gives q + q̇·age with attitude "propagated" (A⁻¹ of A·q̇ returns q̇
    to 1e-12), as reported with "as-is" or for a status from after the instant, and the rates
    last commanded when it reports no angular velocity."""
    from types import SimpleNamespace

    from gimbal_lab.mavlink.frames import joint_rates_to_angular_velocity
    from gimbal_lab.mavlink.loop import LinkedGimbal

    kin = PaperStudy().config("sphere", "distorted", "circular", "active", 0).gimbal.kinematics
    q, qdot = np.array([0.3, 0.02, -0.2]), np.array([1.1, -0.05, 0.4])
    omega = joint_rates_to_angular_velocity(kin, q, qdot)
    report = SimpleNamespace(q_rad=q, angular_velocity_rad_s=omega, frame="vehicle", time_s=2.0)
    gimbal = object.__new__(LinkedGimbal)  # the loop's side alone: no device, no driver
    gimbal.kinematics, gimbal._home, gimbal._report = kin, np.zeros(3), report
    gimbal._commanded = np.array([-0.7, 0.0, 0.9])
    for propagate, t, expected in ((True, 2.05, q + 0.05 * qdot), (True, 1.99, q), (False, 2.05, q)):
        gimbal._propagate = propagate
        np.testing.assert_allclose(gimbal._known(t), expected, rtol=0, atol=1e-12)
    gimbal._propagate = True
    gimbal._report = SimpleNamespace(q_rad=q, angular_velocity_rad_s=np.full(3, np.nan), frame="vehicle", time_s=2.0)
    np.testing.assert_allclose(gimbal._known(2.1), q + 0.1 * gimbal._commanded, rtol=0, atol=1e-12)
    gimbal._report = None
    np.testing.assert_array_equal(gimbal._known(2.1), np.zeros(3))  # home before the first status


@pytest.mark.parametrize("feedback", ["measured", "commanded only"])
def test_a_propagated_link_knows_the_joints_far_better_at_10_hz(feedback, renderers):
    """The loop's known joints at each frame's truth instant against the true joints there, through
    a 10 Hz link (statuses 0-100 ms old while the gimbal turns at up to 1 rad/s): propagating the
    status by its reported rates at least halves the error of using it as it is (measured: 38.0 →
    8.5 mrad with angle feedback; 44.3 → 16.2 mrad commanded only, whose reports also carry the
    commanded attitude's own gap to the axes, which no propagation removes). What is left is the
    loop's change of command within a status's age: the reported rate is the one of its instant."""
    errors = {}
    for attitude in ("as-is", "propagated"):
        link = GimbalLink(status_rate_hz=10.0, commanded_only=feedback == "commanded only", attitude=attitude)
        config = cell("sphere", revolutions=1.0).with_(pointing__link=link)
        f = simulate(config, renderers(config)).frames
        f = f[np.isfinite(f["known_age_s"])]
        errors[attitude] = float(np.abs(f[KNOWN].to_numpy() - f[JOINTS].to_numpy()).max(axis=1).mean())
    assert errors["as-is"] > 0.01  # the stale status is tens of milliradians off while the gimbal turns
    assert errors["propagated"] < 0.5 * errors["as-is"], errors
