"""The blur-aware sphere localiser (``detection.sphere_coverage``, ``locate_sphere_streak``).

Oracle: a frame made here without the renderer. The exact silhouette of a sphere (the rays within
its angular radius of its centre) at 48 instants of a straight, uniform motion, each pixel
sampled 4 × 4, is averaged in linear light and sRGB-encoded: what an exposure does to a camera's
pixels and what the lab's motion blur does. Truth: the sphere's centre at mid-exposure. The
sphere (radius 0.15 m at 3 m, 27.7 px on the study's 640 × 480, 60° camera) is seen from the axis
and from 15° off it, moving so that its image streaks 0–40 px in several directions.

Tolerances (measured on these frames, then rounded up): noise-free, the range within 4 mm and the
centre within 5 mm of 3 m (0.13 %, 0.17 %) for streaks to 20 px; 15 mm for 40 px, where few pixels
see the sphere for the whole exposure and its colour rests on them. The streak's length is read
from the coverage's second moments without the pixels below coverage 0.15: up to 15 % + 1 px
short, and up to 1.6 px long (a sharp sphere reads 1.2–1.5 px: the 4 × 4 samples' steps of
coverage at the rim); its direction within 1° from 20 px, 5° at 10 px. With sensor noise of std 2 grey levels: 25 mm (the
noise of some 5,000 pixels' coverage). The exact cone fit on the same blurred frames errs by
50–300 mm: the tests would pass no estimate that ignored the blur.
"""

import math

import numpy as np
import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics, undistort
from gimbal_lab.detection import (
    SMOOTH_BACKGROUND,
    STREAK_MIN_PX,
    SphereDetector,
    locate_sphere_ellipse,
    locate_sphere_streak,
    sphere_coverage,
)

CAM = Intrinsics.default()
RADIUS_M = 0.15
RANGE_M = 3.0
TARGET = (0.60, 0.01, 0.01)  # linear RGB: a saturated red
BACKGROUND = (0.05, 0.15, 0.03)  # linear RGB: grass green
RANGE_TOL_M = 0.004
CENTRE_TOL_M = 0.005
LONG_STREAK_TOL_M = 0.015
NOISY_TOL_M = 0.025
STREAK_FLOOR_PX = 1.6  # what the moments read on a sharp sphere (1.5 px at 15° off the axis)


def swept_sphere(start_m, end_m, radius_m=RADIUS_M, lens=None, n_time=48, n_sub=4, noise_std=0.0, seed=0,
                 background=None):
    """RGB uint8 frame of a sphere moving uniformly from ``start_m`` to ``end_m`` (camera frame, m)
    over the exposure: the exact silhouette at ``n_time`` instants, ``n_sub`` × ``n_sub`` samples a
    pixel, the coverage mixing target and background (linear RGB, (H, W, 3); default uniform
    grass) in linear light, then sRGB-encoded."""
    start_m, end_m = np.asarray(start_m, float), np.asarray(end_m, float)
    # the pixels the sphere can reach: its silhouettes at both ends through the pinhole, with room
    # for a lens's displacement
    corners = []
    for centre in (start_m, end_m):
        distance = np.linalg.norm(centre)
        half = math.asin(radius_m / distance) * 1.3
        u, v = CAM.to_pixels([centre[:2] / centre[2]])[0]
        reach = CAM.fx * math.tan(half) / (centre[2] / distance) ** 2 + 12
        corners += [(u - reach, v - reach), (u + reach, v + reach)]
    corners = np.array(corners)
    u0, v0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    u1, v1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int), (CAM.width, CAM.height))
    offsets = (np.arange(n_sub) + 0.5) / n_sub - 0.5
    us = (np.arange(u0, u1)[:, None] + offsets).ravel()
    vs = (np.arange(v0, v1)[:, None] + offsets).ravel()
    uu, vv = np.meshgrid(us, vs)
    xy = CAM.to_normalised(np.column_stack((uu.ravel(), vv.ravel())))
    if lens is not None:
        xy = undistort(xy, lens)
    rays = np.column_stack((xy, np.ones(len(xy))))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    coverage = np.zeros(len(rays))
    for s in (np.arange(n_time) + 0.5) / n_time:
        centre = (1 - s) * start_m + s * end_m
        distance = np.linalg.norm(centre)
        coverage += rays @ (centre / distance) >= math.sqrt(1 - (radius_m / distance) ** 2)
    coverage = (coverage / n_time).reshape(v1 - v0, n_sub, u1 - u0, n_sub).mean(axis=(1, 3))
    linear = np.empty((CAM.height, CAM.width, 3))
    linear[:] = BACKGROUND if background is None else background
    linear[v0:v1, u0:u1] = coverage[..., None] * TARGET + (1 - coverage[..., None]) * linear[v0:v1, u0:u1]
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055) * 255
    if noise_std:
        encoded = encoded + np.random.default_rng(seed).normal(0.0, noise_std, encoded.shape)
    return np.clip(np.round(encoded), 0, 255).astype(np.uint8)


def motion(streak_px, direction_deg, off_axis_deg):
    """(start, middle, end) of a sphere at 3 m, ``off_axis_deg`` right of the axis, moving across the
    line of sight so that its image streaks about ``streak_px`` along ``direction_deg`` (from +u)."""
    theta, phi = math.radians(off_axis_deg), math.radians(direction_deg)
    middle = RANGE_M * np.array([math.sin(theta), 0.0, math.cos(theta)])
    # at θ off the axis an image motion du, dv is a turn of du·cos²θ/f about y and dv·cos θ/f about x
    tangent = np.array([math.cos(theta), 0.0, -math.sin(theta)])
    half = 0.5 * streak_px * RANGE_M / CAM.fx * (math.cos(phi) * math.cos(theta) ** 2 * tangent
                                                  + math.sin(phi) * math.cos(theta) * np.array([0.0, 1.0, 0.0]))
    return middle - half, middle, middle + half


def turned_streak_px(start, end):
    """The streak in the camera turned toward the sphere: the angle its centre sweeps, × f."""
    cosine = start @ end / (np.linalg.norm(start) * np.linalg.norm(end))
    return CAM.fx * math.acos(min(1.0, cosine))


def detect(image):
    detection = SphereDetector(edge_mixing="linear").detect(image)
    assert detection is not None
    return detection


@pytest.mark.parametrize("off_axis_deg", [0, 15])
@pytest.mark.parametrize("direction_deg", [30, 120])
@pytest.mark.parametrize("streak_px", [0, 5, 10, 20, 40])
def test_swept_sphere_centre_range_and_streak(streak_px, direction_deg, off_axis_deg):
    start, middle, end = motion(streak_px, direction_deg, off_axis_deg)
    image = swept_sphere(start, end)
    detection = detect(image)
    centre = locate_sphere_streak(image, detection, CAM, RADIUS_M)
    tolerance = LONG_STREAK_TOL_M if streak_px > 20 else RANGE_TOL_M
    assert abs(np.linalg.norm(centre) - np.linalg.norm(middle)) < tolerance
    assert np.linalg.norm(centre - middle) < max(tolerance, CENTRE_TOL_M)
    coverage = sphere_coverage(image, detection, CAM)
    streak = turned_streak_px(start, end)
    assert 0.85 * streak - 1.0 < coverage.streak_px < streak + STREAK_FLOOR_PX
    if streak_px >= 10 and off_axis_deg == 0:  # on the axis the turned camera is the camera
        angle = math.degrees(math.atan2(coverage.direction[1], coverage.direction[0])) - direction_deg
        assert min(angle % 180, -angle % 180) < (1.0 if streak_px >= 20 else 5.0)


@pytest.mark.parametrize("streak_px", [10, 20])
def test_the_cone_fit_misreads_the_same_frames(streak_px):
    """The frames above are ones the exact cone fit of the outline gets wrong by tens of mm."""
    start, middle, end = motion(streak_px, 30, 15)
    image = swept_sphere(start, end)
    detection = detect(image)
    cone_error = abs(np.linalg.norm(locate_sphere_ellipse(detection, CAM, RADIUS_M)) - RANGE_M)
    streak_error = abs(np.linalg.norm(locate_sphere_streak(image, detection, CAM, RADIUS_M)) - RANGE_M)
    assert cone_error > 0.05 and streak_error < RANGE_TOL_M


@pytest.mark.parametrize("streak_px, seed", [(0, 1), (10, 2), (20, 3), (30, 4)])
def test_with_sensor_noise(streak_px, seed):
    start, middle, end = motion(streak_px, 60, 15)
    image = swept_sphere(start, end, noise_std=2.0, seed=seed)
    centre = locate_sphere_streak(image, SphereDetector(edge_mixing="linear").detect(image), CAM, RADIUS_M)
    assert np.linalg.norm(centre - middle) < NOISY_TOL_M


def test_through_a_lens_each_pixel_keeps_its_ray_and_solid_angle():
    lens = BrownConrady.default()
    start, middle, end = motion(15, 45, 15)
    image = swept_sphere(start, end, lens=lens)
    detection = detect(image)
    centre = locate_sphere_streak(image, detection, CAM, RADIUS_M, distortion=lens)
    assert np.linalg.norm(centre - middle) < CENTRE_TOL_M
    # the barrel lens shrinks the image off the axis: read as a pinhole the sphere looks farther
    pinhole = locate_sphere_streak(image, detection, CAM, RADIUS_M)
    assert np.linalg.norm(pinhole) - RANGE_M > 0.05


def test_a_sharp_sphere_is_the_cone_fit():
    start, middle, end = motion(0, 0, 15)
    image = swept_sphere(start, end)
    detection = detect(image)
    assert sphere_coverage(image, detection, CAM).streak_px < STREAK_MIN_PX
    np.testing.assert_array_equal(locate_sphere_streak(image, detection, CAM, RADIUS_M),
                                  locate_sphere_ellipse(detection, CAM, RADIUS_M))


def test_a_blob_on_the_border_falls_back_to_the_cone_fit_and_one_near_it_is_read():
    image = swept_sphere(*motion(10, 0, 0)[::2])
    cut = np.roll(image, -(320 - 10), axis=1)  # the blob's left end beyond the image's left edge
    detection = detect(cut)
    assert detection.touches_border and sphere_coverage(cut, detection, CAM) is None
    np.testing.assert_array_equal(locate_sphere_streak(cut, detection, CAM, RADIUS_M),
                                  locate_sphere_ellipse(detection, CAM, RADIUS_M))
    # a sphere 26° left of the axis: its blob ends 10 px from the left edge, so the region around
    # it (1.25 × its radius + 3 px) is cut by the border; what is cut off is background
    start, middle, end = motion(10, 90, -26)
    near = swept_sphere(start, end)
    detection = detect(near)
    assert not detection.touches_border and detection.outline_px[:, 0].min() < 1.25 * detection.radius_px
    centre = locate_sphere_streak(near, detection, CAM, RADIUS_M)
    assert np.linalg.norm(centre - middle) < CENTRE_TOL_M


@pytest.mark.parametrize("ground", ["stripes", "horizon"])
def test_a_background_that_is_not_smooth_falls_back_to_the_cone_fit(ground):
    """Grass in stripes 20 px wide, 20 % brighter and darker (the lab's ground), or a sky above
    grass through the blob: either is read as coverage, so the cone fit is returned."""
    rows = np.arange(CAM.height)[:, None, None]
    if ground == "stripes":
        background = np.array(BACKGROUND) * (1 + 0.2 * np.sign(np.sin(2 * np.pi * (rows + 0.5) / 40)))
    else:
        background = np.where(rows < CAM.cy, np.array([0.26, 0.48, 0.83]), np.array(BACKGROUND))
    background = np.broadcast_to(background, (CAM.height, CAM.width, 3))
    start, middle, end = motion(10, 30, 0)
    image = swept_sphere(start, end, background=background)
    detection = detect(image)
    assert sphere_coverage(image, detection, CAM).background_rms > SMOOTH_BACKGROUND
    np.testing.assert_array_equal(locate_sphere_streak(image, detection, CAM, RADIUS_M),
                                  locate_sphere_ellipse(detection, CAM, RADIUS_M))


def test_sensor_noise_on_a_uniform_ground_is_smooth():
    start, middle, end = motion(10, 60, 15)
    image = swept_sphere(start, end, noise_std=2.0, seed=5)
    assert sphere_coverage(image, detect(image), CAM).background_rms < 0.5 * SMOOTH_BACKGROUND


def test_bad_input_is_named():
    image = swept_sphere(*motion(5, 0, 0)[::2])
    detection = detect(image)
    with pytest.raises(ValueError, match="mixing"):
        sphere_coverage(image, detection, CAM, mixing="gamma")
    with pytest.raises(TypeError, match="rgb"):
        locate_sphere_streak(image.tolist(), detection, CAM, RADIUS_M)
    with pytest.raises(ValueError, match="radius_m"):
        locate_sphere_streak(image, detection, CAM, -1.0)


# ----------------------------------------------------------------------------------------------
# the lab's own blurred frames
# ----------------------------------------------------------------------------------------------
T_BODY_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
RENDER_TOL_M = 0.070  # measured 47–54 mm short at 3.1 m (see sphere_coverage's Notes)


def test_on_the_renderers_blurred_frames_with_the_sky_behind():
    """The sphere on the paper's circle seen by a still camera at 1/60 s (streaks of 8–12 px), the
    upper half of the circle, where the sky is behind it: the streak method errs by less than
    70 mm, the cone fit of the outline by more than 300 mm on the same frames."""
    from gimbal_lab.platform import BodyMotion
    from gimbal_lab.scene import SceneRenderer
    from gimbal_lab.trajectories import Trajectory, target_pose

    body, circle = BodyMotion.static(), Trajectory.circular()

    def pose_fn(t):
        return body.T_world_body(t) @ T_BODY_CAM, target_pose(circle, t)

    exposure_s = 1.0 / 60.0
    with SceneRenderer(CAM, target="sphere") as scene:
        for t_s in (0.1, 0.5, 0.9):
            image = scene.render_motion(pose_fn, t_s, exposure_s)
            T_world_cam, T_world_target = pose_fn(t_s + exposure_s / 2)
            truth = (np.linalg.inv(T_world_cam) @ T_world_target[:, 3])[:3]
            detection = SphereDetector().detect(image)
            streak = locate_sphere_streak(image, detection, CAM, 0.1)
            cone = locate_sphere_ellipse(detection, CAM, 0.1)
            assert np.linalg.norm(streak - truth) < RENDER_TOL_M
            assert abs(np.linalg.norm(cone) - np.linalg.norm(truth)) > 0.3


def test_window_rays_from_the_kept_grid_are_those_undistorted_afresh():
    # the camera's half-pixel grid is kept and read by window: bit for bit what undistorting the
    # window's points afresh gives (the function the grid replaces, written out here), for barrel,
    # pincushion and tangential lenses, windows anywhere (the border included), read in any order
    from gimbal_lab import detection as det

    def fresh(box, lens):
        u0, v0, u1, v1 = box
        uu, vv = np.meshgrid(np.arange(u0 - 0.5, u1, 0.5), np.arange(v0 - 0.5, v1, 0.5))
        xy = undistort(CAM.to_normalised(np.column_stack((uu.ravel(), vv.ravel()))), lens)
        return xy[:, 0].reshape(uu.shape), xy[:, 1].reshape(uu.shape)

    rng = np.random.default_rng(7)
    for lens in (BrownConrady(k1=-0.25, k2=0.05, p1=0.001, p2=-0.0005), BrownConrady(k1=0.2), BrownConrady.default()):
        det._HALF_PIXEL_GRIDS.clear()
        boxes = [(0, 0, 640, 480), (600, 440, 640, 480), (0, 0, 1, 1)]
        for _ in range(12):
            u0, v0 = int(rng.integers(0, 600)), int(rng.integers(0, 440))
            boxes.insert(1, (u0, v0, u0 + int(rng.integers(1, 41)), v0 + int(rng.integers(1, 41))))
        for box in boxes:
            x, y = det._HalfPixelGrid.window(det._half_pixel_grid(CAM, lens), *box)
            fx, fy = fresh(box, lens)
            assert np.array_equal(x, fx) and np.array_equal(y, fy), (lens, box)
            rays, omega = det._window_rays(box, CAM, lens)
            assert rays.shape == (box[3] - box[1], box[2] - box[0], 3) and np.all(omega > 0)
    # a box beyond the image is undistorted afresh; a lens that folds inside the image fails as before
    grid = det._half_pixel_grid(CAM, BrownConrady(k1=-0.25))
    assert grid.window(630, 470, 641, 480) is None and grid.window(-1, 0, 5, 5) is None
    folding = BrownConrady(k1=0.3, k2=-1.5)  # its radial image peaks at r = 0.56 inside the corners (0.72)
    with pytest.raises(det.UndistortionError):
        fresh((0, 0, 640, 480), folding)
    with pytest.raises(det.UndistortionError):
        det._window_rays((0, 0, 640, 480), CAM, folding)
    assert det._half_pixel_grid(CAM, folding).window(0, 0, 640, 480) is None
    assert len(det._HALF_PIXEL_GRIDS) <= det._HALF_PIXEL_GRIDS_KEPT
