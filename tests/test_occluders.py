"""Occluders: their geometry against brute-force sampling, their renders against the camera model,
and the closed loop's truth columns against the rendered frames.

Oracles: points sampled densely along each line of sight (is any inside the box?),
:func:`gimbal_lab.camera.project` of the box's corners, the sphere's tangent-cone geometry by hand,
and the rendered frames themselves (the grey of the occluder at the target's centre pixel).
"""

import math

import numpy as np
import pytest

from gimbal_lab.camera import Intrinsics, project
from gimbal_lab.detection import SphereDetector
from gimbal_lab.scene import Occluder, SceneRenderer, points_visible, sphere_rim_points
from gimbal_lab.config import Camera, Platform, Pointing, Target
from gimbal_lab.simulation import TrackingConfig, simulate

CAM = Intrinsics.default()


def camera_pose(position=(0.0, 0.0, 2.0)):
    """OpenCV camera frame looking along world +x."""
    T = np.eye(4)
    T[:3, :3] = np.column_stack(([0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]))
    T[:3, 3] = position
    return T


def sphere_at(p):
    T = np.eye(4)
    T[:3, 3] = p
    return T


def brute_force_blocked(box: Occluder, origin, point, n=20001):
    t = np.linspace(0.0, 1.0, n)[:, None]
    samples = origin + t * (np.asarray(point) - origin)
    lo, hi = box.bounds_m
    return bool(np.any(np.all((samples >= lo) & (samples <= hi), axis=1)))


def test_blocks_agrees_with_dense_sampling_of_each_segment():
    rng = np.random.default_rng(5)
    box = Occluder("panel", centre_m=(1.2, 0.1, 1.7), size_m=(0.02, 0.6, 0.6))
    origin = np.array([0.03, 0.0, 1.955])
    points = np.column_stack((rng.uniform(0.5, 4.0, 400), rng.uniform(-1.5, 1.5, 400), rng.uniform(0.5, 3.0, 400)))
    fast = box.blocks(origin, points)
    slow = np.array([brute_force_blocked(box, origin, p) for p in points])
    # dense sampling misses segments that clip a corner by under 1/20000 of their length: allow none here
    assert (fast == slow).all()
    assert 20 < fast.sum() < 380  # both outcomes are exercised


def test_blocks_handles_axis_parallel_segments_and_points_before_the_box():
    box = Occluder("pole", centre_m=(1.0, 0.0, 1.0), size_m=(0.15, 0.15, 2.0))
    o = np.array([0.0, 0.0, 1.0])
    assert box.blocks(o, [3.0, 0.0, 1.0])  # straight through, parallel to y and z faces
    assert not box.blocks(o, [3.0, 0.3, 1.0])  # at x = 1.075 m it is 0.1075 m aside: beside it
    assert not box.blocks(o, [0.9, 0.0, 1.0])  # ends before the box
    assert box.blocks(o, [1.0, 0.0, 1.0])  # ends inside it
    assert box.blocks(o, [3.0, 0.0, 2.5])  # at the pole (x ≈ 1) the segment is at z ≈ 1.5, below its 2 m top
    assert not box.blocks(o, [3.0, 0.0, 4.5])  # at x = 0.925 m it is at z = 2.16 m: over the top
    assert points_visible([], o, np.zeros((4, 3))).all()


def test_bad_occluders_are_clear_errors():
    with pytest.raises(ValueError, match="size_m"):
        Occluder("pole", (1, 0, 1), (0.15, 0.0, 2.0))
    with pytest.raises(ValueError, match="centre_m"):
        Occluder("pole", (1, 0), (0.15, 0.15, 2.0))
    with pytest.raises(ValueError, match="name"):
        Occluder("", (1, 0, 1), (0.15, 0.15, 2.0))
    with pytest.raises(TypeError, match="Occluder"):
        SceneRenderer(CAM, occluders=[(1, 0, 1)])


def test_rim_points_lie_on_the_sphere_and_on_its_tangent_cone():
    o, c, r = np.array([0.0, 0.0, 2.0]), np.array([3.0, 0.5, 1.2]), 0.1
    rim = sphere_rim_points(o, c, r, n=24)
    assert np.allclose(np.linalg.norm(rim - c, axis=1), r, atol=1e-12)
    assert np.allclose(np.einsum("ij,ij->i", rim - c, rim - o), 0.0, atol=1e-12)  # tangent: radius ⟂ sight line
    with pytest.raises(ValueError, match="outside the sphere"):
        sphere_rim_points(c, c, r)


@pytest.fixture(scope="module")
def scene():
    box = Occluder("pole", centre_m=(1.0, 0.0, 1.0), size_m=(0.15, 0.15, 2.0))
    with SceneRenderer(CAM, occluders=[box]) as windowed, SceneRenderer(CAM, occluders=[box], antialias="full") as full:
        yield box, windowed, full


def test_the_occluder_is_drawn_where_its_corners_project(scene):
    box, renderer, _ = scene
    T_cam = camera_pose()
    image = renderer.render(T_cam, sphere_at((3.0, 1.5, 2.5)))
    lo, hi = box.bounds_m
    front = np.array([[lo[0], y, z] for y in (lo[1], hi[1]) for z in (lo[2], min(hi[2], 1.99))])
    p_cam = (front - T_cam[:3, 3]) @ T_cam[:3, :3]
    uv = project(p_cam, CAM)
    u0, u1 = np.floor(uv[:, 0].min()) + 2, np.ceil(uv[:, 0].max()) - 2
    v0 = np.ceil(uv[:, 1].min()) + 2
    inside = image[int(v0):, int(u0):int(u1) + 1].reshape(-1, 3).astype(int)
    grey = inside[:, 0]
    assert np.all(np.abs(inside - grey[:, None]) <= 1)  # grey: R = G = B (matte grey, one light colour)
    left = image[int(v0):, int(u0) - 6].astype(int)
    assert np.any(np.abs(left[:, 0] - left[:, 1]) > 10)  # beside it: the green ground


def test_a_sphere_behind_the_occluder_is_hidden_and_beside_it_is_seen(scene):
    _, renderer, _ = scene
    T_cam = camera_pose()
    detector = SphereDetector()
    assert detector.detect(renderer.render(T_cam, sphere_at((3.0, 0.0, 1.5)))) is None
    assert detector.detect(renderer.render(T_cam, sphere_at((3.0, 0.6, 1.5)))) is not None


def test_windowed_antialiasing_keeps_the_cut_target_bit_equal_to_a_full_render(scene):
    box, windowed, full = scene
    T_cam = camera_pose()
    for y in (0.2, 0.25, 0.3, -0.27):  # the pole's shadow at 3 m ends at |y| = 0.225 m: the sphere is cut
        T_target = sphere_at((3.0, y, 1.5))
        a, b = windowed.render(T_cam, T_target), full.render(T_cam, T_target)
        x0, y0, w, h = windowed._target_box(T_cam, T_target)
        assert np.array_equal(a[y0:y0 + h, x0:x0 + w], b[y0:y0 + h, x0:x0 + w])
        window = a[y0:y0 + h, x0:x0 + w].astype(int)
        red = (window[..., 0] > 150) & (window[..., 1] < 60)
        grey = (np.abs(window[..., 0] - window[..., 1]) <= 1) & (np.abs(window[..., 1] - window[..., 2]) <= 1)
        assert red.sum() > 20 and grey.sum() > 20  # both the sphere and the pole are in the window


def test_fast_motion_blur_refuses_occluders(scene):
    _, renderer, _ = scene
    T_cam, T_target = camera_pose(), sphere_at((3.0, 0.5, 1.5))
    with pytest.raises(ValueError, match="occluders"):
        renderer.render_motion(lambda t: (T_cam, T_target), 0.0, 1 / 60)
    with pytest.raises(ValueError, match="occluders"):
        TrackingConfig(target=Target(occluders=(Occluder("pole", (1, 0, 1), (0.15, 0.15, 2)),)),
                       camera=Camera(exposure_s=1 / 60, blur="fast"))


# ----------------------------------------------------------------------------------------------
# the closed loop's truth columns
def test_hidden_frames_are_those_whose_centre_pixel_shows_the_occluder():
    from gimbal_lab.simulation import closed_loop, make_renderer

    pole = Occluder("pole", centre_m=(0.83, 0.0, 0.98), size_m=(0.15, 0.15, 1.955))
    config = TrackingConfig(target=Target(occluders=(pole,)), camera=Camera(noise_std=0.0), revolutions=1.0, seed=2)
    renderer = make_renderer(config)
    try:
        rows = list(closed_loop(config, renderer))
    finally:
        renderer.close()
    columns = __import__("gimbal_lab.simulation", fromlist=["_COLUMNS"])._COLUMNS
    hidden_col, u_col, v_col = (columns.index(c) for c in ("hidden", "true_u_px", "true_v_px"))
    frac_col, det_col = columns.index("visible_fraction"), columns.index("detected")
    n_hidden = 0
    for row, image in rows:
        u, v = int(round(row[u_col])), int(round(row[v_col]))
        r, g, b = image[v, u].astype(int)
        is_grey = abs(r - g) <= 2 and abs(g - b) <= 2
        assert bool(row[hidden_col]) == is_grey, (row[0], image[v, u])
        n_hidden += bool(row[hidden_col])
        if row[frac_col] == 1.0:
            assert row[det_col]  # a wholly visible sphere is detected
        assert (row[frac_col] < 1.0) or not row[hidden_col]
    assert 3 <= n_hidden <= 12  # this pole hides about 0.2 s of the 2 s revolution: 6 frames


def test_config_round_trips_occluders_filters_and_the_manoeuvring_path():
    pole = Occluder("pole", centre_m=(0.83, 0.0, 0.98), size_m=(0.15, 0.15, 1.955))
    config = TrackingConfig(target=Target(trajectory="manoeuvring", occluders=(pole,)),
                            pointing=Pointing("filter", "ca"), seed=4)
    again = TrackingConfig.from_dict(config.to_dict())
    assert again == config and again.key == config.key
    manoeuvring = TrackingConfig(target=Target(trajectory="manoeuvring"))
    assert config.path is manoeuvring.with_(seed=4).path  # drawn once per seed
    assert not np.allclose(config.path.position(1.0), manoeuvring.with_(seed=5).path.position(1.0))
    with pytest.raises(ValueError, match="pointing.filter"):
        Pointing("filter", "ekf")
    with pytest.raises(TypeError, match="Occluder"):
        Target(occluders=((1, 2, 3),))
    with pytest.raises(ValueError, match="still platform"):
        TrackingConfig(pointing=Pointing("filter"), platform=Platform(motion="hover"))


def test_filter_pointing_run_logs_a_consistent_prediction_and_is_deterministic():
    config = TrackingConfig(target=Target(trajectory="manoeuvring"), pointing=Pointing("filter", "cv"), revolutions=0.5,
                            seed=1)
    a, b = simulate(config), simulate(config)
    assert a.frames.equals(b.frames)
    f = a.frames
    tracked = f["filter_nees"].notna()
    assert tracked.mean() > 0.9
    error = np.linalg.norm(f.loc[tracked, ["filter_x_m", "filter_y_m", "filter_z_m"]].to_numpy()
                           - f.loc[tracked, ["true_x_m", "true_y_m", "true_z_m"]].to_numpy(), axis=1)
    assert np.median(error) < 0.05  # the filter follows a 1 m/s target to a few centimetres
    assert f["detected"].iloc[5:].all()
    assert math.isfinite(f["filter_nees"].iloc[-1])
