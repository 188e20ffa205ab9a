"""Wide-field rendering: cube faces remapped to Kannala–Brandt fisheye lenses.

Oracles: a single pinhole :class:`SceneRenderer` aimed at the cube's seams and corners (resampled
to the fisheye's pixels through :func:`gimbal_lab.camera.project`), the analytic cone tangent to
the sphere through :func:`gimbal_lab.camera.backproject` (itself pinned to ``cv2.fisheye``),
``cv2.aruco`` corners undistorted by ``cv2.fisheye.undistortPoints`` and ``cv2.solvePnP``, and
hand-derived face sizes. One renderer per configuration (module scope).
"""

import math

import cv2
import numpy as np
import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics, KannalaBrandt, backproject, project
from gimbal_lab.scene import _DECODE_LUT, _ENCODE_LUT, _LINEAR_LEVELS, ARUCO_DICTIONARY, SceneRenderer
from gimbal_lab.widefield import FACE_NAMES, WideFieldRenderer, face_focal_lengths_px, face_rotation

LENS_185, F_185 = KannalaBrandt.equidistant_for_fov(640, math.radians(185.0))
CAM_185 = Intrinsics(F_185, F_185, 319.5, 239.5, 640, 480)
DEFAULT_F_PX = Intrinsics.default().fx
# docs/design.md, lens sweep: range 3 m, target scaled so that its on-axis image matches the
# default camera's (sphere radius ≈ 18.5 px, marker ≈ 55 px).
RANGE_M = 3.0
SPHERE_M = 0.10 * DEFAULT_F_PX / F_185  # 0.28 m
MARKER_M = 0.30 * DEFAULT_F_PX / F_185  # 0.84 m


def camera_pose(forward, down_hint=(0.0, 0.0, -1.0), position=(0.0, 0.0, 2.0)):
    """OpenCV camera looking along world ``forward``, its image-down axis as close to ``down_hint`` as possible."""
    z = np.asarray(forward, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(down_hint, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack((x, np.cross(z, x), z))
    T[:3, 3] = position
    return T


T_LEVEL = camera_pose((1.0, 0.0, 0.0))  # 2 m up, looking along world +x: ground below, sky above
T_UPSIDE_DOWN = camera_pose((1.0, 0.0, 0.0), down_hint=(0.0, 0.0, 1.0))  # rolled 180°: the up face sees ground
# Axis 45° above the horizon, image +x towards the zenith: rays along +x of the image from the
# axis to past 90° all look at the sky (elevation ≥ 45°), so the sphere's background is sky.
T_SKYWARD = camera_pose((1.0, 0.0, 1.0), down_hint=(0.0, -1.0, 0.0))


def direction(theta_deg, phi_deg):
    """Unit ray θ off the optical axis at azimuth φ from image +x (towards +y, image down)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def world_point(T_world_cam, p_cam):
    T = np.eye(4)
    T[:3, 3] = T_world_cam[:3, :3] @ p_cam + T_world_cam[:3, 3]
    return T


def pixel_rays(intrinsics, lens, valid_mask):
    """Unit rays (H·W, 3) of every pixel (zeros outside ``valid_mask``), via camera.backproject."""
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=float), np.arange(intrinsics.height, dtype=float))
    uv = np.column_stack((u.ravel(), v.ravel()))
    rays = np.zeros((len(uv), 3))
    rays[valid_mask.ravel()] = backproject(uv[valid_mask.ravel()], intrinsics, lens)
    return rays


def encode_linear(linear):
    return _ENCODE_LUT[np.clip(linear * _LINEAR_LEVELS + 0.5, 0, _LINEAR_LEVELS).astype(np.uint16)]


def pinhole_reference(wide, rays, T_world_cam, T_world_target, axis_cam, half_angle_rad, **scene_kwargs):
    """The wide-field frame as one pinhole camera aimed along ``axis_cam`` sees it.

    The pinhole (focal length = the largest face's) renders the cone of rays within
    ``half_angle_rad`` of its axis; each fisheye pixel in that cone is sampled from it bilinearly in
    linear light (as the renderer does). Returns the reference image and the cone's mask.
    """
    K = wide.intrinsics
    f = max(face.focal_px for face in wide.faces)
    n = 2 * math.ceil(f * math.tan(half_angle_rad) + 3) + 1
    pinhole = Intrinsics(f, f, (n - 1) / 2, (n - 1) / 2, n, n)
    axis = np.asarray(axis_cam, dtype=float) / np.linalg.norm(axis_cam)
    R_cam_ref = camera_pose(axis, down_hint=(0.0, 1.0, 0.0) if abs(axis[1]) < 0.9 else (0.0, 0.0, 1.0),
                            position=(0, 0, 0))[:3, :3]
    T_world_ref = T_world_cam.copy()
    T_world_ref[:3, :3] = T_world_cam[:3, :3] @ R_cam_ref
    with SceneRenderer(pinhole, target=wide.target, **scene_kwargs) as reference:
        image = reference.render(T_world_ref, T_world_target)
    cone = (rays @ axis >= math.cos(half_angle_rad)) & wide.valid_mask.ravel()
    uv = np.full((len(rays), 2), -100.0)
    uv[cone] = project(rays[cone] @ R_cam_ref, pinhole, None)
    maps = [uv[:, i].reshape(K.height, K.width).astype(np.float32) for i in (0, 1)]
    linear = cv2.remap(cv2.LUT(image, _DECODE_LUT), maps[0], maps[1], cv2.INTER_LINEAR)
    return encode_linear(linear), cone.reshape(K.height, K.width)


def seam_band(rays, shape):
    """Pixels with a 4-neighbour served by another face (the faces of the module's rule), dilated by 1 px."""
    axes = np.array([face_rotation(name)[:, 2] for name in FACE_NAMES])
    face = np.argmax(rays @ axes.T, axis=1).reshape(shape)
    band = np.zeros(shape, dtype=bool)
    band[:, 1:] |= face[:, 1:] != face[:, :-1]
    band[:, :-1] |= face[:, 1:] != face[:, :-1]
    band[1:, :] |= face[1:, :] != face[:-1, :]
    band[:-1, :] |= face[1:, :] != face[:-1, :]
    return cv2.dilate(band.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def red_mask(image):
    """Red-sphere pixels against the sky: red above green, and blue at most half the sky's (235/2).

    The red sphere has no blue, so the blue channel falls with coverage: a pixel counts as sphere
    when more than half of it is covered.
    """
    rgb = image.astype(np.int16)
    return (rgb[:, :, 0] > rgb[:, :, 1]) & (rgb[:, :, 2] <= 117)


@pytest.fixture(scope="module")
def sphere_185():
    with WideFieldRenderer(CAM_185, LENS_185, target="sphere", sphere_radius_m=SPHERE_M) as r:
        yield r


@pytest.fixture(scope="module")
def rays_185(sphere_185):
    return pixel_rays(CAM_185, LENS_185, sphere_185.valid_mask)


# --- face sizes and layout -----------------------------------------------------------------------


def test_face_rotations_are_proper_and_point_along_the_cube_axes():
    axes = {"front": (0, 0, 1), "right": (1, 0, 0), "left": (-1, 0, 0), "down": (0, 1, 0), "up": (0, -1, 0),
            "back": (0, 0, -1)}
    for name in FACE_NAMES:
        R = face_rotation(name)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(R[:, 2], axes[name])


def test_face_focal_lengths_follow_the_density_rule_by_hand():
    """The 185° equidistant lens at 640 × 480 (f = 198.21 px).

    A ray in the plane through the optical axis and a side face's axis, θ off the optical axis,
    meets the side face α = 90° − θ off its axis. The lens's tangential density there is
    f·θ/sin θ px/rad, the face's sparsest f_face/cos α = f_face/sin θ, so f_face ≥ f·θ, the
    ray's image radius: 319.5 px at the image's left and right edges, 239.5 px at the top and
    bottom. On the front face (α = θ) f·(θ/sin θ)·cos θ ≤ f, reached on the axis; sizes are
    rounded up to a whole-pixel face side (half-pixel focal lengths).
    """
    focal = face_focal_lengths_px(CAM_185, LENS_185)
    assert list(focal) == ["front", "right", "left", "down", "up"]  # no back face: rays ≤ 115.4°
    assert focal["front"] == math.ceil(2 * F_185) / 2 == 198.5
    assert focal["right"] == focal["left"] == 319.5
    assert focal["down"] == focal["up"] == 239.5


def test_back_face_is_added_exactly_when_rays_reach_the_cube_corner_angle():
    """A back-face ray is at least acos(−1/√3) = 125.26° off the optical axis (the cube's corners)."""
    corner_deg = math.degrees(math.acos(-1.0 / math.sqrt(3.0)))
    _, f = KannalaBrandt.equidistant_for_fov(320, math.radians(300.0))
    K = Intrinsics(f, f, 159.5, 159.5, 320, 320)  # the image reaches 150° along its diagonals
    below = face_focal_lengths_px(K, KannalaBrandt(max_field_rad=math.radians(corner_deg - 0.2)))
    above = face_focal_lengths_px(K, KannalaBrandt(max_field_rad=math.radians(corner_deg + 0.2)))
    assert "back" not in below and "back" in above


# --- seams and the image circle ------------------------------------------------------------------


SEAM_CASES = [  # (camera pose, reference axis in the camera frame)
    ("level", (1.0, 1.0, 1.0)),  # front | right | down corner (ground)
    ("level", (-1.0, 1.0, 1.0)),  # front | left | down corner (ground)
    ("level", (1.0, -0.1, 1.0)),  # front | right seam across the horizon
    ("upside_down", (1.0, -1.0, 1.0)),  # front | right | up corner (ground: the camera is rolled)
    ("upside_down", (-1.0, -1.0, 1.0)),  # front | left | up corner
]


def seam_differences(wide, rays, poses, cases, sphere_radius_m):
    """Per case: (mean |Δ| raw, mean |Δ| after a σ = 1.5 px blur in the cone, the same in the seam band)."""
    K = wide.intrinsics
    target = np.eye(4)
    target[:3, 3] = (0.0, 0.0, 32.0)  # the sphere 30 m overhead, out of these cones
    frames = {name: wide.render(T, target) for name, T in poses.items()}
    band = seam_band(rays, (K.height, K.width))
    out = []
    for pose, axis in cases:
        reference, cone = pinhole_reference(wide, rays, poses[pose], target, axis, math.radians(35.0),
                                            sphere_radius_m=sphere_radius_m)
        inner = cv2.erode(cone.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)  # blur support inside
        raw = np.abs(frames[pose].astype(float) - reference).max(axis=2)
        blur = [cv2.GaussianBlur(im.astype(np.float32), (0, 0), 1.5) for im in (frames[pose], reference)]
        smooth = np.abs(blur[0] - blur[1]).max(axis=2)
        assert (inner & band).sum() > 300  # the cone does straddle seams
        out.append((raw[cone].mean(), smooth[inner].mean(), smooth[inner & band].mean()))
    return out


def test_seams_match_a_single_pinhole_view(sphere_185, rays_185):
    """Across face seams and cube corners the frame equals one pinhole camera aimed at them.

    Each case aims a pinhole at a seam or corner and resamples its 35°-half-angle cone to the
    fisheye's pixels. Both images sample the same scene on different grids, so the ground's
    speckle texture (per-texel noise) differs pixel by pixel: mean |Δ| (max over channels)
    < 3 grey levels raw. After a σ = 1.5 px Gaussian, which removes that sampling noise but not a
    seam (a misplaced face shifts the checker edges and the horizon by pixels), the mean |Δ| must
    be < 1.5 grey levels in the cone and in the band of pixels next to a seam. Measured: raw
    0.75–1.95, blurred 0.28–0.45, seam band 0.21–0.57 (a face looking the wrong way: ~80).
    """
    results = seam_differences(sphere_185, rays_185, {"level": T_LEVEL, "upside_down": T_UPSIDE_DOWN},
                               SEAM_CASES, SPHERE_M)
    for case, (raw, smooth, band) in zip(SEAM_CASES, results):
        assert raw < 3.0 and smooth < 1.5 and band < 1.5, (case, raw, smooth, band)


def test_valid_pixels_are_never_black(sphere_185):
    """Level and upside-down camera: ground and sky fill the 185° field (the whole 640 × 480 frame,
    rays up to 115.4°). The darkest scene colour is the dark ground green (≥ 25 grey levels)."""
    assert sphere_185.valid_mask.all()
    for T in (T_LEVEL, T_UPSIDE_DOWN):
        image = sphere_185.render(T, world_point(T, direction(30.0, 20.0) * RANGE_M))
        assert image.shape == (480, 640, 3) and image.dtype == np.uint8
        assert image.max(axis=2).min() > 20


def test_outside_the_image_circle_is_black_and_the_mask_is_analytic():
    """A circular 185° lens (field limited to 92.5°) at 320 × 240, with sensor noise.

    valid_mask is the disc of radius f·92.5° = 160 px (an equidistant lens), clipped by the
    frame; outside it every pixel is exactly 0 even with noise, inside every pixel is lit (> 15
    grey levels: the darkest ground, 25, less 5σ of noise).
    """
    _, f = KannalaBrandt.equidistant_for_fov(320, math.radians(185.0))
    K = Intrinsics(f, f, 159.5, 119.5, 320, 240)
    lens = KannalaBrandt(max_field_rad=math.radians(92.5))
    u, v = np.meshgrid(np.arange(320.0), np.arange(240.0))
    radius_px = np.hypot(u - 159.5, v - 119.5)
    with WideFieldRenderer(K, lens, noise_std=2.0, seed=7) as wide:
        assert np.array_equal(wide.valid_mask, radius_px <= f * math.radians(92.5) + 1e-9)
        assert not wide.valid_mask.all() and wide.valid_mask[119, :].all()  # circle reaches the sides
        frames = [wide.render(T_LEVEL, world_point(T_LEVEL, (3.0, 0.0, 0.0))) for _ in range(2)]
    for image in frames:
        assert (image[~wide.valid_mask] == 0).all()
        assert image.max(axis=2)[wide.valid_mask].min() > 15
    assert not np.array_equal(frames[0], frames[1])  # fresh noise every frame


def test_back_face_seams_match_a_single_pinhole_view():
    """A 280° lens (field limited to 140°) at reduced size, 320 × 320: six faces; the back face's
    seams checked as above (same tolerances; measured raw 0.87–1.98, blurred 0.30–0.48, seam band
    0.29–0.72), and pixels beyond 140° black."""
    _, f = KannalaBrandt.equidistant_for_fov(320, math.radians(280.0))
    K = Intrinsics(f, f, 159.5, 159.5, 320, 320)
    lens = KannalaBrandt(max_field_rad=math.radians(140.0))
    cases = [("level", (1.0, 1.0, -1.0)), ("level", (0.0, 1.0, -1.0)), ("level", (-1.0, 0.1, -1.0))]
    with WideFieldRenderer(K, lens, sphere_radius_m=SPHERE_M) as wide:
        assert [face.name for face in wide.faces] == list(FACE_NAMES)
        rays = pixel_rays(K, lens, wide.valid_mask)
        results = seam_differences(wide, rays, {"level": T_LEVEL}, cases, SPHERE_M)
        image = wide.render(T_LEVEL, world_point(T_LEVEL, (3.0, 0.0, 0.0)))
    for case, (raw, smooth, band) in zip(cases, results):
        assert raw < 3.0 and smooth < 1.5 and band < 1.5, (case, raw, smooth, band)
    assert (image[~wide.valid_mask] == 0).all() and image.max(axis=2)[wide.valid_mask].min() > 20


# --- geometry of the target ----------------------------------------------------------------------

# (θ, φ) in degrees: on the axis, on the front/right seam (45°, 0°) and the front/down seam
# (45°, 90°), up to 88° along the image's horizontal axis and 100° towards a corner.
SPHERE_DIRECTIONS_DEG = [(0, 0), (30, 0), (45, 0), (45, 90), (60, -50), (75, 20), (88, 0), (100, 38)]


def test_sphere_silhouette_matches_the_tangent_cone(sphere_185, rays_185):
    """Rendered red mask vs the analytic silhouette: pixels whose ray is within asin(r/d) of the centre.

    The sphere (r = 0.28 m at 3 m, 18.5 px radius on the axis, up to 27 px tangentially at 100°)
    is sampled at pixel centres. IoU ≥ 0.96 and mask centroids within 0.25 px. The IoU is bounded
    by the rasteriser's 4-sample coverage, not by the wide-field path: a pixel 50–60 % covered
    shows 2 of 4 samples, exactly half the sky's blue, and counts as sky; a 640 × 480 pinhole
    SceneRenderer with the same focal length scores 0.963–0.990 for such spheres near its axis
    (measured, depending on where the outline falls within pixels). A misplaced face moves the
    silhouette by pixels; a half-pixel slip of a face fails the centroid bound (measured 0.48 px).
    Measured: IoU 0.983–0.990, centroids ≤ 0.08 px apart.
    """
    cos_cone = math.cos(math.asin(SPHERE_M / RANGE_M))
    for theta, phi in SPHERE_DIRECTIONS_DEG:
        centre = direction(theta, phi)
        image = sphere_185.render(T_SKYWARD, world_point(T_SKYWARD, centre * RANGE_M))
        rendered = red_mask(image)
        analytic = (rays_185 @ centre >= cos_cone).reshape(rendered.shape)
        iou = (rendered & analytic).sum() / (rendered | analytic).sum()
        shift = np.argwhere(rendered).mean(axis=0) - np.argwhere(analytic).mean(axis=0)
        assert iou >= 0.96 and np.abs(shift).max() < 0.25, (theta, phi, iou, shift)


def test_marker_pose_through_the_fisheye_within_two_percent():
    """ArUco plate (0.84 m, 55 px on the axis) at 3 m through the 185° lens, camera 10 m up.

    Corners from ``cv2.aruco`` (sub-pixel), undistorted by ``cv2.fisheye.undistortPoints``, and
    IPPE-square PnP in normalised coordinates: translation within 2 % of the distance. Off axis
    the marker is turned to face the camera, then by 10–15° about its vertical axis; (40°, 120°)
    straddles the front/down seam. Measured 0.5–0.8 %. Beyond about 55° off axis the marker's
    edges bend enough (equidistant projection) that ``cv2.aruco`` fails to fit a quadrilateral
    at some azimuths and yaws; the positions here are ones it detects.
    """
    lens = LENS_185
    T_world_cam = camera_pose((1.0, 0.0, 0.0), position=(0.0, 0.0, 10.0))
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY), params)
    half = MARKER_M / 2
    object_points = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
    errors = []
    with WideFieldRenderer(CAM_185, lens, target="aruco", marker_length_m=MARKER_M,
                           plate_size_m=MARKER_M * 4 / 3) as wide:
        for theta, phi, yaw_deg in [(0, 0, 10), (30, 45, -15), (40, 120, 15), (50, 200, 10), (70, 200, 10)]:
            d = direction(theta, phi)
            z = -d  # the plate's normal towards the camera
            x = np.cross((0.0, -1.0, 0.0), z)
            x /= np.linalg.norm(x)
            a = math.radians(yaw_deg)
            turn = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
            T_cam_marker = np.eye(4)
            T_cam_marker[:3, :3] = np.column_stack((x, np.cross(z, x), z)) @ turn
            T_cam_marker[:3, 3] = RANGE_M * d
            image = wide.render(T_world_cam, T_world_cam @ T_cam_marker)
            corners, ids, _ = detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
            assert ids is not None and ids.ravel().tolist() == [0], (theta, phi)
            normalised = cv2.fisheye.undistortPoints(corners[0].reshape(-1, 1, 2).astype(np.float64), CAM_185.K,
                                                     lens.coefficients).reshape(-1, 2)
            ok, _, tvec = cv2.solvePnP(object_points, normalised, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            assert ok
            errors.append(np.linalg.norm(tvec.ravel() - T_cam_marker[:3, 3]) / RANGE_M)
    assert max(errors) < 0.02, errors


# --- interface -----------------------------------------------------------------------------------


def test_exposure_of_a_still_scene_equals_the_sharp_frame(sphere_185):
    """Averaging three identical sub-frames in 16-bit linear light returns them exactly."""
    target = world_point(T_LEVEL, direction(20.0, 30.0) * RANGE_M)
    sharp = sphere_185.render(T_LEVEL, target)
    blurred = sphere_185.render_exposure(lambda t_s: (T_LEVEL, target), 0.0, 0.01, 3)
    assert np.array_equal(sharp, blurred)


def test_brown_conrady_and_pinhole_lenses_delegate_to_one_scene_renderer():
    K = Intrinsics.from_fov(160, 120, math.radians(60.0))
    target = world_point(T_LEVEL, (3.0, 0.2, 0.1))
    for lens in (None, BrownConrady.default()):
        with WideFieldRenderer(K, lens) as wide, SceneRenderer(K, lens) as scene:
            assert wide.faces == () and wide.valid_mask.all() and wide.valid_mask.shape == (120, 160)
            assert np.array_equal(wide.render(T_LEVEL, target), scene.render(T_LEVEL, target))


def test_face_px_sets_every_face():
    _, f = KannalaBrandt.equidistant_for_fov(160, math.radians(185.0))
    with WideFieldRenderer(Intrinsics(f, f, 79.5, 59.5, 160, 120), LENS_185, face_px=100) as wide:
        assert {face.focal_px for face in wide.faces} == {50.0}
        assert wide.render(T_LEVEL, world_point(T_LEVEL, (3.0, 0.0, 0.0))).shape == (120, 160, 3)
    with pytest.raises(RuntimeError, match="closed"):
        wide.render(T_LEVEL, np.eye(4))


@pytest.mark.parametrize(
    "args, kwargs, error, match",
    [
        (("not intrinsics", LENS_185), {}, TypeError, "intrinsics"),
        ((CAM_185, "fisheye"), {}, TypeError, "lens"),
        ((CAM_185, LENS_185), {"target": "cube"}, ValueError, "target"),
        ((CAM_185, LENS_185), {"distortion": BrownConrady()}, TypeError, "distortion"),
        ((CAM_185, LENS_185), {"colour": "red"}, TypeError, "colour"),
        ((CAM_185, LENS_185), {"face_px": 3}, ValueError, "face_px"),
        ((CAM_185, LENS_185), {"face_px": 64.5}, ValueError, "face_px"),
        ((CAM_185, LENS_185), {"faces": ("front", "left", "right")}, ValueError, "too wide.*up"),
        ((CAM_185, LENS_185), {"faces": ("front", "sideways")}, ValueError, "faces"),
        ((CAM_185, LENS_185), {"faces": "front"}, TypeError, "faces"),
        ((CAM_185, LENS_185), {"noise_std": -1.0}, ValueError, "noise_std"),
        ((CAM_185, None), {"face_px": 512}, ValueError, "KannalaBrandt"),
        # the whole sphere of directions: density without bound at the back pole
        ((Intrinsics(320 / math.pi, 320 / math.pi, 319.5, 239.5, 640, 480),
          KannalaBrandt.equidistant_for_fov(640, 2 * math.pi)[0]), {}, ValueError, "too wide for a cube map"),
    ],
)
def test_bad_configuration_raises_before_any_context(args, kwargs, error, match):
    with pytest.raises(error, match=match):
        WideFieldRenderer(*args, **kwargs)


def test_bad_poses_raise(sphere_185):
    with pytest.raises(ValueError, match="T_world_cam"):
        sphere_185.render(np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="T_world_cam"):
        sphere_185.render(np.diag([2.0, 1.0, 1.0, 1.0]), np.eye(4))
    with pytest.raises(ValueError, match="T_world_target"):
        sphere_185.render(T_LEVEL, np.full((4, 4), np.nan))
