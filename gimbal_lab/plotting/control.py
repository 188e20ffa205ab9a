"""Figures for gimbal control (paper §3.2.3, Fig. 5): block diagram, Bode, tuning, loops."""

from __future__ import annotations

import math

import numpy as np


def _axes(ax, figsize=(7, 3.5)):
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=figsize)
    return ax.figure, ax


def block_diagram(ax=None):
    """Fig. 5: the inner rate loop (PID, 3-DoF gimbal, IMU) inside the outer image loop.

    Returns
    -------
    matplotlib.axes.Axes
    """
    from matplotlib.patches import Circle, FancyArrowPatch, FancyBboxPatch, Rectangle

    _, ax = _axes(ax, figsize=(12, 4.6))
    ax.set_xlim(0, 13.4)
    ax.set_ylim(0.1, 4.7)
    ax.set_aspect("equal")
    ax.axis("off")
    fs = 8.5

    def box(x, y, w, h, text, color):
        ax.add_patch(
            FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.05", fc=color, ec="black", lw=1.2)
        )
        ax.text(x, y, text, ha="center", va="center", fontsize=fs)

    def sum_node(x, y):
        ax.add_patch(Circle((x, y), 0.22, fc="white", ec="black", lw=1.2, zorder=3))
        ax.text(x, y, "Σ", ha="center", va="center", fontsize=10, zorder=4)
        ax.text(x - 0.32, y + 0.34, "+", ha="center", va="center", fontsize=10)
        ax.text(x + 0.22, y - 0.4, "−", ha="center", va="center", fontsize=12)

    def line(points, label=None, segment=0, offset=(0.0, 0.12), va="bottom"):
        for i, (p0, p1) in enumerate(zip(points[:-1], points[1:])):
            last = i == len(points) - 2
            ax.add_patch(
                FancyArrowPatch(p0, p1, arrowstyle="-|>" if last else "-", mutation_scale=12, lw=1.2,
                                shrinkA=0, shrinkB=0)
            )
        if label:
            (x0, y0), (x1, y1) = points[segment], points[segment + 1]
            ax.text((x0 + x1) / 2 + offset[0], (y0 + y1) / 2 + offset[1], label, ha="center", va=va, fontsize=fs)

    y = 3.0
    # loop regions
    ax.add_patch(Rectangle((4.95, 1.0), 5.2, 2.95, fill=False, ls="--", ec="#1f4e79", lw=1))
    ax.text(7.65, 4.05, "inner loop: joint rates, per joint at 1 kHz", ha="center", fontsize=fs, color="#1f4e79")
    ax.text(7.0, 0.22, "outer loop: image error, once per camera frame", ha="center", fontsize=fs,
            color="#8a5a00")
    # blocks
    ax.text(0.55, y, "$u_{ref}, v_{ref}$\n(image\ncentre)", ha="center", va="center", fontsize=fs)
    sum_node(1.65, y)
    box(3.6, y, 2.1, 1.0, "outer loop\npixel → camera rate\n→ joint rates ($J^{-1}$)", "#fde9c9")
    sum_node(5.55, y)
    box(7.05, y, 1.7, 0.9, "PID × 3\n(Ziegler–Nichols)", "#d6e9f8")
    box(9.3, y, 1.7, 0.9, "3-DoF gimbal\n(yaw, roll, pitch\nmotors)", "#dff0d8")
    box(9.3, 1.6, 1.5, 0.6, "IMU (gyro)", "#dff0d8")
    box(11.75, y, 1.6, 0.9, "monocular\ncamera +\ndetector", "#eadcf2")
    # signals
    line([(1.05, y), (1.43, y)])
    line([(1.87, y), (2.5, y)], "$e_u, e_v$", offset=(-0.05, 0.1))
    line([(4.7, y), (5.33, y)], "$\\dot q_{ref}$", offset=(-0.12, 0.08))
    line([(5.77, y), (6.15, y)], "$\\Delta\\dot\\theta, \\Delta\\dot\\psi, \\Delta\\dot\\phi$", offset=(0.0, 0.55))
    line([(7.95, y), (8.4, y)], "τ")
    line([(10.2, y), (10.9, y)], "pose", offset=(0.1, 0.1))
    line([(9.3, y - 0.5), (9.3, 1.95)], "rate", offset=(0.3, 0.0), va="center")
    line([(8.5, 1.6), (5.55, 1.6), (5.55, y - 0.22)], "measured $\\dot q$", offset=(0.0, -0.12), va="top")
    line([(12.6, y), (13.0, y), (13.0, 0.65), (1.65, 0.65), (1.65, y - 0.22)], "target centre (u, v)",
         segment=2, offset=(2.5, 0.08))
    return ax


def bode_crossover(system, Ku: float, Tu: float, fig=None, omega=None):
    """Bode plot of the plant with the phase crossover ω_pc = 2π/Tu and the gain margin Ku.

    Parameters
    ----------
    system : control.LTI
    Ku, Tu : float
        Ultimate gain and period (from ``control.ultimate_gain``).
    fig : matplotlib.figure.Figure, optional
    omega : ndarray, optional
        Frequencies, rad/s.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if fig is None:
        fig = plt.figure(figsize=(7, 5))
    ax_mag, ax_ph = fig.subplots(2, 1, sharex=True)
    w_pc = 2.0 * math.pi / Tu
    if omega is None:
        omega = np.logspace(math.log10(w_pc) - 3, math.log10(w_pc) + 1, 600)
    resp = system(1j * omega)
    resp = np.asarray(resp).reshape(-1)
    mag_db = 20 * np.log10(np.abs(resp))
    phase_deg = np.degrees(np.unwrap(np.angle(resp)))
    ax_mag.semilogx(omega, mag_db, color="C0")
    ax_ph.semilogx(omega, phase_deg, color="C0")
    mag_pc = -20 * math.log10(Ku)
    for ax in (ax_mag, ax_ph):
        ax.axvline(w_pc, color="C3", ls="--", lw=1)
        ax.grid(True, which="both", alpha=0.3)
    ax_ph.axhline(-180, color="gray", lw=0.8)
    ax_ph.plot([w_pc], [-180], "o", color="C3")
    ax_mag.plot([w_pc], [mag_pc], "o", color="C3")
    ax_mag.axhline(0, color="gray", lw=0.8)
    ax_mag.annotate(
        f"|G(jω_pc)| = 1/Ku\nKu = {Ku:.3g}",
        (w_pc, mag_pc),
        xytext=(-110, -30),
        textcoords="offset points",
        fontsize=8,
        arrowprops=dict(arrowstyle="->", lw=0.8),
    )
    ax_ph.annotate(
        f"phase crossover\nω_pc = {w_pc:.0f} rad/s (Tu = {Tu * 1e3:.1f} ms)",
        (w_pc, -180),
        xytext=(-175, -5),
        textcoords="offset points",
        fontsize=8,
        arrowprops=dict(arrowstyle="->", lw=0.8),
    )
    ax_mag.set_ylabel("|G| (dB; rad/s per N·m)")
    ax_ph.set_ylabel("phase (deg)")
    ax_ph.set_xlabel("ω (rad/s)")
    ax_ph.set_ylim(-450, 0)
    ax_ph.set_yticks([-450, -360, -270, -180, -90, 0])
    return fig


def rate_traces(sims: dict, ax=None, signal: str = "measured_rate", reference: bool = False, t_scale: float = 1e3):
    """Rate traces of several ``AxisSimulation`` results (one line each), time in ms.

    Parameters
    ----------
    sims : dict of str -> AxisSimulation
    signal : {"measured_rate", "rate"}
    reference : bool
        Also draw the first simulation's reference.
    """
    _, ax = _axes(ax)
    for i, (label, sim) in enumerate(sims.items()):
        ax.plot(sim.t * t_scale, getattr(sim, signal), label=label, color=f"C{i}", lw=1.2)
    if reference and sims:
        first = next(iter(sims.values()))
        ax.plot(first.t * t_scale, first.reference, "k--", lw=0.8, label="reference")
    ax.set_xlabel("t (ms)" if t_scale == 1e3 else "t (s)")
    ax.set_ylabel("rate (rad/s)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return ax


def relay_trace(experiment, Ku_margin: float | None = None, Tu_margin: float | None = None, fig=None,
                window_s: float = 0.06):
    """Relay experiment: measured rate and relay torque at the start and at the end of the run.

    Parameters
    ----------
    experiment : control.RelayExperiment
    Ku_margin, Tu_margin : float, optional
        ``control.ultimate_gain``'s values, printed next to the relay's.
    window_s : float
        Length of each of the two panels, s: the start (limit cycle building up) and the end
        (inside the analysed part).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if fig is None:
        fig = plt.figure(figsize=(10, 3.4))
    axes = fig.subplots(1, 2, sharey=True)
    t = experiment.t
    windows = [(t[0], t[0] + window_s), (t[-1] - window_s, t[-1])]
    for ax, (lo, hi), title in zip(axes, windows, ("start", "end (analysed)")):
        sel = (t >= lo) & (t <= hi)
        ax.plot(t[sel] * 1e3, experiment.measured_rate[sel], color="C0", lw=1.3, label="measured rate")
        ax.set_xlabel("t (ms)")
        ax.grid(True, alpha=0.3)
        ax.set_title(title, fontsize=9)
        ax2 = ax.twinx()
        ax2.step(t[sel] * 1e3, experiment.torque_cmd[sel] * 1e3, where="post", color="C1", lw=0.9, alpha=0.8,
                 label="relay torque")
        ax2.set_ylim(np.array([-1.6, 1.6]) * np.abs(experiment.torque_cmd).max() * 1e3)
        if ax is axes[1]:
            ax2.set_ylabel("torque (mN·m)", color="C1")
        else:
            ax2.set_yticklabels([])
    axes[0].set_ylabel("rate (rad/s)")
    text = f"relay: Ku = {experiment.Ku:.4g}, Tu = {experiment.Tu * 1e3:.2f} ms"
    if Ku_margin is not None and Tu_margin is not None:
        text += f"   ·   margin: Ku = {Ku_margin:.4g}, Tu = {Tu_margin * 1e3:.2f} ms"
    fig.suptitle(text, fontsize=9)
    handles = axes[0].get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    axes[0].legend(handles, [h.get_label() for h in handles], fontsize=8, loc="lower left")
    fig.tight_layout()
    return fig


def disturbance_rejection(closed, open_loop, base_rate=None, fig=None):
    """Axis rate under a base-rate disturbance, with and without the rate loop.

    Top: base rate and camera rate without control; bottom: camera rate with the rate loop
    (in mrad/s, it is orders of magnitude smaller).

    Parameters
    ----------
    closed, open_loop : AxisSimulation
    base_rate : ndarray, shape (N,), optional
        The base's rate, rad/s, drawn for reference.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if fig is None:
        fig = plt.figure(figsize=(7, 4.6))
    ax, ax_cl = fig.subplots(2, 1, sharex=True)
    if base_rate is not None:
        ax.plot(closed.t, base_rate, color="0.6", lw=1, label="base rate")
    ax.plot(open_loop.t, open_loop.rate, color="C1", lw=1.2, label="camera rate, no control")
    ax.plot(closed.t, closed.rate, color="C0", lw=1.2, label="camera rate, rate loop")
    ax.set_ylabel("rate (rad/s)")
    ax.legend(fontsize=8)
    ax_cl.plot(closed.t, 1e3 * closed.rate, color="C0", lw=1.0, label="camera rate, rate loop")
    ax_cl.set_ylabel("rate (mrad/s)")
    ax_cl.set_xlabel("t (s)")
    ax_cl.legend(fontsize=8)
    for a in (ax, ax_cl):
        a.grid(True, alpha=0.3)
    return fig


def pointing_trace(sim, fig=None, intrinsics=None):
    """Outer loop: the target's path in the image and its offset from the centre over time.

    Parameters
    ----------
    sim : control.PointingSimulation
    intrinsics : camera.Intrinsics, optional
        Draws the image frame and centre.
    """
    import matplotlib.pyplot as plt

    if fig is None:
        fig = plt.figure(figsize=(10, 3.6))
    ax_img, ax_t = fig.subplots(1, 2, gridspec_kw=dict(width_ratios=[1.1, 1.4]))
    uv = sim.uv_px
    ax_img.plot(uv[:, 0], uv[:, 1], ".-", color="C0", ms=3, lw=0.8)
    first = np.flatnonzero(np.isfinite(uv[:, 0]))
    if first.size:
        ax_img.plot(*uv[first[0]], "o", color="C1", label="start")
    if intrinsics is not None:
        ax_img.plot(intrinsics.cx, intrinsics.cy, "k+", ms=12, label="centre")
        ax_img.set_xlim(0, intrinsics.width - 1)
        ax_img.set_ylim(intrinsics.height - 1, 0)
        ax_img.set_aspect("equal")
    ax_img.set_xlabel("u (px)")
    ax_img.set_ylabel("v (px)")
    ax_img.legend(fontsize=8)
    ax_img.set_title("target in the image", fontsize=9)
    ax_t.plot(sim.t, sim.error_px[:, 0], label="u − cx")
    ax_t.plot(sim.t, sim.error_px[:, 1], label="v − cy")
    ax_t.plot(sim.t, np.hypot(sim.error_px[:, 0], sim.error_px[:, 1]), "k", lw=0.8, label="|offset|")
    ax_t.set_xlabel("t (s)")
    ax_t.set_ylabel("offset from centre (px)")
    ax_t.grid(True, alpha=0.3)
    ax_t.legend(fontsize=8)
    fig.tight_layout()
    return fig
