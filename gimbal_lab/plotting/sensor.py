"""Figures of the sensor model (docs/design.md, "Sensor and light"): what light does to the noise."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from ..sensor import SensorModel, grey_noise_closed_form, snr_closed_form

__all__ = ["plot_noise_vs_exposure"]


def plot_noise_vs_exposure(light_lux=(10.0, 100.0, 1000.0, 10_000.0), exposures_s=None, sensor: str = "IMX273",
                           f_number: float = 2.8, grey_level: int = 128, fixed_noise_std: float | None = 2.0,
                           simulate: bool = True, seed: int = 0, fig=None):
    """SNR and grey-level noise of a flat grey surface against exposure, one curve per light level.

    Lines are the closed forms (:func:`gimbal_lab.sensor.snr_closed_form`,
    :func:`gimbal_lab.sensor.grey_noise_closed_form`) with the auto-gain's K for a frame of
    ``grey_level``; markers (``simulate``) the standard deviation and mean/std of a 200 × 200 flat
    field recorded by :meth:`gimbal_lab.sensor.SensorModel.record`. Where the auto-gain stops at
    its cap the noise in grey levels falls with the light (the frame darkens); where the full well
    fills the pixel reads 255 and the curves end. Where the mean is within about 3 σ of 0
    (SNR below ~3) the clip at 0 lifts the simulated points off the closed form, which ignores it.

    Parameters
    ----------
    light_lux : sequence of float
        Scene illuminances, lx.
    exposures_s : array_like, optional
        Exposures, s (default 0.1 ms to 1/30 s, log-spaced).
    sensor : str
        A built-in sensor (:data:`gimbal_lab.sensor.SENSORS`).
    f_number : float
        The lens's f-number.
    grey_level : int
        The rendered grey value of the surface (its reflectance × 255).
    fixed_noise_std : float or None
        Draw the fixed camera's constant noise (grey levels) for comparison; None leaves it out.
    simulate : bool
        Add Monte Carlo points.
    seed : int
        Seed of the Monte Carlo points.
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib Figure
        Left: SNR (log scale); right: noise in grey levels.
    """
    exposures_s = np.geomspace(1e-4, 1 / 30, 25) if exposures_s is None else np.asarray(exposures_s, dtype=float)
    if fig is None:
        fig = plt.figure(figsize=(10.0, 3.8))
    ax_snr, ax_dn = fig.subplots(1, 2)
    flat = np.full((200, 200), grey_level, np.uint8)
    rng = np.random.default_rng(seed)
    for i, lux in enumerate(light_lux):
        model = SensorModel(sensor, light_lux=float(lux), f_number=f_number)
        figures = model.figures
        mean_e = np.array([model.electrons_at_full_reflectance(t) * grey_level / 255.0 for t in exposures_s])
        gains = np.array([model.auto_gain(flat, t) for t in exposures_s])
        clear = mean_e < figures.saturation_e
        snr = np.where(clear, snr_closed_form(mean_e, figures.dark_noise_e, gains), np.nan)
        noise = np.where(clear, grey_noise_closed_form(mean_e, figures.dark_noise_e, gains), np.nan)
        colour = f"C{i}"
        ax_snr.plot(exposures_s * 1e3, snr, color=colour, label=f"{lux:g} lx")
        ax_dn.plot(exposures_s * 1e3, noise, color=colour, label=f"{lux:g} lx")
        if simulate:
            picks = exposures_s[::4]
            recorded = [model.record(flat, t, rng).astype(float) for t in picks]
            ax_snr.plot(picks * 1e3, [y.mean() / y.std() if y.std() > 0 else np.nan for y in recorded], "o",
                        color=colour, ms=4, mfc="none")
            ax_dn.plot(picks * 1e3, [y.std() for y in recorded], "o", color=colour, ms=4, mfc="none")
    if fixed_noise_std is not None:
        ax_dn.axhline(fixed_noise_std, color="0.3", ls="--", lw=1, label=f"fixed {fixed_noise_std:g}")
        ax_snr.axhline(grey_level / fixed_noise_std, color="0.3", ls="--", lw=1, label="fixed")
    for ax in (ax_snr, ax_dn):
        ax.set_xscale("log")
        ax.set_xlabel("exposure (ms)")
        ax.grid(True, which="both", alpha=0.3)
    ax_snr.set_yscale("log")
    ax_snr.set_ylabel("SNR")
    ax_dn.set_ylabel("noise (grey levels, σ)")
    ax_snr.set_title(f"{sensor}, f/{f_number:g}, grey {grey_level}: lines closed form, circles simulated",
                     fontsize=9)
    ax_dn.legend(fontsize=8, title="light", title_fontsize=8)
    fig.tight_layout()
    return fig
