"""Detector speed at 640 × 480 on one core, against the bare OpenCV calls each one wraps.

Run: ``python benchmarks/bench_detection.py [--repeats N]``. Frames come from the scene renderer
(sphere and ArUco targets at 3 m, pinhole and with the study's distortion). Each line prints the
median time per frame, frames per second, and the ratio wrapper / bare OpenCV measured in the
same run. Targets (docs/design.md): sphere ≥ 1000 frames/s, ArUco ≥ 300 frames/s.
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import cv2
import numpy as np

from gimbal_lab.camera import BrownConrady, Intrinsics
from gimbal_lab.detection import (
    ArucoTracker,
    Rectifier,
    SphereDetector,
    locate_sphere_circle,
    locate_sphere_ellipse,
)
from gimbal_lab.scene import SceneRenderer

T_WORLD_CAM = np.array([[0.0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 2], [0, 0, 0, 1]])
R_WORLD_MARKER = np.array([[0.0, 0, -1], [-1, 0, 0], [0, 1, 0]])


def median_time_s(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls in batches (after one warm-up)."""
    fn()
    batch = 20
    times = []
    for _ in range(max(1, repeats // batch)):
        start = time.perf_counter()
        for _ in range(batch):
            fn()
        times.append((time.perf_counter() - start) / batch)
    return float(np.median(times))


def frames(intrinsics, distortion):
    T_sphere = np.eye(4)
    T_sphere[:3, 3] = (3.0, 0.2, 2.1)
    T_marker = np.eye(4)
    T_marker[:3, :3] = R_WORLD_MARKER
    T_marker[:3, 3] = (3.0, 0.2, 2.1)
    with SceneRenderer(intrinsics, distortion=distortion, target="sphere") as scene:
        sphere = scene.render(T_WORLD_CAM, T_sphere)
    with SceneRenderer(intrinsics, distortion=distortion, target="aruco") as scene:
        marker = scene.render(T_WORLD_CAM, T_marker)
    return sphere, marker


def main(repeats: int = 1000) -> None:
    cv2.setNumThreads(1)
    cam, lens = Intrinsics.default(), BrownConrady.default()
    sphere, marker = frames(cam, None)
    sphere_d, marker_d = frames(cam, lens)

    detector = SphereDetector()
    lower = [np.array(v, np.uint8) for v in detector.hsv_lower]
    upper = [np.array(v, np.uint8) for v in detector.hsv_upper]

    def bare_sphere(img=sphere):
        hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV)
        mask = cv2.inRange(hsv, lower[0], upper[0]) | cv2.inRange(hsv, lower[1], upper[1])
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        return cv2.minEnclosingCircle(max(contours, key=cv2.contourArea))

    det = detector.detect(sphere)
    aruco_params = cv2.aruco.DetectorParameters()
    bare_aruco_detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), aruco_params)
    tracker = ArucoTracker(cam)
    tracker_subpix = ArucoTracker(cam, refinement="subpix")
    subpix_params = cv2.aruco.DetectorParameters()
    subpix_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    bare_subpix = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), subpix_params)

    def bare_aruco(img=marker, detector=bare_aruco_detector):
        corners, ids, _ = detector.detectMarkers(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
        return [
            cv2.solvePnP(tracker.object_points_m, c.reshape(4, 2), cam.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            for c in corners
        ]

    rectifier = Rectifier(cam, lens)
    map1, map2 = cv2.initUndistortRectifyMap(cam.K, lens.coefficients, None, cam.K, cam.size, cv2.CV_16SC2)
    rect_detector = SphereDetector(rectifier=rectifier)

    rows = [
        ("sphere detect", lambda: detector.detect(sphere), bare_sphere),
        ("sphere detect + circle", lambda: locate_sphere_circle(detector.detect(sphere), cam, 0.1), bare_sphere),
        ("sphere detect + ellipse", lambda: locate_sphere_ellipse(detector.detect(sphere), cam, 0.1), bare_sphere),
        (
            "sphere detect + ellipse (lens)",
            lambda: locate_sphere_ellipse(detector.detect(sphere_d), cam, 0.1, lens),
            lambda: bare_sphere(sphere_d),
        ),
        ("sphere rectify + detect", lambda: rect_detector.detect(sphere_d), lambda: bare_sphere(sphere_d)),
        ("ellipse localisation alone", lambda: locate_sphere_ellipse(det, cam, 0.1), lambda: cv2.fitEllipse(det.contour_px.astype(np.float32))),
        ("aruco detect + pose (none)", lambda: tracker.detect(marker), bare_aruco),
        ("aruco detect + pose (subpix)", lambda: tracker_subpix.detect(marker), lambda: bare_aruco(detector=bare_subpix)),
        ("rectify 640x480", lambda: rectifier.rectify(sphere_d), lambda: cv2.remap(sphere_d, map1, map2, cv2.INTER_LINEAR)),
    ]
    print(f"OpenCV {cv2.__version__}, threads = {cv2.getNumThreads()}, {repeats} calls per row (median of batches)")
    print(f"{'step':34s} {'ms/frame':>9s} {'frames/s':>9s} {'bare ms':>9s} {'ratio':>6s}")
    for name, ours, bare in rows:
        t_ours, t_bare = median_time_s(ours, repeats), median_time_s(bare, repeats)
        print(f"{name:34s} {t_ours * 1e3:9.3f} {1 / t_ours:9.0f} {t_bare * 1e3:9.3f} {t_ours / t_bare:6.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1000)
    main(parser.parse_args().repeats)
