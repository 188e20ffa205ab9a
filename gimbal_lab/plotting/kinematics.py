"""Figures for the gimbal kinematics: DH frames in 3-D, pointing at targets (paper §3.2.4, Figs. 6–7).

Every pose comes from :class:`gimbal_lab.kinematics.GimbalKinematics`; these functions only draw.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["plot_gimbal", "plot_gimbal_configurations", "plot_pointing", "plot_joint_angles"]

_AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")  # x, y, z


def _new_3d_ax(ax, figsize=(6.0, 5.5)):
    if ax is None:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=figsize, layout="constrained")
        ax = fig.add_subplot(projection="3d")
    return ax


def _triad(ax, T, length, label=None, lw=2.0, alpha=1.0, style="-"):
    o = T[:3, 3]
    for k in range(3):
        e = o + length * T[:3, k]
        ax.plot(*zip(o, e), style, color=_AXIS_COLOURS[k], lw=lw, alpha=alpha)
    if label:
        tip = o + 1.08 * length * T[:3, 2]
        ax.text(*tip, label, fontsize="small")


def _equal_box(ax, points, pad):
    pts = np.asarray(points)
    centre = (pts.max(axis=0) + pts.min(axis=0)) / 2
    half = (pts.max(axis=0) - pts.min(axis=0)).max() / 2 + pad
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))


def _frustum(ax, T, depth, half_w, half_h, colour="0.3"):
    """A camera pyramid in OpenCV axes (x right, y down, z forward)."""
    corners = [(-half_w, -half_h), (half_w, -half_h), (half_w, half_h), (-half_w, half_h)]
    o = T[:3, 3]
    pts = [T[:3, :3] @ np.array([x * depth, y * depth, depth]) + o for x, y in corners]
    for p in pts:
        ax.plot(*zip(o, p), color=colour, lw=0.8)
    ring = pts + pts[:1]
    ax.plot(*np.array(ring).T, color=colour, lw=0.8)
    # "up" marker on the image's top edge (−y_cam) so roll is visible
    top = (pts[0] + pts[1]) / 2
    ax.plot(*zip(top, top - 0.35 * depth * T[:3, 1]), color=colour, lw=1.5)


def plot_gimbal(kin, q_rad, ax=None, T_world_base=None, axis_length_m=0.025, show_dh_frames=True,
                title=None, check_limits=True, box_half_m=None):
    """The gimbal at joint angles ``q_rad``: mount, joint axes, DH frames and the camera.

    Draws the base triad at the mount, the drop to the centre of rotation, the three joint axes
    through it (yaw, roll, pitch), the DH frames 1–3 (thin, shorter each), the camera's optical
    frame (OpenCV axes) with a small view pyramid whose top edge carries a tick, and the optical
    axis. Axis colours: x red, y green, z blue.

    Parameters
    ----------
    kin : GimbalKinematics
    q_rad : array_like, shape (3,)
        Joint angles (yaw, roll, pitch), rad.
    ax : mpl_toolkits.mplot3d Axes3D, optional
    T_world_base : ndarray, shape (4, 4), optional
        Draw in this frame (default: the base frame).
    axis_length_m : float
        Length of the frame triads, m.
    show_dh_frames : bool
        Draw the DH frames 1–3 at the centre of rotation.
    title : str, optional
    check_limits : bool
        Passed to the kinematics.
    box_half_m : float, optional
        Half-size of the cubic view box around the centre of rotation, m (default: fit the drawing).

    Returns
    -------
    Axes3D
    """
    ax = _new_3d_ax(ax)
    T0 = np.eye(4) if T_world_base is None else np.asarray(T_world_base, float)
    frames = [T0 @ T for T in kin.frames(q_rad, check_limits=check_limits)]
    L = axis_length_m
    base, cam = frames[0], frames[4]
    centre = frames[1][:3, 3]
    _triad(ax, base, L, "base")
    ax.plot(*zip(base[:3, 3], centre), color="0.2", lw=3, alpha=0.6)  # the yaw arm
    ax.plot(*zip(centre, cam[:3, 3]), color="0.2", lw=3, alpha=0.6)  # the camera arm
    for i, name in enumerate(("yaw", "roll", "pitch")):
        z = frames[i][:3, 2]
        ax.plot(*zip(centre - 1.6 * L * z, centre + 1.6 * L * z), ":", color="0.4", lw=1)
        # label at the negative end: the positive ends carry the camera and the base
        ax.text(*(centre - 1.75 * L * z), f"{name} axis", fontsize="x-small", color="0.3", ha="center")
    if show_dh_frames:
        for i in (1, 2, 3):
            _triad(ax, frames[i], L * (1.0 - 0.2 * i), lw=1.0, alpha=0.6, style="--")
    _triad(ax, cam, 0.8 * L, "cam")
    _frustum(ax, cam, depth=1.2 * L, half_w=0.5, half_h=0.375)
    ax.plot(*zip(cam[:3, 3], cam[:3, 3] + 2 * L * cam[:3, 2]), color="tab:orange", lw=1.2)
    if box_half_m is None:
        pts = [T[:3, 3] for T in frames] + [cam[:3, 3] + 2 * L * cam[:3, 2]]
        _equal_box(ax, pts, pad=1.5 * L)
    else:
        _equal_box(ax, [centre], pad=box_half_m)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=c, lw=2) for c in _AXIS_COLOURS]
    handles += [Line2D([], [], color="tab:orange", lw=1.2)]
    ax.legend(handles, ["x", "y", "z", "optical axis"], loc="upper left", fontsize="x-small", ncols=2)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    q_deg = np.degrees(np.asarray(q_rad, float))
    ax.set_title(title or "yaw {:.0f}°, roll {:.0f}°, pitch {:.0f}°".format(*q_deg), fontsize="medium")
    return ax


def plot_gimbal_configurations(kin, configurations: dict, fig=None, ncols=3, **kwargs):
    """One :func:`plot_gimbal` panel per joint configuration.

    Parameters
    ----------
    kin : GimbalKinematics
    configurations : dict of str to array_like, shape (3,)
        Panel title → joint angles (yaw, roll, pitch), rad.
    fig : matplotlib Figure, optional
    ncols : int
    **kwargs
        Passed to :func:`plot_gimbal`.

    Returns
    -------
    matplotlib Figure
    """
    import matplotlib.pyplot as plt

    kwargs.setdefault("box_half_m", 0.07)  # the same scale in every panel
    n = len(configurations)
    ncols = min(ncols, n)
    nrows = math.ceil(n / ncols)
    if fig is None:
        fig = plt.figure(figsize=(4.6 * ncols, 4.4 * nrows), layout="constrained")
    for k, (name, q) in enumerate(configurations.items()):
        ax = fig.add_subplot(nrows, ncols, k + 1, projection="3d")
        plot_gimbal(kin, q, ax=ax, title=name, **kwargs)
    return fig


def plot_pointing(kin, q_list, targets, T_world_base=None, ax=None, path=None, ray_colour="tab:orange"):
    """Camera poses that point at targets: optical axes from the camera to each target.

    Parameters
    ----------
    kin : GimbalKinematics
    q_list : array_like, shape (N, 3)
        Joint angles for each target, rad.
    targets : array_like, shape (N, 3)
        Target points, in the frame of ``T_world_base`` (default: base), m.
    T_world_base : ndarray, shape (4, 4), optional
    ax : Axes3D, optional
    path : array_like, shape (M, 3), optional
        A curve to draw (e.g. the target's trajectory), same frame as ``targets``.
    ray_colour : str

    Returns
    -------
    Axes3D
    """
    ax = _new_3d_ax(ax, figsize=(7.0, 5.5))
    T0 = np.eye(4) if T_world_base is None else np.asarray(T_world_base, float)
    targets = np.atleast_2d(np.asarray(targets, float))
    if path is not None:
        path = np.asarray(path, float)
        ax.plot(*path.T, color="0.5", lw=1, label="trajectory")
    pts = [T0[:3, 3]]
    for q, p in zip(np.atleast_2d(q_list), targets):
        T = T0 @ kin.forward(q)
        c = T[:3, 3]
        reach = np.linalg.norm(p - c)
        ax.plot(*zip(c, c + reach * T[:3, 2]), color=ray_colour, lw=0.8)
        pts += [c, p]
    ax.scatter(*targets.T, color="tab:red", s=20, depthshade=False, label="targets")
    ax.scatter(*T0[:3, 3], color="k", marker="^", s=40, depthshade=False, label="gimbal base")
    _triad(ax, T0, 0.4, lw=1.5)
    _equal_box(ax, pts + ([] if path is None else list(path)), pad=0.2)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(loc="upper left", fontsize="small")
    return ax


def plot_joint_angles(x, q_rad, kin=None, ax=None, xlabel="trajectory phase [°]"):
    """Joint angles (degrees) against a parameter such as the trajectory phase or time.

    Parameters
    ----------
    x : array_like, shape (N,)
        Abscissa (displayed as given).
    q_rad : array_like, shape (N, 3)
        Joint angles (yaw, roll, pitch), rad.
    kin : GimbalKinematics, optional
        When given, joint limits inside the plotted range are drawn as dotted lines.
    ax : matplotlib Axes, optional
    xlabel : str

    Returns
    -------
    matplotlib Axes
    """
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(7.0, 3.6), layout="constrained")
    q_deg = np.degrees(np.asarray(q_rad, float))
    for i, name in enumerate(("yaw", "roll", "pitch")):
        ax.plot(x, q_deg[:, i], color=f"C{i}", label=name)
    if kin is not None:
        lo_plot, hi_plot = ax.get_ylim()
        for i, (lo, hi) in enumerate(kin.joint_limits_rad):
            for lim in (math.degrees(lo), math.degrees(hi)):
                if lo_plot - 5 <= lim <= hi_plot + 5:
                    ax.axhline(lim, color=f"C{i}", ls=":", lw=1)
    ax.axhline(0.0, color="0.3", lw=0.6)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("joint angle [°]")
    ax.legend(loc="best", fontsize="small")
    return ax
