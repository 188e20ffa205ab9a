"""The run's config: each part's own rules, the rules tying two parts (each named once, with both
parts in its message), nested dicts and TOML tables, the two levels of change, equality and keys."""

import hashlib
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics, KannalaBrandt
from gimbal_lab.config import (
    STREAMS, Camera, Estimator, Gimbal, Platform, Pointing, Target, TrackingConfig, check_parts, seed_stream, streams,
)
from gimbal_lab.control import AxisPlant, PIDGains, RateLoop
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.platform import BodyMotion, HoverSway, WaypointFlight
from gimbal_lab.scene import Occluder


def test_the_defaults_are_the_paper_studys_fixed_parameters():
    c = TrackingConfig()
    K = c.camera.intrinsics
    # 60° across 640 px: f = 320 / tan(30°) = 554.2563 px, principal point at the image centre
    assert math.isclose(K.fx, 320.0 / math.tan(math.radians(30.0)), rel_tol=1e-12) and K.fy == K.fx
    assert (K.cx, K.cy, K.width, K.height) == (319.5, 239.5, 640, 480)
    assert c.camera.lens_model is None and (c.camera.fps, c.camera.latency_frames, c.camera.noise_std) == (30, 1, 2)
    assert c.target.kind == "sphere" and c.target.trajectory == "circular" and c.target.period_s == 2.0
    assert c.pointing.mount == "stabilised" and not c.pointing.active and c.platform.motion == "static"
    assert c.n_frames == 120 and c.label == "sphere/undistorted/circular/passive"
    # 30 mm ahead of and 45 mm below the mount (the DH chain's cos(π/2) leaves ~1e-34 m in y)
    np.testing.assert_allclose(c.home_camera_m, [0.03, 0.0, 2.0 - 0.045], rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------
# each part's own rules name part.field
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "part, kwargs, message",
    [
        (Camera, dict(lens="fisheye"), "camera.lens"),
        (Camera, dict(lens=3), "camera.lens"),
        (Camera, dict(lens={"model": "division", "k1": 0.1}), "unknown lens model"),
        (Camera, dict(fps=-30), "camera.fps"),
        (Camera, dict(fps=float("inf")), "camera.fps"),
        (Camera, dict(width=640.5), "camera.width"),
        (Camera, dict(width=0), "camera.width"),
        (Camera, dict(height=10**6), "camera.height"),
        (Camera, dict(hfov_rad=math.radians(185.0)), "camera.hfov_rad"),
        (Camera, dict(lens=KannalaBrandt(), hfov_rad=math.radians(361.0)), "camera.hfov_rad"),
        (Camera, dict(latency_frames=0.5), "camera.latency_frames"),
        (Camera, dict(noise_std=-1), "camera.noise_std"),
        (Camera, dict(blur="motion"), "camera.blur"),
        (Camera, dict(n_subframes=0), "camera.n_subframes"),
        (Camera, dict(exposure_s=0.01, blur="subframes", n_subframes=1), "camera.n_subframes must be >= 2"),
        # an exposure without its blur only when asked for ("none"); a count that does nothing
        (Camera, dict(exposure_s=0.01, n_subframes=4), r"camera.n_subframes=4 does nothing unless camera.blur="),
        (Camera, dict(exposure_s=0.0, blur="subframes", n_subframes=4), r"camera.n_subframes=4 does nothing"),
        (Camera, dict(exposure_s=0.01, blur="none", readout_s=0.01), "camera.readout_s > 0 .* needs camera.blur='fast'"),
        # the camera's own rules that tie its fields
        (Camera, dict(exposure_s=0.1), "camera.exposure_s"),  # longer than a frame at 30/s
        (Camera, dict(exposure_s=0.01, latency_frames=0), "camera.latency_frames >= 1"),
        (Camera, dict(readout_s=0.01, blur="subframes"), "camera.readout_s > 0 .* needs camera.blur='fast'"),
        (Camera, dict(readout_s=0.05, blur="fast"), "camera.readout_s"),  # longer than a frame
        (Camera, dict(lens=KannalaBrandt(), exposure_s=0.01, blur="fast"), "camera.blur='subframes'"),
        (Camera, dict(lens=KannalaBrandt(), readout_s=0.01), "camera.readout_s > 0 .* and a fisheye lens"),
        (Camera, dict(calibration=Intrinsics.default(), hfov_rad=1.0), "camera.hfov_rad and camera.calibration"),
        (Camera, dict(calibration=Intrinsics.default(), hfov_rad=None, width=800), "camera.width=800 differs"),
        (Gimbal, dict(inner_rate_hz=0.0), "gimbal.inner_rate_hz"),
        (Gimbal, dict(inner_rate_hz=300.0), "gimbal.inner_rate_hz=300 must be >= 333.333"),
        (Gimbal, dict(gyro_noise_rad_s_rthz=-1e-3), "gimbal.gyro_noise_rad_s_rthz"),
        (Gimbal, dict(max_joint_rate_rad_s=0.0), "gimbal.max_joint_rate_rad_s"),
        (Gimbal, dict(kinematics="default"), "gimbal.kinematics must be a GimbalKinematics"),
        (Gimbal, dict(plants=(AxisPlant.storm32("yaw"),)), "gimbal.plants must be three"),
        (Gimbal, dict(rate_gains=(PIDGains(1.0),) * 2 + ({"kp": 1, "kd": 2, "kq": 3},)), "gimbal.rate_gains.2. key"),
        (Platform, dict(motion="orbit"), "platform.motion"),
        (Platform, dict(altitude_m=0.0), "platform.altitude_m"),
        (Platform, dict(motion_phase_s=-1.0), "platform.motion_phase_s"),
        (Platform, dict(sway=3), "platform.sway must be a HoverSway"),
        (Platform, dict(motion="flight", altitude_m=4.0), "platform.altitude_m=4 differs from the height platform.flight"),
        (Target, dict(kind="cube"), "target.kind"),
        (Target, dict(trajectory="spiral"), "target.trajectory"),
        (Target, dict(period_s=0.0), "target.period_s"),
        (Target, dict(start_phase_s=2.0), r"target.start_phase_s must be in \[0, target.period_s"),
        (Target, dict(sphere_radius_m=0.0), "target.sphere_radius_m"),
        (Target, dict(marker_length_m=-0.3), "target.marker_length_m"),
        (Target, dict(occluders=((1, 2, 3),)), "target.occluders"),
        (Target, dict(occluders=Occluder("pole", (1, 0, 1), (0.1, 0.1, 2))), "target.occluders"),
        (Target, dict(cone_half_angle_rad=0.5), "target.cone_half_angle_rad=0.5 applies to target.trajectory 'cone'"),
        (Target, dict(trajectory="cone", cone_half_angle_rad=0.0), "target.cone_half_angle_rad"),
        (Target, dict(trajectory="cone", cone_half_angle_rad=math.pi / 2), "target.cone_half_angle_rad"),
        (Target, dict(cone_range_m=2.0), "target.cone_range_m=2.0 applies to target.trajectory 'cone'"),
        (Target, dict(trajectory="cone", cone_range_m=0.0), "target.cone_range_m"),
        (Target, dict(trajectory="cone", cone_range_m=101.0), "target.cone_range_m"),
        (Pointing, dict(kind="image"), "pointing.kind"),
        (Pointing, dict(kind="filter", filter="ekf"), "pointing.filter"),
        (Pointing, dict(kind="paper", filter="cv"), "pointing.filter='cv' applies to pointing.kind 'filter' only"),
        (Pointing, dict(kind="filter", coast_s=1.5), "pointing.coast_s=1.5 applies to pointing.kind 'paper' only"),
        (Pointing, dict(kind="paper", coast_s=-1.0), "pointing.coast_s"),
        (Pointing, dict(kind="paper", coast_s="1.5"), "pointing.coast_s"),
        (Estimator, dict(sphere_method="hough"), "estimator.sphere_method"),
        (Estimator, dict(lens_strategy="undistorted"), "estimator.lens_strategy"),
        (Estimator, dict(lens_strategy=True), "estimator.lens_strategy"),
        (Estimator, dict(aruco_refinement="fine"), "estimator.aruco_refinement"),
    ],
)
def test_a_part_refuses_a_bad_field_naming_it(part, kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message):
        part(**kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(revolutions=0), "revolutions"),
        (dict(revolutions=float("nan")), "revolutions"),
        (dict(revolutions=True), "revolutions"),
        (dict(revolutions="2"), "revolutions"),
        (dict(seed=-1), "seed"),
        (dict(seed=1.5), "seed"),
        (dict(camera="default"), "camera must be a Camera"),
        (dict(pointing=Target()), "pointing must be a Pointing"),
    ],
)
def test_the_runs_own_fields_are_checked(kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message):
        TrackingConfig(**kwargs)


# ----------------------------------------------------------------------------------------------
# the rules that tie two parts: one function, both parts in every message
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        # the latency must leave a frame to steer: 120 frames in the default run
        (dict(camera=Camera(latency_frames=120)), r"camera.latency_frames=120 .*revolutions × target.period_s × camera.fps"),
        (dict(revolutions=0.001), r"at least one frame: revolutions × target.period_s × camera.fps"),
        (dict(revolutions=1e5, camera=Camera(fps=1000.0)), r"revolutions × target.period_s × camera.fps must be <="),
        (dict(camera=Camera(fps=2000.0)), "gimbal.inner_rate_hz=1000 must be >= camera.fps=2000"),
        (dict(estimator=Estimator(lens_strategy="undistort")),
         "estimator.lens_strategy 'undistort' needs a lens; camera.lens is 'none'"),
        (dict(estimator=Estimator(lens_strategy="rectify"), camera=Camera(lens=BrownConrady())),
         "estimator.lens_strategy 'rectify' needs a lens; camera.lens is BrownConrady"),
        (dict(target=Target(occluders=(Occluder("pole", (1, 0, 1), (0.15, 0.15, 2)),)),
              camera=Camera(exposure_s=1 / 60, blur="fast")), "target.occluders need camera.blur 'subframes'"),
        (dict(pointing=Pointing("predictive"), platform=Platform(motion="hover")),
         "pointing 'predictive' assumes a still platform; platform.motion is 'hover'"),
        (dict(pointing=Pointing("filter"), platform=Platform(motion="flight")),
         "pointing 'filter' assumes a still platform; platform.motion is 'flight'"),
    ],
)
def test_a_rule_tying_two_parts_names_both(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrackingConfig(**kwargs)


def test_the_rules_tying_parts_accept_what_they_allow():
    """The edge each rule draws: the last frame a latency may take, an inner rate equal to the frame
    rate, a known lens, occluders with sub-frame blur, the paper's loop on a moving body."""
    TrackingConfig(camera=Camera(latency_frames=119))
    TrackingConfig(camera=Camera(fps=1000.0), revolutions=0.01)
    TrackingConfig(estimator=Estimator(lens_strategy="undistort"), camera=Camera(lens="default"))
    TrackingConfig(target=Target(occluders=(Occluder("pole", (1, 0, 1), (0.15, 0.15, 2)),)),
                   camera=Camera(exposure_s=1 / 60, blur="subframes", n_subframes=4))
    TrackingConfig(pointing=Pointing("paper"), platform=Platform(motion="flight"))
    check_parts(TrackingConfig())  # callable on its own, as the config's constructor calls it


def test_the_old_passive_mount_rule_cannot_be_broken():
    """The flat config refused passive_mount="fixed" with mode="active"; a pointing is one kind, so
    "fixed and active" cannot be written."""
    kinds = {kind: (Pointing(kind).mount, Pointing(kind).mode) for kind in
             ("fixed", "stabilised", "paper", "predictive", "filter")}
    assert kinds == {"fixed": ("fixed", "passive"), "stabilised": ("stabilised", "passive"),
                     "paper": ("active", "active"), "predictive": ("active", "active"),
                     "filter": ("active", "active")}
    assert Pointing("filter").filter == "imm" and Pointing("stabilised").filter is None


def test_the_paper_pointing_coasts_on_its_last_command_for_coast_s_then_holds():
    """The outer-loop part the config builds: measurements reach the image loop, whose last command
    is held between them and, once the target is lost, for ``pointing.coast_s`` (ImageLoop's own
    logic is worked by hand in tests/test_control.py)."""
    from gimbal_lab.config import Measurement

    def outer_after(config, lost_frames):
        kin = config.gimbal.kinematics
        outer = config.pointing.build(config, kin, None)
        K, q = config.camera.intrinsics, np.zeros(3)
        seen = Measurement(0, 0.0, np.array([K.cx + 80.0, K.cy]), q, 3.0, np.zeros(3), np.eye(4))
        outer.observe(seen, q)
        tracking = outer.command(1 / 30, q)
        for k in range(lost_frames):
            outer.observe(seen._replace(frame=k + 1, uv_px=None), q)
        return tracking, outer.command((lost_frames + 1) / 30, q)

    coasting = TrackingConfig(pointing=Pointing("paper", coast_s=0.5))
    tracking, later = outer_after(coasting, 15)  # 0.5 s at 30 frames/s: still its last command
    assert np.linalg.norm(tracking) > 0.1 and np.array_equal(later, tracking)
    assert np.all(outer_after(coasting, 16)[1] == 0.0)  # then it holds
    assert np.all(outer_after(TrackingConfig(pointing=Pointing("paper")), 1)[1] == 0.0)  # the default holds at once
    assert "coast_s" not in TrackingConfig(pointing=Pointing("paper")).to_dict()["pointing"]  # keys of before kept


# ----------------------------------------------------------------------------------------------
# a calibrated camera
# ----------------------------------------------------------------------------------------------
def test_a_calibrated_camera_uses_its_intrinsics_and_size():
    K = Intrinsics(900.0, 905.0, 650.2, 355.7, 1280, 720)
    camera = Camera(calibration=K, lens=BrownConrady(k1=-0.2))
    assert camera.intrinsics is K and (camera.width, camera.height) == (1280, 720) and camera.hfov_rad is None
    assert math.isclose(camera.horizontal_field_rad, 2 * math.atan(640 / 900.0), rel_tol=1e-15)
    # a fisheye's field by the equidistant rule, θ = r/f: half the width at 200 px is 640/200 rad off the axis
    fisheye = Camera(calibration=Intrinsics(200.0, 200.0, 639.5, 359.5, 1280, 720), lens=KannalaBrandt())
    assert math.isclose(fisheye.horizontal_field_rad, 1280 / 200.0)
    config = TrackingConfig(camera=camera)
    assert TrackingConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    # a field-of-view camera's 60° and 640 × 480 would contradict the calibration: they go with it
    with pytest.raises(ValueError, match="camera.hfov_rad and camera.calibration"):
        Camera().replace(calibration=K)
    with pytest.raises(ValueError, match="camera.width=640 differs from camera.calibration.width=1280"):
        Camera().replace(calibration=K, hfov_rad=None)
    assert Camera().replace(calibration=K, hfov_rad=None, width=None, height=None) == Camera(calibration=K)


DATA = Path(__file__).resolve().parents[1] / "data"
#: A real calibration shipped with the lab (OpenCV's ChArUco tutorial camera): fx ≠ fy, the principal
#: point 38 px below the image centre, a Brown–Conrady lens with k3 = 2.95.
CHARUCO = DATA / "calibration" / "opencv_charuco_tutorial_640x480.yml"


def test_a_camera_from_a_calibration_file_holds_the_files_numbers_not_its_path(tmp_path):
    """Oracle: cv2.FileStorage's own reading of the file's camera_matrix and distortion_coefficients."""
    import shutil

    import cv2

    raw = cv2.FileStorage(str(CHARUCO), cv2.FILE_STORAGE_READ)
    K_raw, D_raw = raw.getNode("camera_matrix").mat(), raw.getNode("distortion_coefficients").mat().ravel()
    raw.release()
    camera = Camera.from_calibration(CHARUCO, fps=60.0, noise_std=1.0)
    np.testing.assert_array_equal(camera.intrinsics.K, K_raw)
    np.testing.assert_array_equal(camera.lens_model.coefficients, D_raw)
    assert (camera.width, camera.height, camera.hfov_rad, camera.fps, camera.noise_std) == (640, 480, None, 60.0, 1.0)
    table = camera.to_dict()
    assert table["calibration"] == {"fx": K_raw[0, 0], "fy": K_raw[1, 1], "cx": K_raw[0, 2], "cy": K_raw[1, 2],
                                    "width": 640, "height": 480}
    assert table["lens"] == {"model": "brown_conrady", **dict(zip(("k1", "k2", "p1", "p2", "k3"), D_raw))}
    assert str(CHARUCO) not in json.dumps(table) and Camera.from_dict(table) == camera
    # the key follows the numbers: the same file elsewhere is the same run, a changed number another
    moved = shutil.copy(CHARUCO, tmp_path / "moved.yml")
    assert TrackingConfig(camera=Camera.from_calibration(moved, fps=60.0, noise_std=1.0)).key == \
        TrackingConfig(camera=camera).key
    changed = tmp_path / "changed.yml"
    changed.write_text(CHARUCO.read_text().replace("4.5251072219637672e+02", "4.5251072219638000e+02"))  # fx up by 3e-12 px
    assert TrackingConfig(camera=Camera.from_calibration(changed, fps=60.0, noise_std=1.0)).key != \
        TrackingConfig(camera=camera).key
    # an ideal lens in the file is an ideal camera
    from gimbal_lab.calibration import Calibration, save_calibration

    ideal = save_calibration(tmp_path / "ideal.yml", Calibration(Intrinsics(500.0, 510.0, 300.25, 250.5, 640, 480), None))
    assert Camera.from_calibration(ideal).lens == "none" and Camera.from_calibration(ideal).lens_model is None


def test_a_calibration_file_gives_the_focal_length_size_and_lens_alone(tmp_path):
    for name, value in (("hfov_rad", 1.0), ("width", 640), ("height", 480), ("lens", "none"),
                        ("calibration", Intrinsics.default())):
        with pytest.raises(ValueError, match=f"camera.{name} comes from the calibration file"):
            Camera.from_calibration(CHARUCO, **{name: value})
    with pytest.raises(FileNotFoundError, match="no such calibration file"):
        Camera.from_calibration(tmp_path / "missing.yml")
    with pytest.raises(ValueError, match="camera.fps"):
        Camera.from_calibration(CHARUCO, fps=-1.0)  # the camera's own fields are checked as ever
    bad = tmp_path / "skew.yml"
    bad.write_text(CHARUCO.read_text().replace("data: [ 4.5251072219637672e+02, 0.,", "data: [ 4.5251072219637672e+02, 1.,"))
    with pytest.raises(ValueError, match=r"skew.yml.*camera_matrix: skew"):
        Camera.from_calibration(bad)


def _rim_m(centre_cam_m, radius_m, n=4000):
    """Points of a sphere's occluding rim (camera frame, m): the circle where its tangent cone from the
    optical centre touches it, radius r·sqrt(1 − r²/D²) about c·(1 − r²/D²) in the plane normal to c."""
    c = np.asarray(centre_cam_m, float)
    D = np.linalg.norm(c)
    k = 1.0 - (radius_m / D) ** 2
    e1 = np.cross(c / D, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(c / D, e1)
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return c * k + radius_m * math.sqrt(k) * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))


def _area_centroid(points_px):
    import cv2

    m = cv2.moments(np.asarray(points_px, np.float32).reshape(-1, 1, 2))
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def _red_centroid(image):
    """Centroid of the red sphere's pixels against the sky (red above green, the sky's blue more than
    half gone: tests/test_scene.py's rule)."""
    import cv2

    rgb = image.astype(np.int16)
    mask = ((rgb[:, :, 0] > rgb[:, :, 1]) & (rgb[:, :, 2] < 235 // 2)).astype(np.uint8)
    m = cv2.moments(mask, binaryImage=True)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def _pitched_up(pitch_rad):
    """OpenCV optical frame looking along world +x pitched up by ``pitch_rad`` (world Z-up), at 2 m."""
    z = np.array([math.cos(pitch_rad), 0.0, math.sin(pitch_rad)])
    x = np.array([0.0, -1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack((x, np.cross(z, x), z))
    T[:3, 3] = (0.0, 0.0, 2.0)
    return T


#: Pitched 30° up: sky behind every sphere, so the red mask sees one background colour.
_T_SKY = _pitched_up(math.radians(30.0))


def _world_at(p_cam_m):
    T = np.eye(4)
    T[:3, 3] = _T_SKY[:3, :3] @ np.asarray(p_cam_m, float) + _T_SKY[:3, 3]
    return T


def test_a_calibrated_camera_renders_where_opencv_projects():
    """The renderer of a camera from a real calibration (fx ≠ fy, principal point off the centre, a
    strong Brown–Conrady lens) against ``cv2.projectPoints`` with the file's raw numbers.

    On the optical axis the sphere is a disc about the principal point: its centroid within 0.1 px
    of (cx, cy), the lab's requirement (docs/design.md, Conventions); a renderer that put the
    principal point at the image centre would miss by 38 px. Off the axis the oracle is the area
    centroid of the rim as OpenCV projects it, within 0.5 px (tests/test_scene.py's bound for the
    silhouette centroid: anti-aliased edges and facets contribute hundredths of a pixel). Measured:
    0.08 px on the axis, 0.02–0.09 px off it; rendering without the lens misses by 2.2 px, a principal
    point half a pixel off fails the axis bound.
    """
    import cv2

    camera = Camera.from_calibration(CHARUCO)
    K, D = camera.intrinsics.K, camera.lens_model.coefficients
    renderer = camera.make_renderer(Target())
    try:
        on_axis = _red_centroid(renderer.render(_T_SKY, _world_at((0.0, 0.0, 3.0))))
        assert np.abs(on_axis - (camera.intrinsics.cx, camera.intrinsics.cy)).max() < 0.1, on_axis
        errors = []
        for p_cam in [(0.6, 0.4, 3.0), (-0.9, 0.5, 2.5), (1.2, -0.9, 4.0), (0.8, 0.6, 2.0), (-0.75, -0.55, 2.2)]:
            rim_px = cv2.projectPoints(_rim_m(p_cam, 0.10), np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
            rendered = _red_centroid(renderer.render(_T_SKY, _world_at(p_cam)))
            errors.append(np.abs(rendered - _area_centroid(rim_px)).max())
        assert max(errors) < 0.5, errors
    finally:
        renderer.close()


def test_a_calibrated_fisheye_renders_where_opencv_fisheye_projects(tmp_path):
    """A Kannala–Brandt calibration (fx ≠ fy, the principal point off the centre) through the
    wide-field renderer against ``cv2.fisheye.projectPoints``: rim centroids within 0.5 px, as for
    the pinhole lens (tests/test_widefield.py measures its silhouette centroids within 0.08 px).
    Measured 0.02–0.14 px; fy taken for fx misses by 3.9 px, a centred principal point by 11.8 px."""
    import cv2

    from gimbal_lab.calibration import Calibration, save_calibration

    K = Intrinsics(205.0, 211.0, 331.25, 228.75, 640, 480)
    lens = KannalaBrandt(0.03, -0.012, 0.004, -0.0007)
    camera = Camera.from_calibration(save_calibration(tmp_path / "fisheye.yml", Calibration(K, lens)))
    assert isinstance(camera.lens_model, KannalaBrandt)
    renderer = camera.make_renderer(Target(sphere_radius_m=0.2))
    try:
        errors = []
        for p_cam in [(0.0, 0.0, 3.0), (1.5, 0.4, 2.5), (-2.0, -1.0, 2.0), (2.5, 1.5, 1.0), (-1.0, 1.2, 2.8)]:
            rim = _rim_m(p_cam, 0.2).reshape(-1, 1, 3)
            rim_px = cv2.fisheye.projectPoints(rim, np.zeros(3), np.zeros(3), K.K, lens.coefficients)[0].reshape(-1, 2)
            rendered = _red_centroid(renderer.render(_T_SKY, _world_at(p_cam)))
            errors.append(np.abs(rendered - _area_centroid(rim_px)).max())
        assert max(errors) < 0.5, errors
    finally:
        renderer.close()


# ----------------------------------------------------------------------------------------------
# what the parts build
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("motion", ["static", "hover", "vibration", "flight"])
def test_the_platform_builds_the_body_the_flat_config_built(motion):
    """Oracle: BodyMotion's own constructors as the flat config called them (the seed's "body"
    child of SeedSequence(seed).spawn, the replicate's phase as the time offset, a still body at the
    platform's height)."""
    import dataclasses

    seed, phase = 7, 3.25
    body_seed = np.random.SeedSequence(seed).spawn(len(STREAMS))[STREAMS.index("body")]  # the "body" child
    altitude = 2.0 if motion == "flight" else 3.5
    platform = Platform(motion=motion, motion_phase_s=phase, altitude_m=altitude)
    expected = {
        "static": BodyMotion.static((0.0, 0.0, altitude)),
        "hover": dataclasses.replace(BodyMotion.hover(body_seed, position_m=(0.0, 0.0, altitude)), time_offset_s=phase),
        "vibration": dataclasses.replace(BodyMotion.hover(body_seed, vibration=True, position_m=(0.0, 0.0, altitude)),
                                         time_offset_s=phase),
        "flight": dataclasses.replace(BodyMotion.flying(body_seed), time_offset_s=phase),
    }[motion]
    t = np.linspace(0.0, 3.0, 301)
    np.testing.assert_array_equal(platform.body(seed).T_world_body(t), expected.T_world_body(t))
    np.testing.assert_array_equal(platform.body(seed).angular_rate_body(t), expected.angular_rate_body(t))


def test_a_platforms_own_motion_parameters_reach_the_body():
    calm = Platform(motion="hover", sway=HoverSway(roll_pitch_rms_rad=0.0, yaw_rms_rad=0.0, position_rms_m=0.0))
    body = calm.body(3)
    t = np.linspace(0.0, 2.0, 50)
    np.testing.assert_allclose(body.attitude(t)[0], 0.0, atol=0.0)
    higher = WaypointFlight(start_m=(0.0, -1.5, 3.0), end_m=(0.0, 1.5, 3.0))
    flying = Platform(motion="flight", flight=higher, altitude_m=3.0).body(3)
    assert abs(flying.position(0.0)[0, 2] - 3.0) < 0.2  # at 3 m, within the sway


def test_the_gimbal_hands_its_axes_and_gains_to_the_mount():
    plants = tuple(AxisPlant.storm32(a, torque_limit_Nm=0.03) for a in ("yaw", "roll", "pitch"))
    gains = (PIDGains(0.01), PIDGains(0.02, 0.1), PIDGains(0.03, 0.0, 1e-5))
    mount = Gimbal(plants=plants, rate_gains=gains).mount(BodyMotion.static(), "active", 10, seed=0)
    assert [a.plant for a in mount.axes] == list(plants) and [loop.gains for loop in mount.rate_loops] == list(gains)
    default = Gimbal().mount(BodyMotion.static(), "active", 10, seed=0)
    zn = RateLoop(AxisPlant.storm32("pitch"), dt_s=1e-3).gains  # Ziegler–Nichols from the plant
    assert default.rate_loops[2].gains == zn and default.plants[2] == AxisPlant.storm32("pitch")


def test_renderers_are_shared_by_what_they_draw_only():
    base = TrackingConfig()
    assert base.renderer_key == base.with_(seed=4, pointing__kind="paper", target__start_phase_s=1.0).renderer_key
    for changed in (base.with_(target__sphere_radius_m=0.2), base.with_(camera__lens="default"),
                    base.with_(target__kind="aruco"), base.with_(camera__hfov_rad=1.0)):
        assert changed.renderer_key != base.renderer_key


# ----------------------------------------------------------------------------------------------
# changes at two levels
# ----------------------------------------------------------------------------------------------
def test_with_is_replace_of_a_part():
    c = TrackingConfig()
    assert c.with_(camera__fps=60, seed=3) == c.replace(camera=c.camera.replace(fps=60), seed=3)
    assert c.with_(camera__fps=60).camera.fps == 60 and c.camera.fps == 30  # a copy
    deep = c.with_(platform__motion="hover", platform__sway__yaw_rms_rad=0.01)
    assert deep.platform.sway == HoverSway(yaw_rms_rad=0.01) and deep.platform.motion == "hover"
    assert c.replace(camera__noise_std=0.0).camera.noise_std == 0.0  # replace takes the same spelling


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(colour="red"), "TrackingConfig has no field.*colour"),
        (dict(camera__colour="red"), "camera has no field.*colour"),
        (dict(lens__k1=0.1), "TrackingConfig has no field 'lens'"),
        (dict(camera=Camera(), camera__fps=60), "both replaced and changed"),
        (dict(camera__fps__x=1), "camera.fps is not a part"),
        (dict(camera__fps=-1), "camera.fps must be"),
    ],
)
def test_a_change_names_what_it_cannot_change(changes, message):
    with pytest.raises(ValueError, match=message):
        TrackingConfig().with_(**changes)


# ----------------------------------------------------------------------------------------------
# dicts, TOML tables and keys
# ----------------------------------------------------------------------------------------------
_VARIED = [
    TrackingConfig(),
    TrackingConfig(camera=Camera(lens=BrownConrady(k1=-0.1)), target=Target(start_phase_s=1.25), seed=3),
    TrackingConfig(camera=Camera(lens=KannalaBrandt(k1=0.01), hfov_rad=math.radians(150.0)),
                   estimator=Estimator(lens_strategy="rectify"), target=Target(trajectory="cone")),
    TrackingConfig(platform=Platform(motion="vibration", sway=HoverSway(attitude_hz=2.0)),
                   camera=Camera(exposure_s=1 / 60, blur="fast", readout_s=0.02),
                   gimbal=Gimbal(gyro_noise_rad_s_rthz=1e-4, rate_gains=(PIDGains(0.01),) * 3)),
    TrackingConfig(target=Target(trajectory="manoeuvring", occluders=(Occluder("pole", (1, 0, 1), (0.15, 0.15, 2)),)),
                   pointing=Pointing("filter", "ca")),
    TrackingConfig(pointing=Pointing("paper", coast_s=1.5),
                   target=Target(trajectory="cone", cone_half_angle_rad=math.radians(40.0))),
    TrackingConfig(target=Target(trajectory="cone", cone_half_angle_rad=math.radians(12.0), cone_range_m=4.2)),
    TrackingConfig(gimbal=Gimbal(kinematics=GimbalKinematics(0.05, 0.02, ((-1, 1), (-0.5, 0.5), (-2, 1))),
                                 plants=tuple(AxisPlant.storm32(a) for a in ("yaw", "roll", "pitch")))),
]


def test_the_cone_range_puts_every_point_of_the_path_at_that_distance_from_the_home_camera():
    # hand geometry: a circle about the home axis at half-angle α and range D lies D from the camera;
    # the default (None) keeps the lab's CONE_RANGE_M and the store key of configs without it
    from gimbal_lab.config import CONE_RANGE_M

    home = np.array([0.1, 0.0, 1.955])
    alpha = math.radians(17.0)
    for range_m, expected in ((2.6, 2.6), (None, CONE_RANGE_M)):
        target = Target(trajectory="cone", cone_half_angle_rad=alpha, cone_range_m=range_m)
        path = target.path(seed=0, duration_s=4.0, home_camera_m=home, field_rad=math.radians(60.0))
        points = np.array([path.position(t) for t in np.linspace(0.0, 2.0, 9)])
        assert np.linalg.norm(points - home, axis=1) == pytest.approx(expected, rel=1e-12)
        off_axis = np.arccos((points[:, 0] - home[0]) / np.linalg.norm(points - home, axis=1))
        assert off_axis == pytest.approx(alpha, rel=1e-9)
    assert "cone_range_m" not in Target(trajectory="cone").to_dict()


@pytest.mark.parametrize("config", _VARIED, ids=lambda c: c.label)
def test_a_config_round_trips_through_plain_dicts(config):
    data = json.loads(json.dumps(config.to_dict()))  # plain JSON values only
    again = TrackingConfig.from_dict(data)
    assert again == config and hash(again) == hash(config) and again.key == config.key
    assert set(data) == {"camera", "gimbal", "platform", "target", "pointing", "estimator", "revolutions", "seed"}
    assert "None" not in repr(data)  # no null: every table can be written as TOML


def test_a_config_is_built_from_toml_tables():
    text = """
revolutions = 1.5
seed = 4

[camera]
fps = 60.0
lens = { model = "brown_conrady", k1 = -0.1 }

[platform]
motion = "hover"

[platform.sway]
yaw_rms_rad = 0.01

[target]
kind = "aruco"
occluders = [{ name = "pole", centre_m = [1.0, 0.0, 1.0], size_m = [0.15, 0.15, 2.0] }]

[pointing]
kind = "paper"
"""
    config = TrackingConfig.from_dict(tomllib.loads(text))
    expected = TrackingConfig(camera=Camera(fps=60.0, lens=BrownConrady(k1=-0.1)),
                              platform=Platform(motion="hover", sway=HoverSway(yaw_rms_rad=0.01)),
                              target=Target(kind="aruco", occluders=(Occluder("pole", (1, 0, 1), (0.15, 0.15, 2)),)),
                              pointing=Pointing("paper"), revolutions=1.5, seed=4)
    assert config == expected


@pytest.mark.parametrize(
    "data, message",
    [
        ({"colour": "red"}, "unknown TrackingConfig key.*colour"),
        ({"camera": {"fsp": 60}}, r"unknown camera key\(s\): fsp"),
        ({"platform": {"sway": {"yaw_rms_deg": 1}}}, r"unknown platform.sway key\(s\): yaw_rms_deg"),
        ({"target": "sphere"}, "target must be a Target"),
        ({"gimbal": {"kinematics": {"drop_m": 0.1}}}, r"unknown gimbal.kinematics key\(s\): drop_m"),
        ({"camera": {"lens": {"model": "kannala_brandt", "p1": 0.1}}}, r"camera.lens \(kannala_brandt\) key.*p1"),
        ({"platform": {"sway": {"damping": -1}}}, "platform.sway: damping must be > 0"),
        ({"camera": {"calibration": {"fx": 0.0, "fy": 1.0, "cx": 0.0, "cy": 0.0, "width": 64, "height": 48}}},
         "camera.calibration: fx must be > 0"),
    ],
)
def test_a_dict_with_unknown_keys_names_part_and_key(data, message):
    with pytest.raises((ValueError, TypeError), match=message):
        TrackingConfig.from_dict(data)


#: What the flat config of before the parts wrote into a results store's sidecar for
#: TrackingConfig(mode="active", distortion="default") (its to_dict at commit 3b6ce23), and its key.
_OLD_FLAT = {
    "altitude_m": 2.0, "aruco_refinement": "subpix", "blur": "subframes", "distortion": "default", "exposure_s": 0.0,
    "fps": 30.0, "gyro_noise_rad_s_rthz": 0.0, "height": 480, "hfov_rad": 1.0471975511965976,
    "inner_rate_hz": 1000.0, "latency_frames": 1, "lens_strategy": "ignore", "marker_length_m": 0.3,
    "mode": "active", "motion": "static", "motion_phase_s": 0.0, "n_subframes": 1, "noise_std": 2.0,
    "occluders": [], "outer_loop": "paper", "passive_mount": "stabilised", "period_s": 2.0, "readout_s": 0.0,
    "revolutions": 2.0, "seed": 0, "sphere_method": "circle", "sphere_radius_m": 0.1, "start_phase_s": 0.0,
    "target": "sphere", "target_filter": "imm", "trajectory": "circular", "width": 640,
}
_OLD_KEY = "c8f986226a0bc786"


def test_an_old_flat_sidecar_is_not_a_config_and_its_key_is_never_served(monkeypatch):
    import gimbal_lab.config as config_module

    assert hashlib.sha256(json.dumps(_OLD_FLAT, sort_keys=True).encode()).hexdigest()[:16] == _OLD_KEY
    with pytest.raises(ValueError, match="unknown TrackingConfig key.*distortion.*mode"):
        TrackingConfig.from_dict(_OLD_FLAT)
    same_run = TrackingConfig(camera=Camera(lens="default"), pointing=Pointing("paper"))
    assert same_run.key != _OLD_KEY
    # the schema enters the key: the same fields under another schema version hash differently
    key = same_run.key
    monkeypatch.setattr(config_module, "SCHEMA", "gimbal-lab/tracking-config/3")
    assert same_run.key != key


def test_equal_configs_are_equal_by_value_and_distinct_ones_are_not():
    a, b = TrackingConfig(), TrackingConfig(gimbal=Gimbal(kinematics=GimbalKinematics()))
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1  # GimbalKinematics compares by identity; Gimbal by value
    narrower = GimbalKinematics(joint_limits_rad=((-1, 1), (-0.5, 0.5), (-1, 0.5)))
    others = [a.with_(seed=1), a.with_(camera__noise_std=1.0), a.replace(gimbal=Gimbal(kinematics=narrower)),
              a.with_(platform__sway__damping=0.5), a.with_(pointing__kind="fixed")]
    assert len({a, *others}) == 1 + len(others)
    assert len({a.key, *(c.key for c in others)}) == 1 + len(others)


# ----------------------------------------------------------------------------------------------
# a replicate's named random streams (docs/design.md, "Repairs")
# ----------------------------------------------------------------------------------------------
def test_named_streams_are_the_children_of_the_seeds_sequence():
    """Oracle: numpy's own SeedSequence(seed).spawn; child i is STREAMS[i]."""
    assert STREAMS == ("phase", "noise", "body", "gyro", "plan", "flight_phase")
    for seed in (0, 1, 17, 2**40):
        children = np.random.SeedSequence(seed).spawn(len(STREAMS))
        for name, child in zip(STREAMS, children):
            assert np.array_equal(seed_stream(seed, name).generate_state(8), child.generate_state(8))
            assert np.array_equal(streams(seed)[name].generate_state(8), child.generate_state(8))


def test_streams_of_replicates_0_to_20_are_pairwise_distinct():
    """Every (seed, name) pair of 21 replicates draws its own numbers: 126 streams, no two alike in
    their first 4 words of state or their first draws. The old scheme's collision (replicate 2's
    phase, ``default_rng([1, 2])``, was replicate 1's gyro, ``SeedSequence([1, 2])``) cannot recur."""
    states, draws = {}, {}
    for seed in range(21):
        for name in STREAMS:
            states[(seed, name)] = tuple(seed_stream(seed, name).generate_state(4).tolist())
            draws[(seed, name)] = tuple(np.random.default_rng(seed_stream(seed, name)).uniform(size=4).tolist())
    assert len(set(states.values())) == len(states) == 126
    assert len(set(draws.values())) == len(draws) == 126
    old_phase_2 = np.random.default_rng([1, 2]).uniform(size=4)
    old_gyro_1 = np.random.default_rng(np.random.SeedSequence([1, 2])).uniform(size=4)
    assert np.array_equal(old_phase_2, old_gyro_1)  # the collision the named streams replace
    assert draws[(2, "phase")] != draws[(1, "gyro")]


@pytest.mark.parametrize("seed, name, error", [(-1, "gyro", ValueError), (1.5, "gyro", ValueError),
                                                ("3", "gyro", TypeError), (3, "wind", ValueError)])
def test_a_bad_stream_request_names_what_is_allowed(seed, name, error):
    with pytest.raises(error, match="seed|stream name"):
        seed_stream(seed, name)


def test_each_draw_of_a_run_comes_from_its_own_stream():
    """The body's sway, the gyro and the manoeuvring plan of a config are those of its seed's named
    streams (oracles: BodyMotion, GimbalMount's generator and ManoeuvringTarget built from the child
    SeedSequence by hand), and another seed changes each of them."""
    from gimbal_lab.trajectories import ManoeuvringTarget

    seed = 5
    child = dict(zip(STREAMS, np.random.SeedSequence(seed).spawn(len(STREAMS))))
    config = TrackingConfig(platform=Platform(motion="vibration"), seed=seed)
    t = np.linspace(0.0, 2.0, 201)
    expected_body = BodyMotion(position_m=(0.0, 0.0, 2.0), sway=HoverSway(), vibration=config.platform.vibration,
                               seed=child["body"])
    np.testing.assert_array_equal(config.body.T_world_body(t), expected_body.T_world_body(t))
    assert not np.allclose(config.replace(seed=6).body.T_world_body(t), expected_body.T_world_body(t))
    from gimbal_lab.mount import GimbalMount

    gimbal = Gimbal(gyro_noise_rad_s_rthz=1e-4)
    mount = gimbal.mount(config.body, "stabilised", 50, seed)
    by_hand = GimbalMount(gimbal.kinematics, config.body, "stabilised", gimbal.dt_s, 50, 1e-4,
                          np.random.default_rng(child["gyro"]))
    np.testing.assert_array_equal(mount._noise, by_hand._noise)  # the gyro's filtered white noise
    assert not np.allclose(gimbal.mount(config.body, "stabilised", 50, 6)._noise, by_hand._noise)
    plan = TrackingConfig(target=Target(trajectory="manoeuvring"), seed=seed).path
    by_hand = ManoeuvringTarget(seed=child["plan"], duration_s=plan.duration_s)
    np.testing.assert_array_equal(plan.position(t), by_hand.position(t))
    other = TrackingConfig(target=Target(trajectory="manoeuvring"), seed=6).path
    assert not np.allclose(other.position(t), plan.position(t))


# ----------------------------------------------------------------------------------------------
# the camera's noise: fixed, or the EMVA 1288 sensor tied to light (docs/design.md, "Sensor and light")
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fields, message", [
    (dict(light_lux=300.0), r"camera.light_lux=300.0 does nothing with camera.noise='fixed'"),
    (dict(sensor="IMX273"), r"camera.sensor='IMX273' does nothing with camera.noise='fixed'"),
    (dict(f_number=2.8), r"camera.f_number=2.8 does nothing with camera.noise='fixed'"),
    (dict(noise="sensor", light_lux=300.0), r"camera.noise='sensor' needs camera.exposure_s > 0"),
    (dict(noise="sensor", exposure_s=0.004), r"camera.noise='sensor' needs camera.light_lux"),
    (dict(noise="sensor", exposure_s=0.004, light_lux=300.0, noise_std=3.0),
     r"camera.noise_std=3 does nothing with camera.noise='sensor'"),
    (dict(noise="sensor", exposure_s=0.004, light_lux=0.0), r"camera.light_lux"),
    (dict(noise="sensor", exposure_s=0.004, light_lux=300.0, sensor="IMX999"), r"camera.sensor must be one of"),
    (dict(noise="sensor", exposure_s=0.004, light_lux=300.0, f_number=0.0), r"camera.f_number"),
    (dict(noise="gaussian"), r"camera.noise must be one of"),
])
def test_camera_noise_fields_refuse_what_would_do_nothing(fields, message):
    with pytest.raises(ValueError, match=message):
        Camera(**fields)


def test_a_fixed_noise_camera_keeps_its_dict_and_key():
    """noise='fixed' is the default and is left out of the dict, as are the unset light fields, so
    a config of before the field has the same dict (and store key) as before."""
    assert set(Camera().to_dict()) == {"width", "height", "hfov_rad", "lens", "fps", "latency_frames", "exposure_s",
                                       "readout_s", "blur", "noise_std"}
    assert TrackingConfig().key == TrackingConfig(camera=Camera(noise="fixed")).key
    assert Camera.from_dict(Camera().to_dict()).noise == "fixed"


def test_a_sensor_camera_round_trips_and_records_over_its_exposure():
    """The scenario file's [camera] says noise, light_lux and sensor; the camera fills in the
    lens's f/2.8, round-trips through its dict, and add_noise is SensorModel.record over the
    camera's exposure (the oracle: the model called directly with the same generator state)."""
    from gimbal_lab.sensor import SensorModel

    table = tomllib.loads('[camera]\nexposure_s = 0.004\nnoise = "sensor"\nlight_lux = 300\nsensor = "IMX273"\n')
    config = TrackingConfig.from_dict(table)
    camera = config.camera
    assert (camera.noise, camera.light_lux, camera.sensor, camera.f_number) == ("sensor", 300.0, "IMX273", 2.8)
    assert Camera.from_dict(camera.to_dict()) == camera
    assert TrackingConfig.from_dict(config.to_dict()) == config
    assert config.key != config.replace(camera=camera.replace(light_lux=30.0)).key
    image = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    expected = SensorModel("IMX273", light_lux=300.0, f_number=2.8).record(image, 0.004, np.random.default_rng(9))
    np.testing.assert_array_equal(camera.add_noise(image, np.random.default_rng(9)), expected)
    # less light, more noise at the same exposure (the fixed camera's noise would not change)
    flat = np.full((100, 100), 128, np.uint8)
    dim = camera.replace(light_lux=30.0)
    assert dim.add_noise(flat, np.random.default_rng(1)).std() > 2 * camera.add_noise(flat, np.random.default_rng(1)).std()


def _blurred_disc(centre_u_px: float, streak_px: int) -> np.ndarray:
    """A red disc of radius 25 px on grass, smeared along u over ``streak_px`` px in linear light."""
    import cv2

    linear = np.empty((480, 640, 3))
    linear[:] = (0.05, 0.15, 0.03)
    mask = np.zeros((480, 640), np.uint8)
    cv2.circle(mask, (int(centre_u_px), 240), 25, 1, -1)
    linear[mask == 1] = (0.6, 0.01, 0.01)
    linear = cv2.filter2D(linear, -1, np.full((1, streak_px), 1.0 / streak_px))
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
    return np.round(255 * encoded).astype(np.uint8)


def test_estimator_streak_reads_each_frames_pixels_and_records_the_cone_fit_beside_it():
    from gimbal_lab import detection

    estimator = Estimator(sphere_method="streak")
    assert Estimator.from_dict(estimator.to_dict()) == estimator
    camera, target = Camera(), Target(kind="sphere")
    run = estimator.build(camera, target)
    K, r = camera.intrinsics, target.sphere_radius_m
    for u in (300.0, 360.0):  # two frames in turn: each estimate reads its own frame
        image = _blurred_disc(u, 15)
        det = detection.SphereDetector().detect(image)
        uv, p, alt = run(image)
        np.testing.assert_array_equal(p, detection.locate_sphere_streak(image, det, K, r))
        np.testing.assert_array_equal(alt, detection.locate_sphere_ellipse(det, K, r))
        np.testing.assert_array_equal(uv, det.center_px)
        assert detection.sphere_coverage(image, det, K).streak_px > detection.STREAK_MIN_PX
        assert not np.allclose(p, alt, atol=1e-3)  # a streak: the coverage, not the cone fit
    assert estimator.build(camera, target, alt=False)(image)[2] is None
