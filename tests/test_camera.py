"""Camera model: OpenCV is the oracle for projection and distortion."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_lab.camera import (
    BrownConrady,
    Intrinsics,
    UndistortionError,
    backproject,
    distort,
    distort_pixels,
    project,
    undistort,
    undistort_pixels,
)

CAM = Intrinsics.default()
DIST = BrownConrady.default()


def random_points_in_view(n, seed=0):
    """Points 1–8 m in front of the camera whose pinhole image lies inside the frame."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 8.0, n)
    u = rng.uniform(0, CAM.width - 1, n)
    v = rng.uniform(0, CAM.height - 1, n)
    return np.column_stack(((u - CAM.cx) / CAM.fx * z, (v - CAM.cy) / CAM.fy * z, z))


def test_default_camera_matches_design():
    assert CAM.width == 640 and CAM.height == 480
    assert CAM.fx == pytest.approx(554.26, abs=0.005)  # docs/design.md rounds to 0.01 px
    assert (CAM.cx, CAM.cy) == (319.5, 239.5)
    assert np.array_equal(CAM.K, [[CAM.fx, 0, 319.5], [0, CAM.fy, 239.5], [0, 0, 1]])


@pytest.mark.parametrize("distortion", [None, DIST], ids=["pinhole", "default-distortion"])
def test_project_matches_opencv(distortion):
    points = random_points_in_view(2000)
    ours = project(points, CAM, distortion)
    coeffs = np.zeros(5) if distortion is None else distortion.coefficients
    theirs, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), CAM.K, coeffs)
    # Both evaluate the same polynomial in double precision: 1e-6 px leaves ~6 orders of margin.
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-6


def test_points_behind_camera_are_nan():
    uv = project([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0], [0.1, 0.2, 2.0]], CAM, DIST)
    assert np.isnan(uv[:2]).all()
    assert np.isfinite(uv[2]).all()


def test_optical_axis_projects_to_principal_point():
    assert np.allclose(project([0.0, 0.0, 3.0], CAM, DIST), [[CAM.cx, CAM.cy]], atol=1e-12)


# Normalised coordinates spanning the whole distorted image of the default camera (and a margin).
image_xy = st.tuples(
    st.floats(-(CAM.cx + 20) / CAM.fx, (CAM.cx + 20) / CAM.fx),
    st.floats(-(CAM.cy + 20) / CAM.fy, (CAM.cy + 20) / CAM.fy),
)


@settings(max_examples=300, deadline=None)
@given(image_xy)
def test_undistort_inverts_distort(xy):
    x = np.array([xy])
    # Newton converges quadratically; 1e-9 is the bound, the solver aims at 1e-12.
    assert np.abs(undistort(distort(x, DIST), DIST) - x).max() < 1e-9
    assert np.abs(distort(undistort(x, DIST), DIST) - x).max() < 1e-10


def test_undistort_matches_opencv_over_the_image():
    grid = np.stack(np.meshgrid(np.arange(0, 640, 8.0), np.arange(0, 480, 8.0)), -1).reshape(-1, 2)
    ours = undistort_pixels(grid, CAM, DIST)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    theirs = cv2.undistortPoints(grid[:, None, :], CAM.K, DIST.coefficients, None, None, CAM.K, criteria)
    # OpenCV's fixed-point iteration converges linearly; 1e-6 px is far below anything visible.
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-6
    # our Newton stops once |distort(x) − x_d| < 1e-12 (normalised), 5.5e-10 px at f = 554 px on any
    # CPU (measured 5.47e-10); 1e-8 px adds room for the pixel conversions
    assert np.abs(distort_pixels(ours, CAM, DIST) - grid).max() < 1e-8


def test_backproject_recovers_ray():
    points = random_points_in_view(1000, seed=1)
    for distortion in (None, DIST):
        rays = backproject(project(points, CAM, distortion), CAM, distortion)
        assert np.allclose(rays[:, 2], 1.0)
        assert np.abs(rays[:, :2] - points[:, :2] / points[:, 2:]).max() < 1e-10


def test_undistort_raises_where_model_folds():
    strong = BrownConrady(k1=-0.5)  # r(1 - 0.5 r^2) peaks at r = sqrt(2/3), value 0.544
    assert strong.radial_limit() == pytest.approx(math.sqrt(2 / 3))
    assert np.isfinite(undistort([[0.5, 0.0]], strong)).all()
    with pytest.raises(UndistortionError, match="monotonic"):
        undistort([[0.6, 0.0]], strong)


def test_gazebo_legacy_conversion_lands_on_same_pixel():
    legacy = dict(k1=-0.4, k2=0.15, k3=-0.02, p1=0.001, p2=-0.0007)
    converted = BrownConrady.from_gazebo_legacy(**legacy, intrinsics=CAM)
    points = random_points_in_view(500, seed=2)
    pinhole = project(points, CAM)
    # Gazebo-classic legacy: the same polynomial on texture coordinates (u - cx) / S, S = max(W, H).
    s = max(CAM.width, CAM.height)
    x = (pinhole[:, 0] - CAM.cx) / s
    y = (pinhole[:, 1] - CAM.cy) / s
    r2 = x * x + y * y
    radial = 1 + legacy["k1"] * r2 + legacy["k2"] * r2**2 + legacy["k3"] * r2**3
    xd = x * radial + 2 * legacy["p1"] * x * y + legacy["p2"] * (r2 + 2 * x * x)
    yd = y * radial + legacy["p1"] * (r2 + 2 * y * y) + 2 * legacy["p2"] * x * y
    gazebo_px = np.column_stack((xd * s + CAM.cx, yd * s + CAM.cy))
    assert np.abs(project(points, CAM, converted) - gazebo_px).max() < 1e-9


def test_from_fov():
    cam = Intrinsics.from_fov(1280, 720, math.radians(90))
    assert cam.fx == pytest.approx(640.0) and cam.fy == pytest.approx(640.0)
    assert (cam.cx, cam.cy) == (639.5, 359.5)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(fx=0.0), "fx"),
        (dict(fy=-5.0), "fy"),
        (dict(cx=float("nan")), "cx"),
        (dict(width=0), "width"),
        (dict(height=10.5), "height"),
    ],
)
def test_intrinsics_reject_bad_values(kwargs, field):
    params = dict(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480) | kwargs
    with pytest.raises(ValueError, match=field):
        Intrinsics(**params)


def test_distortion_rejects_nan_and_wrong_types():
    with pytest.raises(ValueError, match="k2"):
        BrownConrady(k2=float("nan"))
    with pytest.raises(TypeError, match="distortion"):
        project([0, 0, 1], CAM, distortion=[0.1, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="hfov_rad"):
        Intrinsics.from_fov(640, 480, math.pi)


@pytest.mark.parametrize("bad", [np.zeros((4, 2)), np.zeros(4), np.zeros((2, 3, 3))])
def test_wrong_shapes_raise(bad):
    with pytest.raises(ValueError, match="points_cam"):
        project(bad, CAM)
    with pytest.raises(ValueError, match="xy_norm"):
        distort(np.zeros((3, 3)), DIST)


# --- Kannala–Brandt fisheye ---------------------------------------------------------------------
from gimbal_lab.camera import KannalaBrandt, UndistortionError, backproject, distort, undistort  # noqa: E402

FISHEYE = KannalaBrandt(k1=-0.013, k2=-0.0053, k3=0.0014, k4=-0.0002)  # a stated mild fisheye (not a calibration)
FISH_K = Intrinsics(width=640, height=480, fx=204.0, fy=204.0, cx=319.5, cy=239.5)


def _cv_K(K):
    return np.array([[K.fx, 0.0, K.cx], [0.0, K.fy, K.cy], [0.0, 0.0, 1.0]])


def _directions(max_angle_rad, n, seed=0):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.0, max_angle_rad, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    return np.column_stack((np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta))) * rng.uniform(0.5, 9.0, (n, 1))


def test_fisheye_project_matches_cv2_fisheye_over_the_front_hemisphere():
    """cv2.fisheye.projectPoints is the oracle up to 89° off axis: agreement within 1e-6 px."""
    pts = _directions(np.radians(89.0), 3000)
    ours = project(pts, FISH_K, FISHEYE)
    theirs, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _cv_K(FISH_K),
                                          FISHEYE.coefficients)
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-6  # measured ~1e-10 px


def test_fisheye_undistort_matches_cv2_fisheye_undistort_points():
    pts = _directions(np.radians(85.0), 2000, seed=1)
    uv = project(pts, FISH_K, FISHEYE)
    theirs = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), _cv_K(FISH_K), FISHEYE.coefficients).reshape(-1, 2)
    ours = undistort(FISH_K.to_normalised(uv), FISHEYE)
    # OpenCV iterates to its own tolerance; compare in pixels of the pinhole with the same f
    assert np.abs(ours - theirs).max() * FISH_K.fx < 1e-6
    assert np.abs(ours - pts[:, :2] / pts[:, 2:]).max() < 1e-9  # and the analytic truth


def test_fisheye_beyond_ninety_degrees_round_trips_through_unit_rays():
    """A 185° lens: rays up to 92.5° off axis project and back-project to themselves (1e-9)."""
    lens, f = KannalaBrandt.equidistant_for_fov(640, np.radians(185.0))
    K = Intrinsics(width=640, height=480, fx=f, fy=f, cx=319.5, cy=239.5)
    dirs = _directions(np.radians(92.5), 2000, seed=2)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    uv = project(dirs, K, lens)
    assert np.isfinite(uv).all()
    # equidistant: the image radius is f·θ exactly (hand oracle)
    theta = np.arctan2(np.hypot(dirs[:, 0], dirs[:, 1]), dirs[:, 2])
    assert np.abs(np.hypot(uv[:, 0] - 319.5, uv[:, 1] - 239.5) - f * theta).max() < 1e-9
    rays = backproject(uv, K, lens)
    assert np.abs(np.linalg.norm(rays, axis=1) - 1).max() < 1e-12
    assert np.abs(rays - dirs).max() < 1e-9
    # the half width is reached at half the field: 320 px at 92.5°
    assert f * np.radians(92.5) == pytest.approx(320.0, rel=1e-12)


@given(st.floats(0.0, 1.5), st.floats(-np.pi, np.pi))
@settings(max_examples=300, deadline=None)
def test_fisheye_distort_undistort_round_trip(theta, phi):
    x, y = np.tan(theta) * np.cos(phi), np.tan(theta) * np.sin(phi)
    back = undistort(distort([x, y], FISHEYE), FISHEYE)[0]
    assert np.hypot(back[0] - x, back[1] - y) <= 1e-9 * max(1.0, np.hypot(x, y))


def test_fisheye_errors_name_the_field_limit():
    lens = KannalaBrandt(max_field_rad=np.radians(100.0))
    with pytest.raises(ValueError, match="field limit 100.00°"):
        project([[0.0, 1.0, -0.5]], FISH_K, lens)  # 116.6° off axis
    with pytest.raises(UndistortionError, match="image circle"):
        backproject([[319.5 + 204.0 * 1.9, 239.5]], FISH_K, lens)  # radius 1.9 > 100° = 1.745
    with pytest.raises(UndistortionError, match="90°"):
        undistort([[1.7, 0.0]], lens)  # 97° has no pinhole coordinates
    with pytest.raises(ValueError, match="stops rising"):
        KannalaBrandt(k1=-0.3, max_field_rad=np.radians(150))
    assert KannalaBrandt(k1=-0.3).max_field_rad == pytest.approx(np.sqrt(1 / 0.9), rel=1e-12)  # 1 − 0.9θ² = 0
    with pytest.raises(TypeError, match="KannalaBrandt"):
        project([[0, 0, 1.0]], FISH_K, "fisheye")
