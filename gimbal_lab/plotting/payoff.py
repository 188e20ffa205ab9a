"""Figures of the payoff map (docs/design.md, "The payoff map"): Δ against each factor, the
factors' ranking, the map with its break-even boundary. They draw tables; they import no study."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import MaxNLocator

__all__ = ["plot_delta_vs_factors", "plot_ranking", "plot_payoff_map"]

#: Colour of a point's family-level class.
CLASS_COLOURS = {"pays off": "tab:green", "does not": "tab:red", "open": "0.55"}


def plot_delta_vs_factors(points, factors, columns=(("delta_best", "Δ best"), ("delta_paper", "Δ paper")), fig=None):
    """Each point's mean Δ (mm) with its 95 % interval against every factor, one panel per factor.

    Parameters
    ----------
    points : DataFrame
        One row per point: each factor's value, ``COL_m``, ``COL_low_m``, ``COL_high_m`` for every
        ``COL`` of ``columns``, and ``class`` (colours the first column's points).
    factors : list of dict
        ``name``, ``label`` (with unit), ``low``, ``high`` of each factor, in panel order; ``integer``
        (optional) puts ticks on whole numbers only.
    columns : sequence of (str, str)
        The responses drawn (column stem, legend label); the first filled, the others hollow.
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib Figure
        Below the dashed zero line the active camera beats the best passive one.
    """
    n = len(factors)
    cols = 4
    rows = -(-n // cols)
    if fig is None:
        fig = plt.figure(figsize=(3.2 * cols, 2.7 * rows))
    axes = fig.subplots(rows, cols, sharey=True, squeeze=False).ravel()
    colours = points["class"].map(CLASS_COLOURS).fillna("0.55").to_list() if "class" in points else ["C0"] * len(points)
    for ax, f in zip(axes, factors):
        x = points[f["name"]].to_numpy(float)
        for k, (stem, label) in enumerate(columns):
            y = 1000 * points[f"{stem}_m"].to_numpy(float)
            low, high = 1000 * points[f"{stem}_low_m"].to_numpy(float), 1000 * points[f"{stem}_high_m"].to_numpy(float)
            err = np.vstack([np.where(np.isfinite(low), y - low, 0.0), np.where(np.isfinite(high), high - y, 0.0)])
            shift = 0.008 * (f["high"] - f["low"]) * k
            ax.errorbar(x + shift, y, yerr=err, fmt="none", ecolor="0.7" if k else "0.45", lw=0.8, zorder=1)
            if k == 0:
                ax.scatter(x, y, c=colours, s=16, zorder=2, label=label)
            else:
                ax.scatter(x + shift, y, facecolors="none", edgecolors="0.35", s=16, zorder=2, label=label)
        ax.axhline(0.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel(f["label"], fontsize=8)
        ax.set_xlim(f["low"] - 0.05 * (f["high"] - f["low"]), f["high"] + 0.05 * (f["high"] - f["low"]))
        ax.tick_params(labelsize=7)
        if f.get("integer"):
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in axes[n:]:
        ax.set_visible(False)
    for ax in axes[::cols]:
        ax.set_ylabel("Δ = active − best passive (mm)", fontsize=8)
    ax.set_yscale("symlog", linthresh=1.0)
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, label=f"Δ best, {k} (family)")
               for k, c in CLASS_COLOURS.items()]
    if len(columns) > 1:
        handles.append(plt.Line2D([], [], ls="", marker="o", mfc="none", color="0.35", label=columns[1][1]))
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), frameon=False, fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig


def plot_ranking(rankings: dict, labels: dict | None = None, ax=None):
    """The factors' first-order indices with their 95 % intervals, one bar group per response.

    Parameters
    ----------
    rankings : dict
        Response label → ranking table (``factor``, ``s1``, ``s1_low``, ``s1_high``); the factors
        are drawn in the first table's rank order.
    labels : dict, optional
        Factor name → label shown.
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4))
    labels = labels or {}
    order = list(next(iter(rankings.values()))["factor"])
    width = 0.8 / len(rankings)
    x = np.arange(len(order))
    for k, (name, table) in enumerate(rankings.items()):
        t = table.set_index("factor").reindex(order)
        s1 = t["s1"].to_numpy(float)
        err = np.vstack([s1 - t["s1_low"].to_numpy(float), t["s1_high"].to_numpy(float) - s1])
        ax.bar(x + (k - (len(rankings) - 1) / 2) * width, s1, width, yerr=err, capsize=3, label=name,
               color=f"C{k}", alpha=0.85)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(x, [labels.get(f, f) for f in order], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("rbd_fast first-order index S1")
    ax.legend(frameon=False, fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return ax


def plot_payoff_map(points, a: str, b: str, a_values, b_values, surface, xlabel: str | None = None,
                    ylabel: str | None = None, ax=None):
    """The map on two factors: every point coloured by its family-level class, the fitted surface
    of Δ (mm) shaded, and its zero contour, the break-even boundary, drawn.

    Parameters
    ----------
    points : DataFrame
        One row per point with columns ``a``, ``b`` and ``class``.
    a, b : str
        The factors on the x and y axes.
    a_values, b_values : ndarray
        The grid's factor values; ``surface[i, j]`` is Δ (m) at (a_values[j], b_values[i]).
    xlabel, ylabel : str, optional
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 5))
    z = 1000 * np.asarray(surface, float)
    reach = float(np.nanmax(np.abs(z))) or 1.0
    mesh = ax.pcolormesh(a_values, b_values, z, cmap="RdYlGn_r", vmin=-reach, vmax=reach, shading="auto", alpha=0.6)
    plt.colorbar(mesh, ax=ax, label="fitted Δ best (mm): < 0 the gimbal pays off")
    if z.min() < 0.0 < z.max():
        ax.contour(a_values, b_values, z, levels=[0.0], colors="k", linewidths=1.6)
        ax.plot([], [], "k-", label="break-even (fitted Δ = 0)")
    for cls, colour in CLASS_COLOURS.items():
        sel = points["class"] == cls
        if sel.any():
            ax.scatter(points.loc[sel, a], points.loc[sel, b], color=colour, edgecolors="k", s=36, zorder=3,
                       label=f"{cls} ({int(sel.sum())})")
    ax.set_xlabel(xlabel or a)
    ax.set_ylabel(ylabel or b)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False, fontsize=8)
    return ax
