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
from gimbal_lab.camera import KannalaBrandt  # noqa: E402

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


# --- Brown–Conrady undistortion over the whole monotonic disc ------------------------------------
from gimbal_lab.camera import _distort_jacobian, _residual_floor  # noqa: E402

TOL = 1e-12  # undistort's default stopping residual


def _inverse_jacobian_norm(x, lens):
    """‖J⁻¹‖₂ of the distortion map at each point of x (N, 2): how a residual becomes an error in x."""
    dxx, dxy, dyx, dyy = _distort_jacobian(x[:, 0], x[:, 1], lens)
    J = np.stack((np.column_stack((dxx, dxy)), np.column_stack((dyx, dyy))), axis=1)
    return 1.0 / np.linalg.svd(J, compute_uv=False)[:, -1]


def _valid_points(lens, fractions, angles, r_cap=2.0):
    """Points at ``fractions`` of the monotonic disc's radius (capped at ``r_cap``) that the centre
    reaches without crossing a fold: det J > 0 at 64 steps along the segment from the origin.
    That is the region where undistort must find the preimage (tangential terms can fold the
    map inside the disc, and beyond such a fold a point shares its image with one before it)."""
    r = np.asarray(fractions) * min(lens.radial_limit(), r_cap)
    x = np.column_stack((r * np.cos(angles), r * np.sin(angles)))
    along = (x[:, None, :] * np.linspace(0.0, 1.0, 65)[None, 1:, None]).reshape(-1, 2)
    dxx, dxy, dyx, dyy = _distort_jacobian(along[:, 0], along[:, 1], lens)
    return x[np.all((dxx * dyy - dxy * dyx).reshape(len(x), 64) > 0, axis=1)]


# subnormal coefficients are refused by BrownConrady itself (test_lens_coefficients_that_cannot_be_solved_are_named)
coefficient = st.floats(-1.0, 1.0, allow_subnormal=False)
tangential = st.floats(-0.05, 0.05, allow_subnormal=False)  # five times a strongly decentred real lens


@settings(database=None, max_examples=400, derandomize=True, deadline=None)
@given(
    k1=st.one_of(st.floats(0.0, 1.0, allow_subnormal=False), coefficient),  # strong pincushion (k1 up to +1) and mixed signs
    k2=coefficient, k3=coefficient, p1=tangential, p2=tangential,
    polar=st.lists(st.tuples(st.floats(0.0, 0.999), st.floats(0.0, 2 * np.pi)), min_size=1, max_size=16),
)
def test_undistort_finds_every_point_of_the_monotonic_disc(k1, k2, k3, p1, p2, polar):
    """Any lens, any point inside the disc where the radial map rises (and det J > 0): the round
    trip distort → undistort comes back. Bound: undistort stops at residual ≤ tol once the
    residual's rounding floor is below tol (checked); distort(x) itself carries up to that floor;
    so |x_back − x| ≤ ‖J⁻¹‖ (tol + floor) to first order, and 2× that covers the second order."""
    lens = BrownConrady(k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    fractions, angles = np.array(polar).T
    x = _valid_points(lens, fractions, angles)
    if len(x) == 0:
        return
    assert _residual_floor(x[:, 0], x[:, 1], lens).max() < TOL  # the premise of the bound below
    back = undistort(distort(x, lens), lens, tol=TOL)
    bound = 2.0 * _inverse_jacobian_norm(x, lens) * 2.0 * TOL
    assert np.all(np.hypot(*(back - x).T) <= bound)


def test_undistort_of_a_strong_pincushion_lens_reaches_the_edge_of_the_disc_and_no_further():
    """k1 = 1, k2 = −0.5: r + r³ − 0.5 r⁵ rises until 1 + 3s − 2.5s² = 0 (s = r²), i.e.
    s = (3 + √19)/5; the disc's image reaches r(1 + s − s²/2) there (hand-derived). A point
    just inside that image has a preimage (found, though it starts outside the disc); a point
    just beyond has none in the disc (refused)."""
    lens = BrownConrady(k1=1.0, k2=-0.5)
    s = (3 + math.sqrt(19)) / 5
    assert lens.radial_limit() == pytest.approx(math.sqrt(s), rel=1e-14)
    edge = math.sqrt(s) * (1 + s - s * s / 2)  # 1.6848...
    angles = np.linspace(0, 2 * np.pi, 17)
    inside = 0.999 * edge * np.column_stack((np.cos(angles), np.sin(angles)))
    back = undistort(inside, lens)
    assert np.all(np.hypot(*back.T) < math.sqrt(s))
    assert np.abs(distort(back, lens) - inside).max() <= TOL
    with pytest.raises(UndistortionError, match=r"1 of 2 points .* monotonic disc"):
        undistort([[0.5, 0.0], [0.0, 1.001 * edge]], lens)


def test_undistort_agrees_with_opencv_where_opencv_converges():
    """cv2.undistortPoints with a criteria (fixed-point iteration from x_d, EPS 1e-15) is the oracle on
    random lenses, pincushion included, for every point where OpenCV itself converged to a
    point of the disc (its answer re-projects, by cv2.projectPoints, within 1e-13). Agreement:
    ‖J⁻¹‖ times the two answers' residuals and rounding floors, doubled."""
    rng = np.random.default_rng(7)
    compared = 0
    for _ in range(200):
        k1, k2, k3 = rng.uniform(-1, 1, 3)
        lens = BrownConrady(k1, k2, *rng.uniform(-0.01, 0.01, 2), k3)
        x = _valid_points(lens, rng.uniform(0, 0.999, 40), rng.uniform(0, 2 * np.pi, 40))
        xd = distort(x, lens)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
        theirs = cv2.undistortPoints(xd[:, None, :], np.eye(3), lens.coefficients, None, None, None, criteria)[:, 0, :]
        with np.errstate(invalid="ignore", over="ignore"):
            again = cv2.projectPoints(np.column_stack((theirs, np.ones(len(theirs)))), np.zeros(3), np.zeros(3),
                                      np.eye(3), lens.coefficients)[0][:, 0, :]
            residual = np.hypot(*(again - xd).T)
            converged = np.isfinite(residual) & (residual < 1e-13) & (np.hypot(*theirs.T) < lens.radial_limit())
        if not converged.any():
            continue
        ours = undistort(xd[converged], lens, tol=TOL)
        floors = _residual_floor(*x[converged].T, lens)
        bound = 2.0 * _inverse_jacobian_norm(x[converged], lens) * (TOL + residual[converged] + 2 * floors)
        assert np.all(np.hypot(*(ours - theirs[converged]).T) <= bound)
        compared += int(converged.sum())
    assert compared > 2000  # of about 8000 points: OpenCV converges on most, not on strong pincushion edges


@pytest.mark.parametrize("hfov", [5e-324, 1e-310, 0.0, -0.1, math.inf, -math.inf, math.nan, math.pi, 4.0])
def test_from_fov_refuses_fields_of_view_that_are_not_normal_floats_below_180_degrees(hfov):
    with pytest.raises(ValueError, match="hfov_rad"):
        Intrinsics.from_fov(640, 480, hfov)


def test_from_fov_names_the_field_of_view_when_the_focal_length_overflows():
    # normal, but (W/2)/tan(hfov/2) = 320/1.5e-308 exceeds the largest double
    with pytest.raises(ValueError, match=r"hfov_rad = 3e-308 is too small"):
        Intrinsics.from_fov(640, 480, 3e-308)
    tiny = Intrinsics.from_fov(640, 480, 1e-300)  # still representable: f = 640/1e-300
    assert tiny.fx == pytest.approx(6.4e302, rel=1e-12)


@pytest.mark.parametrize("lens_type, name", [(BrownConrady, "k1"), (BrownConrady, "k3"), (KannalaBrandt, "k4")])
def test_lens_coefficients_too_large_for_the_fold_radius_are_named(lens_type, name):
    """Where the radial map folds is a root of 1 + 3 k1 s + 5 k2 s² + 7 k3 s³ (+ 9 k4 s⁴);
    a coefficient whose multiple overflows a double is refused by name (not a LinAlgError)."""
    with pytest.raises(ValueError, match=rf"{name} = -?1e\+308 is too large"):
        lens_type(**{name: 1e308})
    with pytest.raises(ValueError, match=rf"{name} = -1e\+308 is too large"):
        lens_type(**{name: -1e308})


@pytest.mark.parametrize(
    "coefficients, s_fold",
    [
        # hand-derived smallest positive roots of the fold polynomial in s = r²
        (dict(k2=-1.0, k3=1e-300), math.sqrt(1 / 5)),  # 1 − 5s² + 7e-300 s³: the huge root is not the first
        (dict(k1=0.1, k3=5e-324), math.inf),  # every coefficient positive: no fold
        (dict(k3=-5e-324), 1 / (7 * 5e-324) ** (1 / 3)),  # subnormal, yet the fold is far but finite
        (dict(k1=-1e300), 1 / 3e300),  # 1 + 3 k1 s
        (dict(k1=1e200, k3=-1e-200), None),  # 1 + 3e200 s − 7e-200 s³: s² ≈ 3e200/7e-200
    ],
)
def test_fold_radius_is_found_for_coefficients_of_any_magnitude(coefficients, s_fold):
    """np.roots (companion-matrix eigenvalues) lost the small root beside a huge one and raised
    LinAlgError when the leading coefficient was subnormal; the fold radius is exact here."""
    lens = BrownConrady(**coefficients)
    if s_fold is None:
        s_fold = math.sqrt(3e200) / math.sqrt(7e-200)  # the constant 1 shifts it by a relative 1e-400
    assert lens.radial_limit() == pytest.approx(math.sqrt(s_fold), rel=1e-14)
    fisheye = KannalaBrandt(**{("k4" if k == "k3" else k): v for k, v in coefficients.items()})
    assert fisheye.max_field_rad <= math.pi


def test_undistort_stops_at_the_rounding_floor_of_large_distorted_radii():
    """k3 = 1e4: distorted radii reach 1e5, where |distort(x) − x_d| cannot be computed below
    ~1e-11 (16 ε Σ|terms|); undistort must stop there instead of refusing for want of 1e-12."""
    lens = BrownConrady(k3=1e4)  # rises everywhere: no fold
    angles = np.linspace(0, 2 * np.pi, 50)
    x = np.linspace(0.8, 1.5, 50)[:, None] * np.column_stack((np.cos(angles), np.sin(angles)))
    floors = _residual_floor(x[:, 0], x[:, 1], lens)
    assert floors.min() > TOL  # the case this test is about
    back = undistort(distort(x, lens), lens, tol=TOL)
    assert np.all(np.hypot(*(back - x).T) <= 2.0 * _inverse_jacobian_norm(x, lens) * 2.0 * floors)


@pytest.mark.parametrize(
    "lens, x",
    [
        (BrownConrady(k1=-0.9754748644582147, k2=0.6217928499304206, p1=-0.006420096369023222,
                      p2=0.006236085819915679, k3=-0.13164080103821285), [-0.4440581810946724, -1.293961422184878]),
        (BrownConrady(k1=0.7557191297283954, k2=0.9587667675982561, p1=0.04938974296169657,
                      p2=0.00024715694852740777, k3=-0.17484508312920077), [-0.11767305140154294, 1.9933493277938041]),
        (BrownConrady(k1=-0.09661484305711654, k2=0.7424838855014644, p1=-0.04441106023600049,
                      p2=0.000986670050676354, k3=-0.329342459022548), [1.1390326988580532, -0.410005173851677]),
    ],
)
def test_undistort_damps_newton_steps_that_would_overshoot(lens, x):
    """Valid points (0.93–0.95 of the disc) whose distorted radius lies just beyond the radial
    image of the disc, pushed out by the tangential terms: the radial start sits on the disc's
    edge and full Newton steps from there leave it. Found with scripts/undistort_failure_rate.py's
    sampling (|p| ≤ 0.05) against a variant without damping, which refused all three."""
    x = np.array([x])
    assert len(_valid_points(lens, [np.hypot(*x[0]) / min(lens.radial_limit(), 2.0)], [np.arctan2(x[0, 1], x[0, 0])])) == 1
    back = undistort(distort(x, lens), lens, tol=TOL)
    assert np.hypot(*(back - x)[0]) <= 2.0 * _inverse_jacobian_norm(x, lens)[0] * 2.0 * TOL


# --- the rational lens (OpenCV's CALIB_RATIONAL_MODEL) -------------------------------------------
from gimbal_lab.camera import Rational  # noqa: E402

#: A wide phone-style lens: strong barrel from a falling ratio, L(∞) = k3/k6 = 1/6, rising everywhere.
PHONE = Rational(k1=2.2, k2=0.8, p1=0.0005, p2=-0.0003, k3=0.02, k4=2.6, k5=1.5, k6=0.12)


@pytest.mark.parametrize("lens", [PHONE, Rational(k1=-0.2, k2=0.05, p1=0.001, k3=0.01, k4=0.3, k5=-0.1, k6=0.02)],
                         ids=["phone", "mixed-signs"])
def test_rational_project_matches_opencv(lens):
    """cv2.projectPoints with the 8 coefficients is the oracle, at Brown–Conrady's tolerance
    (test_project_matches_opencv: the same rational function in double precision, 1e-6 px)."""
    points = random_points_in_view(2000)
    ours = project(points, CAM, lens)
    theirs, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), CAM.K, lens.coefficients)
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-6


@pytest.mark.parametrize("lens", [PHONE, Rational(k1=-0.2, k2=0.05, p1=0.001, k3=0.01, k4=0.3, k5=-0.1, k6=0.02)],
                         ids=["phone", "mixed-signs"])
def test_rational_undistort_matches_opencv_over_the_image(lens):
    """cv2.undistortPoints with the 8 coefficients is the oracle, at Brown–Conrady's tolerance
    (test_undistort_matches_opencv_over_the_image: 1e-6 px; re-distorted within 1e-8 px)."""
    grid = np.stack(np.meshgrid(np.arange(0, 640, 8.0), np.arange(0, 480, 8.0)), -1).reshape(-1, 2)
    ours = undistort_pixels(grid, CAM, lens)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    theirs = cv2.undistortPoints(grid[:, None, :], CAM.K, lens.coefficients, None, None, CAM.K, criteria)
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-6
    assert np.abs(distort_pixels(ours, CAM, lens) - grid).max() < 1e-8
    rays = backproject(grid, CAM, lens)
    assert np.abs(project(rays, CAM, lens) - grid).max() < 1e-8


def test_a_rational_lens_without_a_denominator_is_the_brown_conrady_lens():
    """k4 = k5 = k6 = 0: L = N/1, bit for bit the Brown–Conrady map."""
    x = random_points_in_view(500)[:, :2] / 4.0
    bc = BrownConrady(k1=-0.25, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.01)
    rational = Rational(k1=-0.25, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.01)
    np.testing.assert_array_equal(distort(x, rational), distort(x, bc))
    assert rational.radial_limit() == bc.radial_limit()


@pytest.mark.parametrize(
    "lens, r_fold, rd_fold",
    [
        (Rational(k4=1.0), 1.0, 0.5),  # r/(1 + r²): slope (1 − r²)/(1 + r²)², peak 1/2 at r = 1
        (Rational(k4=-1.0), 1.0, math.inf),  # r/(1 − r²) rises to its pole at r = 1
        (Rational(k1=-0.5), math.sqrt(2 / 3), math.sqrt(2 / 3) * 2 / 3),  # Brown–Conrady's k1 = −0.5
        (PHONE, math.inf, math.inf),
    ],
    ids=["peak", "pole", "numerator-only", "phone"],
)
def test_rational_fold_radius_is_where_the_map_turns_or_its_denominator_vanishes(lens, r_fold, rd_fold):
    """Hand-derived: d/dr [r N/D] = [N D + 2 s (N' D − N D')]/D², s = r². Distorted radii just inside
    the disc's image have a preimage in the disc; just beyond, none (a pole's image is unbounded:
    a distorted radius of 1e3 still has one, to the rounding floor of N/D beside the pole)."""
    assert lens.radial_limit() == pytest.approx(r_fold, rel=1e-14)
    if not math.isfinite(r_fold):
        return
    assert lens.radial_image(r_fold) == pytest.approx(rd_fold, rel=1e-14)
    inside = 0.999 * rd_fold if math.isfinite(rd_fold) else 1e3
    back = undistort([[0.0, inside]], lens)
    assert np.hypot(*back[0]) < r_fold
    assert np.abs(distort(back, lens) - [[0.0, inside]]).max() <= max(TOL, _residual_floor(*back.T, lens)[0])
    if math.isfinite(rd_fold):
        with pytest.raises(UndistortionError, match="monotonic disc"):
            undistort([[1.001 * rd_fold, 0.0]], lens)


def test_rational_coefficients_are_checked_by_name():
    with pytest.raises(ValueError, match="k5 must be finite"):
        Rational(k5=math.nan)
    with pytest.raises(ValueError, match=r"k6 = 1e\+308 is too large"):
        Rational(k6=1e308)
    with pytest.raises(TypeError, match="a BrownConrady, a Rational, a KannalaBrandt or None"):
        distort([[0.1, 0.2]], (0.1, 0.0, 0.0, 0.0, 0.0))


@settings(database=None, max_examples=300, derandomize=True, deadline=None)
@given(
    k1=coefficient, k2=coefficient, k3=coefficient, p1=tangential, p2=tangential,
    k4=st.floats(0.0, 3.0, allow_subnormal=False), k5=coefficient, k6=coefficient,
    polar=st.lists(st.tuples(st.floats(0.0, 0.999), st.floats(0.0, 2 * np.pi)), min_size=1, max_size=16),
)
def test_rational_undistort_inverts_distort_over_the_monotonic_disc(k1, k2, k3, p1, p2, k4, k5, k6, polar):
    """The round trip distort → undistort for any rational lens, at any point inside the disc where
    its radial map rises (before any pole) and det J > 0; the bound as for Brown–Conrady
    (test_undistort_finds_every_point_of_the_monotonic_disc): 2‖J⁻¹‖ (tol + floor)."""
    lens = Rational(k1=k1, k2=k2, p1=p1, p2=p2, k3=k3, k4=k4, k5=k5, k6=k6)
    fractions, angles = np.array(polar).T
    x = _valid_points(lens, fractions, angles)
    if len(x) == 0:
        return
    floors = _residual_floor(x[:, 0], x[:, 1], lens)
    back = undistort(distort(x, lens), lens, tol=TOL)
    bound = 2.0 * _inverse_jacobian_norm(x, lens) * 2.0 * np.maximum(TOL, floors)
    assert np.all(np.hypot(*(back - x).T) <= bound)


def test_the_rational_lens_is_a_rigs_lens_in_configs_and_scenario_files(tmp_path):
    """[camera.lens] model = "rational" in a scenario file builds the Camera whose lens is that
    Rational; its table (to_dict) gives it back, and an unknown model is named."""
    from gimbal_lab.config import Camera, TrackingConfig
    from gimbal_lab.studies.scenario import Scenario

    camera = Camera(lens={"model": "rational", **{k: float(v) for k, v in zip(
        ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), PHONE.coefficients)}})
    assert camera.lens == PHONE and camera.lens_model == PHONE and camera.lens_label == "custom"
    assert camera.to_dict()["lens"]["model"] == "rational"
    assert Camera.from_dict(camera.to_dict()) == camera
    with pytest.raises(ValueError, match=r"unknown lens model 'rationl' \(brown_conrady, rational or kannala_brandt\)"):
        Camera(lens={"model": "rationl"})
    scenario = tmp_path / "phone.toml"
    scenario.write_text(
        'description = "a wide phone lens"\n'
        "[camera.lens]\n"
        'model = "rational"\n'
        "k1 = 2.2\nk2 = 0.8\np1 = 0.0005\np2 = -0.0003\nk3 = 0.02\nk4 = 2.6\nk5 = 1.5\nk6 = 0.12\n"
        "[sweep]\n"
        'pointing = ["fixed", "paper"]\n')
    read = Scenario.from_toml(scenario)
    assert TrackingConfig.from_dict(read.base).camera.lens_model == PHONE
