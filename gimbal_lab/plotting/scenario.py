"""Figures of a scenario's report (docs/design.md, "Scenario files")."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

__all__ = ["plot_cells"]

_MODE_COLOURS = {"passive": "tab:blue", "active": "tab:orange"}


def plot_cells(summary, fig=None):
    """The distance error and the detection rate of every cell, each mean with its 95 % interval.

    Parameters
    ----------
    summary : DataFrame
        :func:`gimbal_lab.studies.scenario.summary_table` output: one row per cell with ``label``,
        ``mode``, ``mean_abs_error_m``, ``ci_low_m``, ``ci_high_m``, ``detection_rate``,
        ``rate_ci_low``, ``rate_ci_high``.
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib Figure
        Two panels sharing the cells' axis: error (mm) and detection rate; a cell without a
        detection has no error point, a cell with one replicate no interval.
    """
    n = len(summary)
    if n == 0:
        raise ValueError("no cells to plot")
    if fig is None:
        fig = plt.figure(figsize=(11, 0.38 * n + 1.6))
    ax_err, ax_rate = fig.subplots(1, 2, sharey=True, gridspec_kw={"width_ratios": [1.6, 1]})
    y = np.arange(n)[::-1]
    for mode, colour in _MODE_COLOURS.items():
        sel = summary["mode"].to_numpy() == mode
        if not sel.any():
            continue
        for ax, (value, low, high, k) in ((ax_err, ("mean_abs_error_m", "ci_low_m", "ci_high_m", 1000.0)),
                                          (ax_rate, ("detection_rate", "rate_ci_low", "rate_ci_high", 1.0))):
            v, lo, hi = (k * summary[c].to_numpy(float)[sel] for c in (value, low, high))
            err = np.vstack((np.where(np.isfinite(lo), v - lo, 0.0), np.where(np.isfinite(hi), hi - v, 0.0)))
            ax.errorbar(v, y[sel], xerr=err, fmt="o", color=colour, ms=5, capsize=3, label=mode)
    ax_err.set_yticks(y, summary["label"], fontsize=8)
    ax_err.set_xlabel("distance error (mm): mean of replicates, 95 % interval")
    ax_err.set_xlim(left=0)
    ax_rate.set_xlabel("detection rate, 95 % interval")
    ax_rate.set_xlim(-0.02, 1.02)
    for ax in (ax_err, ax_rate):
        ax.grid(axis="x", alpha=0.3)
        ax.set_ylim(-0.7, n - 0.3)
    ax_err.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False, fontsize=8)
    fig.tight_layout()
    return fig
