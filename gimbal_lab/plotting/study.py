"""Figures of the closed-loop study (paper §4.1, Figs. 10–14)."""

from __future__ import annotations

import numpy as np
import matplotlib.pyplot as plt

from ..trajectories import Trajectory

__all__ = ["plot_trajectories", "plot_error_bars", "plot_xyz", "plot_pixel_offset"]

_MODE_COLOURS = {"passive": "tab:blue", "active": "tab:orange"}


def plot_trajectories(period_s: float = 2.0, camera_m=(0.0, 0.0, 2.0), ax=None):
    """Fig. 10: the circular and diagonal target motions in the world, with the gimbal camera."""
    if ax is None:
        fig = plt.figure(figsize=(6, 5))
        ax = fig.add_subplot(projection="3d")
    t = np.linspace(0, period_s, 200)
    for traj, colour in ((Trajectory.circular(period_s), "tab:red"), (Trajectory.diagonal(period_s), "tab:green")):
        p = traj.position(t)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=colour, label=traj.kind)
    ax.scatter(*camera_m, color="k", marker="s", label="gimbal camera")
    ax.plot([camera_m[0], 3.0], [camera_m[1], 0.0], [camera_m[2], 2.0], "k:", lw=1, label="home optical axis")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_xlim(0, 4)
    ax.set_ylim(-2, 2)
    ax.set_zlim(0, 4)
    ax.set_box_aspect((1, 1, 1))  # equal metres on every axis
    ax.legend(loc="upper left")
    ax.set_title("Target trajectories (world frame)")
    return ax


def plot_error_bars(summary, target: str, ax=None, methods=None):
    """Figs. 11 and 13: mean ± std distance error per condition, passive vs active bars.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.experiments.summarize` output.
    target : {"sphere", "aruco"}
    methods : list of str, optional
        Sphere methods to show side by side (e.g. ["circle", "ellipse"]); default: all present.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4))
    df = summary[summary["target"] == target]
    methods = list(dict.fromkeys(df["method"])) if methods is None else list(methods)
    conditions = [(d, t) for d in ("undistorted", "distorted") for t in ("circular", "diagonal")]
    series = [(meth, mode) for meth in methods for mode in ("passive", "active")]
    width = 0.8 / len(series)
    x = np.arange(len(conditions))
    hatches = ["", "//", "..", "xx"]
    for j, (meth, mode) in enumerate(series):
        means, stds = [], []
        for d, t in conditions:
            row = df[(df["distortion"] == d) & (df["trajectory"] == t) & (df["mode"] == mode) & (df["method"] == meth)]
            means.append(1000 * row["mean_error_m"].iloc[0] if len(row) else np.nan)
            stds.append(1000 * row["std_error_m"].iloc[0] if len(row) else np.nan)
        label = mode if len(methods) == 1 else f"{meth}, {mode}"
        ax.bar(x + (j - (len(series) - 1) / 2) * width, means, width, yerr=stds, capsize=3,
               color=_MODE_COLOURS[mode], hatch=hatches[methods.index(meth) % len(hatches)],
               edgecolor="k", linewidth=0.5, label=label)
    ax.set_xticks(x, [f"{d}\n{t}" for d, t in conditions])
    ax.set_ylabel("|d_est − d_true| [mm] (mean ± std)")
    ax.set_title(f"Distance error, {target}")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    return ax


def plot_xyz(result, revolution: int = 1, fig=None):
    """Figs. 12 and 14: estimated vs true target x, y, z (world) over one revolution."""
    if fig is None:
        fig = plt.figure(figsize=(9, 6))
    axes = fig.subplots(3, 1, sharex=True)
    f = result.frames
    period = result.config.period_s
    sel = f[(f["t_s"] >= revolution * period) & (f["t_s"] < (revolution + 1) * period)]
    for ax, axis in zip(axes, "xyz"):
        ax.plot(sel["t_s"], sel[f"true_{axis}_m"], "k-", lw=1.5, label="ground truth")
        ax.plot(sel["t_s"], sel[f"est_{axis}_m"], ".", color=_MODE_COLOURS[result.config.mode], ms=4, label="estimate")
        ax.set_ylabel(f"{axis} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    axes[0].set_title(f"{result.config.label}: world coordinates over revolution {revolution}")
    axes[-1].set_xlabel("t [s]")
    return fig


def plot_pixel_offset(results, labels=None, ax=None):
    """Distance of the detected target from the image centre over time, one line per run.

    ``labels`` (one per run) default to the runs' labels.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3.5))
    labels = [r.config.label for r in results] if labels is None else list(labels)
    if len(labels) != len(results):
        raise ValueError(f"labels must have one entry per run ({len(results)}), got {len(labels)}")
    for r, label in zip(results, labels):
        ax.plot(r.frames["t_s"], r.frames["offset_px"], lw=1, label=label)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("offset from image centre [px]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return ax
