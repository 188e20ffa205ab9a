"""Scene synthesis: rendered geometry against the camera model, OpenCV's ArUco detector and PnP.

Oracles: :func:`gimbal_lab.camera.project` (itself pinned to ``cv2.projectPoints``) of the true
3-D geometry, ``cv2.aruco.ArucoDetector`` for marker corners and ids, ``cv2.solvePnP`` for the
marker pose, and analytic sphere silhouettes. One renderer per configuration (module scope).
"""

import math
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics, project
from gimbal_lab.scene import (
    ARUCO_DICTIONARY,
    SceneRenderer,
    _DECODE_LUT,
    _ENCODE_LUT,
    _LINEAR_LEVELS,
    linear_to_srgb,
    marker_corners,
    opencv_to_opengl_camera,
    srgb_to_linear,
)

CAM = Intrinsics.default()
DIST = BrownConrady.default()
RADIUS_M = 0.10
MARKER_M = 0.30


def camera_pose(pitch_up_rad=0.0, position=(0.0, 0.0, 2.0)):
    """OpenCV camera frame looking along world +x, pitched up by ``pitch_up_rad`` (world Z-up)."""
    c, s = math.cos(pitch_up_rad), math.sin(pitch_up_rad)
    z = np.array([c, 0.0, s])  # forward
    x = np.array([0.0, -1.0, 0.0])  # right
    y = np.cross(z, x)  # down
    T = np.eye(4)
    T[:3, :3] = np.column_stack((x, y, z))
    T[:3, 3] = position
    return T


# Pitched up 30° (half the vertical field of view is 23.4°): sky behind every target, so the
# red-threshold mask sees one background colour.
T_SKY = camera_pose(math.radians(30.0))
T_HOME = camera_pose()


def target_pose(T_world_cam, p_cam, R_world_target=None):
    """Target at ``p_cam`` (camera frame); orientation facing the camera if not given."""
    T = np.eye(4)
    T[:3, 3] = T_world_cam[:3, :3] @ p_cam + T_world_cam[:3, 3]
    T[:3, :3] = T_world_cam[:3, :3] @ R_MARKER_FACING_CAMERA_CAM if R_world_target is None else R_world_target
    return T


# Marker axes in the camera frame when it faces the camera squarely: x right, y up, z towards it.
R_MARKER_FACING_CAMERA_CAM = np.column_stack(([1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]))


def to_camera(T_world_cam, points_world):
    T = np.linalg.inv(T_world_cam)
    return points_world @ T[:3, :3].T + T[:3, 3]


def red_mask(image):
    """Red-sphere pixels against the sky: red above green, and the sky's blue more than half gone.

    The red sphere has no blue whatever its shading, so thresholding blue at half the sky's
    (235 / 2) classifies an anti-aliased edge pixel (colours mixed by coverage) as sphere when
    it is more than half covered, on the lit and the shaded side alike.
    """
    rgb = image.astype(np.int16)
    return ((rgb[:, :, 0] > rgb[:, :, 1]) & (rgb[:, :, 2] < 235 // 2)).astype(np.uint8)


def mask_centroid(mask):
    m = cv2.moments(mask, binaryImage=True)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def silhouette_polygon(centre_cam, radius_m, intrinsics, distortion, n=4000):
    """Image of the sphere's occluding rim: the circle where the tangent cone touches it.

    For a sphere of radius r at distance D, the rim is the circle of radius r·sqrt(1 − r²/D²)
    centred at c·(1 − r²/D²), in the plane normal to c. Its projection (through the lens
    distortion, a one-to-one warp of the image plane) is the silhouette's boundary.
    """
    c = np.asarray(centre_cam, dtype=float)
    D = np.linalg.norm(c)
    k = 1.0 - (radius_m / D) ** 2
    d = c / D
    e1 = np.cross(d, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rim = c * k + radius_m * math.sqrt(k) * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    return project(rim, intrinsics, distortion)


def polygon_centroid(points_px):
    m = cv2.moments(points_px.astype(np.float32).reshape(-1, 1, 2))
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def aruco_detector():
    params = cv2.aruco.DetectorParameters()
    # Sub-pixel corners: without refinement the corners sit on the contour's pixel grid (≈1 px).
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY), params)


@pytest.fixture(scope="module")
def sphere_pinhole():
    with SceneRenderer(CAM, target="sphere", sphere_radius_m=RADIUS_M) as r:
        yield r


@pytest.fixture(scope="module")
def sphere_distorted():
    with SceneRenderer(CAM, DIST, target="sphere", sphere_radius_m=RADIUS_M) as r:
        yield r


@pytest.fixture(scope="module")
def aruco_pinhole():
    with SceneRenderer(CAM, target="aruco", marker_length_m=MARKER_M) as r:
        yield r


@pytest.fixture(scope="module")
def aruco_distorted():
    with SceneRenderer(CAM, DIST, target="aruco", marker_length_m=MARKER_M) as r:
        yield r


# Sphere centres in the camera frame, 2–4 m deep, from the axis to near the image corner
# (normalised radius up to 0.5, where the default lens moves points by ≈ 14 px).
SPHERE_POSITIONS_CAM = [
    (0.0, 0.0, 3.0),
    (0.6, 0.4, 3.0),
    (-0.9, 0.5, 2.5),
    (1.2, -0.9, 4.0),
    (0.8, 0.6, 2.0),
    (-0.75, -0.55, 2.2),
]


def test_camera_axis_conversion_is_the_documented_flip():
    T = camera_pose(0.3, (1.0, 2.0, 3.0))
    T_gl = opencv_to_opengl_camera(T)
    # OpenGL camera: x the same, y = −y_cv (up), looks down −z: −z_gl = z_cv.
    assert np.allclose(T_gl[:3, 0], T[:3, 0])
    assert np.allclose(T_gl[:3, 1], -T[:3, 1])
    assert np.allclose(-T_gl[:3, 2], T[:3, 2])
    assert np.allclose(T_gl[:3, 3], T[:3, 3])
    assert np.allclose(opencv_to_opengl_camera(T_gl), T)


@pytest.mark.parametrize("cx, cy", [(319.5, 239.5), (301.3, 252.75)])
def test_point_on_optical_axis_lands_on_principal_point(cx, cy):
    """A sphere centred on the optical axis images as a disc centred on (cx, cy).

    On the axis the silhouette is an exact circle around the principal point; a 0.5 px
    convention slip (pixel centre vs edge) would move the centroid by 0.5 px. The binary mask's
    centroid of a 37 px-wide anti-aliased disc is good to a few hundredths of a pixel; 0.1 px
    is the requirement (docs/design.md).
    """
    K = Intrinsics(CAM.fx, CAM.fy, cx, cy, CAM.width, CAM.height)
    with SceneRenderer(K, target="sphere") as r:
        image = r.render(T_SKY, target_pose(T_SKY, (0.0, 0.0, 3.0)))
    assert np.abs(mask_centroid(red_mask(image)) - (cx, cy)).max() < 0.1


@pytest.mark.parametrize("distorted", [False, True])
def test_sphere_blob_centroid_matches_projected_silhouette(distorted, sphere_pinhole, sphere_distorted):
    """Centroid of the rendered red blob vs the centroid of the analytically projected silhouette.

    Off the axis a sphere's silhouette is an ellipse whose centroid is not the projected centre
    (and lens distortion bends it further), so the oracle is the area centroid of the projected
    occluding rim (4000 points; polygon error ≪ 0.01 px). Tolerance 0.5 px (issue 3): anti-aliased
    edge classification and the icosphere's facets (sag < 0.06 % of the radius) contribute a few
    hundredths of a pixel, so a half-pixel convention error would fail.
    """
    renderer, dist = (sphere_distorted, DIST) if distorted else (sphere_pinhole, None)
    errors = []
    for p_cam in SPHERE_POSITIONS_CAM:
        image = renderer.render(T_SKY, target_pose(T_SKY, p_cam))
        expected = polygon_centroid(silhouette_polygon(p_cam, RADIUS_M, CAM, dist))
        errors.append(np.abs(mask_centroid(red_mask(image)) - expected).max())
    assert max(errors) < 0.5, errors


def test_silhouette_centroid_differs_from_projected_centre_off_axis():
    """The oracle matters: at the corner position the two differ by more than the tolerance's tenth."""
    p_cam = SPHERE_POSITIONS_CAM[4]
    shift = polygon_centroid(silhouette_polygon(p_cam, RADIUS_M, CAM, DIST)) - project(p_cam, CAM, DIST)[0]
    assert np.linalg.norm(shift) > 0.05


MARKER_POSITIONS_CAM = [(0.0, 0.0, 3.0), (0.5, -0.4, 3.0), (-0.6, 0.4, 2.0), (1.0, 0.6, 4.0), (-0.8, -0.5, 2.5)]


@pytest.mark.parametrize("distorted", [False, True])
def test_aruco_corners_match_projected_corners(distorted, aruco_pinhole, aruco_distorted):
    """Detected corners (id 0, OpenCV's corner order) vs ``project`` of the true corners, 0.5 px.

    Matching corner by corner also pins the marker's orientation: a mirrored or rotated texture
    would swap corners by tens of pixels. Measured errors are ≤ 0.35 px, dominated by
    ``cornerSubPix``'s bias, which depends on where the corner falls within a pixel.
    """
    renderer, dist = (aruco_distorted, DIST) if distorted else (aruco_pinhole, None)
    detector = aruco_detector()
    for p_cam in MARKER_POSITIONS_CAM:
        T_world_marker = target_pose(T_HOME, p_cam)
        image = renderer.render(T_HOME, T_world_marker)
        corners, ids, _ = detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
        assert ids is not None and ids.ravel().tolist() == [0], p_cam
        expected = project(to_camera(T_HOME, marker_corners(T_world_marker, MARKER_M)), CAM, dist)
        error = np.abs(corners[0][0] - expected).max()
        assert error < 0.5, (p_cam, error)


def test_aruco_pose_from_solvepnp_within_one_percent(aruco_pinhole):
    """IPPE-square PnP on the detected corners recovers inv(T_world_cam) @ T_world_marker.

    Translation within 1 % of the distance (issue 3) at 2–4 m; the marker is also turned by
    up to 25° about its vertical axis so that the recovered rotation is exercised (its normal
    within 3°: a 0.3 px corner error on a ≥ 40 px marker tilts the plane by about a degree).
    """
    detector = aruco_detector()
    half = MARKER_M / 2
    object_points = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
    # Not exactly square-on at the axis: there the corners are perfectly symmetric and OpenCV's
    # IPPE-square returns rvec = 0 (the π rotation collapses when converted to a vector).
    for p_cam, yaw_deg in [((0.0, 0.0, 2.0), 10.0), ((0.4, -0.3, 3.0), 20.0), ((-0.7, 0.5, 4.0), -25.0)]:
        a = math.radians(yaw_deg)
        turn = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        R_world_marker = T_HOME[:3, :3] @ R_MARKER_FACING_CAMERA_CAM @ turn
        T_world_marker = target_pose(T_HOME, p_cam, R_world_marker)
        image = aruco_pinhole.render(T_HOME, T_world_marker)
        corners, ids, _ = detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
        assert ids is not None and ids.ravel().tolist() == [0]
        ok, rvec, tvec = cv2.solvePnP(object_points, corners[0][0], CAM.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        assert ok
        T_cam_marker = np.linalg.inv(T_HOME) @ T_world_marker
        distance = np.linalg.norm(T_cam_marker[:3, 3])
        assert np.linalg.norm(tvec.ravel() - T_cam_marker[:3, 3]) < 0.01 * distance, (p_cam, tvec.ravel())
        normal = cv2.Rodrigues(rvec)[0][:, 2]
        angle = math.degrees(math.acos(np.clip(normal @ T_cam_marker[:3, 2], -1, 1)))
        assert angle < 3.0, (p_cam, angle)


def test_distorted_frames_have_no_black_pixels(sphere_distorted):
    """Barrel distortion looks beyond the pinhole frame: the canvas must cover every source.

    Home camera (ground and sky in view) and a rolled, pitched-down camera (ground in every
    corner). The darkest scene colour is the dark ground green (≥ 25 grey levels in green).
    """
    assert sphere_distorted.canvas_intrinsics.width > CAM.width
    roll = camera_pose(math.radians(-20.0))
    for T in (T_HOME, roll):
        image = sphere_distorted.render(T, target_pose(T, (0.3, 0.1, 3.0)))
        assert image.shape == (CAM.height, CAM.width, 3)
        assert image.max(axis=2).min() > 20


def test_srgb_round_trip_is_exact_for_every_code():
    """decode → quantised linear → encode returns each of the 256 codes (lossless sharp frames)."""
    codes = np.arange(256)
    levels = np.floor(_DECODE_LUT[codes] * np.float32(_LINEAR_LEVELS) + np.float32(0.5)).astype(int)
    assert np.array_equal(_ENCODE_LUT[levels], codes)
    x = np.linspace(0, 1, 101)
    assert np.allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)


def moving_sphere(T_world_cam, y_start_m, y_end_m, depth_m, duration_s):
    """pose_fn: sphere crossing the view horizontally at constant speed (camera frame x)."""

    def pose_fn(t_s):
        x = y_start_m + (y_end_m - y_start_m) * t_s / duration_s
        return T_world_cam, target_pose(T_world_cam, (x, 0.0, depth_m))

    return pose_fn


def test_single_subframe_exposure_equals_render_at_mid_exposure(sphere_distorted):
    pose_fn = moving_sphere(T_SKY, -0.5, 0.5, 3.0, 1.0)
    t0, exposure = 0.2, 0.1
    blurred = sphere_distorted.render_exposure(pose_fn, t0, exposure, 1)
    assert np.array_equal(blurred, sphere_distorted.render(*pose_fn(t0 + exposure / 2)))


def test_motion_blur_streak_length_matches_projected_motion(sphere_pinhole):
    """A sphere moving 1 m sideways at 3 m during the exposure: streak length vs projected motion.

    Sub-frames are sampled at the middles of n equal slices, so the rendered discs' centres span
    (n − 1)/n of the exposure's motion. Along the row through the centre, the linear-light red
    coverage (from the blue channel: sky blue is bright, the red sphere has none) falls to
    1/n of a disc at the streak's ends; crossing 0.5/n there locates the first and last discs'
    half-coverage edges just as crossing 0.5 does for a sharp disc. Streak length = streak
    extent − sharp disc width; tolerance 1 px (issue 3). The motion is symmetric about the
    axis, so the end discs have equal widths and silhouette shifts (< 0.1 px).
    """
    n = 16
    pose_fn = moving_sphere(T_SKY, -0.5, 0.5, 3.0, 1.0)
    row = int(CAM.cy)

    def coverage(image):
        linear_blue = srgb_to_linear(image[:, :, 2] / 255.0)
        sky = linear_blue[0:5].mean()  # top rows: sky only
        return np.clip((sky - linear_blue[row : row + 2].mean(axis=0)) / sky, 0.0, 1.0)

    def extent(profile, level):
        above = np.flatnonzero(profile >= level)
        i, j = above[0], above[-1]
        left = i - (profile[i] - level) / (profile[i] - profile[i - 1])
        right = j + (profile[j] - level) / (profile[j] - profile[j + 1])
        return right - left

    blurred = sphere_pinhole.render_exposure(pose_fn, 0.0, 1.0, n)
    sharp = sphere_pinhole.render(*pose_fn(0.5 / n))
    streak = extent(coverage(blurred), 0.5 / n) - extent(coverage(sharp), 0.5)
    first, last = (project(to_camera(T_SKY, pose_fn(t)[1][:3, 3]), CAM)[0, 0] for t in (0.5 / n, 1 - 0.5 / n))
    assert abs(streak - (last - first)) < 1.0, (streak, last - first)
    assert (last - first) > 150  # a long streak: 1 px is under 1 % of it


def test_same_poses_give_identical_images(aruco_distorted):
    T_target = target_pose(T_HOME, (0.3, -0.2, 2.5))
    first = aruco_distorted.render(T_HOME, T_target)
    aruco_distorted.render(camera_pose(0.2), target_pose(T_HOME, (-0.5, 0.3, 3.5)))
    assert np.array_equal(aruco_distorted.render(T_HOME, T_target), first)


def test_noise_is_seeded_and_has_the_requested_std():
    small = Intrinsics.from_fov(160, 120, math.radians(60.0))
    frames = []
    for seed in (7, 7, 8):
        with SceneRenderer(small, noise_std=4.0, seed=seed) as r:
            frames.append(r.render(T_SKY, target_pose(T_SKY, (0.0, 0.0, 3.0))).astype(float))
    with SceneRenderer(small) as r:
        clean = r.render(T_SKY, target_pose(T_SKY, (0.0, 0.0, 3.0))).astype(float)
    assert np.array_equal(frames[0], frames[1]) and not np.array_equal(frames[0], frames[2])
    residual = (frames[0] - clean)[5:50]  # sky rows: far from 0 and 255, so no clipping
    assert residual.std() == pytest.approx(4.0, rel=0.05)  # 57 600 samples: std error ≈ 0.3 %


def _rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def test_memory_stays_flat_over_1000_frames():
    """RSS after 1000 more frames grows < 16 MB (16 kB/frame).

    The failure this guards against (pyrender's shader cache missing on every frame) leaks
    megabytes per frame. Memory use does not depend on the image size, so a 160 × 120 camera
    with distortion keeps the test quick while exercising the whole render path.
    """
    small = Intrinsics.from_fov(160, 120, math.radians(60.0))
    with SceneRenderer(small, DIST, target="aruco") as r:
        for i in range(50):
            r.render(T_HOME, target_pose(T_HOME, (0.01 * i, 0.0, 3.0)))
        before = _rss_bytes()
        for i in range(1000):
            r.render(T_HOME, target_pose(T_HOME, (0.3 * math.sin(i), 0.2 * math.cos(i), 3.0)))
        after = _rss_bytes()
    assert after - before < 16 * 2**20, (after - before) / 2**20


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"target": "cube"}, "target"),
        ({"sphere_radius_m": 0.0}, "sphere_radius_m"),
        ({"plate_size_m": 0.2}, "plate_size_m"),
        ({"marker_id": 50}, "marker_id"),
        ({"noise_std": -1.0}, "noise_std"),
        ({"sphere_rgb": (1, 0)}, "sphere_rgb"),
    ],
)
def test_bad_configuration_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SceneRenderer(CAM, **kwargs)


def test_bad_inputs_raise(sphere_pinhole):
    with pytest.raises(ValueError, match="T_world_cam"):
        sphere_pinhole.render(np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="n_subframes"):
        sphere_pinhole.render_exposure(lambda t: (T_HOME, np.eye(4)), 0.0, 0.1, 0)
    with pytest.raises(ValueError, match="exposure_s"):
        sphere_pinhole.render_exposure(lambda t: (T_HOME, np.eye(4)), 0.0, -0.1, 2)


def test_missing_backend_error_names_the_packages():
    """In a fresh process asked for OSMesa: it renders if libosmesa6 is installed, else the error
    names the Debian packages of both backends (never a bare OpenGL traceback)."""
    script = (
        "from gimbal_lab.camera import Intrinsics\n"
        "from gimbal_lab.scene import RenderBackendError, SceneRenderer\n"
        "try:\n"
        "    SceneRenderer(Intrinsics.from_fov(64, 48, 1.0)).close()\n"
        "    print('rendered')\n"
        "except RenderBackendError as exc:\n"
        "    print('error:', exc)\n"
    )
    env = {**os.environ, "PYOPENGL_PLATFORM": "osmesa"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip()
    assert line == "rendered" or ("libosmesa6" in line and "libegl1 libgl1-mesa-dri" in line), line


# --- anti-aliasing in a window around the target ------------------------------------------------
# Target positions in the camera frame (metres): centred, off-centre, near a corner, straddling
# the image's edge, far away on the horizon, close (its window covers most of the canvas, so
# the whole canvas is multisampled), behind the camera (no second pass at all).
WINDOW_POSITIONS_CAM = {
    "centred": (0.0, 0.0, 3.0),
    "off-centre": (0.6, 0.4, 3.0),
    "corner": (1.0, -0.7, 2.0),
    "edge": (1.17, 0.2, 2.0),
    "horizon": (0.3, 0.0, 40.0),
    "close": (0.0, 0.05, 0.3),
    "behind": (0.0, 0.0, -3.0),
}


@pytest.mark.parametrize("target", ["sphere", "aruco"])
@pytest.mark.parametrize("lens", [None, DIST], ids=["pinhole", "distorted"])
def test_windowed_antialiasing_keeps_every_target_pixel(target, lens):
    """Oracle: the same scene multisampled everywhere (``antialias="full"``).

    Inside the target's window the canvas is identical, bit for bit. Outside it one sample per
    pixel changes under 1 % of the values, by at most two grey levels (measured: one level in
    0.4–0.5 % of values, two in one pixel of 307,200), except where the ground's far edge meets
    the sky (every larger difference lies within 1 px of a sky pixel) — and the output frames'
    red and dark pixels, which the detectors threshold, are the same."""
    from gimbal_lab.scene import _SKY_U8

    windowed = SceneRenderer(CAM, lens, target=target)
    full = SceneRenderer(CAM, lens, target=target, antialias="full")
    try:
        for name, p_cam in WINDOW_POSITIONS_CAM.items():
            T_world_target = target_pose(T_HOME, np.array(p_cam))
            a = windowed._render_sharp_canvas(T_HOME, T_world_target).astype(int)
            b = full._render_sharp_canvas(T_HOME, T_world_target).astype(int)
            box = windowed._target_box(T_HOME, T_world_target)
            if name == "behind":
                assert box is None
            elif name == "close":
                assert box[2] * box[3] > 0.4 * a.shape[0] * a.shape[1]
                assert np.array_equal(a, b)  # one pass, multisampled everywhere
            else:
                x0, y0, w, h = box
                assert 0 < w * h < 0.1 * a.shape[0] * a.shape[1], name
                assert np.array_equal(a[y0 : y0 + h, x0 : x0 + w], b[y0 : y0 + h, x0 : x0 + w]), name
            sky = np.all(b == _SKY_U8, axis=2).astype(np.uint8)
            near_sky = cv2.dilate(sky, np.ones((3, 3), np.uint8)) > 0
            large = np.abs(a - b).max(axis=2) > 2
            assert not np.any(large & ~near_sky), name
            assert np.mean(np.abs(a - b) > 0) < 0.01, name
            frame_a = windowed.render(T_HOME, T_world_target)
            frame_b = full.render(T_HOME, T_world_target)
            assert np.array_equal(red_mask(frame_a), red_mask(frame_b)), name
            assert np.array_equal(frame_a.max(axis=2) < 60, frame_b.max(axis=2) < 60), name
    finally:
        windowed.close()
        full.close()


def test_a_still_camera_reuses_its_background():
    """A fixed camera draws the background once; its frames are those of a renderer drawing
    everything afresh each time (bit for bit), and a camera that moves draws it again."""
    target_path = [target_pose(T_HOME, np.array([x, 0.2, 3.0])) for x in (-0.6, 0.0, 0.5)]
    with SceneRenderer(CAM, DIST, target="aruco") as reusing, SceneRenderer(CAM, DIST, target="aruco") as fresh:
        for T_world_target in target_path:
            fresh._background = None
            assert np.array_equal(reusing.render(T_HOME, T_world_target), fresh.render(T_HOME, T_world_target))
        assert reusing.background_renders == 1 and fresh.background_renders == 3
        reusing.render(camera_pose(0.01), target_path[0])
        assert reusing.background_renders == 2


@pytest.mark.parametrize("target", ["sphere", "aruco"])
@pytest.mark.parametrize("lens", [DIST, BrownConrady(k1=0.15, p1=0.004, p2=-0.003)], ids=["barrel", "pincushion"])
def test_a_still_camera_remaps_only_the_targets_window(target, lens):
    """Oracle: ``cv2.remap`` of the whole sharp canvas through the lens's maps. With the
    background reused, only the output pixels reading the target's window are remapped again;
    every frame must be that oracle bit for bit: the target anywhere in the view, cut by the
    image's edge, in the canvas margin that only the corners' taps reach, outside the canvas
    and behind the camera. A rectangle one pixel short on any side breaks it somewhere here."""
    rng = np.random.default_rng(7)
    positions = [(0.0, 0.0, 3.0), (0.0, 0.0, -3.0), (2.5, 0.0, 2.0), (0.0, 2.2, 2.0)]
    positions += [(x * 1.1 * z * 320 / 554, y * 1.1 * z * 240 / 554, z)  # around the image's rim
                  for x, y, z in zip(rng.uniform(-1, 1, 40), rng.choice([-1, 1], 40) * rng.uniform(0.8, 1.0, 40),
                                     rng.uniform(1.5, 4.0, 40))]
    positions += [tuple(p) for p in rng.uniform((-1.5, -1.1, 2.0), (1.5, 1.1, 5.0), (20, 3))]
    with SceneRenderer(CAM, lens, target=target) as renderer:
        renders = []
        for p_cam in positions:
            T_world_target = target_pose(T_HOME, np.array(p_cam))
            frame = renderer.render(T_HOME, T_world_target)
            renders.append(renderer._last_window)
            oracle = cv2.remap(renderer._render_sharp_canvas(T_HOME, T_world_target), renderer._map1,
                               renderer._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            assert np.array_equal(frame, oracle), p_cam
        assert renderer.background_renders == 1
    windows = [w for w in renders if not isinstance(w, str) and w is not None]
    assert "none" in renders and len(windows) > 50  # the cheap path was taken, target seen and unseen


@pytest.mark.parametrize("lens", [DIST, BrownConrady(k1=0.15, p1=0.004, p2=-0.003)], ids=["barrel", "pincushion"])
def test_the_remapped_rectangle_holds_every_pixel_the_window_reaches(lens):
    """Oracle: ``cv2.remap`` itself, of a canvas that is 255 inside a box and 0 elsewhere. Every
    output pixel that comes out non-zero must lie inside ``_output_rect(box)``; and the rectangle
    must lie inside the bounding box (plus one pixel, for taps of weight zero) of the pixels that
    read the box rounded out to whole 16-px tiles, which is all it looks up. Boxes are drawn
    anywhere on the canvas, margins included, with their edges on and off the tile grid."""
    from gimbal_lab.scene import _TAP_TILE_PX

    rng = np.random.default_rng(3)
    with SceneRenderer(CAM, lens, target="sphere") as renderer:
        width, height = renderer.canvas_intrinsics.size
        boxes = [(0, 0, width, height), (0, 0, 1, 1), (width - 1, height - 1, 1, 1)]
        for _ in range(300):
            x0, y0 = int(rng.integers(0, width - 1)), int(rng.integers(0, height - 1))
            if rng.random() < 0.5:  # an edge on the tile grid
                x0, y0 = x0 // _TAP_TILE_PX * _TAP_TILE_PX, y0 // _TAP_TILE_PX * _TAP_TILE_PX
            w, h = int(rng.integers(1, min(120, width - x0) + 1)), int(rng.integers(1, min(120, height - y0) + 1))
            boxes.append((x0, y0, w, h))

        def reached(x0, y0, x1, y1):
            canvas = np.zeros((height, width), np.uint8)
            canvas[y0:y1, x0:x1] = 255
            out = cv2.remap(canvas, renderer._map1, renderer._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            return np.nonzero(out)

        tile = _TAP_TILE_PX
        empty = 0
        for x0, y0, w, h in boxes:
            v, u = reached(x0, y0, x0 + w, y0 + h)
            rect = renderer._output_rect((x0, y0, w, h))
            if len(u) == 0:
                empty += 1
                continue
            assert rect is not None, (x0, y0, w, h)
            u0, v0, u1, v1 = rect
            assert u0 <= u.min() and u.max() < u1 and v0 <= v.min() and v.max() < v1, (x0, y0, w, h)
            v, u = reached(x0 // tile * tile, y0 // tile * tile, -(-(x0 + w) // tile) * tile, -(-(y0 + h) // tile) * tile)
            assert u.min() - 1 <= u0 and u1 - 1 <= u.max() + 1, (x0, y0, w, h)
            assert v.min() - 1 <= v0 and v1 - 1 <= v.max() + 1, (x0, y0, w, h)
        assert empty < 0.2 * len(boxes)


def test_antialias_must_be_window_or_full():
    with pytest.raises(ValueError, match="antialias"):
        SceneRenderer(CAM, target="sphere", antialias="msaa")


# --- sensor noise -----------------------------------------------------------------------------
def test_sensor_noise_is_a_rounded_gaussian():
    """Oracle: P(round(n) = k) = Φ((k + ½)/σ) − Φ((k − ½)/σ) for n ~ N(0, σ²) (scipy.stats.norm).

    2·10⁶ samples: each bin's frequency within 5 standard errors of its probability.
    """
    from scipy.stats import norm

    from gimbal_lab.scene import add_sensor_noise

    image = np.full((1000, 1000, 2), 100, np.uint8)
    noisy = add_sensor_noise(image, 2.0, np.random.default_rng(5)).astype(int) - 100
    n = noisy.size
    for k in range(-7, 8):
        p = norm.cdf((k + 0.5) / 2.0) - norm.cdf((k - 0.5) / 2.0)
        freq = np.count_nonzero(noisy == k) / n
        assert abs(freq - p) < 5 * np.sqrt(p * (1 - p) / n) + 1e-5, (k, freq, p)
    assert noisy.std() == pytest.approx(np.sqrt(4.0 + 1 / 12), rel=5e-3)  # σ² + 1/12 of rounding


def test_sensor_noise_is_seeded_and_clipped():
    from gimbal_lab.scene import add_sensor_noise

    image = np.zeros((50, 60, 3), np.uint8)
    image[:, 30:] = 255
    a = add_sensor_noise(image, 3.0, np.random.default_rng(1))
    assert np.array_equal(a, add_sensor_noise(image, 3.0, np.random.default_rng(1)))
    assert not np.array_equal(a, add_sensor_noise(image, 3.0, np.random.default_rng(2)))
    assert a.dtype == np.uint8 and a[:, :30].min() == 0 and a[:, 30:].max() == 255
    assert add_sensor_noise(image, 0.0, np.random.default_rng(1)) is image
    with pytest.raises(ValueError, match="std"):
        add_sensor_noise(image, float("nan"), np.random.default_rng(1))
    with pytest.raises(TypeError, match="uint8"):
        add_sensor_noise(image.astype(float), 2.0, np.random.default_rng(1))


def test_sensor_noise_draws_are_the_generators_bytes():
    """The 16-bit draws are numpy's own ``Generator.bytes`` stream (the oracle) read as
    little-endian uint16, so seeded runs keep their noise; sizes that are not a multiple of four
    samples take the leading draws of whole 64-bit words."""
    from gimbal_lab.scene import _rounded_gaussian_table, add_sensor_noise

    table = _rounded_gaussian_table(2.0)
    for shape in ((48, 64, 3), (7, 5, 3)):
        image = np.full(shape, 128, np.uint8)
        size = image.size
        oracle = np.frombuffer(np.random.default_rng(9).bytes(2 * size), dtype="<u2")
        expected = 128 + table[oracle].reshape(shape)
        rng = np.random.default_rng(9)
        assert np.array_equal(add_sensor_noise(image, 2.0, rng), expected)
        # the generator moved on by whole words: the next draw is the word after them
        following = np.random.default_rng(9).bit_generator.random_raw(-(-size // 4) + 1)[-1]
        assert rng.bit_generator.random_raw() == following


def test_a_stuck_gl_call_fails_fast_with_a_message():
    # A driver call that never returns is simulated by a sleep inside the watchdog's block: the
    # process must exit promptly with status 70 and say what was stuck, not idle until a timeout.
    import subprocess
    import sys
    import time

    code = (
        "import time\n"
        "from gimbal_lab.scene import _fail_if_stuck\n"
        "with _fail_if_stuck('creating the OpenGL context', 0.5):\n"
        "    time.sleep(30)\n"
    )
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 70
    assert time.monotonic() - start < 25
    assert "creating the OpenGL context has not finished after 0.5 s" in done.stderr
    assert "GIMBAL_LAB_GL_TIMEOUT_S" in done.stderr
    assert "time.sleep" in done.stderr or "line 4" in done.stderr  # the stuck thread's traceback


def test_the_watchdog_stays_quiet_when_the_block_finishes():
    import subprocess
    import sys

    code = (
        "from gimbal_lab.scene import _fail_if_stuck\n"
        "with _fail_if_stuck('x', 0.5):\n"
        "    pass\n"
        "import time; time.sleep(1.0); print('alive')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "alive" and "stuck" not in done.stderr
