"""Figures of the occlusion study: occluders in view, metrics per loop, and run timelines."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

__all__ = ["plot_occlusion_metrics", "plot_occlusion_timelines", "plot_occluder_views"]

_LOOP_COLOURS = {"paper": "tab:gray", "CV": "tab:blue", "CA": "tab:green", "IMM": "tab:red", "passive": "tab:purple"}
_METRICS = {
    "pointing_error_deg": ("pointing error, every frame [°]", 1.0),
    "hidden_pointing_deg": ("pointing error while hidden [°]", 1.0),
    "reappear_error_deg": ("pointing error when it reappears [°]", 1.0),
    "lost_pct": ("track losses [% of episodes]", 1.0),
    "reacquire_frames": ("frames to re-acquire", 1.0),
    "after_error_m": ("distance error after re-acquisition [mm]", 1000.0),
}


def plot_occlusion_metrics(summary, metrics=None, fig=None):
    """Grouped bars: each metric per occlusion (x) and loop (colour), one row per target.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.occlusion.summary_table` output.
    metrics : sequence of str, optional
        Columns of ``summary`` to draw (default: pointing error, while hidden, at reappearance,
        track losses, frames to re-acquire, distance error after re-acquisition). The pointing
        error carries its 95 % interval.

    Returns
    -------
    Figure
    """
    metrics = list(_METRICS) if metrics is None else list(metrics)
    unknown = [m for m in metrics if m not in _METRICS]
    if unknown:
        raise ValueError(f"unknown metric(s) {unknown}; choose from {list(_METRICS)}")
    if summary is None or len(summary) == 0:
        raise ValueError("summary holds no rows")
    targets = list(dict.fromkeys(summary["target"]))
    occlusions = list(dict.fromkeys(summary["occlusion"]))
    loops = [loop for loop in _LOOP_COLOURS if (summary["loop"] == loop).any()]
    if fig is None:
        fig = plt.figure(figsize=(3.3 * len(metrics) + 1.0, 3.0 * len(targets)), layout="constrained")
    axes = fig.subplots(len(targets), len(metrics), squeeze=False)
    width = 0.8 / max(len(loops), 1)
    x = np.arange(len(occlusions))
    for r, target in enumerate(targets):
        for c, metric in enumerate(metrics):
            ax = axes[r, c]
            label, scale = _METRICS[metric]
            for j, loop in enumerate(loops):
                df = summary[(summary["target"] == target) & (summary["loop"] == loop)].set_index("occlusion")
                ys = scale * df.reindex(occlusions)[metric].to_numpy(float)
                yerr = None
                if metric == "pointing_error_deg":
                    lo = df.reindex(occlusions)["ci_low_deg"].to_numpy(float)
                    hi = df.reindex(occlusions)["ci_high_deg"].to_numpy(float)
                    yerr = np.nan_to_num(np.clip(np.vstack((ys - lo, hi - ys)), 0.0, None))
                ax.bar(x + (j - (len(loops) - 1) / 2) * width, np.nan_to_num(ys), width, yerr=yerr, capsize=2,
                       color=_LOOP_COLOURS[loop], label=loop if (r, c) == (0, 0) else None)
            ax.set_xticks(x, occlusions, rotation=30, ha="right", fontsize=8)
            ax.set_ylabel(label, fontsize=8)
            ax.set_title(f"{target}", fontsize=9)
            ax.grid(axis="y", alpha=0.3)
    fig.legend(loc="outside right upper", title="loop")
    return fig


def plot_occlusion_timelines(runs, target: str = "circle", occlusion: str = "panel 1.0 s", fig=None):
    """One replicate of every loop: the pointing error against time, hidden frames shaded and
    missed detections marked, for one target and occlusion.

    Parameters
    ----------
    runs : mapping of str to TrackingResult
        Loop name → its run of one cell and replicate
        (:func:`gimbal_lab.studies.occlusion.timeline_runs` picks them from a study's results).
    target, occlusion : str
        The cell's target and occlusion names (the title).

    Returns
    -------
    Figure
    """
    from ..evaluation import pointing_error_deg

    chosen = dict(runs)
    if not chosen:
        raise ValueError(f"no run of {target!r} with {occlusion!r}")
    if fig is None:
        fig = plt.figure(figsize=(9.0, 3.6), layout="constrained")
    ax = fig.subplots()
    shaded = False
    for loop in (name for name in _LOOP_COLOURS if name in chosen):
        f = chosen[loop].frames
        t = f["t_mid_s"].to_numpy(float)
        if not shaded:
            hidden = f["hidden"].to_numpy(bool)
            ax.fill_between(t, 0, 1, where=hidden, transform=ax.get_xaxis_transform(), color="0.85", step="mid",
                            label="target hidden")
            shaded = True
        angle = pointing_error_deg(f)
        ax.plot(t, angle, color=_LOOP_COLOURS[loop], lw=1.2, label=loop)
        missed = ~f["detected"].to_numpy(bool)
        ax.plot(t[missed], angle[missed], "x", ms=3, color=_LOOP_COLOURS[loop])
    config = next(iter(chosen.values())).config
    camera = config.camera
    half_field = np.degrees(camera.horizontal_field_rad) / 2
    ax.axhline(half_field * camera.height / camera.width, color="k", ls=":", lw=0.8, label="half vertical field")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("optical axis to target [°]")
    ax.set_title(f"{target}, {occlusion}, seed {config.seed} (x: not detected)", fontsize=9)
    ax.legend(fontsize=8, ncol=3)
    ax.grid(alpha=0.3)
    return fig


def plot_occluder_views(views: dict, fig=None):
    """The home camera's frames with each occluder: ``views`` maps a title to an RGB image."""
    if not views:
        raise ValueError("views holds no images")
    if fig is None:
        fig = plt.figure(figsize=(3.2 * len(views), 2.7), layout="constrained")
    axes = fig.subplots(1, len(views), squeeze=False)[0]
    for ax, (title, image) in zip(axes, views.items()):
        ax.imshow(image)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    return fig
