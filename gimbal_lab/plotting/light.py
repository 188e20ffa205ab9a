"""Figures of the buying-rule map (docs/design.md, "Exposure as a choice, and a buying rule"): the
map of where a gimbal pays over the streak at the shortest exposure and the light, and each
point's Δ against that streak. They draw tables; they import no study."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np

__all__ = ["CLASS_COLOURS", "plot_buying_map", "plot_delta_vs_streak"]

#: Colour of a point's family-level class.
CLASS_COLOURS = {"pays": "tab:green", "does not": "tab:red", "open": "0.6"}
_CLASS_LABELS = {"pays": "gimbal pays", "does not": "gimbal does not pay", "open": "open"}


def _s_limits(ax, points, boundary) -> None:
    """The x range: the points' s and the rule, a factor of 2 beyond (a band reaching further is cut)."""
    s = points["s_px"].to_numpy(float)
    s = list(s[np.isfinite(s) & (s > 0)])
    if math.isfinite(float(boundary.s_px)):
        s.append(float(boundary.s_px))
    if s:
        ax.set_xlim(min(s) / 2.0, max(s) * 2.0)


def _boundary(ax, boundary, label: bool = True) -> None:
    """The rule's s* as a vertical line over its shaded band (nothing when there is none)."""
    s, low, high = (float(getattr(boundary, k)) for k in ("s_px", "low_px", "high_px"))
    if not math.isfinite(s):
        return
    if math.isfinite(low) and math.isfinite(high):
        ax.axvspan(low, high, color="0.85", zorder=0, label="95 % band" if label else None)
    ax.axvline(s, color="k", lw=1.6, zorder=1, label=f"s* = {s:.3g} px" if label else None)


def plot_buying_map(points, boundary, ax=None):
    """Where a gimbal pays: every point at (s, light), coloured by its family-level class.

    Parameters
    ----------
    points : DataFrame
        One row per point: ``s_px`` (the target's streak at the shortest exposure the light
        allows, px), ``light_lux`` and ``class`` ("pays", "does not", "open").
    boundary : object
        With ``s_px``, ``low_px``, ``high_px`` (the rule and its 95 % band, px; NaN for none) and
        ``note`` (why there is none).
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
        Both axes logarithmic; the rule is the vertical line, its band shaded.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.8))
    _boundary(ax, boundary)
    for cls, colour in CLASS_COLOURS.items():
        sel = points["class"] == cls
        if sel.any():
            ax.scatter(points.loc[sel, "s_px"], points.loc[sel, "light_lux"], s=48, zorder=3,
                       color=colour if cls != "open" else "none", edgecolors=colour if cls == "open" else "k",
                       linewidths=1.2, label=f"{_CLASS_LABELS[cls]} ({int(sel.sum())})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _s_limits(ax, points, boundary)
    ax.set_xlabel("target's streak at the shortest exposure the light allows, s (px)")
    ax.set_ylabel("light (lx)")
    if not math.isfinite(float(boundary.s_px)):
        ax.set_title(str(boundary.note), fontsize=9)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False, fontsize=8)
    return ax


def plot_delta_vs_streak(points, boundary, ax=None):
    """Each point's mean Δ = best active − best passive (mm) with its 95 % interval against s.

    Parameters
    ----------
    points : DataFrame
        ``s_px``, ``delta_m``, ``delta_low_m``, ``delta_high_m`` and ``class``.
    boundary : object
        As for :func:`plot_buying_map`.
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
        Below the dashed zero line the gimbal's best pipeline beats the best passive one.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.2))
    _boundary(ax, boundary, label=False)
    ax.axhline(0.0, color="k", ls="--", lw=0.8)
    for cls, colour in CLASS_COLOURS.items():
        sel = (points["class"] == cls) & np.isfinite(points["delta_m"].to_numpy(float))
        if not sel.any():
            continue
        p = points[sel]
        y = 1000 * p["delta_m"].to_numpy(float)
        low, high = 1000 * p["delta_low_m"].to_numpy(float), 1000 * p["delta_high_m"].to_numpy(float)
        err = np.vstack([np.where(np.isfinite(low), y - low, 0.0), np.where(np.isfinite(high), high - y, 0.0)])
        ax.errorbar(p["s_px"], y, yerr=err, fmt="o", color=colour, mec="k", ms=6, capsize=2, lw=1, zorder=3,
                    label=f"{_CLASS_LABELS[cls]} ({int(sel.sum())})")
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1.0)  # millimetres and metres on one axis, as the payoff map's
    _s_limits(ax, points, boundary)
    ax.set_xlabel("target's streak at the shortest exposure the light allows, s (px)")
    ax.set_ylabel("Δ = best active − best passive (mm)")
    ax.legend(loc="best", frameon=False, fontsize=8)
    return ax
