"""Static accuracy sweeps of the detectors: analytic silhouettes and rendered frames.

Each sweep places the target at known poses (no closed loop), runs a detector and localiser and
returns a tidy table of signed errors. Notebooks 04 and 05 plot them; the closed-loop study lives
in :mod:`gimbal_lab.simulation` and :mod:`gimbal_lab.studies`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .camera import BrownConrady, Intrinsics
from .detection import (
    SphereDetection,
    SphereDetector,
    locate_sphere_circle,
    locate_sphere_ellipse,
    sphere_silhouette_px,
)

__all__ = ["analytic_sphere_errors", "rendered_sphere_errors", "rendered_marker_errors", "pointing_error_deg"]




def _range_error_m(estimate, truth) -> float:
    return float("nan") if estimate is None else float(np.linalg.norm(estimate) - np.linalg.norm(truth))


def analytic_sphere_errors(centers_cam_m, radius_m: float, intrinsics: Intrinsics, distortion: BrownConrady | None = None):
    """Circle and exact methods on noise-free silhouettes (no pixels): the geometric error alone.

    For each centre, the silhouette from :func:`sphere_silhouette_px` (through the lens when
    given) is localised by the circle method (pinhole assumed, as published), the exact method
    ignoring the lens, and the exact method with the lens model.

    Parameters
    ----------
    centers_cam_m : array_like, shape (N, 3)
        Sphere centres in the camera frame, metres.
    radius_m : float
    intrinsics : Intrinsics
    distortion : BrownConrady, optional

    Returns
    -------
    pandas.DataFrame
        One row per centre: ``distance_m``, ``off_axis_deg``, and the signed range errors
        (estimate − truth, metres) ``circle_m``, ``ellipse_pinhole_m``, ``ellipse_lens_m``.
    """
    import pandas as pd

    rows = []
    for center in np.asarray(centers_cam_m, dtype=float).reshape(-1, 3):
        contour = sphere_silhouette_px(center, radius_m, intrinsics, distortion, n_points=2000)
        mean = contour.mean(axis=0)
        (u, v), radius_px = cv2.minEnclosingCircle((contour - mean).astype(np.float32))
        det = SphereDetection(mean + (u, v), radius_px, contour, 1.0)
        rows.append(
            dict(
                distance_m=float(np.linalg.norm(center)),
                off_axis_deg=math.degrees(math.acos(center[2] / np.linalg.norm(center))),
                circle_m=_range_error_m(locate_sphere_circle(det, intrinsics, radius_m), center),
                ellipse_pinhole_m=_range_error_m(locate_sphere_ellipse(det, intrinsics, radius_m), center),
                ellipse_lens_m=_range_error_m(locate_sphere_ellipse(det, intrinsics, radius_m, distortion), center),
            )
        )
    return pd.DataFrame(rows)


def rendered_sphere_errors(renderer, T_world_cam, centers_cam_m, radius_m: float, detector: SphereDetector | None = None):
    """Detect and localise the sphere in frames rendered at known centres.

    Parameters
    ----------
    renderer : gimbal_lab.scene.SceneRenderer
        A sphere renderer; its ``intrinsics`` and ``distortion`` describe the frames.
    T_world_cam : ndarray, shape (4, 4)
        Camera pose (OpenCV optical frame) for every frame.
    centers_cam_m : array_like, shape (N, 3)
        True sphere centres in the camera frame, metres.
    radius_m : float
    detector : SphereDetector, optional
        Default :class:`SphereDetector` ().

    Returns
    -------
    pandas.DataFrame
        One row per frame: ``distance_m``, ``off_axis_deg``, ``detected``, and signed range
        errors (metres) ``circle_m`` (as published), ``ellipse_pinhole_m`` (exact method, lens
        ignored) and ``ellipse_lens_m`` (exact method with the renderer's lens model).
    """
    import pandas as pd

    detector = detector if detector is not None else SphereDetector()
    intrinsics, distortion = renderer.intrinsics, renderer.distortion
    rows = []
    for center in np.asarray(centers_cam_m, dtype=float).reshape(-1, 3):
        T_world_target = np.eye(4)
        T_world_target[:3, 3] = (np.asarray(T_world_cam) @ np.append(center, 1.0))[:3]
        det = detector.detect(renderer.render(T_world_cam, T_world_target))
        row = dict(
            distance_m=float(np.linalg.norm(center)),
            off_axis_deg=math.degrees(math.acos(center[2] / np.linalg.norm(center))),
            detected=det is not None,
        )
        if det is not None:
            row.update(
                circle_m=_range_error_m(locate_sphere_circle(det, intrinsics, radius_m), center),
                ellipse_pinhole_m=_range_error_m(locate_sphere_ellipse(det, intrinsics, radius_m), center),
                ellipse_lens_m=_range_error_m(locate_sphere_ellipse(det, intrinsics, radius_m, distortion), center),
            )
        rows.append(row)
    return pd.DataFrame(rows)


def rendered_marker_errors(renderer, T_world_cam, T_cam_markers, trackers: dict):
    """Marker pose errors of several trackers on frames rendered at known poses.

    Parameters
    ----------
    renderer : gimbal_lab.scene.SceneRenderer
        An ArUco renderer.
    T_world_cam : ndarray, shape (4, 4)
    T_cam_markers : sequence of ndarray, shape (4, 4)
        True marker poses in the camera frame.
    trackers : dict of str to ArucoTracker
        Named trackers to compare on the same frames.

    Returns
    -------
    pandas.DataFrame
        One row per (frame, tracker): ``frame``, ``tracker``, ``distance_m``,
        ``view_angle_deg`` (between the marker normal and the line of sight), ``detected``,
        ``translation_error_m`` (|t_est − t_true|), ``range_error_m`` (signed) and
        ``rotation_error_deg`` (angle of R_estᵀ R_true).
    """
    import pandas as pd

    rows = []
    for i, T_cam_marker in enumerate(T_cam_markers):
        T_cam_marker = np.asarray(T_cam_marker, dtype=float)
        frame = renderer.render(T_world_cam, np.asarray(T_world_cam) @ T_cam_marker)
        t_true = T_cam_marker[:3, 3]
        sight = -t_true / np.linalg.norm(t_true)
        view = math.degrees(math.acos(np.clip(T_cam_marker[:3, 2] @ sight, -1.0, 1.0)))
        for name, tracker in trackers.items():
            pose = tracker.detect(frame).get(renderer.marker_id)
            row = dict(frame=i, tracker=name, distance_m=float(np.linalg.norm(t_true)), view_angle_deg=view,
                       detected=pose is not None)
            if pose is not None:
                cos_angle = (np.trace(pose.R_cam_marker.T @ T_cam_marker[:3, :3]) - 1.0) / 2.0
                row.update(
                    translation_error_m=float(np.linalg.norm(pose.t_cam_marker_m - t_true)),
                    range_error_m=pose.distance_m - float(np.linalg.norm(t_true)),
                    rotation_error_deg=math.degrees(math.acos(np.clip(cos_angle, -1.0, 1.0))),
                )
            rows.append(row)
    return pd.DataFrame(rows)


def pointing_error_deg(frames) -> np.ndarray:
    """Angle between the optical axis and the target's true direction per frame of a frame table
    (its ``true_cam_{x,y,z}_m`` columns), degrees."""
    x, y, z = (frames[f"true_cam_{a}_m"].to_numpy(float) for a in "xyz")
    return np.degrees(np.arctan2(np.hypot(x, y), z))
