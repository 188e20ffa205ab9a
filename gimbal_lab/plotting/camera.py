"""Figures for the camera model: projection, lens-distortion fields and grids (paper §3.2, §4.1).

Every number comes from :mod:`gimbal_lab.camera`; these functions only draw.
"""

from __future__ import annotations

import numpy as np

from ._common import interactive

from ..camera import BrownConrady, Intrinsics, distort_pixels

__all__ = [
    "plot_projection",
    "plot_displacement_field",
    "plot_distorted_grid",
    "plot_grid_comparison",
    "plot_radial_displacement",
    "distortion_explorer",
]


def _new_ax(ax, figsize=(6.4, 4.8)):
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def _image_axes(ax, intrinsics: Intrinsics, margin_px: float = 20.0):
    """Image coordinates: u to the right, v down, the sensor outline and the principal point."""
    from matplotlib.patches import Rectangle

    w, h = intrinsics.width, intrinsics.height
    ax.add_patch(Rectangle((-0.5, -0.5), w, h, fill=False, color="0.3", lw=1.0))
    ax.plot(intrinsics.cx, intrinsics.cy, "+", color="0.3", ms=10)
    ax.set_xlim(-0.5 - margin_px, w - 0.5 + margin_px)
    ax.set_ylim(h - 0.5 + margin_px, -0.5 - margin_px)
    ax.set_aspect("equal")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")


def plot_projection(uv_px, intrinsics: Intrinsics, labels=None, ax=None, uv_distorted_px=None):
    """Projected points on the image plane.

    Parameters
    ----------
    uv_px : array_like, shape (N, 2)
        Pixel coordinates of the pinhole projection (NaN rows are skipped).
    intrinsics : Intrinsics
    labels : sequence of str, optional
        One label per point.
    ax : matplotlib Axes, optional
    uv_distorted_px : array_like, shape (N, 2), optional
        The same points through a lens model; drawn with an arrow from the pinhole pixel.

    Returns
    -------
    matplotlib Axes
    """
    ax = _new_ax(ax)
    uv = np.atleast_2d(np.asarray(uv_px, float))
    _image_axes(ax, intrinsics)
    ax.plot(uv[:, 0], uv[:, 1], "o", color="C0", label="pinhole")
    if uv_distorted_px is not None:
        uvd = np.atleast_2d(np.asarray(uv_distorted_px, float))
        ax.plot(uvd[:, 0], uvd[:, 1], "x", color="C3", label="with distortion")
        for a, b in zip(uv, uvd):
            if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
                ax.annotate("", xy=b, xytext=a, arrowprops=dict(arrowstyle="->", color="C3", lw=0.8))
        ax.legend(loc="lower right", fontsize="small")
    if labels is not None:
        for (u, v), text in zip(uv, labels):
            if np.isfinite(u) and np.isfinite(v):
                ax.annotate(text, (u, v), xytext=(5, -8), textcoords="offset points", fontsize="small")
    ax.set_title(f"projection, {intrinsics.width}×{intrinsics.height} px, fx = {intrinsics.fx:.1f} px")
    return ax


def _pixel_grid(intrinsics: Intrinsics, step_px: float):
    us = np.arange(0.0, intrinsics.width, step_px)
    vs = np.arange(0.0, intrinsics.height, step_px)
    us = us + (intrinsics.width - 1 - us[-1]) / 2  # centre the grid on the image
    vs = vs + (intrinsics.height - 1 - vs[-1]) / 2
    U, V = np.meshgrid(us, vs)
    return np.column_stack((U.ravel(), V.ravel()))


def plot_displacement_field(
    intrinsics: Intrinsics, distortion: BrownConrady, ax=None, step_px: float = 40.0, gain: float = 1.0
):
    """Where the lens moves each pinhole pixel: arrows from the ideal to the distorted pixel.

    Parameters
    ----------
    intrinsics : Intrinsics
    distortion : BrownConrady
    ax : matplotlib Axes, optional
    step_px : float
        Grid spacing of the arrows, px.
    gain : float
        Arrow length = ``gain`` × displacement (1: true length in pixels).

    Returns
    -------
    matplotlib Axes
    """
    ax = _new_ax(ax)
    uv = _pixel_grid(intrinsics, step_px)
    duv = distort_pixels(uv, intrinsics, distortion) - uv
    mag = np.hypot(duv[:, 0], duv[:, 1])
    _image_axes(ax, intrinsics)
    q = ax.quiver(
        uv[:, 0], uv[:, 1], gain * duv[:, 0], gain * duv[:, 1], mag,
        angles="xy", scale_units="xy", scale=1.0, cmap="viridis", width=0.004,
    )
    ax.figure.colorbar(q, ax=ax, label="displacement [px]", shrink=0.8)
    scale = "true length" if gain == 1 else f"arrows ×{gain:g}"
    ax.set_title(f"displacement field ({scale}), max {mag.max():.1f} px")
    return ax


def _grid_lines(intrinsics: Intrinsics, n_u: int, n_v: int, samples: int = 200):
    """Straight lines of the pinhole image: n_u vertical and n_v horizontal, each (samples, 2)."""
    w, h = intrinsics.width - 1.0, intrinsics.height - 1.0
    t = np.linspace(0.0, 1.0, samples)
    lines = [np.column_stack((np.full_like(t, u), t * h)) for u in np.linspace(0.0, w, n_u)]
    lines += [np.column_stack((t * w, np.full_like(t, v))) for v in np.linspace(0.0, h, n_v)]
    return lines


def plot_distorted_grid(
    intrinsics: Intrinsics, distortion: BrownConrady, ax=None, n_lines: tuple[int, int] = (9, 7), title=None
):
    """Straight lines of the pinhole image (dashed) and where the lens puts them (solid).

    Parameters
    ----------
    intrinsics : Intrinsics
    distortion : BrownConrady
    ax : matplotlib Axes, optional
    n_lines : (int, int)
        Number of vertical and horizontal lines.
    title : str, optional

    Returns
    -------
    matplotlib Axes
    """
    ax = _new_ax(ax)
    _image_axes(ax, intrinsics, margin_px=0.15 * max(intrinsics.width, intrinsics.height))
    for line in _grid_lines(intrinsics, *n_lines):
        bent = distort_pixels(line, intrinsics, distortion)
        ax.plot(line[:, 0], line[:, 1], "--", color="0.7", lw=0.8)
        ax.plot(bent[:, 0], bent[:, 1], "-", color="C0", lw=1.2)
    d = distortion
    ax.set_title(title or f"k1={d.k1:g}, k2={d.k2:g}, p1={d.p1:g}, p2={d.p2:g}, k3={d.k3:g}", fontsize="medium")
    return ax


def plot_grid_comparison(intrinsics: Intrinsics, lenses: dict, fig=None):
    """One distorted-grid panel per lens, side by side (e.g. barrel vs pincushion).

    Parameters
    ----------
    intrinsics : Intrinsics
    lenses : dict of str to BrownConrady
        Panel title → lens model.
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib Figure
    """
    import matplotlib.pyplot as plt

    n = len(lenses)
    if fig is None:
        fig = plt.figure(figsize=(4.8 * n, 4.2), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, (name, lens) in zip(axes, lenses.items()):
        plot_distorted_grid(intrinsics, lens, ax=ax, title=name)
    return fig


def plot_radial_displacement(intrinsics: Intrinsics, lenses: dict, ax=None, n_directions: int = 72):
    """Radial displacement (px, negative = towards the centre) versus distance from the centre.

    For each lens the line is the mean over ``n_directions`` directions and the band its range
    (the tangential terms make the displacement depend on direction). Vertical lines mark the
    image's half-height, half-width and corner radius.

    Parameters
    ----------
    intrinsics : Intrinsics
    lenses : dict of str to BrownConrady
    ax : matplotlib Axes, optional
    n_directions : int

    Returns
    -------
    matplotlib Axes
    """
    ax = _new_ax(ax)
    cx, cy = intrinsics.cx, intrinsics.cy
    corner = float(np.hypot(max(cx, intrinsics.width - 1 - cx), max(cy, intrinsics.height - 1 - cy)))
    radius = np.linspace(0.0, corner, 200)
    phi = np.linspace(0.0, 2 * np.pi, n_directions, endpoint=False)
    R, P = np.meshgrid(radius, phi)
    direction = np.column_stack((np.cos(P.ravel()), np.sin(P.ravel())))
    uv = np.column_stack((cx, cy)) + R.ravel()[:, None] * direction
    for i, (name, lens) in enumerate(lenses.items()):
        duv = distort_pixels(uv, intrinsics, lens) - uv
        radial = np.sum(duv * direction, axis=1).reshape(R.shape)
        ax.plot(radius, radial.mean(axis=0), color=f"C{i}", label=name)
        ax.fill_between(radius, radial.min(axis=0), radial.max(axis=0), color=f"C{i}", alpha=0.25, lw=0)
    for r, text in ((cy, "half-height"), (cx, "half-width"), (corner, "corner")):
        ax.axvline(r, color="0.5", lw=0.8, ls=":")
        ax.annotate(text, (r, 1.0), xycoords=("data", "axes fraction"), rotation=90,
                    va="top", ha="right", fontsize="small", color="0.4")
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xlabel("distance of the pinhole pixel from (cx, cy) [px]")
    ax.set_ylabel("radial displacement [px] (< 0: inward)")
    ax.legend(loc="lower left", fontsize="small")
    return ax


def distortion_explorer(intrinsics: Intrinsics, lens: BrownConrady | None = None, k_range: float = 0.5):
    """Interactive k1/k2 sliders redrawing the distorted grid and displacement field (ipywidgets).

    The sliders move k1 and k2 only; the lens's other coefficients (p1, p2, k3) are held at the
    values of ``lens``, and the figure's title states them, so the starting picture is the
    static figure of the same lens.

    Parameters
    ----------
    intrinsics : Intrinsics
    lens : BrownConrady, optional
        Starting lens (default: the study's, ``BrownConrady.default()``).
    k_range : float
        Sliders span [−k_range, k_range] (> 0).

    Returns
    -------
    ipywidgets.interactive or None
        Display it in a notebook; in a headless run it renders once with the initial values.
    """
    import dataclasses

    import ipywidgets
    import matplotlib.pyplot as plt
    from IPython.display import display

    lens = BrownConrady.default() if lens is None else lens
    if not isinstance(lens, BrownConrady):
        raise TypeError(f"lens must be a BrownConrady, got {type(lens).__name__}")
    if not (np.isfinite(k_range) and k_range > 0):
        raise ValueError(f"k_range must be finite and > 0, got {k_range!r}")

    def draw(k1, k2):
        shown = dataclasses.replace(lens, k1=k1, k2=k2)
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
        plot_distorted_grid(intrinsics, shown, ax=axes[0])
        plot_displacement_field(intrinsics, shown, ax=axes[1])
        fig.suptitle(f"k1 = {k1:.3f}, k2 = {k2:.3f}; held: p1 = {lens.p1:g}, p2 = {lens.p2:g}, k3 = {lens.k3:g}")
        display(fig)
        plt.close(fig)

    step = k_range / 100
    return interactive(
        draw,
        k1=ipywidgets.FloatSlider(value=lens.k1, min=-k_range, max=k_range, step=step, readout_format=".3f"),
        k2=ipywidgets.FloatSlider(value=lens.k2, min=-k_range, max=k_range, step=step, readout_format=".3f"),
    )
