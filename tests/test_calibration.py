"""Calibration files: read exactly (OpenCV's projection with the file's raw numbers is the oracle)
or refused with a message naming the culprit.

Projection tolerance: ours and OpenCV evaluate the same polynomial in double precision on pixel
coordinates below 10⁴ px, so they differ by rounding (~1e-12 px); 1e-9 px leaves a thousandfold
margin and is far below what a misread coefficient moves (a k3 read as p1 moves pixels by > 1 px).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from gimbal_lab import realworld as rw
from gimbal_lab.calibration import MAX_IMAGE_SIDE_PX, Calibration, load_calibration, save_calibration
from gimbal_lab.camera import BrownConrady, Intrinsics, KannalaBrandt, Rational, project

REAL = Path("/work/shared/data/real-aruco")
PX_TOL = 1e-9
K_RAW = [[612.25, 0.0, 301.5], [0.0, 615.75, 251.125], [0.0, 0.0, 1.0]]  # off-centre principal point


def points_in_view(K, size, n=500, seed=0, max_angle_rad=None):
    """3-D points (N, 3) in front of a camera with matrix K whose pinhole images fill the frame,
    or, with ``max_angle_rad``, directions up to that angle off the axis (for a fisheye)."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.5, 5.0, n)
    if max_angle_rad is not None:
        theta, phi = rng.uniform(0, max_angle_rad, n), rng.uniform(-np.pi, np.pi, n)
        return np.column_stack((np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta))) * depth[:, None]
    K = np.asarray(K, float)
    u, v = rng.uniform(0, size[0] - 1, n), rng.uniform(0, size[1] - 1, n)
    return np.column_stack(((u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth))


def assert_projects_like_opencv(calibration, K_raw, D_raw, fisheye=False):
    """Our projection through the read calibration equals OpenCV's with the file's raw numbers."""
    K_raw, D_raw = np.asarray(K_raw, float), np.asarray(D_raw, float).reshape(-1)
    if fisheye:
        points = points_in_view(K_raw, calibration.image_size, max_angle_rad=math.radians(80))
        theirs = cv2.fisheye.projectPoints(points[:, None, :], np.zeros(3), np.zeros(3), K_raw, D_raw)[0]
    else:
        points = points_in_view(K_raw, calibration.image_size)
        theirs = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K_raw, D_raw)[0]
    ours = project(points, calibration.intrinsics, calibration.lens)
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < PX_TOL


def write_opencv(path, nodes: dict) -> Path:
    """A calibration file written by OpenCV itself (cv2.FileStorage picks YAML/XML/JSON by suffix)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in nodes.items():
        fs.write(name, value)
    fs.release()
    return Path(path)


def ros_yaml(path, *, K=K_RAW, D=(-0.21, 0.043, 0.0012, -0.0007, 0.0051), model="plumb_bob", size=(640, 480),
             extra="") -> Path:
    """A hand-written ROS camera_info YAML (camera_calibration_parsers' layout)."""
    K_text = ", ".join(repr(float(v)) if isinstance(v, (int, float)) else str(v) for v in np.ravel(K).tolist()) \
        if not isinstance(K, str) else K
    lines = [f"image_width: {size[0]}", f"image_height: {size[1]}", "camera_name: webcam",
             "camera_matrix:", "  rows: 3", "  cols: 3", f"  data: [{K_text}]"]
    if model is not None:
        lines.append(f"distortion_model: {model}")
    if D is not None:
        D_text = ", ".join(repr(float(v)) if isinstance(v, (int, float)) else str(v) for v in D)
        lines += ["distortion_coefficients:", "  rows: 1", f"  cols: {len(D)}", f"  data: [{D_text}]"]
    lines += ["rectification_matrix:", "  rows: 3", "  cols: 3", "  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]"]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n" + extra)
    return path


# --------------------------------------------------------------------------------------------
# real calibrations (kept outside the repository)
# --------------------------------------------------------------------------------------------


@pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} (real calibrations, not in the repository) is absent")
def test_real_opencv_calibrations_project_as_opencv_does():
    charuco = REAL / "tutorial_camera_charuco.yml"  # OpenCV's calibration output: size, k3 = 2.95, RMS
    raw = cv2.FileStorage(str(charuco), cv2.FILE_STORAGE_READ)  # OpenCV's own reading is the oracle
    K_raw, D_raw = raw.getNode("camera_matrix").mat(), raw.getNode("distortion_coefficients").mat()
    raw.release()
    calibration = load_calibration(charuco)
    assert calibration.image_size == (640, 480)
    assert isinstance(calibration.distortion, BrownConrady)
    assert calibration.rms_px == 0.18234905535936044
    np.testing.assert_array_equal(calibration.intrinsics.K, K_raw)
    np.testing.assert_array_equal(calibration.distortion.coefficients, D_raw.reshape(-1))
    assert_projects_like_opencv(calibration, K_raw, D_raw)
    with pytest.raises(ValueError, match="image_size"):
        load_calibration(charuco, image_size=(1280, 720))  # disagrees with the file

    params = REAL / "tutorial_camera_params.yml"  # states no image size: refused unless given
    with pytest.raises(ValueError, match=r"tutorial_camera_params\.yml.*image_width/image_height: missing"):
        load_calibration(params)
    raw = cv2.FileStorage(str(params), cv2.FILE_STORAGE_READ)
    K_raw, D_raw = raw.getNode("camera_matrix").mat(), raw.getNode("distortion_coefficients").mat()
    raw.release()
    calibration = load_calibration(params, image_size=(640, 480))  # the size of its photograph
    np.testing.assert_array_equal(calibration.intrinsics.K, K_raw)
    np.testing.assert_array_equal(calibration.distortion.coefficients, D_raw.reshape(-1))  # its k3 is 0
    assert_projects_like_opencv(calibration, K_raw, D_raw)


# --------------------------------------------------------------------------------------------
# files written by OpenCV, and by hand in ROS's layout
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".yml", ".xml", ".json"])
@pytest.mark.parametrize(
    "D",
    [
        [-0.31, 0.12, 0.0011, -0.0006, -0.027],
        [-0.31, 0.12, 0.0011, -0.0006, -0.027, 0.0, 0.0, 0.0],  # rational model, k4..k6 = 0
        [0.4, -0.2, 0.0011, -0.0006, 0.05] + [0.0] * 9,  # 14 numbers, pincushion
    ],
    ids=["5", "8", "14"],
)
def test_pinhole_lenses_written_by_opencv_are_read_exactly(tmp_path, suffix, D):
    path = write_opencv(tmp_path / f"cam{suffix}", {
        "image_width": 640, "image_height": 480, "camera_matrix": np.array(K_RAW),
        "distortion_coefficients": np.array(D).reshape(-1, 1), "avg_reprojection_error": 0.25})
    calibration = load_calibration(path)
    assert calibration.image_size == (640, 480) and calibration.rms_px == 0.25 and calibration.views == 0
    np.testing.assert_array_equal(calibration.intrinsics.K, K_RAW)
    np.testing.assert_array_equal(calibration.distortion.coefficients, (D + [0.0])[:5])
    assert_projects_like_opencv(calibration, K_RAW, D)


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_an_opencv_fisheye_calibration_is_read_as_kannala_brandt(tmp_path, suffix):
    """OpenCV's camera-calibration sample marks a cv2.fisheye calibration with fisheye_model: 1."""
    D = [-0.013, -0.0053, 0.0014, -0.0002]
    path = write_opencv(tmp_path / f"fish{suffix}", {
        "image_width": 640, "image_height": 480, "flags": 0, "fisheye_model": 1,
        "camera_matrix": np.array(K_RAW), "distortion_coefficients": np.array(D).reshape(-1, 1)})
    calibration = load_calibration(path)
    assert isinstance(calibration.distortion, KannalaBrandt)
    np.testing.assert_array_equal(calibration.distortion.coefficients, D)
    assert_projects_like_opencv(calibration, K_RAW, D, fisheye=True)


@pytest.mark.parametrize(
    "model, D",
    [
        ("plumb_bob", [-0.21, 0.043, 0.0012, -0.0007, 0.0051]),
        ("rational_polynomial", [-0.21, 0.043, 0.0012, -0.0007, 0.0051, 0.0, 0.0, 0.0]),
        ("radtan", [-0.21, 0.043, 0.0012, -0.0007]),  # Kalibr's name: k1, k2, p1, p2
    ],
)
def test_ros_pinhole_models_are_read_as_brown_conrady(tmp_path, model, D):
    calibration = load_calibration(ros_yaml(tmp_path / "camera_info.yaml", D=D, model=model))
    assert isinstance(calibration.distortion, BrownConrady) and math.isnan(calibration.rms_px)
    np.testing.assert_array_equal(calibration.intrinsics.K, K_RAW)
    np.testing.assert_array_equal(calibration.distortion.coefficients, (D + [0.0])[:5])
    assert_projects_like_opencv(calibration, K_RAW, D)


#: A wide phone lens in OpenCV's rational model (k1, k2, p1, p2, k3, k4, k5, k6).
RATIONAL_D = [2.2, 0.8, 0.0005, -0.0003, 0.02, 2.6, 1.5, 0.12]


@pytest.mark.parametrize("suffix", [".yml", ".xml", ".json"])
@pytest.mark.parametrize("D", [RATIONAL_D, RATIONAL_D + [0.0] * 4, RATIONAL_D + [0.0] * 6], ids=["8", "12", "14"])
def test_an_opencv_rational_calibration_is_read_as_the_rational_lens(tmp_path, suffix, D):
    """OpenCV's CALIB_RATIONAL_MODEL writes 8 numbers (12 or 14 with thin-prism and tilt terms at 0)."""
    path = write_opencv(tmp_path / f"phone{suffix}", {
        "image_width": 640, "image_height": 480, "camera_matrix": np.array(K_RAW),
        "distortion_coefficients": np.array(D).reshape(-1, 1)})
    calibration = load_calibration(path)
    assert isinstance(calibration.distortion, Rational)
    np.testing.assert_array_equal(calibration.distortion.coefficients, RATIONAL_D)
    assert_projects_like_opencv(calibration, K_RAW, D)


def test_ros_rational_polynomial_is_read_as_the_rational_lens(tmp_path):
    calibration = load_calibration(ros_yaml(tmp_path / "phone.yaml", D=RATIONAL_D, model="rational_polynomial"))
    assert isinstance(calibration.distortion, Rational)
    assert_projects_like_opencv(calibration, K_RAW, RATIONAL_D)


def test_ros_equidistant_is_read_as_kannala_brandt_not_brown_conrady(tmp_path):
    """The issue: k3, k4 of an equidistant lens landed in p1, p2 of a Brown–Conrady one."""
    D = [0.061, -0.017, 0.0029, -0.0004]
    calibration = load_calibration(ros_yaml(tmp_path / "fish.yaml", D=D, model="equidistant"))
    assert isinstance(calibration.distortion, KannalaBrandt)
    np.testing.assert_array_equal(calibration.distortion.coefficients, D)
    assert_projects_like_opencv(calibration, K_RAW, D, fisheye=True)


def test_a_principal_point_anywhere_is_accepted(tmp_path):
    K = [[800.0, 0.0, -1250.5], [0.0, 790.0, 4100.25], [0.0, 0.0, 1.0]]
    calibration = load_calibration(ros_yaml(tmp_path / "shifted.yaml", K=K))
    assert (calibration.intrinsics.cx, calibration.intrinsics.cy) == (-1250.5, 4100.25)


@pytest.mark.parametrize("suffix", [".yml", ".xml", ".json"])
@pytest.mark.parametrize(
    "lens",
    [
        BrownConrady(k1=-0.25, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.1 / 3),
        KannalaBrandt(k1=-0.013, k2=-0.0053, k3=0.0014, k4=-0.0002),
        KannalaBrandt(k1=-0.013, max_field_rad=1.2345678901234567),
        Rational(k1=2.2, k2=0.8, p1=0.0005, p2=-0.0003, k3=0.02, k4=2.6, k5=1.5, k6=0.12 / 7),
        None,
    ],
    ids=["brown-conrady", "kannala-brandt", "fisheye-field-limit", "rational", "ideal"],
)
def test_save_then_load_gives_back_the_same_doubles(tmp_path, suffix, lens):
    cam = Intrinsics(fx=554.2562584220408, fy=554.25625842204, cx=319.5 + 1 / 3, cy=239.5, width=640, height=480)
    original = Calibration(cam, lens, rms_px=0.1234567890123456789, views=17)
    path = save_calibration(tmp_path / "sub" / f"cam{suffix}", original)
    loaded = load_calibration(path)
    assert loaded == original  # dataclass equality: every double bit for bit
    raw = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # the model's name, for ROS and OpenCV readers
    named = raw.getNode("distortion_model").string()
    raw.release()
    assert named == {KannalaBrandt: "equidistant", Rational: "rational_polynomial"}.get(type(lens), "plumb_bob")


def test_an_ideal_lens_must_be_said_and_is_read_as_none(tmp_path):
    zeros = load_calibration(ros_yaml(tmp_path / "zeros.yaml", D=[0, 0, 0, 0, 0]))
    assert zeros.distortion is None and zeros.lens is None
    empty = load_calibration(ros_yaml(tmp_path / "empty.yaml", D=[], model="plumb_bob"))
    assert empty.distortion is None
    with pytest.raises(ValueError, match=r"missing\.yaml.*distortion_coefficients: missing"):
        load_calibration(ros_yaml(tmp_path / "missing.yaml", D=None, model=None))
    with pytest.raises(ValueError, match=r"distortion_coefficients: missing"):
        load_calibration(ros_yaml(tmp_path / "model_only.yaml", D=None))  # plumb_bob, but no list
    with pytest.raises(ValueError, match=r"distortion_coefficients: an empty list with no distortion_model"):
        load_calibration(ros_yaml(tmp_path / "empty_no_model.yaml", D=[], model=None))
    with pytest.raises(ValueError, match=r"0 numbers for a Kannala–Brandt"):
        load_calibration(ros_yaml(tmp_path / "empty_fisheye.yaml", D=[], model="equidistant"))


def test_realworld_still_offers_the_calibration_functions():
    assert rw.load_calibration is load_calibration and rw.save_calibration is save_calibration
    assert rw.Calibration is Calibration


# --------------------------------------------------------------------------------------------
# refusals: one per case, each naming the culprit
# --------------------------------------------------------------------------------------------


def test_an_unknown_distortion_model_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"distortion_model: 'double_sphere' is not a lens model.*plumb_bob"):
        load_calibration(ros_yaml(tmp_path / "ds.yaml", model="double_sphere"))


def test_an_equidistant_lens_needs_exactly_four_coefficients(tmp_path):
    with pytest.raises(ValueError, match=r"5 numbers for a Kannala–Brandt.*exactly 4: k1, k2, k3, k4"):
        load_calibration(ros_yaml(tmp_path / "fish5.yaml", D=[0.06, -0.017, 0.003, -0.0004, 0.0], model="equidistant"))


def test_fisheye_model_contradicting_distortion_model_is_refused(tmp_path):
    path = ros_yaml(tmp_path / "both.yaml", D=[0.06, -0.017, 0.003, -0.0004], model="plumb_bob", extra="fisheye_model: 1\n")
    with pytest.raises(ValueError, match=r"fisheye_model: 1 contradicts distortion_model 'plumb_bob'"):
        load_calibration(path)


@pytest.mark.parametrize(
    "count, index, name",
    [(12, 8, "s1"), (12, 9, "s2"), (14, 13, "tau_y")],
)
def test_coefficients_the_lab_cannot_model_must_be_exactly_zero(tmp_path, count, index, name):
    D = [-0.21, 0.043, 0.0012, -0.0007, 0.0051] + [0.0] * (count - 5)
    D[index] = 1e-9
    path = write_opencv(tmp_path / "cam.yml", {"image_width": 640, "image_height": 480,
                                               "camera_matrix": np.array(K_RAW), "distortion_coefficients": np.array(D)})
    with pytest.raises(ValueError, match=rf"distortion_coefficients: {name} = 1e-09 not zero"):
        load_calibration(path)


def test_four_coefficients_without_a_model_node_are_refused_naming_both_readings(tmp_path):
    """The issue: an OpenCV fisheye calibration (no model node) was read as Brown–Conrady."""
    D = [-0.013, -0.0053, 0.0014, -0.0002]
    nodes = {"image_width": 640, "image_height": 480, "camera_matrix": np.array(K_RAW),
             "distortion_coefficients": np.array(D).reshape(-1, 1)}
    with pytest.raises(ValueError, match=r"cam\.yml.*distortion_coefficients: 4 numbers with no distortion_model or "
                                         r"fisheye_model.*Brown–Conrady k1, k2, p1, p2.*Kannala–Brandt k1, k2, k3, k4"
                                         r".*allowed: a node saying which: distortion_model: plumb_bob"):
        load_calibration(write_opencv(tmp_path / "cam.yml", nodes))
    with pytest.raises(ValueError, match=r"4 numbers with no distortion_model"):
        load_calibration(ros_yaml(tmp_path / "no_model.yaml", D=D, model=None))
    # the node that says which settles it, each way
    pinhole = load_calibration(write_opencv(tmp_path / "pinhole.yml", {**nodes, "fisheye_model": 0}))
    assert isinstance(pinhole.distortion, BrownConrady)
    assert_projects_like_opencv(pinhole, K_RAW, D)
    fisheye = load_calibration(write_opencv(tmp_path / "fisheye.yml", {**nodes, "fisheye_model": 1}))
    assert isinstance(fisheye.distortion, KannalaBrandt)
    assert_projects_like_opencv(fisheye, K_RAW, D, fisheye=True)
    named = load_calibration(ros_yaml(tmp_path / "named.yaml", D=D, model="plumb_bob"))
    assert named.distortion == pinhole.distortion


def square_camera(f_px):
    return [[f_px, 0.0, 319.5], [0.0, f_px, 239.5], [0.0, 0.0, 1.0]]


def test_a_lens_that_folds_inside_the_image_is_refused_by_name(tmp_path):
    """k1 = -0.5 alone: d/dr [r (1 + k1 r²)] = 1 + 3 k1 r² = 0 at r² = 2/3, where the distorted
    radius peaks at r_max = √(2/3)·(1 − 1/3) = 0.5443 (by hand). A 640 × 480 image with cx, cy at its
    centre has its corner at normalised radius 400/f (the image spans −0.5 … 639.5 px): inside the
    fold for f = 740 px (0.5405), beyond it for f = 730 px (0.5479)."""
    D = [-0.5, 0.0, 0.0, 0.0, 0.0]
    inside = load_calibration(ros_yaml(tmp_path / "inside.yaml", K=square_camera(740.0), D=D))
    assert inside.distortion.radial_limit() == pytest.approx(math.sqrt(2 / 3), rel=1e-15)
    assert inside.distortion.radial_image(math.sqrt(2 / 3)) == pytest.approx(math.sqrt(2 / 3) * 2 / 3, rel=1e-15)
    with pytest.raises(ValueError, match=r"beyond\.yaml.*distortion_coefficients: the lens folds inside the image: "
                                         r"its radial map stops rising at undistorted radius 0\.816497, distorted "
                                         r"radius 0\.544331, but the image corner lies at distorted radius 0\.547945"):
        load_calibration(ros_yaml(tmp_path / "beyond.yaml", K=square_camera(730.0), D=D))
    # the file: rising everywhere in exact arithmetic, but r (1 + k1 r²) overflows long before any
    # pixel's preimage is found, so every position came out NaN
    with pytest.raises(ValueError, match=r"absurd\.yaml.*distortion_coefficients: the lens cannot be inverted over "
                                         r"the image in double precision"):
        load_calibration(ros_yaml(tmp_path / "absurd.yaml", D=[1e300, 0.0, 0.0, 0.0, 0.0]))


def test_a_rational_lens_that_folds_inside_the_image_is_refused_by_name(tmp_path):
    """k4 = 1 alone: r/(1 + r²) peaks at r = 1 with distorted radius 1/2 (by hand); the corner of a
    640 × 480 image lies at 400/f: inside for f = 810 px (0.4938), beyond for f = 790 px (0.5063)."""
    D = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    inside = load_calibration(ros_yaml(tmp_path / "inside.yaml", K=square_camera(810.0), D=D, model="rational_polynomial"))
    assert isinstance(inside.distortion, Rational)
    with pytest.raises(ValueError, match=r"distortion_coefficients: the lens folds inside the image: its radial map "
                                         r"stops rising at undistorted radius 1, distorted radius 0\.5, but the image "
                                         r"corner lies at distorted radius 0\.506329"):
        load_calibration(ros_yaml(tmp_path / "beyond.yaml", K=square_camera(790.0), D=D, model="rational_polynomial"))


def test_a_fisheye_that_folds_inside_the_image_is_refused_by_name(tmp_path):
    """k1 = -0.3 alone: dθ_d/dθ = 1 − 0.9 θ² = 0 at θ = 1.0541 rad, where θ_d = θ·(1 − 0.3 θ²) = 0.70273
    (by hand). The nearest edge of a 640 × 480 image with cy at its centre lies at 240/f: inside the
    fold for f = 345 px (0.69565), beyond it for f = 338 px (0.71006). The corners may lie beyond (a
    circular fisheye's corners are dark)."""
    D = [-0.3, 0.0, 0.0, 0.0]
    inside = load_calibration(ros_yaml(tmp_path / "inside.yaml", K=square_camera(345.0), D=D, model="equidistant"))
    assert isinstance(inside.distortion, KannalaBrandt)
    with pytest.raises(ValueError, match=r"distortion_coefficients: the fisheye's θ_d\(θ\) stops rising at 60\.4° off "
                                         r"the axis, at normalised radius 0\.702728, inside the image \(its nearest "
                                         r"edge lies at 0\.710059\)"):
        load_calibration(ros_yaml(tmp_path / "beyond.yaml", K=square_camera(338.0), D=D, model="equidistant"))


def test_a_node_given_twice_is_refused(tmp_path):
    """The issue: with two camera_matrix nodes, OpenCV's reader takes the first silently."""
    twice = ros_yaml(tmp_path / "twice.yaml")
    text = twice.read_text()
    twice.write_text(text + "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n")
    with pytest.raises(ValueError, match=r"twice\.yaml.*camera_matrix: appears twice; allowed: each node once"):
        load_calibration(twice)
    inner = tmp_path / "inner.yaml"
    inner.write_text(text.replace("  rows: 3\n", "  rows: 3\n  rows: 4\n", 1))
    with pytest.raises(ValueError, match=r"inner\.yaml.*camera_matrix/rows: appears twice"):
        load_calibration(inner)
    xml = write_opencv(tmp_path / "cam.xml", {"image_width": 640, "image_height": 480, "camera_matrix": np.array(K_RAW),
                                               "distortion_coefficients": np.zeros(5)})
    xml.write_text(xml.read_text().replace("<image_height>480</image_height>",
                                           "<image_height>480</image_height><image_height>720</image_height>"))
    with pytest.raises(ValueError, match=r"cam\.xml.*image_height: appears twice"):
        load_calibration(xml)


def test_image_sides_are_bounded(tmp_path):
    limit = MAX_IMAGE_SIDE_PX
    assert load_calibration(ros_yaml(tmp_path / "widest.yaml", size=(limit, 480))).image_size == (limit, 480)
    with pytest.raises(ValueError, match=rf"huge\.yaml.*image_width: {limit + 1} px; allowed: at most {limit} px"):
        load_calibration(ros_yaml(tmp_path / "huge.yaml", size=(limit + 1, 480)))
    with pytest.raises(ValueError, match=r"image_height: 1000000000000 px; allowed: at most"):
        load_calibration(ros_yaml(tmp_path / "absurd.yaml", size=(640, 10**12)))


def test_an_unsupported_coefficient_count_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"distortion_coefficients: 6 numbers; allowed: 4, 5, 8, 12 or 14"):
        load_calibration(ros_yaml(tmp_path / "six.yaml", D=[0.1, 0.0, 0.0, 0.0, 0.0, 0.0]))


@pytest.mark.parametrize(
    "K, culprit",
    [
        ("612.25, 0, abc, 0, 615.75, 251.125, 0, 0, 1", r"camera_matrix entry 2: 'abc' is not a number"),
        ('612.25, 0, 301.5, 0, "615.75", 251.125, 0, 0, 1', r"camera_matrix entry 4: '615.75' is not a number"),
        ("612.25, 0, 301.5, 0, .nan, 251.125, 0, 0, 1", r"camera_matrix entry 4: nan is not finite"),
        ("612.25, 0, 301.5, 0, 615.75, -.inf, 0, 0, 1", r"camera_matrix entry 5: -inf is not finite"),
    ],
    ids=["string", "quoted-number", "nan", "inf"],
)
def test_non_numeric_or_non_finite_camera_matrix_entries_are_refused(tmp_path, K, culprit):
    with pytest.raises(ValueError, match=culprit):
        load_calibration(ros_yaml(tmp_path / "bad_K.yaml", K=K))


def test_non_finite_distortion_coefficients_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"distortion_coefficients entry 1: inf is not finite"):
        load_calibration(ros_yaml(tmp_path / "bad_D.yaml", D=[-0.2, ".inf", 0, 0, 0]))


@pytest.mark.parametrize(
    "K, culprit",
    [
        ([[612.25, 0.5, 301.5], [0, 615.75, 251.125], [0, 0, 1]], r"camera_matrix: skew K\[0\]\[1\] = 0.5"),
        ([[612.25, 0, 301.5], [3.0, 615.75, 251.125], [0, 0, 1]], r"camera_matrix: K\[1\]\[0\] = 3.0"),
        ([[612.25, 0, 301.5], [0, 615.75, 251.125], [0, 0, 2]], r"camera_matrix: bottom row \(0.0, 0.0, 2.0\)"),
        ([[612.25, 0, 301.5], [0, 615.75, 251.125], [1e-3, 0, 1]], r"camera_matrix: bottom row \(0.001, 0.0, 1.0\)"),
        ([[-612.25, 0, 301.5], [0, 615.75, 251.125], [0, 0, 1]], r"camera_matrix: fx = K\[0\]\[0\] = -612.25"),
        ([[612.25, 0, 301.5], [0, 0.0, 251.125], [0, 0, 1]], r"camera_matrix: fy = K\[1\]\[1\] = 0.0"),
    ],
    ids=["skew", "lower-left", "bottom-row-scale", "bottom-row-entry", "fx", "fy"],
)
def test_camera_matrices_the_pinhole_model_cannot_hold_are_refused(tmp_path, K, culprit):
    with pytest.raises(ValueError, match=culprit):
        load_calibration(ros_yaml(tmp_path / "bad_K.yaml", K=K))


def test_a_camera_matrix_that_is_not_3x3_is_refused(tmp_path):
    path = write_opencv(tmp_path / "cam.yml", {"image_width": 640, "image_height": 480,
                                               "camera_matrix": np.array(K_RAW)[:2],
                                               "distortion_coefficients": np.zeros(5)})
    with pytest.raises(ValueError, match=r"camera_matrix: 2 x 3; allowed: 3 x 3"):
        load_calibration(path)
    mismatch = ros_yaml(tmp_path / "mismatch.yaml").read_text().replace("  data: [-0.21", "  data: [9.0, -0.21", 1)
    (tmp_path / "mismatch.yaml").write_text(mismatch)  # cols: 5 but 6 numbers
    with pytest.raises(ValueError, match=r"distortion_coefficients: rows x cols = 1 x 5 but data holds 6 numbers"):
        load_calibration(tmp_path / "mismatch.yaml")


@pytest.mark.parametrize(
    "width, culprit",
    [("640.5", r"image_width: 640.5 is not an integer"), ("-640", r"image_width: -640"),
     ('"640"', r"image_width: '640' is not a number"), ("0", r"image_width: 0")],
)
def test_image_sizes_that_are_not_positive_integers_are_refused(tmp_path, width, culprit):
    path = ros_yaml(tmp_path / "size.yaml")
    path.write_text(path.read_text().replace("image_width: 640", f"image_width: {width}"))
    with pytest.raises(ValueError, match=culprit):
        load_calibration(path)


def test_a_huge_lens_coefficient_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"distortion_coefficients: lens coefficient k3 = 1e\+308 is too large"):
        load_calibration(ros_yaml(tmp_path / "huge.yaml", D=[0.1, 0.0, 0.0, 0.0, 1e308]))


def test_unreadable_or_missing_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_calibration(tmp_path / "nope.yaml")
    no_matrix = tmp_path / "no_matrix.yaml"
    no_matrix.write_text("image_width: 640\nimage_height: 480\ndistortion_coefficients: [0, 0, 0, 0, 0]\n")
    with pytest.raises(ValueError, match=r"no_matrix\.yaml.*camera_matrix: missing"):
        load_calibration(no_matrix)
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("::: [ not yaml {{\n")
    with pytest.raises(ValueError, match="garbage.yaml"):
        load_calibration(garbage)


def test_the_sample_calibration_is_the_study_camera():
    sample = load_calibration(Path(__file__).parents[1] / "data" / "calibration" / "sample_640x480.yml")
    assert sample.intrinsics == Intrinsics.default()
    assert sample.distortion == BrownConrady.default()
