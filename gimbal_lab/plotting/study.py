"""Figures of the closed-loop study (paper §4.1, Figs. 10–14) and of its verdicts."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import matplotlib.ticker
import numpy as np

from ._common import interactive

from ..trajectories import Trajectory

__all__ = ["plot_trajectories", "plot_error_bars", "plot_xyz", "plot_pixel_offset", "plot_forest", "plot_run_frame",
           "run_explorer", "plot_mount_bars", "plot_mount_frames", "plot_body_motions", "plot_lens_sweep",
           "plot_lens_costs", "plot_lens_views", "plot_lens_radii", "plot_lens_error_cost", "plot_lens_h2_limits",
           "plot_pipeline_costs", "plot_gains"]

_MODE_COLOURS = {"passive": "tab:blue", "active": "tab:orange"}
_VERDICT_COLOURS = {"holds": "tab:green", "does not hold": "tab:red", "inconclusive": "0.45"}
_MOUNT_COLOURS = {"fixed": "tab:gray", "stabilised": "tab:blue", "active": "tab:orange"}
_STRATEGY_COLOURS = {"ignore": "tab:gray", "undistort": "tab:green", "rectify": "tab:purple"}
_TARGET_TITLES = {"sphere": "sphere", "aruco": "ArUco marker"}
_PIPELINE_COLOURS = {"active (paper)": "tab:orange", "active (best)": "tab:red", "best passive": "tab:blue"}
_CONDITION_MARKERS = {("undistorted", "circular"): "o", ("undistorted", "diagonal"): "s",
                      ("distorted", "circular"): "^", ("distorted", "diagonal"): "D"}
_GAIN_COLOURS = {"G_full": "tab:purple", "G_sharp": "tab:green", "G_static": "tab:gray"}
_CLAIM_SIGN = {"equivalent": "≈", "non-inferior": "≤"}


def plot_trajectories(period_s: float = 2.0, camera_m=(0.0, 0.0, 2.0), ax=None):
    """Fig. 10: the circular and diagonal target motions in the world, with the gimbal camera."""
    if ax is None:
        fig = plt.figure(figsize=(7.5, 5.5))
        ax = fig.add_subplot(projection="3d")
    t = np.linspace(0, period_s, 200)
    for traj, colour in ((Trajectory.circular(period_s), "tab:red"), (Trajectory.diagonal(period_s), "tab:green")):
        p = traj.position(t)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=colour, label=traj.kind)
    ax.scatter(*camera_m, color="k", marker="s", label="gimbal camera")
    ax.plot([camera_m[0], 3.0], [camera_m[1], 0.0], [camera_m[2], 2.0], "k:", lw=1, label="home optical axis")
    ax.set_xlabel("x [m]", labelpad=8)
    ax.set_ylabel("y [m]", labelpad=8)
    ax.set_zlabel("z [m]", labelpad=8)
    ax.set_xlim(0, 4)
    ax.set_ylim(-2, 2)
    ax.set_zlim(0, 4)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(plt.MultipleLocator(1.0))  # whole metres: no colliding labels
    ax.set_box_aspect((1, 1, 1))  # equal metres on every axis
    ax.figure.legend(*ax.get_legend_handles_labels(), loc="center left", bbox_to_anchor=(0.78, 0.5), frameon=False)
    ax.figure.subplots_adjust(right=0.78)
    ax.set_title("Target trajectories (world frame)")
    return ax


def plot_error_bars(summary, target: str, ax=None, methods=None):
    """Figs. 11 and 13: mean distance error per cell over replicates, with its 95 % interval.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.paper.summary_table` output (columns ``mean_abs_error_m``,
        ``ci_low_m``, ``ci_high_m`` per cell and method).
    target : {"sphere", "aruco"}
    methods : list of str, optional
        Localisers to show side by side (e.g. ["circle", "ellipse"]); default: the first present.

    Notes
    -----
    The whiskers are the 95 % t-interval of the mean over replicates (the paper shows ± one std of
    frames, which mixes spread within a revolution with uncertainty); a lower end below zero is
    drawn at zero, since the mean of an absolute error cannot be negative.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4.2))
    df = summary[summary["target"] == target]
    if df.empty:
        raise ValueError(f"summary holds no {target} rows")
    methods = list(dict.fromkeys(df["method"]))[:1] if methods is None else list(methods)
    conditions = [(d, t) for d in ("undistorted", "distorted") for t in ("circular", "diagonal")]
    series = [(meth, mode) for meth in methods for mode in ("passive", "active")]
    width = 0.8 / len(series)
    x = np.arange(len(conditions))
    hatches = ["", "//", "..", "xx"]
    for j, (meth, mode) in enumerate(series):
        means, lows, highs = [], [], []
        for d, t in conditions:
            row = df[(df["distortion"] == d) & (df["trajectory"] == t) & (df["mode"] == mode) & (df["method"] == meth)]
            if len(row) > 1:
                raise ValueError(f"summary holds {len(row)} rows for {target}/{d}/{t}/{mode}/{meth}")
            ok = len(row) == 1
            means.append(1000 * row["mean_abs_error_m"].iloc[0] if ok else np.nan)
            lows.append(1000 * row["ci_low_m"].iloc[0] if ok else np.nan)
            highs.append(1000 * row["ci_high_m"].iloc[0] if ok else np.nan)
        means, lows, highs = map(np.asarray, (means, lows, highs))
        lows = np.maximum(lows, 0.0)  # a mean |error| cannot be negative: the whisker stops at 0
        yerr = np.vstack((means - lows, highs - means))
        label = mode if len(methods) == 1 else f"{meth}, {mode}"
        ax.bar(x + (j - (len(series) - 1) / 2) * width, means, width, yerr=yerr, capsize=3,
               color=_MODE_COLOURS[mode], hatch=hatches[methods.index(meth) % len(hatches)],
               edgecolor="k", linewidth=0.5, label=label)
    ax.set_xticks(x, [f"{d}\n{t}" for d, t in conditions])
    ax.set_ylabel("|d_est − d_true| [mm]\nmean of replicates, 95 % CI")
    ax.set_ylim(bottom=0)
    ax.set_title("Distance error, " + {"sphere": "sphere", "aruco": "ArUco marker"}.get(target, target))
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(axis="y", alpha=0.3)
    return ax


def plot_xyz(result, revolution: int = 1, fig=None):
    """Figs. 12 and 14: estimated vs true target x, y, z (world) over one revolution.

    ``revolution`` counts from 0 (the acquisition revolution); the title counts from 1, as users do.
    """
    if fig is None:
        fig = plt.figure(figsize=(9, 6))
    axes = fig.subplots(3, 1, sharex=True)
    f = result.frames
    n_rev = int(round(result.config.revolutions))
    if not 0 <= revolution < max(n_rev, 1):
        raise ValueError(f"revolution must be in [0, {n_rev - 1}] for this run, got {revolution!r}")
    sel = f[f["revolution"] == revolution]
    for ax, axis in zip(axes, "xyz"):
        ax.plot(sel["t_mid_s"], sel[f"true_{axis}_m"], "k-", lw=1.5, label="ground truth")
        ax.plot(sel["t_mid_s"], sel[f"est_{axis}_m"], ".", color=_MODE_COLOURS[result.config.pointing.mode], ms=4,
                label="estimate")
        ax.set_ylabel(f"{axis} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.12), ncol=2, frameon=False, fontsize=8)
    kind = "acquisition" if revolution == 0 else "measured"
    fig.suptitle(f"{result.config.label} (seed {result.config.seed}): world coordinates, revolution "
                 f"{revolution + 1} of {n_rev} ({kind})", fontsize=10)
    axes[-1].set_xlabel("t [s]")
    return fig


def plot_pixel_offset(results, labels=None, ax=None):
    """Distance of the detected target from the image centre over time, one line per run.

    ``labels`` (one per run) default to the runs' labels. The first revolution is shaded
    (acquisition).
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3.5))
    labels = [r.config.label for r in results] if labels is None else list(labels)
    if len(labels) != len(results):
        raise ValueError(f"labels must have one entry per run ({len(results)}), got {len(labels)}")
    for r, label in zip(results, labels):
        ax.plot(r.frames["t_mid_s"], r.frames["offset_px"], lw=1, label=label)
    if results:
        ax.axvspan(0, results[0].config.target.period_s, color="0.9", zorder=0, label="acquisition")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("offset from image centre [px]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return ax


def plot_forest(verdicts, ax=None):
    """Forest plot of the claims: each paired difference a − b with its interval, in units of δ.

    Every row is one checked condition; the shaded band is ±δ (the smallest effect of interest,
    or the equivalence margin for "≈" claims, or the non-inferiority margin for "≤" claims), so a
    claim "a < b" holds where the interval lies left of 0 and its point left of −1, and "a ≤ b"
    (at least as good) where the interval (90 %: one-sided 95 % bounds) ends left of +1, and
    "a ≈ b" where the interval (90 %) lies inside ±1: a point near 0 alone is not enough. Colours
    give the verdict at 95 %; where the table has the family-level verdict (``verdict_holm``,
    :func:`gimbal_lab.stats.holm`) and it differs, the point is hollow (decisive alone,
    inconclusive in the family). The right margin prints the
    difference and interval in mm, or in the row's ``unit`` when the table has that column
    ("m", printed in mm, or "px"). A row without an interval (too few replicates) shows its point.
    """
    n = len(verdicts)
    if n == 0:
        raise ValueError("no verdicts to plot")
    if ax is None:
        _, ax = plt.subplots(figsize=(9, 0.32 * n + 1.2))
    y = np.arange(n)[::-1]
    scale = verdicts["delta"].to_numpy()
    point = verdicts["difference"].to_numpy() / scale
    low = verdicts["low"].to_numpy() / scale
    high = verdicts["high"].to_numpy() / scale
    ax.axvspan(-1, 1, color="0.9", zorder=0, label="±δ")
    ax.axvline(0, color="k", lw=0.8)
    changed = (verdicts["verdict_holm"] != verdicts["verdict"]).to_numpy() if "verdict_holm" in verdicts \
        else np.zeros(n, bool)
    for verdict, colour in _VERDICT_COLOURS.items():
        for hollow in (False, True):
            sel = (verdicts["verdict"].to_numpy() == verdict) & (changed == hollow)
            if sel.any():
                ax.errorbar(point[sel], y[sel], xerr=np.vstack((point[sel] - low[sel], high[sel] - point[sel])),
                            fmt="o", color=colour, ms=4, capsize=2, mfc="white" if hollow else colour,
                            label=f"{verdict}, inconclusive after Holm" if hollow else verdict)
    labels = [f"{r.id} {r.condition}: {r.a} {_CLAIM_SIGN.get(r.kind, '<')} {r.b}" for r in verdicts.itertuples()]
    ax.set_yticks(y, labels, fontsize=7)
    ax.set_xscale("symlog", linthresh=2.0)
    reach = float(np.nanmax(np.abs(np.concatenate((low, high, [2.0])))))
    ax.set_xlim(-1.6 * reach, 1.6 * reach)
    ticks = [t for t in (-1000, -100, -10, -1, 0, 1, 10, 100, 1000) if abs(t) <= 1.6 * reach]
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    label = "(a − b) / δ   (symmetric log scale; claim “a < b” holds left of −1"
    if (verdicts["kind"] == "non-inferior").any():
        label += "; “a ≤ b”, at least as good, where the interval ends left of +1"
    if (verdicts["kind"] == "equivalent").any():
        label += "; “a ≈ b” where the interval (90 %) lies inside ±1, the shaded band, wherever its point"
    ax.set_xlabel(label + ")")
    units = verdicts["unit"] if "unit" in verdicts else ["m"] * n
    for yi, r, unit in zip(y, verdicts.itertuples(), units):
        k, name = (1000.0, "mm") if unit == "m" else (1.0, unit)
        text = (f"{k * r.difference:+.1f} [{k * r.low:+.1f}, {k * r.high:+.1f}] {name}" if np.isfinite(r.low)
                else f"no interval: {r.n} complete pair(s)")
        ax.annotate(text, (1.01, yi), xycoords=("axes fraction", "data"), fontsize=6.5, va="center")
    ax.set_ylim(-0.7, n - 0.3)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, frameon=False, fontsize=8)
    return ax


def plot_pipeline_costs(summary, fig=None):
    """Each pipeline's distance error against its CPU cost per frame, one panel per target.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.paper.pipeline_summary` with costs: per target, distortion,
        trajectory and pipeline, ``common_abs_error_m`` with ``ci_low_m`` and ``ci_high_m`` (the
        frames all pipelines detected) and ``cost_ms``.

    Returns
    -------
    Figure
        x: detection and localisation, ms of CPU per frame; y: error in mm on a log axis (95 %
        interval of the mean over replicates). Colour: the pipeline; marker: the camera and path.
        "active (best)" and "best passive" run the same estimator, so they share their x.
    """
    if summary.empty:
        raise ValueError("summary holds no rows")
    targets = list(dict.fromkeys(summary["target"]))
    if fig is None:
        fig = plt.figure(figsize=(5.0 * len(targets) + 2.4, 4.2), layout="constrained")
    axes = fig.subplots(1, len(targets), squeeze=False)[0]
    for ax, target in zip(axes, targets):
        df = summary[summary["target"] == target]
        for row in df.itertuples():
            y = 1000.0 * row.common_abs_error_m
            low, high = 1000.0 * row.ci_low_m, 1000.0 * row.ci_high_m
            yerr = None
            if np.isfinite(low) and np.isfinite(high):
                yerr = [[min(y - low, 0.95 * y)], [high - y]]  # the log axis stays positive
            ax.errorbar(row.cost_ms, y, yerr=yerr, fmt=_CONDITION_MARKERS.get((row.distortion, row.trajectory), "o"),
                        color=_PIPELINE_COLOURS.get(row.pipeline, "k"), ms=6, capsize=2, mec="k", mew=0.4)
        ax.set_yscale("log")
        for axis in (ax.yaxis.set_major_formatter, ax.yaxis.set_minor_formatter):  # plain millimetres, not 1.2×10¹
            axis(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.set_xlim(0, 1.15 * float(np.nanmax(df["cost_ms"])))
        ax.set_xlabel("detection + localisation [ms CPU per frame]")
        ax.set_ylabel("|d_est − d_true| [mm], frames all detected")
        ax.set_title(_TARGET_TITLES.get(target, target))
        ax.grid(alpha=0.3, which="both")
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=p) for p, c in _PIPELINE_COLOURS.items()]
    handles += [plt.Line2D([], [], color="0.4", marker=m, ls="", label=f"{d}, {t}")
                for (d, t), m in _CONDITION_MARKERS.items()]
    axes[-1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=8)
    return fig


def plot_gains(summary, fig=None):
    """The moving drone's gain of the active over the stabilised camera, decomposed, per motion.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.moving_drone.gain_summary`: per target, motion and gain
        (``G_full``, ``G_sharp``, ``G_static``) the mean over replicates (``mean_m``) and its 95 %
        interval (``low_m``, ``high_m``).

    Returns
    -------
    Figure
        One panel per target: bars of the three gains (mm) per motion with their intervals; a
        gain without an interval (fewer than two replicates with frames both mounts detected)
        is drawn without whiskers, one without any value is marked ×.
    """
    if summary.empty:
        raise ValueError("summary holds no rows")
    targets = list(dict.fromkeys(summary["target"]))
    motions = list(dict.fromkeys(summary["motion"]))
    gains = [g for g in _GAIN_COLOURS if (summary["gain"] == g).any()]
    if fig is None:
        fig = plt.figure(figsize=(4.6 * len(targets) + 2.0, 3.9), layout="constrained")
    axes = fig.subplots(1, len(targets), squeeze=False)[0]
    x = np.arange(len(motions))
    width = 0.8 / max(len(gains), 1)
    labels = {"G_full": "G_full: the study's runs", "G_sharp": "G_sharp: no exposure blur",
              "G_static": "G_static: target still (body sway alone)"}
    for ax, target in zip(axes, targets):
        df = summary[summary["target"] == target]
        for j, gain in enumerate(gains):
            rows = [df[(df["motion"] == m) & (df["gain"] == gain)] for m in motions]
            pick = lambda r, c: 1000.0 * float(r[c].iloc[0]) if len(r) else np.nan  # noqa: E731
            mean = np.array([pick(r, "mean_m") for r in rows])
            low = np.array([pick(r, "low_m") for r in rows])
            high = np.array([pick(r, "high_m") for r in rows])
            yerr = np.where(np.isfinite(np.vstack((mean - low, high - mean))), np.vstack((mean - low, high - mean)), 0.0)
            offsets = x + (j - (len(gains) - 1) / 2) * width
            ax.bar(offsets, np.nan_to_num(mean), width, yerr=yerr, capsize=2, color=_GAIN_COLOURS[gain],
                   edgecolor="k", linewidth=0.4, label=labels[gain])
            missing = ~np.isfinite(mean)
            if missing.any():
                ax.plot(offsets[missing], np.zeros(missing.sum()), "x", color="k", ms=6)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(x, motions)
        ax.set_ylabel("stabilised − active error [mm]\nexact estimator, frames both detected")
        ax.set_title(_TARGET_TITLES.get(target, target))
        ax.grid(axis="y", alpha=0.3)
    axes[-1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=8)
    return fig


def plot_run_frame(passive, active, frame: int, renderer=None, fig=None):
    """One instant of a cell: the passive and active cameras' frames with the overlays of
    :func:`gimbal_lab.show.annotate`, and both runs' distance error over time with the instant
    marked.

    ``passive`` and ``active`` are the two runs of one cell and replicate; ``frame`` indexes both.
    ``renderer`` (one for the cell's target and lens) is reused when given.
    """
    from ..show import TRACE_FRAMES, annotate, replay

    n = len(passive.frames)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < n:
        raise ValueError(f"frame must be an integer in [0, {n - 1}], got {frame!r}")
    if fig is None:
        fig = plt.figure(figsize=(11, 6.2), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=(3, 1.4))
    for col, result in enumerate((passive, active)):
        ax = fig.add_subplot(grid[0, col])
        row, image = next(replay(result, renderer=renderer, start=frame, stop=frame + 1))
        past = result.frames.iloc[max(0, frame - TRACE_FRAMES + 1): frame + 1]
        ax.imshow(annotate(image, row, result.config, zip(past["true_u_px"], past["true_v_px"]),
                           title=result.config.pointing.mode.upper()))
        ax.set_axis_off()
    ax = fig.add_subplot(grid[1, :])
    for result in (passive, active):
        f = result.frames
        ax.plot(f["t_mid_s"], 1000 * f["abs_error_m"], color=_MODE_COLOURS[result.config.pointing.mode], lw=1.2,
                label=result.config.pointing.mode)
    t = passive.frames["t_mid_s"].iloc[frame]
    ax.axvline(t, color="k", lw=1, ls="--")
    for k in range(1, int(np.ceil(passive.config.revolutions))):
        ax.axvline(k * passive.config.target.period_s, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("t [s] (dotted: a new revolution; the first is acquisition)")
    ax.set_ylabel("|d_est − d_true| [mm]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    c = passive.config
    revolution = int(passive.frames["revolution"].iloc[frame])
    fig.suptitle(f"{c.target.kind}, {c.camera.lens_label}, {c.target.trajectory}, replicate {c.seed}: frame {frame} "
                 f"(t = {t:.2f} s, revolution {revolution + 1} of {int(np.ceil(c.revolutions))})", fontsize=10)
    return fig


def run_explorer(results, frame: int | None = None):
    """Pick a cell and a replicate and scrub through its frames (ipywidgets).

    ``results`` are study runs (e.g. one target's); every cell and replicate with both a passive
    and an active run is offered. Each change redraws :func:`plot_run_frame` (two renders).
    Outside a live kernel (nbmake, a static export) it draws once: the first cell and replicate
    at ``frame`` (default: three quarters through the run).

    Returns
    -------
    ipywidgets.interactive or None
        Its ``result`` is the figure's title for the drawn instant.
    """
    import ipywidgets
    from IPython.display import display

    from ..simulation import make_renderer

    pairs: dict = {}
    for r in results:
        c = r.config
        pairs.setdefault((f"{c.camera.lens_label}/{c.target.trajectory}", c.seed), {})[c.pointing.mode] = r
    pairs = {k: v for k, v in pairs.items() if set(v) == {"passive", "active"}}
    if not pairs:
        raise ValueError("results hold no cell with both a passive and an active run")
    cells = list(dict.fromkeys(k[0] for k in pairs))
    seeds = sorted({k[1] for k in pairs})
    n = max(len(v["passive"].frames) for v in pairs.values())
    start = (3 * n) // 4 if frame is None else frame
    renderers: dict = {}

    def draw(cell, replicate, frame):
        pair = pairs.get((cell, replicate))
        if pair is None:
            print(f"no runs for {cell}, replicate {replicate}")
            return None
        c = pair["passive"].config
        key = c.renderer_key  # what make_renderer builds from
        if key not in renderers:
            renderers[key] = make_renderer(c)
        fig = plot_run_frame(pair["passive"], pair["active"], min(frame, len(pair["passive"].frames) - 1),
                             renderer=renderers[key])
        title = fig.get_suptitle()
        display(fig)
        plt.close(fig)
        return title

    return interactive(
        draw,
        cell=ipywidgets.Dropdown(options=cells, value=cells[0], description="cell"),
        replicate=ipywidgets.Dropdown(options=seeds, value=seeds[0], description="replicate"),
        frame=ipywidgets.IntSlider(value=start, min=0, max=n - 1, step=1, description="frame",
                                   continuous_update=False),
    )


def plot_mount_bars(summary, fig=None):
    """The moving-drone study per cell: common-frame distance error, detection rate and blur streak.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.moving_drone.summary_table` output.

    Returns
    -------
    Figure
        Rows: error (mm, over the frames every mount detected, 95 % CI), detection rate, streak
        (px, 95 % CI); columns: targets. Bars: motions × shutters, one colour per mount; a cell
        without common detections has no error bar (marked ×).
    """
    targets = list(dict.fromkeys(summary["target"]))
    if not targets:
        raise ValueError("summary holds no rows")
    if fig is None:
        fig = plt.figure(figsize=(5.2 * len(targets) + 1.6, 8.4), layout="constrained")
    axes = fig.subplots(3, len(targets), squeeze=False, sharex=True)
    mounts = [m for m in _MOUNT_COLOURS if (summary["mount"] == m).any()]
    conditions = list(dict.fromkeys(zip(summary["motion"], summary["shutter"])))
    x = np.arange(len(conditions))
    width = 0.8 / len(mounts)
    panels = (("common_abs_error_m", "ci_low_m", "ci_high_m", 1000.0, "|d_est − d_true| [mm]\nframes every mount detected"),
              ("detection_rate", None, None, 1.0, "detection rate"),
              ("mean_streak_px", "streak_ci_low_px", "streak_ci_high_px", 1.0, "target blur streak [px]"))
    for col, target in enumerate(targets):
        df = summary[summary["target"] == target]
        for row, (value, low, high, k, label) in enumerate(panels):
            ax = axes[row, col]
            for j, mount in enumerate(mounts):
                cells = [df[(df["motion"] == m) & (df["shutter"] == s) & (df["mount"] == mount)] for m, s in conditions]
                pick = lambda c, name: k * float(c[name].iloc[0]) if (name and len(c)) else np.nan  # noqa: E731
                means = np.array([pick(c, value) for c in cells])
                offsets = x + (j - (len(mounts) - 1) / 2) * width
                yerr = None
                if low:
                    lows = np.maximum(np.array([pick(c, low) for c in cells]), 0.0)
                    highs = np.array([pick(c, high) for c in cells])
                    yerr = np.vstack((means - lows, highs - means))
                    yerr = np.where(np.isfinite(yerr), yerr, 0.0)
                ax.bar(offsets, np.nan_to_num(means), width, yerr=yerr, capsize=2, color=_MOUNT_COLOURS[mount],
                       edgecolor="k", linewidth=0.4, label=mount)
                missing = ~np.isfinite(means)
                if missing.any():
                    ax.plot(offsets[missing], np.zeros(missing.sum()), "x", color="k", ms=6)
            ax.set_ylabel(label)
            ax.set_ylim(0, 1.05 if value == "detection_rate" else None)
            ax.grid(axis="y", alpha=0.3)
            if row == 0:
                ax.set_title({"sphere": "sphere", "aruco": "ArUco marker"}.get(target, target))
            if row == 2:
                ax.set_xticks(x, [f"{m}\n{s}" for m, s in conditions], fontsize=8)
    axes[0, -1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig


def crop_around(image: np.ndarray, u: float, v: float, zoom_px: int) -> np.ndarray | None:
    """The ``2·zoom_px`` square of ``image`` centred on pixel (u, v), black beyond the image's
    edges; None when (u, v) is not finite or lies outside the image (no crop to show)."""
    h, w = image.shape[:2]
    if not (np.isfinite(u) and np.isfinite(v)):
        return None
    cu, cv = int(round(u)), int(round(v))
    if not (0 <= cu <= w and 0 <= cv <= h):
        return None
    pad = np.pad(image, ((zoom_px, zoom_px), (zoom_px, zoom_px)) + ((0, 0),) * (image.ndim - 2), constant_values=0)
    return pad[cv: cv + 2 * zoom_px, cu: cu + 2 * zoom_px]


def plot_mount_frames(runs, frame: int, renderer=None, zoom_px: int = 48, fig=None):
    """One instant seen by several runs of one cell (the moving-drone study's three mounts).

    Top row: each run's blurred frame with the overlays of :func:`gimbal_lab.show.annotate`;
    bottom row: a crop of ``2·zoom_px`` pixels around the target's true centre, enlarged, where
    the blur streak shows. ``runs`` share the target and lens; ``renderer`` is reused when given.
    """
    from ..show import annotate, replay
    from ..simulation import make_renderer

    runs = list(runs)
    if not runs:
        raise ValueError("no runs to show")
    n = len(runs[0].frames)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < n:
        raise ValueError(f"frame must be an integer in [0, {n - 1}], got {frame!r}")
    if fig is None:
        fig = plt.figure(figsize=(4.2 * len(runs), 6.4), layout="constrained")
    axes = fig.subplots(2, len(runs), squeeze=False, height_ratios=(3, 2.4))
    own = renderer is None
    renderer = make_renderer(runs[0].config) if own else renderer
    try:
        for col, result in enumerate(runs):
            c = result.config
            row, image = next(replay(result, renderer=renderer, start=frame, stop=frame + 1))
            axes[0, col].imshow(annotate(image, row, c, title=f"{c.pointing.mount.upper()}  streak {row.streak_px:.1f} px"))
            axes[0, col].set_axis_off()
            ax = axes[1, col]
            crop = crop_around(image, row.true_u_px, row.true_v_px, zoom_px)
            if crop is not None:
                ax.imshow(crop, interpolation="nearest")
                ax.set_title(f"{2 * zoom_px} × {2 * zoom_px} px around the target", fontsize=9)
            else:
                ax.set_title("the target's centre is outside the frame", fontsize=9)
            ax.set_axis_off()
    finally:
        if own:
            renderer.close()
    c = runs[0].config
    readout_s = c.camera.readout_s
    shutter = f"rolling shutter {1000 * readout_s:.0f} ms" if readout_s > 0 else "global shutter"
    fig.suptitle(f"{c.target.kind}, {c.platform.motion}, {shutter}, exposure {1000 * c.camera.exposure_s:.1f} ms, "
                 f"replicate {c.seed}: "
                 f"frame {frame} (t = {runs[0].frames['t_s'].iloc[frame]:.2f} s)", fontsize=10)
    return fig


def plot_body_motions(bodies: dict, duration_s: float = 4.0, zoom_s: float = 0.05, fig=None):
    """The drone body's attitude and position over time, one column per motion.

    Parameters
    ----------
    bodies : dict
        Label → :class:`gimbal_lab.platform.BodyMotion` (e.g. the study's hover, vibration and
        flight bodies of one replicate, ``config.body``).
    duration_s : float
        Time shown, s.
    zoom_s : float
        Length of the inset row's window (from t = 1 s), where the 120 Hz vibration shows.

    Returns
    -------
    Figure
        Rows: roll, pitch and yaw (deg) over ``duration_s``; the same over ``zoom_s``; the body's
        displacement from its start (m).
    """
    if not bodies:
        raise ValueError("no bodies to plot")
    if not duration_s > zoom_s > 0:
        raise ValueError(f"need duration_s > zoom_s > 0, got {duration_s!r}, {zoom_s!r}")
    if fig is None:
        fig = plt.figure(figsize=(4.0 * len(bodies) + 1.0, 7.0), layout="constrained")
    axes = fig.subplots(3, len(bodies), squeeze=False)
    t = np.linspace(0.0, duration_s, 4001)
    tz = np.linspace(1.0, 1.0 + zoom_s, 1001)
    names = ("yaw", "pitch", "roll")
    for col, (label, body) in enumerate(bodies.items()):
        for ax, times in ((axes[0, col], t), (axes[1, col], tz)):
            angles = np.degrees(body.attitude(times)[0])
            for i in (2, 1, 0):
                ax.plot(times, angles[:, i], lw=0.9, label=names[i])
            ax.grid(alpha=0.3)
        axes[0, col].set_title(label)
        axes[1, col].set_xlabel("t [s]")
        p = body.position(t)
        for i, axis in enumerate("xyz"):
            axes[2, col].plot(t, p[:, i] - p[0, i], lw=0.9, label=f"Δ{axis}")
        axes[2, col].set_xlabel("t [s]")
        axes[2, col].grid(alpha=0.3)
        axes[2, col].legend(fontsize=7, loc="upper right")
    axes[0, 0].set_ylabel("attitude [deg]")
    axes[1, 0].set_ylabel(f"attitude [deg]\n{1000 * zoom_s:.0f} ms from t = 1 s")
    axes[2, 0].set_ylabel("position − start [m]")
    axes[0, -1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig


def plot_lens_sweep(summary, value: str = "mean_abs_error_m", fig=None):
    """The lens sweep: one quantity against the lens, a line per strategy, per target and mode.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.lens_sweep.summary_table` output (rows in the sweep's lens order).
    value : {"mean_abs_error_m", "detection_rate_pct", "common_abs_error_m", "estimate_ms"}
        The error is drawn in mm on a log axis with its 95 % interval; the others linearly.

    Returns
    -------
    Figure
        Rows: targets; columns: passive, active. The x axis lists the lenses from the pinhole to the
        185° fisheye (a dotted line separates the Brown–Conrady lenses from the fisheyes). The
        pinhole runs "ignore" only, so the other strategies start at the first distorted lens.
    """
    labels = {"mean_abs_error_m": "|d_est − d_true| [mm]", "common_abs_error_m": "error, common frames [mm]",
              "alt_abs_error_m": "exact cone fit |d_est − d_true| [mm]",
              "detection_rate_pct": "detection rate [%]", "estimate_ms": "detection + localisation [ms/frame]"}
    if value not in labels:
        raise ValueError(f"value must be one of {tuple(labels)}, got {value!r}")
    if "cone" in summary:  # the sweep's own cones; the fisheyes' in-limit cones have a figure of their own
        summary = summary[summary["cone"] == "field"]
    targets = list(dict.fromkeys(summary["target"]))
    if not targets:
        raise ValueError("summary holds no rows")
    lenses = list(dict.fromkeys(summary["lens"]))
    modes = [m for m in _MODE_COLOURS if (summary["mode"] == m).any()]
    if fig is None:
        fig = plt.figure(figsize=(5.0 * len(modes) + 1.8, 3.4 * len(targets)), layout="constrained")
    axes = fig.subplots(len(targets), len(modes), squeeze=False, sharex=True)
    x = {lens: i for i, lens in enumerate(lenses)}
    k = 1000.0 if value.endswith("_m") else 1.0
    for r, target in enumerate(targets):
        for c, mode in enumerate(modes):
            ax = axes[r, c]
            for j, strategy in enumerate(_STRATEGY_COLOURS):
                df = summary[(summary["target"] == target) & (summary["mode"] == mode) & (summary["strategy"] == strategy)]
                if df.empty:
                    continue
                xs = np.array([x[lens] for lens in df["lens"]]) + (j - 1) * 0.08
                ys = k * df[value].to_numpy(float)
                yerr = None
                if value in ("mean_abs_error_m", "alt_abs_error_m"):
                    prefix = "alt_" if value == "alt_abs_error_m" else ""
                    yerr = np.vstack((ys - k * df[f"{prefix}ci_low_m"].to_numpy(float),
                                      k * df[f"{prefix}ci_high_m"].to_numpy(float) - ys))
                    yerr = np.where(np.isfinite(yerr), np.clip(yerr, 0.0, None), 0.0)
                    yerr[0] = np.minimum(yerr[0], 0.95 * np.nan_to_num(ys, nan=1.0))  # keep the log axis positive
                ax.errorbar(xs, ys, yerr=yerr, fmt="o-", ms=4, capsize=2, color=_STRATEGY_COLOURS[strategy],
                            label=strategy)
            families = summary.drop_duplicates("lens").set_index("lens")["family"]
            fisheyes = [x[lens] for lens in lenses if families.get(lens) == "fisheye"]
            if fisheyes and min(fisheyes) > 0:
                ax.axvline(min(fisheyes) - 0.5, color="0.5", ls=":", lw=1)
            if value in ("mean_abs_error_m", "alt_abs_error_m"):
                ax.set_yscale("log")
            if value == "detection_rate_pct":
                ax.set_ylim(-3, 103)
            ax.grid(alpha=0.3, which="both")
            ax.set_title(f"{_TARGET_TITLES.get(target, target)}, {mode}")
            if c == 0:
                ax.set_ylabel(labels[value])
            if r == len(targets) - 1:
                ax.set_xticks(range(len(lenses)), lenses, rotation=30, ha="right", fontsize=8)
    axes[0, -1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, title="lens strategy")
    return fig


def plot_lens_costs(summary, fig=None):
    """Cost per frame of each lens strategy, per target, and of rendering, per lens.

    Left panels (one per target): detection and localisation per frame, rectification included,
    for each strategy: the mean of the passive and active cells, the whisker spanning the two.
    Right: rendering per frame, passive (a still camera) and active (a turning one), where the
    fisheyes' cube map shows. All are wall times measured inside the runs.
    """
    if "cone" in summary:
        summary = summary[summary["cone"] == "field"]
    if summary.empty:
        raise ValueError("summary holds no rows")
    lenses = list(dict.fromkeys(summary["lens"]))
    targets = list(dict.fromkeys(summary["target"]))
    if fig is None:
        fig = plt.figure(figsize=(4.6 * len(targets) + 4.2, 3.9), layout="constrained")
    axes = fig.subplots(1, len(targets) + 1, gridspec_kw={"width_ratios": [2] * len(targets) + [1.6]})
    width = 0.8 / len(_STRATEGY_COLOURS)
    x = np.arange(len(lenses))
    for ax, target in zip(axes, targets):
        df = summary[summary["target"] == target]
        for j, (strategy, colour) in enumerate(_STRATEGY_COLOURS.items()):
            per_lens = df[df["strategy"] == strategy].groupby("lens", sort=False)["estimate_ms"]
            mean, low, high = (np.array([getattr(per_lens, f)().get(lens, np.nan) for lens in lenses])
                               for f in ("mean", "min", "max"))
            yerr = np.nan_to_num(np.vstack((mean - low, high - mean)))
            ax.bar(x + (j - 1) * width, np.nan_to_num(mean), width, yerr=yerr, capsize=2, color=colour,
                   edgecolor="k", linewidth=0.4, label=strategy)
        ax.set_xticks(x, lenses, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("detection + localisation [ms/frame]")
        ax.set_title(f"{_TARGET_TITLES.get(target, target)}: cost of each lens strategy", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        ax.set_ylim(0, 1.2 * ax.get_ylim()[1])  # room for the legend above the bars
    axes[0].legend(frameon=False, fontsize=8, loc="upper left", ncol=3)
    ax_render = axes[-1]
    render = summary.groupby(["lens", "mode"], sort=False)["render_ms"].mean().unstack()
    for j, mode in enumerate(m for m in _MODE_COLOURS if m in render):
        ax_render.bar(x + (j - 0.5) * 0.4, [render[mode].get(lens, np.nan) for lens in lenses], 0.4,
                      color=_MODE_COLOURS[mode], edgecolor="k", linewidth=0.4, label=mode)
    ax_render.set_xticks(x, lenses, rotation=30, ha="right", fontsize=8)
    ax_render.set_ylabel("render [ms/frame]")
    ax_render.set_title("rendering (fisheyes: cube map + remap)", fontsize=9)
    ax_render.legend(frameon=False, fontsize=8)
    ax_render.grid(axis="y", alpha=0.3)
    return fig


def plot_lens_views(views: dict, fig=None):
    """Each lens's passive view of the target and, below, its rectified view.

    ``views`` maps a lens name to ``(image, rectified)`` (:func:`gimbal_lab.studies.lens_sweep.example_view`;
    ``rectified`` None for the pinhole). The fisheyes' rectified views are 90° pinholes: the target,
    0.7 of the half field off the axis, lies outside them.
    """
    if not views:
        raise ValueError("no views to plot")
    n = len(views)
    if fig is None:
        fig = plt.figure(figsize=(2.3 * n, 4.0), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False)
    for j, (name, (image, rectified)) in enumerate(views.items()):
        axes[0, j].imshow(image)
        axes[0, j].set_title(name, fontsize=9)
        if rectified is not None:
            axes[1, j].imshow(rectified)
        else:
            axes[1, j].text(0.5, 0.5, "no lens:\nnothing to rectify", ha="center", va="center", fontsize=8,
                            transform=axes[1, j].transAxes)
        for ax in axes[:, j]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, 0].set_ylabel("camera image", fontsize=9)
    axes[1, 0].set_ylabel("rectified", fontsize=9)
    return fig


def plot_lens_radii(configs: dict, ax=None):
    """Image radius against field angle for each lens, up to the image's corner.

    ``configs`` maps a label to a :class:`gimbal_lab.config.TrackingConfig` (its camera's
    intrinsics and lens); rays in the horizontal plane are projected through each, so
    Brown–Conrady's tangential terms show as they act along x. A dot marks the cone trajectory's
    angle (:meth:`gimbal_lab.config.Target.cone_half_angle`) for configs on the cone.
    """
    from ..camera import project

    if not configs:
        raise ValueError("no lenses to plot")
    if ax is None:
        _, ax = plt.subplots(figsize=(7.5, 4.2), layout="constrained")
    for j, (label, config) in enumerate(configs.items()):
        K, lens = config.camera.intrinsics, config.camera.lens_model
        corner = float(np.hypot(K.width - 1 - K.cx, K.height - 1 - K.cy))
        theta = np.linspace(0.0, math.radians(179.0), 1000)
        fisheye = lens is not None and type(lens).__name__ == "KannalaBrandt"
        if not fisheye:
            theta = theta[theta < math.radians(85.0)]
        rays = np.column_stack((np.sin(theta), np.zeros_like(theta), np.cos(theta)))
        radius = project(rays, K, lens)[:, 0] - K.cx
        keep = radius <= corner
        if not fisheye:  # a barrel polynomial turns back beyond its field: keep its rising part
            rising = np.r_[True, np.diff(radius) > 0]
            keep &= np.cumprod(rising).astype(bool)
        colour = plt.cm.viridis(j / max(len(configs) - 1, 1))
        ax.plot(np.degrees(theta[keep]), radius[keep], color=colour, label=label)
        if config.target.trajectory == "cone":
            beta = config.target.cone_half_angle(config.camera.horizontal_field_rad)
            r = project(np.array([[math.sin(beta), 0.0, math.cos(beta)]]), K, lens)[0, 0] - K.cx
            ax.plot(math.degrees(beta), r, "o", color=colour, ms=5)
    ax.axhline(319.5, color="0.6", ls=":", lw=1)
    ax.axhline(float(np.hypot(319.5, 239.5)), color="0.6", ls="--", lw=1)
    ax.annotate("image edge (x)", (2, 322), fontsize=7, color="0.4")
    ax.annotate("image corner", (2, 402), fontsize=7, color="0.4")
    ax.set_xlabel("angle of the ray off the optical axis [deg]")
    ax.set_ylabel("image radius [px]")
    ax.set_ylim(0, 420)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, frameon=False, loc="lower right")
    return ax.figure


_METHOD_MARKERS = {"circle": "o", "exact": "s", "PnP": "D"}


def plot_lens_error_cost(summary, costs, fig=None):
    """Error against CPU cost per frame for every pipeline of the lens sweep (field cones).

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.lens_sweep.summary_table` (the error on each run's own
        localisations: ``mean_abs_error_m`` for the circle method or PnP, ``alt_abs_error_m`` for
        the sphere's exact cone fit).
    costs : DataFrame
        :func:`gimbal_lab.studies.lens_sweep.cost_summary` (CPU ms per frame, measured apart from
        the runs, with its 95 % interval over replicates).

    Returns
    -------
    Figure
        Rows: targets; columns: passive, active. One point per lens, strategy (colour) and method
        (marker: circle ○, exact cone fit □, PnP ◇), the cost's interval as a horizontal bar; the
        error axis is logarithmic. Lens names label the "ignore" points.
    """
    if summary is None or len(summary) == 0 or costs is None or len(costs) == 0:
        raise ValueError("summary and costs must hold rows")
    if "cone" in summary:
        summary = summary[summary["cone"] == "field"]
    targets = [t for t in _TARGET_TITLES if (costs["target"] == t).any()]
    modes = [m for m in _MODE_COLOURS if (costs["mode"] == m).any()]
    if fig is None:
        fig = plt.figure(figsize=(5.4 * len(modes) + 1.6, 3.9 * len(targets)), layout="constrained")
    axes = fig.subplots(len(targets), len(modes), squeeze=False)
    cell = summary.set_index(["target", "lens", "strategy", "mode"])
    for r, target in enumerate(targets):
        for c, mode in enumerate(modes):
            ax = axes[r, c]
            sel = costs[(costs["target"] == target) & (costs["mode"] == mode)]
            for row in sel.itertuples():
                key = (target, row.lens, row.strategy, mode)
                if key not in cell.index:
                    continue
                error_m = cell.loc[key, "alt_abs_error_m" if row.method == "exact" else "mean_abs_error_m"]
                if not np.isfinite(error_m):
                    continue
                xerr = np.array([[row.cpu_ms - row.cpu_ci_low_ms], [row.cpu_ci_high_ms - row.cpu_ms]])
                colour = _STRATEGY_COLOURS[row.strategy]
                filled = row.method != "circle"
                ax.errorbar(row.cpu_ms, 1000.0 * error_m, xerr=np.nan_to_num(np.clip(xerr, 0.0, None)),
                            fmt=_METHOD_MARKERS[row.method], ms=5, capsize=2, color=colour,
                            mfc=colour if filled else "white")
                if row.strategy == "ignore" and row.method != "circle":
                    ax.annotate(row.lens, (row.cpu_ms, 1000.0 * error_m), fontsize=6, xytext=(3, 2),
                                textcoords="offset points", color="0.3")
            ax.set_yscale("log")
            ax.grid(alpha=0.3, which="both")
            ax.set_title(f"{_TARGET_TITLES.get(target, target)}, {mode}", fontsize=9)
            ax.set_xlabel("CPU time per frame, detection + localisation [ms]")
            if c == 0:
                ax.set_ylabel("|d_est − d_true| [mm]")
    handles = [plt.Line2D([], [], color=colour, marker="s", ls="", label=strategy)
               for strategy, colour in _STRATEGY_COLOURS.items()]
    handles += [plt.Line2D([], [], color="k", marker=marker, ls="", mfc="white" if method == "circle" else "k",
                           label={"circle": "circle method", "exact": "exact cone fit", "PnP": "PnP"}[method])
                for method, marker in _METHOD_MARKERS.items() if (costs["method"] == method).any()]
    fig.legend(handles=handles, loc="outside right upper", fontsize=8, frameon=False)
    return fig


def plot_lens_h2_limits(replicates, demand, fig=None):
    """H2 on the fisheyes: active's advantage on the in-limit and the field (over-limit) cones,
    beside what each cone asks of the gimbal.

    Parameters
    ----------
    replicates : DataFrame
        :func:`gimbal_lab.studies.lens_sweep.replicate_table` (the "ignore" runs of the fisheyes).
    demand : DataFrame
        :func:`gimbal_lab.studies.lens_sweep.demand_table` (one row per fisheye and cone).

    Returns
    -------
    Figure
        Left panels, one per target: passive − active error (the paper's pipeline, each run's own
        detections) per fisheye, mean over replicates with its 95 % interval, the field cone
        (0.7 of the half field) and the in-limit 40° cone side by side. Right: each cone's peak yaw
        rate against the loop's 3 rad/s limit (bars) and the share of the active runs' measured
        frames with a joint at its stop (points, right axis).
    """
    import pandas as pd

    from ..stats import mean_interval

    if replicates is None or len(replicates) == 0 or demand is None or len(demand) == 0:
        raise ValueError("replicates and demand must hold rows")
    lenses = list(dict.fromkeys(demand["lens"]))
    targets = [t for t in _TARGET_TITLES if (replicates["target"] == t).any()]
    cones = {"field": ("field cone (0.7 of half field)", "tab:red"), "in-limit": ("in-limit cone (40°)", "tab:green")}
    if fig is None:
        fig = plt.figure(figsize=(4.3 * len(targets) + 4.6, 3.8), layout="constrained")
    axes = fig.subplots(1, len(targets) + 1)
    x = np.arange(len(lenses))
    ignore = replicates[replicates["strategy"] == "ignore"]
    for ax, target in zip(axes, targets):
        for j, (cone, (label, colour)) in enumerate(cones.items()):
            means, lows, highs = [], [], []
            for lens in lenses:
                sel = ignore[(ignore["target"] == target) & (ignore["lens"] == lens) & (ignore["cone"] == cone)]
                per = sel.pivot_table(index="seed", columns="mode", values="mean_abs_error_m")
                gap = (per["passive"] - per["active"]) if {"passive", "active"} <= set(per.columns) else pd.Series(dtype=float)
                mean, low, high = mean_interval(1000.0 * gap.to_numpy(float))
                means.append(mean)
                lows.append(low)
                highs.append(high)
            means, lows, highs = (np.array(v, float) for v in (means, lows, highs))
            yerr = np.nan_to_num(np.clip(np.vstack((means - lows, highs - means)), 0.0, None))
            ax.errorbar(x + (j - 0.5) * 0.18, means, yerr=yerr, fmt="o", ms=5, capsize=3, color=colour, label=label)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xticks(x, lenses, fontsize=8)
        ax.set_xlim(-0.5, len(lenses) - 0.5)
        ax.set_ylabel("passive − active error [mm]")
        ax.set_title(f"{_TARGET_TITLES.get(target, target)}: active's advantage (ignore the lens)", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, frameon=False)
    ax = axes[-1]
    for j, (cone, (label, colour)) in enumerate(cones.items()):
        d = demand[demand["cone"] == cone].set_index("lens").reindex(lenses)
        ax.bar(x + (j - 0.5) * 0.36, d["peak_yaw_rate_rad_s"], 0.36, color=colour, alpha=0.6, edgecolor="k",
               linewidth=0.4, label=f"{label.split(' (')[0]}: peak yaw rate")
    limit = float(demand["rate_limit_rad_s"].iloc[0])
    ax.axhline(limit, color="k", ls="--", lw=1, label=f"loop's limit {limit:g} rad/s")
    ax.set_xticks(x, lenses, fontsize=8)
    ax.set_ylabel("peak yaw rate to centre the cone [rad/s]")
    ax.set_title("demand: rate (bars), frames at a joint stop (points)", fontsize=9)
    twin = ax.twinx()
    for j, (cone, (label, colour)) in enumerate(cones.items()):
        d = demand[demand["cone"] == cone].set_index("lens").reindex(lenses)
        stops = d[[c for c in d.columns if c.startswith("stop_pct_")]].mean(axis=1) if any(
            c.startswith("stop_pct_") for c in d.columns) else np.full(len(lenses), np.nan)
        twin.plot(x + (j - 0.5) * 0.36, stops, "D", color=colour, mec="k", ms=6)
    twin.set_ylabel("active frames at a joint stop [%]")
    twin.set_ylim(0, 100)
    ax.legend(fontsize=7, frameon=False, loc="upper left")
    return fig

