"""ArUco recall, corner accuracy and speed: the project's tracker against OpenCV's default detector.

Run::

    python benchmarks/bench_real_aruco.py [--real DIR] [--seeds 10] [--dictionaries DICT_4X4_50,DICT_6X6_250]
                                          [--repeats 10]

Four detectors see the same grey frames:

* ``gimbal_lab`` -- ``ArucoTracker.detect_corners`` with the tracker's defaults (threshold
  windows 3 and 13 px, a 4x pyramid whose finds are refined on the full frame, sub-pixel
  corners);
* ``gimbal_lab 1-level`` -- the same without the pyramid (``pyramid_factor=1``), to show what
  the pyramid adds and what it costs;
* ``OpenCV`` -- ``cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())``
  (windows 3, 13 and 23 px, no corner refinement), the reference of the speed ratios;
* ``OpenCV+subpix`` -- the same with ``CORNER_REFINE_SUBPIX``.

Two kinds of data:

1. **Real photographs** (``--real DIR``, else ``$GIMBAL_LAB_REAL_ARUCO``; skipped when neither
   is given). The folder is the public test set described in its SOURCES.md; nothing from it is
   copied into the repository. Truth ids: on the ChArUco board photos (5 x 7 squares of 4 cm,
   2 cm markers, DICT_6X6_250) every board marker whose printed code can be read back (at most
   12 of its 8 x 8 cells wrong) where the board geometry puts it, so markers hidden by an object
   do not count; on ``markerNN_*.png`` the id NN (DICT_5X5_100); on
   ``singlemarkersoriginal.jpg`` its six markers (DICT_6X6_250; the photo shows exactly six,
   ids as every detector reads them). Corner truth exists only for the board photos: OpenCV's
   ChArUco detector gives the chessboard corners (sub-pixel saddle points), they are undistorted
   with the published calibration (``tutorial_camera_charuco.yml``), a homography from the
   board plane is fitted to them, and each marker's four corners are predicted from the board
   geometry. Detected corners are undistorted the same way before comparison. The fit residual,
   with and without the undistortion, is printed so the quality of this truth can be judged.
   Without corner truth (single markers), a marker's side is the median of the detectors' sides.
2. **Rendered photo-like markers** with exact truth: ``realworld.PlanarTargetCamera`` (pinhole,
   3x3 supersampling) images one printed marker (random id) at sides from 15 to 400 px, random
   tilt (up to 55 deg), roll and position, in front of a busy background (shading, texture,
   random shapes, text-like marks); ``realworld.PhotoEffects`` adds paper/ink levels, uneven
   light, vignetting, Gaussian defocus (sigma 0.3-1 px, or up to 1.2 % of the side for large,
   close markers), sensor noise and JPEG (quality 30-90). Truth corners are
   ``PlanarTargetCamera.corners_px``. Each frame depends only on (dictionary, size, seed).

Printed: recall per marker side bin (side = square root of the marker's image area) per
detector, false detections (a detection matching no present marker), corner error (median and
95th percentile, px) over the markers every detector found, the mean size bias (detected
side / true side - 1; a range from these corners is wrong by about the same fraction, with the
opposite sign), the markers one detector finds and another misses, and the median time per
640 x 480 frame with ``cv2.setNumThreads(1)``, per data set and dictionary (all detectors are
timed from a grey frame to corners; the tracker's pose step is not included).
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import time
from pathlib import Path

import cv2
import numpy as np

from gimbal_lab import realworld as rw
from gimbal_lab.camera import Intrinsics
from gimbal_lab.detection import ArucoTracker

DETECTORS = ("gimbal_lab", "gimbal_lab 1-level", "OpenCV", "OpenCV+subpix")
REFERENCE = "OpenCV"
BIN_EDGES = (0.0, 25.0, 50.0, 100.0, 300.0, math.inf)
BIN_LABELS = ("<25", "25-50", "50-100", "100-300", ">300")
SIZES_PX = (15, 18, 21, 24, 28, 34, 40, 47, 55, 65, 80, 95, 120, 160, 220, 280, 320, 360, 400)
MARKER_M = 0.15

BOARD_FILES = ("img_00.jpg", "img_01.jpg", "img_02.jpg", "img_03.jpg", "chocclusion_original.jpg")
BOARD_SQUARES, BOARD_SQUARE_M, BOARD_MARKER_M = (5, 7), 0.04, 0.02
BOARD_CALIBRATION = "tutorial_camera_charuco.yml"
SINGLE_FILE, SINGLE_IDS = "singlemarkersoriginal.jpg", (23, 40, 62, 98, 124, 203)
# a board marker counts as present when at most this many of its 8 x 8 cells read wrong
# (visible markers: 0-7 on the test photos; markers under an object: 24 or more)
MAX_WRONG_CELLS = 12


# --------------------------------------------------------------------------------------------
# detectors
# --------------------------------------------------------------------------------------------


def make_detectors(dictionary: str) -> dict:
    """The detectors for one dictionary: name -> f(gray) -> [(id, corners (4, 2)), ...]."""
    aruco_dict = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    tracker = ArucoTracker(Intrinsics.default(), dictionary=dictionary)
    single_level = ArucoTracker(Intrinsics.default(), dictionary=dictionary, pyramid_factor=1)
    subpix = cv2.aruco.DetectorParameters()
    subpix.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX

    def opencv(detector):
        def detect(gray):
            corners, ids, _ = detector.detectMarkers(gray)
            if ids is None:
                return []
            return [(int(i), q.reshape(4, 2).astype(float)) for q, i in zip(corners, ids.reshape(-1))]

        return detect

    return {
        "gimbal_lab": tracker.detect_corners,
        "gimbal_lab 1-level": single_level.detect_corners,
        "OpenCV": opencv(cv2.aruco.ArucoDetector(aruco_dict, cv2.aruco.DetectorParameters())),
        "OpenCV+subpix": opencv(cv2.aruco.ArucoDetector(aruco_dict, subpix)),
    }


def side_px(quad) -> float:
    return math.sqrt(abs(cv2.contourArea(np.asarray(quad, np.float32))))


def size_bin(side: float) -> int:
    for k in range(len(BIN_LABELS)):
        if BIN_EDGES[k] <= side < BIN_EDGES[k + 1]:
            return k
    return len(BIN_LABELS) - 1


def match(truths, detections):
    """Pair truth markers with detections of the same id (nearest centre, within half a side).

    ``truths``: list of (id, truth quad or None); a None quad matches any detection of that id.
    Returns (list with the matched detection quad or None per truth, count of unmatched detections).
    """
    free = list(detections)
    matched = []
    for marker_id, quad in truths:
        candidates = [k for k, (i, _) in enumerate(free) if i == marker_id]
        if quad is not None:
            centre, reach = np.mean(quad, axis=0), 0.5 * side_px(quad) + 2.0
            candidates = [k for k in candidates if np.linalg.norm(free[k][1].mean(axis=0) - centre) < reach]
            candidates.sort(key=lambda k: np.linalg.norm(free[k][1].mean(axis=0) - centre))
        matched.append(free.pop(candidates[0])[1] if candidates else None)
    return matched, len(free)


def new_record(source, name, marker_id, truth_quad, side):
    return {"source": source, "file": name, "id": marker_id, "truth": truth_quad, "side": side, "found": {}}


# --------------------------------------------------------------------------------------------
# real photographs
# --------------------------------------------------------------------------------------------


def read_calibration(path: Path):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K = storage.getNode("camera_matrix").mat()
    dist = storage.getNode("distortion_coefficients").mat()
    storage.release()
    if K is None or dist is None:
        raise ValueError(f"{path}: no camera_matrix / distortion_coefficients")
    return K.astype(float), dist.reshape(-1).astype(float)


def undistort_px(points, K, dist):
    """Distorted pixels -> pixels of the pinhole camera with the same K (iterated to 1e-10)."""
    pts = np.asarray(points, np.float64).reshape(-1, 1, 2)
    if dist is None:
        return pts.reshape(-1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    return cv2.undistortPoints(pts, K, dist, R=None, P=K, criteria=criteria).reshape(-1, 2)


def distort_px(points, K, dist):
    """Pinhole pixels -> distorted pixels (inverse of :func:`undistort_px`)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if dist is None:
        return pts
    normalised = np.column_stack(((pts[:, 0] - K[0, 2]) / K[0, 0], (pts[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pts))))
    return cv2.projectPoints(normalised, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)


def wrong_cells(gray, quad_raw, aruco_dict, marker_id, cell_px=10):
    """How many cells (border included) of the marker at ``quad_raw`` differ from ``marker_id``'s code."""
    cells = aruco_dict.markerSize + 2
    side = cells * cell_px
    target = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32) - 0.5
    warp = cv2.getPerspectiveTransform(np.asarray(quad_raw, np.float32), target)
    patch = cv2.warpPerspective(gray, warp, (side, side), flags=cv2.INTER_LINEAR).astype(float)
    inner = slice(cell_px // 4, cell_px - cell_px // 4)
    means = patch.reshape(cells, cell_px, cells, cell_px)[:, inner, :, inner].mean(axis=(1, 3))
    levels = np.clip(means, 0, 255).astype(np.uint8).reshape(-1, 1)
    threshold, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    code = cv2.aruco.generateImageMarker(aruco_dict, int(marker_id), cells) > 127
    return int(np.sum((means > threshold) != code))


def board_truth(gray, board, K, dist):
    """Predicted corners of every board marker from the interpolated chessboard corners.

    Returns (dict id -> (undistorted quad, raw quad), fit summary) or None when fewer than 8
    chessboard corners are found.
    """
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None or len(ids) < 8:
        return None
    plane = board.getChessboardCorners()[ids.reshape(-1)][:, :2].astype(np.float64)
    fits = {}
    for label, coefficients in (("undistorted", dist), ("raw", None)):
        image = undistort_px(corners, K, coefficients)
        H, _ = cv2.findHomography(plane, image, 0)
        residual = np.linalg.norm(cv2.perspectiveTransform(plane.reshape(-1, 1, 2), H).reshape(-1, 2) - image, axis=1)
        fits[label] = (H, float(np.sqrt(np.mean(residual**2))), float(residual.max()))
    H = fits["undistorted"][0]
    predicted = {}
    for marker_id, object_points in zip(board.getIds().reshape(-1), board.getObjPoints()):
        quad = cv2.perspectiveTransform(np.asarray(object_points, np.float64)[:, :2].reshape(-1, 1, 2), H).reshape(4, 2)
        predicted[int(marker_id)] = (quad, distort_px(quad, K, dist))
    summary = {
        "corners": len(ids),
        "rms": fits["undistorted"][1],
        "max": fits["undistorted"][2],
        "rms_raw": fits["raw"][1],
        "max_raw": fits["raw"][2],
    }
    return predicted, summary


def real_records(folder: Path):
    """Records for every truth marker of the real photographs, plus false-detection counts."""
    records, false, fits, frames = [], {name: 0 for name in DETECTORS}, [], []
    detectors = {name: make_detectors(name) for name in ("DICT_6X6_250", "DICT_5X5_100")}

    calibration = folder / BOARD_CALIBRATION
    if calibration.is_file():
        K, dist = read_calibration(calibration)
    else:
        print(f"  ({calibration.name} not found: board photos are taken as distortion-free)")
        K, dist = None, None
    dict6 = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    board = cv2.aruco.CharucoBoard(BOARD_SQUARES, BOARD_SQUARE_M, BOARD_MARKER_M, dict6)

    jobs = [(name, "DICT_6X6_250", "board") for name in BOARD_FILES]
    jobs.append((SINGLE_FILE, "DICT_6X6_250", "single"))
    jobs += [(p.name, "DICT_5X5_100", "nn") for p in sorted(folder.glob("marker*_*x*.png"))]
    for name, dictionary, kind in jobs:
        path = folder / name
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            print(f"  ({name}: missing or unreadable, skipped)")
            continue
        if image.shape == (480, 640):
            frames.append((dictionary, image))
        found = {det: fn(image) for det, fn in detectors[dictionary].items()}
        if kind == "board":
            if K is None:
                h, w = image.shape
                K = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1.0]])
            truth = board_truth(image, board, K, dist)
            if truth is None:
                print(f"  ({name}: ChArUco board not found, skipped)")
                continue
            predicted, summary = truth
            present = {i: q for i, q in predicted.items() if wrong_cells(image, q[1], dict6, i) <= MAX_WRONG_CELLS}
            summary.update(file=name, present=len(present), board=len(predicted))
            fits.append(summary)
            truths = [(i, q[1]) for i, q in sorted(present.items())]
            new = [new_record("real", name, i, q[0], side_px(q[0])) for i, q in sorted(present.items())]
        elif kind == "single":
            truths = [(i, None) for i in SINGLE_IDS]
            new = [new_record("real", name, i, None, math.nan) for i in SINGLE_IDS]
        else:
            marker_id = int(name[len("marker") :].split("_")[0])
            truths = [(marker_id, None)]
            new = [new_record("real", name, marker_id, None, math.nan)]
        for det, detections in found.items():
            quads, n_false = match(truths, detections)
            false[det] += n_false
            for record, quad in zip(new, quads):
                if quad is None:
                    record["found"][det] = None
                elif record["truth"] is not None:  # compare in undistorted pixels
                    record["found"][det] = undistort_px(quad, K, dist)
                else:
                    record["found"][det] = quad
        for record in new:  # no corner truth: the side is the median of the detectors' sides
            if math.isnan(record["side"]):
                sides = [side_px(q) for q in record["found"].values() if q is not None]
                record["side"] = float(np.median(sides)) if sides else math.nan
        records += new
    return records, false, fits, frames


# --------------------------------------------------------------------------------------------
# rendered photo-like markers
# --------------------------------------------------------------------------------------------


def rotation_z_to(direction):
    """Rotation taking the optical axis (0, 0, 1) onto ``direction``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    axis = np.cross([0.0, 0.0, 1.0], d)
    s, c = np.linalg.norm(axis), d[2]
    if s < 1e-12:
        return np.eye(3)
    return cv2.Rodrigues(axis / s * math.atan2(s, c))[0]


def random_view(camera, target_side_px, centre_m, rng, cell_px_image):
    """A pose showing the marker about ``target_side_px`` across, wholly inside the frame."""
    cam = camera.intrinsics
    half = MARKER_M / 2
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]]) + centre_m[:2]
    margin = max(4.0, 0.5 * cell_px_image)
    low, high = np.array([margin, margin]), np.array(cam.size, float) - 1 - margin
    for attempt in range(200):
        tilt = rng.uniform(0, math.radians(55)) if attempt < 150 else 0.0
        azimuth, roll = rng.uniform(0, 2 * math.pi), rng.uniform(-math.pi, math.pi)
        if attempt >= 100:  # large markers fit only when nearly upright
            roll = rng.normal(0, 0.05) + rng.integers(4) * math.pi / 2
        distance = cam.fx * MARKER_M * math.sqrt(math.cos(tilt)) / target_side_px
        direction = (math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), -math.cos(tilt))
        eye = centre_m + distance * np.array(direction)
        T = rw.look_at_pose(eye, centre_m, up=(math.sin(roll), -math.cos(roll), 0.0))
        corners = camera.corners_px(square, T)
        extent = corners.max(axis=0) - corners.min(axis=0)
        room = (high - low - extent) / 2
        if np.any(room < 0):
            continue
        mid = (low + high) / 2
        for shrink in (1.0, 0.5, 0.25, 0.0):
            pixel = mid + shrink * rng.uniform(-room, room)
            ray = np.array([(pixel[0] - cam.cx) / cam.fx, (pixel[1] - cam.cy) / cam.fy, 1.0])
            T_view = np.eye(4)
            T_view[:3, :3] = rotation_z_to(ray)
            T_shift = T_view @ T
            shifted = camera.corners_px(square, T_shift)
            if np.all(shifted >= low) and np.all(shifted <= high):
                return T_shift, shifted
    raise RuntimeError(f"no view fits a {target_side_px}-px marker in the frame")


def clutter_background(rng, size) -> np.ndarray:
    """A busy reflectance image (H, W): smooth shading, fine texture and random dark and light shapes.

    It gives the detectors what a real scene gives them: many contours, some of them
    quadrilateral, to be rejected (a real photo of a desk still gives more, see the timings).
    """
    width, height = size
    coarse = rng.uniform(-1, 1, (6, 8)).astype(np.float32)
    image = rng.uniform(0.35, 0.65) + 0.15 * cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    image += cv2.GaussianBlur(rng.normal(0, 0.04, (height, width)).astype(np.float32), (0, 0), 1.0)
    for _ in range(int(rng.integers(15, 30))):
        value = float(rng.choice([rng.uniform(0.0, 0.15), rng.uniform(0.8, 1.0), rng.uniform(0.2, 0.7)]))
        centre = rng.uniform((0, 0), (width, height))
        extent = rng.uniform(4, 80)
        shape = int(rng.integers(3))
        if shape == 0:  # a quadrilateral, roughly square
            corners = centre + extent * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
            corners += rng.normal(0, 0.25 * extent, (4, 2))
            cv2.fillConvexPoly(image, np.round(corners).astype(np.int32), value)
        elif shape == 1:
            axes = (int(extent), int(extent * rng.uniform(0.3, 1.0)))
            cv2.ellipse(image, tuple(int(c) for c in centre), axes, rng.uniform(0, 180), 0, 360, value, -1)
        else:
            end = centre + rng.normal(0, 2 * extent, 2)
            thickness = int(rng.integers(1, 6))
            cv2.line(image, tuple(int(c) for c in centre), tuple(int(c) for c in end), value, thickness)
    for _ in range(int(rng.integers(1, 4))):  # blocks of small dark marks, like printed text
        x0, y0 = rng.uniform((0, 0), (width - 60, height - 40))
        glyph = rng.uniform(3, 9)
        for row in range(int(rng.integers(2, 7))):
            for col in range(int(rng.integers(5, 20))):
                if rng.random() < 0.8:
                    x, y = x0 + col * glyph * 1.3, y0 + row * glyph * 1.8
                    w, h = glyph * rng.uniform(0.4, 1.0), glyph * rng.uniform(0.6, 1.0)
                    cv2.rectangle(image, (int(x), int(y)), (int(x + w), int(y + h)), rng.uniform(0.0, 0.2), -1)
    return np.clip(image, 0.0, 1.0)


def render_view(camera, dictionary: str, size: int, seed: int):
    """One photo-like frame of a random marker about ``size`` px across.

    Returns (grey frame, marker id, true corners (4, 2) px, the PhotoEffects used). The
    frame depends only on (dictionary, size, seed).
    """
    aruco_dict = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n_ids = len(aruco_dict.bytesList)
    rng = np.random.default_rng([seed, size, n_ids])
    marker_id = int(rng.integers(n_ids))
    texture, marker_px = rw.printed_marker_texture(dictionary, marker_id, cell_px=60, margin_cells=1.0)
    px_per_m = marker_px / MARKER_M
    margin = (texture.shape[0] - marker_px) / 2
    centre = np.array([(margin + marker_px / 2) / px_per_m] * 2 + [0.0])
    T, truth = random_view(camera, size, centre, rng, size / (aruco_dict.markerSize + 2))
    effects = rw.PhotoEffects(
        paper=rng.uniform(0.55, 0.85),
        ink=rng.uniform(0.02, 0.08),
        uneven_light=rng.uniform(0.1, 0.5),
        vignetting=rng.uniform(0.1, 0.5),
        defocus_px=max(rng.uniform(0.3, 1.0), size * rng.uniform(0.0, 0.012)),
        noise_std=rng.uniform(1.0, 5.0),
        jpeg_quality=int(rng.integers(30, 91)),
    )
    background = clutter_background(rng, camera.intrinsics.size)
    reflectance = camera.render(texture, px_per_m, T, background=background)
    gray = cv2.cvtColor(effects.apply(reflectance, rng), cv2.COLOR_RGB2GRAY)
    return gray, marker_id, truth, effects


def rendered_records(dictionaries, seeds: int):
    camera = rw.PlanarTargetCamera(Intrinsics.default(), None, supersample=3)
    records, false, frames = [], {name: 0 for name in DETECTORS}, []
    for dictionary in dictionaries:
        detectors = make_detectors(dictionary)
        for size in SIZES_PX:
            for seed in range(seeds):
                gray, marker_id, truth, _ = render_view(camera, dictionary, size, seed)
                frames.append((dictionary, gray))
                record = new_record("rendered", f"{dictionary} {size}px seed {seed}", marker_id, truth, side_px(truth))
                for det, fn in detectors.items():
                    quads, n_false = match([(marker_id, truth)], fn(gray))
                    record["found"][det] = quads[0]
                    false[det] += n_false
                records.append(record)
    return records, false, frames


# --------------------------------------------------------------------------------------------
# speed
# --------------------------------------------------------------------------------------------


def speed_ms(frames, repeats: int) -> dict[str, float]:
    """Median over frames of each detector's median ms per call; detectors take turns per frame."""
    detectors = {d: make_detectors(d) for d in {d for d, _ in frames}}
    per_frame = {name: [] for name in DETECTORS}
    for dictionary, gray in frames:
        times = {name: [] for name in DETECTORS}
        for name in DETECTORS:
            detectors[dictionary][name](gray)  # warm-up
        for _ in range(repeats):
            for name in DETECTORS:
                start = time.perf_counter()
                detectors[dictionary][name](gray)
                times[name].append(time.perf_counter() - start)
        for name in DETECTORS:
            per_frame[name].append(np.median(times[name]) * 1e3)
    return {name: float(np.median(v)) for name, v in per_frame.items()}


# --------------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------------


def rows_by_size(records, with_unknown=False):
    """(label, records) per marker-size bin that has any, then markers of unknown size (if asked),
    then all of them."""
    rows = [(label, [r for r in records if size_bin(r["side"]) == k]) for k, label in enumerate(BIN_LABELS)]
    if with_unknown:
        rows.append(("unknown", [r for r in records if math.isnan(r["side"])]))
    rows.append(("all", records))
    return [(label, subset) for label, subset in rows if subset]


def print_recall(records, false):
    print(f"  {'side px':9s} {'markers':>7s}" + "".join(f" {name:>18s}" for name in DETECTORS))
    for label, subset in rows_by_size(records, with_unknown=True):
        cells = ""
        for name in DETECTORS:
            hits = sum(r["found"][name] is not None for r in subset)
            cells += f" {f'{hits}/{len(subset)} {100 * hits / len(subset):5.1f}%':>18s}"
        print(f"  {label:9s} {len(subset):7d}" + cells)
    print(f"  {'false detections':17s}" + "".join(f" {false[name]:18d}" for name in DETECTORS))


def print_corner_errors(records):
    with_truth = [r for r in records if r["truth"] is not None]
    common = [r for r in with_truth if all(r["found"][name] is not None for name in DETECTORS)]
    print(f"  {'side px':9s} {'markers':>7s}" + "".join(f" {name + ' med/p95':>22s}" for name in DETECTORS))
    for label, subset in rows_by_size(common):
        cells = ""
        for name in DETECTORS:
            errors = np.concatenate([np.linalg.norm(r["found"][name] - r["truth"], axis=1) for r in subset])
            cells += f" {f'{np.median(errors):.2f} / {np.percentile(errors, 95):.2f}':>22s}"
        print(f"  {label:9s} {len(subset):7d}" + cells)
    if common:
        cells = ""
        for name in DETECTORS:
            bias = [side_px(r["found"][name]) / side_px(r["truth"]) - 1 for r in common]
            cells += f" {f'{100 * np.mean(bias):+.1f} %':>22s}"
        print(f"  {'size bias':17s}" + cells)
    missing = len(with_truth) - len(common)
    if missing:
        print(f"  ({missing} of {len(with_truth)} markers with corner truth were missed by at least one detector;"
              " not in this table)")


def print_disagreements(records):
    pairs = [("gimbal_lab", other) for other in (REFERENCE, "OpenCV+subpix", "gimbal_lab 1-level")]
    for a, b in [p for pair in pairs for p in (pair, pair[::-1])]:
        lost = [r for r in records if r["found"][b] is not None and r["found"][a] is None]
        if not lost:
            print(f"  found by {b}, missed by {a}: none")
            continue
        print(f"  found by {b}, missed by {a}: {len(lost)}")
        for r in lost:
            print(f"    {r['file']:32s} id {r['id']:4d}  side {r['side']:6.1f} px")


def main(real_dir: str | None, seeds: int, dictionaries: list[str], repeats: int) -> None:
    cv2.setNumThreads(1)
    started = time.perf_counter()
    print(f"OpenCV {cv2.__version__}, threads = {cv2.getNumThreads()}")
    print("detectors: gimbal_lab = ArucoTracker defaults (windows 3/13 px, 4x pyramid, subpix); gimbal_lab 1-level = "
          "the same without the pyramid (pyramid_factor=1);\n           OpenCV = DetectorParameters() defaults "
          "(windows 3/13/23 px); OpenCV+subpix = the same + CORNER_REFINE_SUBPIX")
    timing_frames = []

    print("\n== Real photographs ==")
    if real_dir is None:
        print("  skipped: give --real DIR or set GIMBAL_LAB_REAL_ARUCO to the folder of real photos")
    elif not Path(real_dir).is_dir():
        print(f"  skipped: {real_dir} is not a folder")
    else:
        records, false, fits, frames = real_records(Path(real_dir))
        timing_frames += [("real", d, g) for d, g in frames]
        if fits:
            print("  corner truth of the ChArUco photos: homography board plane -> chessboard corners")
            print(f"  {'file':26s} {'corners':>7s} {'present':>8s} {'fit rms px':>10s} {'fit max px':>10s}"
                  f" {'no undistortion: rms / max':>27s}")
            for f in fits:
                raw = f"{f['rms_raw']:.3f} / {f['max_raw']:.3f}"
                print(f"  {f['file']:26s} {f['corners']:7d} {f['present']:4d}/{f['board']:<3d}"
                      f" {f['rms']:10.3f} {f['max']:10.3f} {raw:>27s}")
        print("\n  recall per marker side (found / present)")
        print_recall(records, false)
        print("\n  corner error, px (ChArUco photos, undistorted pixels; markers found by every detector)")
        print_corner_errors(records)
        print()
        print_disagreements(records)

    print(f"\n== Rendered photo-like markers ({', '.join(dictionaries)}; {len(SIZES_PX)} sizes x {seeds} seeds) ==")
    records, false, frames = rendered_records(dictionaries, seeds)
    timing_frames += [("rendered", d, g) for d, g in frames]
    print("  recall per marker side (found / rendered)")
    print_recall(records, false)
    for dictionary in dictionaries:
        subset = [r for r in records if r["file"].startswith(dictionary)]
        print(f"\n  recall, {dictionary} only")
        print_recall(subset, {name: 0 for name in DETECTORS})
    print("\n  corner error, px (vs PlanarTargetCamera.corners_px; markers found by every detector)")
    print_corner_errors(records)
    print()
    print_disagreements(records)

    print(f"\n== Speed: median ms per 640 x 480 grey frame, {repeats} calls per frame, one thread ==")
    print(f"  {'frames':34s}" + "".join(f" {name:>20s}" for name in DETECTORS))
    for kind in ("real", "rendered"):
        for dictionary in sorted({d for k, d, _ in timing_frames if k == kind}):
            subset = [g for k, d, g in timing_frames if k == kind and d == dictionary]
            if kind == "rendered":
                subset = subset[:: max(1, len(subset) // 20)]  # about 20 frames spread over all sizes
            ms = speed_ms([(dictionary, g) for g in subset], repeats)
            cells = "".join(f" {f'{ms[name]:.2f} ms ({ms[name] / ms[REFERENCE]:.2f}x)':>20s}" for name in DETECTORS)
            print(f"  {f'{kind} {dictionary} ({len(subset)} frames)':34s}" + cells)
    print("  (x: ratio to OpenCV's default detector in this run)")
    print(f"\ntotal {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", default=os.environ.get("GIMBAL_LAB_REAL_ARUCO"),
                        help="folder of the real photographs (default: $GIMBAL_LAB_REAL_ARUCO; none: skip)")
    parser.add_argument("--seeds", type=int, default=10, help="rendered views per size and dictionary")
    parser.add_argument("--dictionaries", default="DICT_4X4_50,DICT_6X6_250",
                        help="comma-separated dictionaries for the rendered markers")
    parser.add_argument("--repeats", type=int, default=10, help="timed calls per frame and detector")
    args = parser.parse_args()
    main(args.real, args.seeds, [d.strip() for d in args.dictionaries.split(",") if d.strip()], args.repeats)
