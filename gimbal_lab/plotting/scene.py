"""Figures for the scene part of the lab (paper §4.1, Figs. 9–10): rendered frames, overlays of
projected trajectories, and the render-versus-camera-model check."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

__all__ = ["plot_frame", "plot_frame_grid", "plot_tracks", "plot_render_check"]


def plot_frame(image, ax=None, title: str | None = None):
    """Show one RGB frame with pixel axes (u right, v down; pixel centres on integers).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
    ax : matplotlib Axes, optional
    title : str, optional

    Returns
    -------
    matplotlib Axes
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.8))
    h, w = image.shape[:2]
    ax.imshow(image, extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation="nearest")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    if title:
        ax.set_title(title)
    return ax


def plot_frame_grid(images, titles=None, ncols: int = 2, fig=None, panel_width_in: float = 4.8):
    """Frames side by side in a grid (e.g. undistorted vs distorted, sharp vs blurred).

    Parameters
    ----------
    images : sequence of ndarray, each (H, W, 3) uint8
    titles : sequence of str, optional
    ncols : int
    fig : matplotlib Figure, optional
    panel_width_in : float
        Width of one panel, inches.

    Returns
    -------
    matplotlib Figure
    """
    images = list(images)
    titles = list(titles) if titles is not None else [None] * len(images)
    nrows = -(-len(images) // ncols)
    h, w = images[0].shape[:2]
    if fig is None:
        fig = plt.figure(figsize=(panel_width_in * ncols, panel_width_in * h / w * nrows + 0.4 * nrows))
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for ax, image, title in zip(axes.flat, images, titles):
        plot_frame(image, ax=ax, title=title)
    for ax in list(axes.flat)[len(images) :]:
        ax.set_axis_off()
    fig.tight_layout()
    return fig


def plot_tracks(image, tracks_px, ax=None, title: str | None = None):
    """A frame with projected image tracks drawn over it (paper Fig. 10's motions).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
    tracks_px : dict of str to ndarray, shape (N, 2)
        Label → pixel positions along a track (e.g. a projected trajectory over one period).
    ax : matplotlib Axes, optional
    title : str, optional

    Returns
    -------
    matplotlib Axes
    """
    ax = plot_frame(image, ax=ax, title=title)
    h, w = image.shape[:2]
    for (label, uv), colour in zip(tracks_px.items(), ("tab:orange", "tab:cyan", "white", "tab:purple")):
        uv = np.asarray(uv)
        ax.plot(uv[:, 0], uv[:, 1], "-", color=colour, lw=1.8, label=label)
        ax.plot(uv[0, 0], uv[0, 1], "o", color=colour, ms=5)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    return ax


def plot_render_check(errors, tolerance_px: float, ax=None):
    """Render-versus-model errors per check, against the tolerance.

    Parameters
    ----------
    errors : pandas.DataFrame
        Columns ``check`` (str: which comparison, e.g. "sphere centroid, distorted") and
        ``error_px`` (float: one measured error per rendered frame).
    tolerance_px : float
        Drawn as a dashed line.
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(7.0, 3.2))
    checks = list(dict.fromkeys(errors["check"]))
    for i, check in enumerate(checks):
        values = errors.loc[errors["check"] == check, "error_px"].to_numpy()
        jitter = np.linspace(-0.15, 0.15, len(values)) if len(values) > 1 else np.zeros(1)
        ax.plot(i + jitter, values, "o", ms=4, alpha=0.8)
        ax.plot([i - 0.3, i + 0.3], [values.max()] * 2, "-", color="k", lw=1)
    ax.axhline(tolerance_px, ls="--", color="tab:red", label=f"tolerance {tolerance_px:g} px")
    ax.set_xticks(range(len(checks)), checks, rotation=15, ha="right")
    ax.set_ylabel("error [px]")
    ax.set_ylim(0, 1.15 * max(tolerance_px, float(errors["error_px"].max())))
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return ax
