"""The closed loop: every grid cell runs, determinism, active centring, truth from geometry,
the world mapping of a moving camera and the mid-exposure instant (the config itself: test_config.py)."""

import math

import numpy as np
import pytest

from gimbal_lab.config import Camera, Estimator, Platform, Pointing, Target
from gimbal_lab.studies.paper import PaperStudy, grid
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.simulation import TrackingConfig, make_renderer, simulate


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


@pytest.mark.parametrize("config", [c.replace(revolutions=0.1) for c in grid(PaperStudy(replicates=2)) if c.seed == 0],
                         ids=lambda c: c.label)
def test_every_grid_cell_runs(config, renderers):
    result = simulate(config, renderer=renderers(config))
    f = result.frames
    assert len(f) == config.n_frames == 6
    assert f["detected"].all()  # the target is fully in view all along both motions
    assert np.isfinite(f["abs_error_m"]).all()
    # measured worst case 5.0 % of the distance (circle method, passive, 18° off axis; ArUco ≤ 3.3 %)
    assert (f["abs_error_m"] < 0.06 * f["d_true_m"]).all()


def test_windowed_antialiasing_leaves_the_paper_grid_unchanged(renderers):
    """Bound of the render speed-up (multisampling only in the target's window, the default)
    against the full multisampled render on the same replicate: every cell of the paper's grid
    detects on the same frames and its distance error moves by at most 0.01 mm (measured: not
    at all, over 60 frames a cell; the anti-aliasing itself is worth 1.6 mm on the active sphere)."""
    from gimbal_lab.scene import SceneRenderer

    full_aa = {}  # one fully multisampled renderer per camera and target, as the windowed ones are shared
    try:
        for config in grid(PaperStudy(replicates=2)):
            if config.seed != 1:
                continue
            config = config.replace(revolutions=0.3)
            windowed = simulate(config, renderer=renderers(config)).frames
            if config.renderer_key not in full_aa:
                full_aa[config.renderer_key] = SceneRenderer(config.camera.intrinsics, config.camera.lens_model,
                                                             target=config.target.kind, antialias="full")
            full = simulate(config, renderer=full_aa[config.renderer_key]).frames
            assert windowed["detected"].equals(full["detected"]), config.label
            np.testing.assert_allclose(windowed["error_m"], full["error_m"], atol=1e-5, rtol=0, err_msg=config.label)
            np.testing.assert_allclose(windowed["offset_px"], full["offset_px"], atol=1e-3, rtol=0,
                                       err_msg=config.label)
    finally:
        for renderer in full_aa.values():
            renderer.close()


def test_windowed_background_leaves_blurred_runs_unchanged():
    """The same bound for blurred frames (the background multisampled only where the target's
    composite reads it): moving-drone cells of both targets, both shutters and every mount detect
    on the same frames with errors within 0.01 mm of a background multisampled everywhere
    (measured: identical over 30 frames in each of the 36 cells)."""
    from gimbal_lab.scene import SceneRenderer
    from gimbal_lab.studies.moving_drone import MovingDroneStudy, grid as drone_grid

    cells = [c for c in drone_grid(MovingDroneStudy(replicates=2)) if c.seed == 1 and c.platform.motion == "vibration"]
    for target in ("sphere", "aruco"):
        chosen = [c.replace(revolutions=0.15) for c in cells if c.target.kind == target][::2]
        camera = chosen[0].camera
        with SceneRenderer(camera.intrinsics, camera.lens_model, target=target) as windowed, \
                SceneRenderer(camera.intrinsics, camera.lens_model, target=target, antialias="full") as full_aa:
            for config in chosen:
                a = simulate(config, renderer=windowed).frames
                b = simulate(config, renderer=full_aa).frames
                assert a["detected"].equals(b["detected"]), config.label
                np.testing.assert_allclose(a["error_m"], b["error_m"], atol=1e-5, rtol=0, err_msg=config.label)


def test_same_seed_same_table(renderers):
    config = TrackingConfig(camera=Camera(noise_std=4.0), pointing=Pointing("paper"), revolutions=0.25, seed=7)
    a = simulate(config, renderer=renderers(config)).frames
    b = simulate(config, renderer=renderers(config)).frames
    assert a.equals(b)
    c = simulate(config.replace(seed=8), renderer=renderers(config)).frames
    assert not a.equals(c)  # the noise really depends on the seed


def test_a_moving_drones_run_is_reproducible_from_its_seed(renderers):
    """Every random draw of a run (sensor noise, body sway and vibration, gyro noise, the flight's
    start point and target phase through the study's streams) comes from its seed: the same config
    gives the same table bit for bit, and the next seed another."""
    from gimbal_lab.studies.moving_drone import MovingDroneStudy

    study = MovingDroneStudy(replicates=2)
    config = study.config("sphere", "flight", "stabilised", "rolling", 1).replace(revolutions=0.15)
    a = simulate(config, renderer=renderers(config)).frames
    b = simulate(study.config("sphere", "flight", "stabilised", "rolling", 1).replace(revolutions=0.15),
                 renderer=renderers(config)).frames
    assert a.equals(b)
    other = study.config("sphere", "flight", "stabilised", "rolling", 2).replace(revolutions=0.15)
    c = simulate(other, renderer=renderers(other)).frames
    assert not np.allclose(a["q_yaw_rad"], c["q_yaw_rad"])  # another body and gyro
    assert not np.allclose(a["true_y_m"], c["true_y_m"])  # another start phase


def test_true_distance_is_geometry(renderers):
    config = TrackingConfig(target=Target(start_phase_s=0.25), revolutions=0.5)
    f = simulate(config, renderer=renderers(config)).frames
    kin = GimbalKinematics.default()
    T_world_base = np.eye(4)
    T_world_base[:3, 3] = (0, 0, 2.0)
    T_world_cam = T_world_base @ kin.T_body_base @ kin.forward(np.zeros(3))
    centre = T_world_cam[:3, 3]
    t = f["t_s"].to_numpy() + 0.25  # the replicate's start phase shifts the motion
    phi = 2 * np.pi * t / 2.0
    truth = np.column_stack((np.full_like(t, 3.0), np.cos(phi), 2.0 + np.sin(phi)))
    assert np.allclose(f[["true_x_m", "true_y_m", "true_z_m"]].to_numpy(), truth, atol=1e-12)
    assert np.allclose(f["d_true_m"], np.linalg.norm(truth - centre, axis=1), atol=1e-9)
    # passive: the gimbal holds its home pose
    assert np.abs(f[["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]].to_numpy()).max() < 1e-9


def test_active_centres_passive_follows_projection(renderers):
    active_cfg = TrackingConfig(pointing=Pointing("predictive"), revolutions=1.5)
    passive_cfg = active_cfg.replace(pointing=Pointing("stabilised"))
    active = simulate(active_cfg, renderer=renderers(active_cfg)).frames
    passive = simulate(passive_cfg, renderer=renderers(passive_cfg)).frames
    settled = active["t_s"] > 1.0
    # the 1 m circle seen from ~3 m sits ~185 px from the centre; passive sees exactly that
    assert passive["offset_px"].median() > 150
    assert np.allclose(passive["offset_px"], passive["true_offset_px"], atol=3.0)  # centroid vs true centre
    # active keeps the sphere within a few pixels once converged
    assert active.loc[settled, "offset_px"].max() < 25
    assert active.loc[settled, "offset_px"].median() < 10


def test_paper_loop_centres_within_its_settled_lag(renderers):
    """The paper's ZN PI loop centres the circling sphere to a few tens of pixels, far from passive."""
    config = TrackingConfig(pointing=Pointing("paper"), revolutions=2.0)
    f = simulate(config, renderer=renderers(config)).frames
    settled = f[f["revolution"] == 1]
    assert settled["offset_px"].mean() < 30  # measured 20 px; passive sees ~185 px
    assert settled["detected"].all()


def test_world_mapping_of_an_active_run_uses_the_pose_of_that_frame(renderers):
    """Exact (ellipse) estimates mapped through the moving camera land on the true centre.

    With the camera turning at up to 3 rad/s, a pose one frame late would move the estimate by
    100–400 mm (measured 112 mm at the 10th percentile); the estimate itself is good to a few mm.
    """
    config = TrackingConfig(camera=Camera(noise_std=0.0), target=Target(start_phase_s=0.3), pointing=Pointing("paper"),
                            estimator=Estimator(sphere_method="ellipse"), revolutions=1.0)
    f = simulate(config, renderer=renderers(config)).frames
    assert f[["qd_yaw_rad_s", "qd_pitch_rad_s"]].abs().max().max() > 1.0  # the camera really moves
    est = f[["est_x_m", "est_y_m", "est_z_m"]].to_numpy()
    true = f[["true_x_m", "true_y_m", "true_z_m"]].to_numpy()
    err = np.linalg.norm(est - true, axis=1)
    assert np.median(err) < 0.010 and err.max() < 0.030  # measured 6.2 mm and 22 mm


def test_truth_is_taken_at_mid_exposure(renderers):
    config = TrackingConfig(camera=Camera(exposure_s=1 / 60, blur="subframes", n_subframes=2),
                            target=Target(trajectory="diagonal", start_phase_s=0.4), revolutions=0.2)
    f = simulate(config, renderer=renderers(config)).frames
    assert np.allclose(f["t_mid_s"], f["t_s"] + 1 / 120, atol=1e-15)
    truth = config.path.position(f["t_s"].to_numpy() + 1 / 120 + 0.4)
    assert np.allclose(f[["true_x_m", "true_y_m", "true_z_m"]].to_numpy(), truth, atol=1e-12)


def test_a_blurred_frame_sees_the_path_the_axes_really_took(renderers, monkeypatch):
    """Active mount, vibrating body, 1/60 s exposure: the joint angles a frame records at its
    mid-exposure instant are those the mount stepped through (cubic between 1 ms steps: within
    2e-6 rad), not the rate of the exposure's start held through it (off by milliradians: the
    image loop's new reference lands as the exposure starts)."""
    import gimbal_lab.mount as mount_module
    from scipy.interpolate import CubicSpline

    steps = {}

    class Recording(mount_module.GimbalMount):
        def advance(self, n, rate_ref=None):
            for _ in range(n):
                super().advance(1, rate_ref)
                steps[self.step_index] = self.q

    monkeypatch.setattr(mount_module, "GimbalMount", Recording)
    config = TrackingConfig(camera=Camera(exposure_s=1 / 60, blur="fast"), platform=Platform(motion="vibration"),
                            target=Target(start_phase_s=0.3), pointing=Pointing("paper"), revolutions=0.5)
    f = simulate(config, renderer=renderers(config)).frames
    k = np.array(sorted(steps))
    path = CubicSpline(k * 1e-3, np.array([steps[i] for i in k]), axis=0)
    q = f[["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]].to_numpy()
    np.testing.assert_allclose(q[2:], path(f["t_mid_s"].to_numpy()[2:]), atol=2e-6, rtol=0)
    held = f[["q0_yaw_rad", "q0_roll_rad", "q0_pitch_rad"]].to_numpy() + (1 / 120) * f[
        ["w_yaw_rad_s", "w_roll_rad_s", "w_pitch_rad_s"]].to_numpy()
    assert np.sqrt(np.mean(np.sum((held - q) ** 2, axis=1))) > 1e-3


def test_render_frame_takes_the_mid_exposure_state_and_integrates_over_the_exposure():
    """Joint angles and target at t_s + exposure/2 (by hand), sub-frame poses along the exposure."""
    from gimbal_lab.simulation import render_frame
    from gimbal_lab.trajectories import target_pose

    class Recorder:
        def __init__(self):
            self.calls = []

        def render(self, T_cam, T_target):
            self.calls.append(("render", T_cam, T_target))
            return "sharp"

        def render_exposure(self, pose_fn, t0, exposure, n):
            self.calls.append(("exposure", [pose_fn(t0 + exposure * (j + 0.5) / n) for j in range(n)]))
            return "blurred"

    camera_pose = lambda q: np.diag([1.0, 1.0, 1.0, 1.0]) + np.pad(np.diag(q), ((0, 1), (0, 1)))
    q0, qd = np.array([0.1, -0.2, 0.3]), np.array([2.0, -1.0, 0.5])
    for exposure, n, kind in ((0.0, None, "sharp"), (1 / 60, 4, "blurred")):
        config = TrackingConfig(camera=Camera(exposure_s=exposure, blur="subframes", n_subframes=n),
                                target=Target(start_phase_s=0.7),
                                pointing=Pointing("paper"))
        renderer = Recorder()
        camera_fn = lambda t: (q0 + qd * (t - 1.5), camera_pose(q0 + qd * (t - 1.5)))
        image, q, T_cam, T_target, t_truth = render_frame(config, renderer, camera_fn, 1.5)
        t_mid = 1.5 + exposure / 2
        assert image == kind and t_truth == t_mid
        np.testing.assert_allclose(q, q0 + qd * exposure / 2, rtol=0, atol=1e-15)  # (1.5 + e/2) − 1.5 rounds
        np.testing.assert_allclose(T_cam, camera_pose(q0 + qd * exposure / 2), rtol=0, atol=1e-15)
        np.testing.assert_allclose(T_target, target_pose(config.path, t_mid + 0.7), atol=1e-15)
        if kind == "blurred":
            for j, (T_c, T_t) in enumerate(renderer.calls[0][1]):
                t = 1.5 + exposure * (j + 0.5) / n
                np.testing.assert_allclose(T_c, camera_pose(q0 + qd * (t - 1.5)), atol=1e-15)
                np.testing.assert_allclose(T_t, target_pose(config.path, t + 0.7), atol=1e-15)
        else:
            assert renderer.calls[0][0] == "render"


@pytest.fixture(scope="module")
def fisheye_strategy_runs():
    """A quarter revolution of the lens sweep's 120° fisheye, passive, sphere, each lens strategy."""
    from gimbal_lab.studies.lens_sweep import LensSweepStudy

    study = LensSweepStudy(replicates=2)
    configs = {s: study.config("sphere", "fisheye 120°", s, "passive", 0).replace(revolutions=0.25)
               for s in ("ignore", "undistort", "rectify")}
    renderer = make_renderer(configs["ignore"])
    try:
        return {s: simulate(c, renderer=renderer) for s, c in configs.items()}
    finally:
        renderer.close()


def test_every_lens_strategy_reports_the_centre_in_the_cameras_own_pixels(fisheye_strategy_runs):
    """The outer loop measures the target where the camera images it, whatever the estimator saw.
    Within 2 px of the true centre (a 34 px sphere 42° off the axis; the enclosing circle's centre
    is not the projected centre). The rectified 90° view never holds the whole sphere on this cone
    (42° off the axis): rectification is checked on frames nearer the axis below."""
    for strategy in ("ignore", "undistort"):
        f = fisheye_strategy_runs[strategy].frames
        f = f[f["detected"]]
        assert len(f) >= 5, strategy
        miss = np.hypot(f["u_px"] - f["true_u_px"], f["v_px"] - f["true_v_px"])
        assert miss.max() < 2.0, (strategy, miss.max())


@pytest.mark.parametrize("target", ["sphere", "aruco"])
def test_the_rectified_estimate_is_mapped_back_to_the_fisheyes_pixels(target):
    """Rectify first: detection on the 90° pinhole view, the centre mapped back through the lens.
    On frames 0°, 15° and 25° off the axis of the 120° fisheye, the reported centre lies within
    1.5 px of the true centre's fisheye image and the position (the sphere's cone fit, the marker's
    pose) within 2 % of the distance; a
    centre left in the rectified view's pixels would miss by tens of pixels off the axis."""
    from gimbal_lab.camera import project
    from gimbal_lab.studies.lens_sweep import LensSweepStudy

    config = LensSweepStudy(replicates=2).config(target, "fisheye 120°", "rectify", "passive", 0)
    estimate = config.estimator.build(config.camera, config.target)
    # the exact cone fit alone (alt=False, as the lens sweep times a pipeline): the same estimate, no other
    exact_alone = config.estimator.replace(sphere_method="ellipse").build(config.camera, config.target, alt=False)
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = GimbalKinematics.default().T_body_cam(np.zeros(3))[:3, :3]
    T_world_cam[:3, 3] = config.home_camera_m
    renderer = make_renderer(config)
    try:
        for off_deg, azimuth_deg in ((0.0, 0.0), (15.0, 30.0), (25.0, 200.0)):
            a, b = math.radians(off_deg), math.radians(azimuth_deg)
            p_cam = 3.0 * np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])
            T_target = target_pose_at(T_world_cam @ np.append(p_cam, 1.0))
            image = renderer.render(T_world_cam, T_target)
            uv, p_est, p_alt = estimate(image)
            assert uv is not None, (target, off_deg)
            if target == "sphere":
                uv_alone, p_alone, none = exact_alone(image)
                assert none is None and np.array_equal(uv_alone, uv) and np.array_equal(p_alone, p_alt)
            p_est = p_alt if target == "sphere" else p_est  # the exact cone fit (the circle's own bias aside)
            truth_px = project(p_cam, config.camera.intrinsics, config.camera.lens_model)[0]
            assert np.hypot(*(uv - truth_px)) < 1.5, (target, off_deg, uv, truth_px)
            assert np.linalg.norm(p_est - p_cam) < 0.02 * 3.0, (target, off_deg)
    finally:
        renderer.close()


def target_pose_at(p_world_h):
    """The study's target pose (fixed marker orientation) at a homogeneous world point."""
    from gimbal_lab.trajectories import R_WORLD_MARKER

    T = np.eye(4)
    T[:3, :3] = R_WORLD_MARKER
    T[:3, 3] = p_world_h[:3]
    return T


def test_the_passive_camera_sees_the_cone_at_its_range_on_every_frame(fisheye_strategy_runs):
    """The cone is built around the home camera's optical centre: the still camera's true distance
    to the target (from the mount's own camera pose) is 3 m on every frame, to 1e-9 m."""
    from gimbal_lab.simulation import CONE_RANGE_M

    d = fisheye_strategy_runs["ignore"].frames["d_true_m"].to_numpy()
    assert np.abs(d - CONE_RANGE_M).max() < 1e-9


def test_knowing_the_fisheye_makes_the_exact_cone_method_exact(fisheye_strategy_runs):
    """The sphere's cone (ellipse) fit, recorded beside the circle method: within 1 % of the distance
    when it undistorts the contour through the fisheye (median; the last frames of this quarter
    revolution clip the sphere at the image's top edge, 45° up), off by more than 5 % on every frame
    when it ignores the lens."""
    rel = lambda r: (r.frames["alt_abs_error_m"] / r.frames["d_true_m"]).dropna()  # noqa: E731
    assert rel(fisheye_strategy_runs["undistort"]).median() < 0.01
    assert rel(fisheye_strategy_runs["ignore"]).min() > 0.05
    assert fisheye_strategy_runs["rectify"].config.label.endswith("/rectify")


def test_a_run_keeps_its_joints_within_their_stops_and_says_when_they_sit_there(renderers):
    """The paper's loop on the circle (which asks for about ±19° of pitch) with the pitch joint
    limited to ±0.1 rad: the recorded joint angles never pass the stops (bit-exact on a still
    body), a frame is flagged at the pitch stop exactly when its start angle sits on one, the stop
    is reached on both sides, and yaw and roll stay free."""
    from gimbal_lab.config import Gimbal

    limits = ((-3.0, 3.0), (-0.7, 0.7), (-0.1, 0.1))
    config = TrackingConfig(gimbal=Gimbal(kinematics=GimbalKinematics(joint_limits_rad=limits)),
                            pointing=Pointing("paper"), revolutions=1.0)
    f = simulate(config, renderer=renderers(config)).frames
    for column in ("q_pitch_rad", "q0_pitch_rad"):
        assert f[column].between(-0.1, 0.1).all()
    at_stop = f["q0_pitch_rad"].abs() == 0.1
    assert f["at_limit_pitch"].equals(at_stop)
    assert (f.loc[at_stop, "q0_pitch_rad"] > 0).any() and (f.loc[at_stop, "q0_pitch_rad"] < 0).any()
    assert not f["at_limit_yaw"].any() and not f["at_limit_roll"].any()
