"""Figures for the detection part of the lab (paper §3.2.1–3.2.2, Figs. 2–4)."""

from __future__ import annotations

import cv2
import matplotlib.pyplot as plt
import numpy as np

from ..detection import conic_to_ellipse, fit_conic, sphere_silhouette_px

__all__ = [
    "plot_sphere_pipeline",
    "plot_sphere_silhouette",
    "plot_range_error",
    "plot_aruco_detection",
    "plot_pose_error",
]


def plot_sphere_pipeline(steps, fig=None):
    """Fig. 4: the sphere detector's stages (RGB, HSV hue, mask, contours, enclosing circle).

    Parameters
    ----------
    steps : gimbal_lab.detection.SpherePipelineSteps
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib Figure
    """
    fig = fig if fig is not None else plt.figure(figsize=(15, 3.4))
    axes = fig.subplots(1, 5)
    axes[0].imshow(steps.rgb)
    axes[0].set_title("input (RGB)")
    axes[1].imshow(steps.hsv[..., 0], cmap="hsv", vmin=0, vmax=180)
    axes[1].set_title("HSV: hue channel")
    axes[2].imshow(steps.mask, cmap="gray")
    axes[2].set_title("threshold mask")
    axes[3].imshow(steps.rgb)
    for i, contour in enumerate(steps.contours):
        closed = np.vstack((contour, contour[:1]))
        axes[3].plot(closed[:, 0], closed[:, 1], "-", lw=1.2, color="yellow" if i == steps.chosen else "cyan")
    axes[3].set_title(f"contours ({len(steps.contours)})")
    axes[4].imshow(steps.rgb)
    det = steps.detection
    if det is not None:
        axes[4].add_patch(plt.Circle(det.center_px, det.radius_px, fill=False, color="yellow", lw=1.2))
        axes[4].plot(*det.center_px, "+", color="yellow")
        zoom = 3 * det.radius_px
        for ax in axes[2:]:
            ax.set_xlim(det.center_px[0] - zoom, det.center_px[0] + zoom)
            ax.set_ylim(det.center_px[1] + zoom, det.center_px[1] - zoom)
    axes[4].set_title("minimum enclosing circle")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def plot_sphere_silhouette(center_cam_m, radius_m, intrinsics, distortion=None, ax=None):
    """Figs. 2–3: a sphere off axis images as an ellipse; its enclosing circle is larger.

    Draws the exact silhouette, its minimum enclosing circle (the paper's circle), the
    projection of the true centre and the centre of the circle, with the image frame.

    Returns
    -------
    matplotlib Axes
    """
    ax = ax if ax is not None else plt.figure(figsize=(6, 4.6)).add_subplot()
    outline = sphere_silhouette_px(center_cam_m, radius_m, intrinsics, distortion, n_points=720)
    mean = outline.mean(axis=0)
    (u, v), radius_px = cv2.minEnclosingCircle((outline - mean).astype(np.float32))
    closed = np.vstack((outline, outline[:1]))
    ax.plot(closed[:, 0], closed[:, 1], "r-", lw=2, label="silhouette (ellipse)")
    ax.add_patch(plt.Circle(mean + (u, v), radius_px, fill=False, ls="--", color="k", label="enclosing circle"))
    from ..camera import project

    centre_px = project(np.asarray(center_cam_m, dtype=float), intrinsics, distortion)[0]
    ax.plot(*centre_px, "bx", ms=9, label="projected sphere centre")
    ax.plot(*(mean + (u, v)), "k+", ms=9, label="circle centre")
    ellipse_centre, semi, _ = conic_to_ellipse(fit_conic(outline))
    ax.set_title(f"axes {2 * semi[0]:.1f} × {2 * semi[1]:.1f} px, circle radius {radius_px:.1f} px")
    ax.set_aspect("equal")
    ax.invert_yaxis()
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    return ax


def plot_range_error(table, x, columns, labels=None, ax=None, closed_form=None, scale=1e3, unit="mm"):
    """Range error of several estimates against one variable (lines, one per column).

    Parameters
    ----------
    table : pandas.DataFrame
    x : str
        Column on the horizontal axis (e.g. ``"off_axis_deg"``, ``"distance_m"``).
    columns : sequence of str
        Error columns in metres.
    labels : sequence of str, optional
    closed_form : (x_values, errors_m), optional
        A reference curve drawn dashed (the circle method's closed form).
    scale, unit : float, str
        Display scale (default millimetres).

    Returns
    -------
    matplotlib Axes
    """
    ax = ax if ax is not None else plt.figure(figsize=(6, 4)).add_subplot()
    data = table.sort_values(x)
    for column, label in zip(columns, labels if labels is not None else columns):
        ax.plot(data[x], data[column] * scale, "o-", ms=3, label=label)
    if closed_form is not None:
        ax.plot(closed_form[0], np.asarray(closed_form[1]) * scale, "k--", lw=1, label="closed form (circle)")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel(x.replace("_deg", " (deg)").replace("_m", " (m)").replace("_", " "))
    ax.set_ylabel(f"range error, estimate − truth ({unit})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax


def plot_aruco_detection(rgb, poses, intrinsics, distortion=None, axis_length_m=0.15, ax=None):
    """Detected markers with their outlines and pose axes (``cv2.drawFrameAxes``).

    Returns
    -------
    matplotlib Axes
    """
    ax = ax if ax is not None else plt.figure(figsize=(7, 5.2)).add_subplot()
    canvas = np.ascontiguousarray(rgb.copy())
    coefficients = None if distortion is None else distortion.coefficients
    for pose in poses.values():
        cv2.polylines(canvas, [np.round(pose.corners_px).astype(np.int32)], True, (255, 200, 0), 1)
        cv2.drawFrameAxes(canvas, intrinsics.K, coefficients, pose.rvec, pose.t_cam_marker_m, axis_length_m, 2)
        ax.text(*pose.corners_px[0], f"id {pose.marker_id}: {pose.distance_m:.3f} m", color="yellow", fontsize=8)
    ax.imshow(canvas)
    ax.set_xticks([])
    ax.set_yticks([])
    return ax


def plot_pose_error(table, x, y="translation_error_m", hue="tracker", ax=None, scale=1e3, unit="mm"):
    """A pose error against one variable, one line per tracker (or other grouping column).

    Returns
    -------
    matplotlib Axes
    """
    ax = ax if ax is not None else plt.figure(figsize=(6, 4)).add_subplot()
    for name, group in table.groupby(hue, sort=False):
        group = group.sort_values(x)
        ax.plot(group[x], group[y] * scale, "o-", ms=3, label=str(name))
    ax.set_xlabel(x.replace("_deg", " (deg)").replace("_m", " (m)").replace("_", " "))
    ylabel = y.replace("_m", "").replace("_deg", "").replace("_", " ")
    ax.set_ylabel(f"{ylabel} ({unit})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax
