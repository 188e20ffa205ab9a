"""The EMVA 1288 sensor model (gimbal_lab.sensor) against hand derivations, its closed form and the
standard's reference implementation (the ``emva1288`` package)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_lab.sensor import (
    NORMAL_ABOVE_E,
    SENSORS,
    SensorModel,
    photons_per_pixel,
    snr_closed_form,
)

IMX273 = SENSORS["IMX273"]
SHAPE = (480, 640)  # one channel of the study's frame: 307,200 pixels


def test_photons_per_pixel_by_hand():
    """300 lx on a white Lambertian surface, f/2.8, T = 0.9, a 3.45 µm pixel, 1 ms at 555 nm.

    Image-plane illuminance 300·0.9/(4·2.8²) = 8.6097 lx = 8.6097/683 W/m² = 0.0126057 W/m²;
    times 3.45e-6² m² and 1e-3 s: 1.50039e-16 J; a 555 nm photon carries
    6.62607015e-34·299792458/555e-9 = 3.57924e-19 J: 419.19 photons.
    """
    assert photons_per_pixel(300.0, 1.0, 2.8, 3.45e-6 ** 2, 1e-3) == pytest.approx(419.19, rel=1e-4)
    # linear in light, reflectance and exposure; inverse square in the f-number
    base = photons_per_pixel(300.0, 1.0, 2.8, 3.45e-6 ** 2, 1e-3)
    assert photons_per_pixel(600.0, 0.5, 2.8, 3.45e-6 ** 2, 2e-3) == pytest.approx(2 * base, rel=1e-12)
    assert photons_per_pixel(300.0, 1.0, 5.6, 3.45e-6 ** 2, 1e-3) == pytest.approx(base / 4, rel=1e-12)


def test_imx273_figures_from_the_cited_numbers():
    """μ_e.sat = 10^(40.2 dB/10) and σ_d = μ_e.sat/10^(71.4 dB/20) − ½ (docs/design.md, "Sensor and light")."""
    assert IMX273.saturation_e == 10471  # 10^4.02 = 10471.3
    assert IMX273.dark_noise_e == pytest.approx(2.32, abs=0.005)  # 10471.3/3715.4 − 0.5 = 2.318
    assert IMX273.min_gain_dn_per_e == pytest.approx(255 / 10471)
    assert IMX273.max_gain_dn_per_e / IMX273.min_gain_dn_per_e == pytest.approx(251.19, rel=1e-4)  # 48 dB


# Light levels × exposures where a flat field at v = 128 stays clear of both clips (checked in the
# test): mean electrons from 27 (300 lx, 0.2 ms) to 5,500 (3,000 lx, 4 ms).
LIGHTS_LUX = (300.0, 1000.0, 3000.0)
EXPOSURES_S = (0.0002, 0.0005, 0.0015, 0.004)


@pytest.mark.parametrize("exact", [False, True], ids=["shortcut", "full"])
@pytest.mark.parametrize("light_lux", LIGHTS_LUX)
def test_snr_matches_closed_form(light_lux, exact):
    """Simulated SNR of a flat field = η μ_p / sqrt(σ_d² + η μ_p + σ_q²/K²), within the Monte Carlo interval.

    SNR is estimated as mean/std over N = 307,200 pixels. Its standard error (delta method, a
    near-normal pixel distribution: kurtosis 3) is SNR·sqrt(1/(N·SNR²) + 1/(2N)); the test allows
    4 standard errors (about 0.1 % to 0.4 %). The mean grey level must equal K·η·μ_p within 4
    standard errors of the mean, std/sqrt(N).
    """
    model = SensorModel(IMX273, light_lux=light_lux, f_number=2.8)
    image = np.full(SHAPE, 128, np.uint8)
    n = image.size
    for i, exposure_s in enumerate(EXPOSURES_S):
        gain = model.auto_gain(image, exposure_s)
        # η μ_p from the photometry and the sensor's figures, not from the model under test
        mean_e = IMX273.quantum_efficiency * photons_per_pixel(light_lux, 128 / 255, 2.8, 3.45e-6 ** 2, exposure_s)
        expected_mean = gain * mean_e
        expected_sd = gain * math.sqrt(IMX273.dark_noise_e ** 2 + mean_e + 1 / 12 / gain ** 2)
        # clear of the clips: 0 and 255 more than 4.5 σ away, the full well 10 σ away
        assert 4.5 * expected_sd < expected_mean < 255 - 4.5 * expected_sd
        assert mean_e + 10 * math.sqrt(mean_e + IMX273.dark_noise_e ** 2) < IMX273.saturation_e
        y = model.record(image, exposure_s, np.random.default_rng(100 + i), exact=exact).astype(float)
        snr = y.mean() / y.std()
        expected = snr_closed_form(mean_e, IMX273.dark_noise_e, gain)
        se = expected * math.sqrt(1 / (n * expected ** 2) + 1 / (2 * n))
        assert abs(snr - expected) < 4 * se, (light_lux, exposure_s, snr, expected)
        assert abs(y.mean() - expected_mean) < 4 * expected_sd / math.sqrt(n), (y.mean(), expected_mean)


def test_saturation_at_the_full_well():
    """Electrons clip at μ_e.sat: with K = 0.4·K_min the full well reads round(0.4·255) = 102 DN,
    below the 8-bit clip, whatever the light beyond it."""
    model = SensorModel(IMX273, light_lux=100_000.0, f_number=2.8)
    image = np.full((100, 100), 255, np.uint8)
    gain = 0.4 * IMX273.min_gain_dn_per_e
    assert model.electrons_at_full_reflectance(0.01) > 10 * IMX273.saturation_e
    y = model.record(image, 0.01, np.random.default_rng(1), gain_dn_per_e=gain)
    assert np.all(y == 102)
    # with the auto-gain at this light K = K_min and the full well fills the 8-bit range
    y = model.record(image, 0.01, np.random.default_rng(1))
    assert model.auto_gain(image, 0.01) == IMX273.min_gain_dn_per_e
    assert np.all(y == 255)


def test_auto_gain_reaches_the_rendered_mean_up_to_its_cap():
    """In enough light the recorded mean is the rendered mean; in too little the gain stops at
    K_max (48 dB above 0 dB) and the image is darker by the missing gain."""
    image = np.full(SHAPE, 100, np.uint8)
    bright = SensorModel(IMX273, light_lux=1000.0, f_number=2.8)
    y = bright.record(image, 0.002, np.random.default_rng(2)).astype(float)
    assert IMX273.min_gain_dn_per_e < bright.auto_gain(image, 0.002) < IMX273.max_gain_dn_per_e
    assert abs(y.mean() - 100) < 4 * y.std() / math.sqrt(y.size)
    dark = SensorModel(IMX273, light_lux=12.0, f_number=2.8)
    mean_e = dark.electrons_at_full_reflectance(0.002) * 100 / 255  # 8.6 e⁻: K would need 11.7 DN/e⁻
    assert dark.auto_gain(image, 0.002) == IMX273.max_gain_dn_per_e
    assert IMX273.max_gain_dn_per_e * mean_e < 60  # well below the rendered 100
    y = dark.record(image, 0.002, np.random.default_rng(2)).astype(float)
    # 0 clips the lower tail (the mean is 2.3 σ above 0), lifting the mean by σ(φ(a) − a·Q(a)) ≈ 0.1 DN:
    # 2 % covers it and the Monte Carlo error (0.04 DN)
    assert y.mean() == pytest.approx(IMX273.max_gain_dn_per_e * mean_e, rel=0.02)


def _ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov distance of two uint8 samples."""
    fa = np.cumsum(np.bincount(a.ravel(), minlength=256)) / a.size
    fb = np.cumsum(np.bincount(b.ravel(), minlength=256)) / b.size
    return float(np.abs(fa - fb).max())


# The 99.9 % quantile of the two-sample Kolmogorov distance for 10⁶ against 10⁶ draws:
# 1.95·sqrt(2/10⁶) = 0.0028.
KS_NOISE = 0.0028


@pytest.mark.parametrize("mean_e, bound", [(10.0, 0.0), (NORMAL_ABOVE_E, 0.006), (4 * NORMAL_ABOVE_E, 0.006)])
def test_normal_shortcut_against_full_model(mean_e, bound):
    """Grey levels with the normal shortcut against the full model (Poisson shot noise), 10⁶ each.

    At and above :data:`NORMAL_ABOVE_E` the stated bound is 0.006 in Kolmogorov distance (the
    Edgeworth term 0.0665·γ is 0.0045 at 200 e⁻); below it the shortcut draws the full model, so
    the bound is 0. Each allows the Monte Carlo noise :data:`KS_NOISE` on top. Gain and black
    level put the mean at 100 DN and resolve the electron distribution to σ/7 or finer.
    """
    model = SensorModel(IMX273, light_lux=1000.0, f_number=2.8)
    exposure_s = mean_e / model.electrons_at_full_reflectance(1.0)
    image = np.full((1000, 1000), 255, np.uint8)
    gain = 60.0 / mean_e
    kwargs = dict(gain_dn_per_e=gain, black_level_dn=40.0)
    fast = model.record(image, exposure_s, np.random.default_rng(3), **kwargs)
    full = model.record(image, exposure_s, np.random.default_rng(4), exact=True, **kwargs)
    assert fast.mean() == pytest.approx(100.0, abs=0.1)
    assert _ks_distance(fast, full) <= bound + KS_NOISE


def test_same_seed_same_image():
    model = SensorModel("IMX273", light_lux=300.0, f_number=2.8)
    image = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    a = model.record(image, 0.001, np.random.default_rng(7))
    assert np.array_equal(a, model.record(image, 0.001, np.random.default_rng(7)))
    assert not np.array_equal(a, model.record(image, 0.001, np.random.default_rng(8)))
    assert a.shape == image.shape and a.dtype == np.uint8


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match="sensor must be one of"):
        SensorModel("IMX999", light_lux=300.0, f_number=2.8)
    with pytest.raises(ValueError, match="light_lux"):
        SensorModel("IMX273", light_lux=0.0, f_number=2.8)
    with pytest.raises(ValueError, match="f_number"):
        SensorModel("IMX273", light_lux=300.0, f_number=float("nan"))
    model = SensorModel("IMX273", light_lux=300.0, f_number=2.8)
    with pytest.raises(ValueError, match="exposure_s"):
        model.record(np.zeros((4, 4), np.uint8), 0.0, np.random.default_rng(0))
    with pytest.raises(TypeError, match="uint8"):
        model.record(np.zeros((4, 4)), 0.001, np.random.default_rng(0))


# --- against the standard's reference implementation -------------------------------------------


def _photon_transfer_data(model: SensorModel, exposures_s, gain: float, black: float, side: int = 200):
    """The data dict :class:`emva1288.process.Data1288` reads: per exposure, a pair of flat fields
    at reflectance 1 and a pair of dark frames (reflectance 0), with their photon counts; a spatial
    set of 4 + 4 frames at the middle exposure."""
    from emva1288.process.routines import get_int_imgs

    white = np.full((side, side), 255, np.uint8)
    black_frame = np.zeros((side, side), np.uint8)
    rng = np.random.default_rng(11)

    def shots(image, exposure_s, count):
        return [model.record(image, exposure_s, rng, gain_dn_per_e=gain, black_level_dn=black) for _ in range(count)]

    def temporal(images):
        d = get_int_imgs(images)
        return {"sum": np.sum(d["sum"]), "pvar": np.sum(d["pvar"]), "dmean": d["dmean"]}

    data = {"temporal": {}, "spatial": {}, "width": side, "height": side}
    for t in exposures_s:
        photons = float(photons_per_pixel(model.light_lux, 1.0, model.f_number, model.figures.pixel_area_m2, t,
                                          model.lens_transmission))
        data["temporal"][t] = {0.0: temporal(shots(black_frame, t, 2)), photons: temporal(shots(white, t, 2))}
    t = exposures_s[len(exposures_s) // 2]
    photons = float(photons_per_pixel(model.light_lux, 1.0, model.f_number, model.figures.pixel_area_m2, t,
                                      model.lens_transmission))
    data["spatial"][t] = {0.0: get_int_imgs(shots(black_frame, t, 4)), photons: get_int_imgs(shots(white, t, 4))}
    return data


def test_emva1288_photon_transfer_recovers_gain_qe_and_dark_noise(monkeypatch):
    """emva1288's photon-transfer analysis of the lab's flat fields returns the lab's K, η and σ_d.

    300 lx, f/2.8, a white flat field (η μ_p = 272 e⁻ per ms) over 24 exposures from 0.02 to
    1.2 ms, K = 1 DN/e⁻ (the 8-bit range ends near 245 e⁻, so the series reaches saturation and
    the analysis finds it) and a 10 DN black level so the dark frames' noise is not clipped at 0;
    200 × 200 pixels per frame. Tolerances: K and η within 2 %, σ_d within 5 % (the variance fits
    over ~15 points of 40,000 pixel pairs are good to a few tenths of a percent; σ_d comes from a
    dark variance of ~5.5 DN² less 1/12).
    """
    from emva1288.process import Data1288, Results1288

    # emva1288's fits call np.asfarray, which numpy 2 removed; give it back for this test only
    monkeypatch.setattr(np, "asfarray", lambda a, dtype=float: np.asarray(a, dtype=dtype), raising=False)
    model = SensorModel(IMX273, light_lux=300.0, f_number=2.8)
    exposures_s = tuple(np.linspace(0.02e-3, 1.2e-3, 24))
    data = Data1288(_photon_transfer_data(model, exposures_s, gain=1.0, black=10.0))
    results = Results1288(data.data, pixel_area=IMX273.pixel_area_m2 * 1e12, loglevel=40)
    assert results.K == pytest.approx(1.0, rel=0.02)
    assert results.QE / 100 == pytest.approx(IMX273.quantum_efficiency, rel=0.02)
    assert results.sigma_d == pytest.approx(IMX273.dark_noise_e, rel=0.05)


def test_noise_figure_draws_the_closed_form():
    """The figure's lines are the closed forms at the auto-gain's K (plotting draws, the sensor computes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gimbal_lab.plotting.sensor import plot_noise_vs_exposure

    exposures_s = np.array([0.001, 0.004])
    fig = plot_noise_vs_exposure(light_lux=(300.0,), exposures_s=exposures_s, fixed_noise_std=None, simulate=False)
    ax_snr, ax_dn = fig.axes
    model = SensorModel(IMX273, light_lux=300.0, f_number=2.8)
    flat = np.full((200, 200), 128, np.uint8)
    mean_e = IMX273.quantum_efficiency * photons_per_pixel(300.0, 128 / 255, 2.8, 3.45e-6 ** 2, exposures_s)
    gains = np.array([model.auto_gain(flat, t) for t in exposures_s])
    np.testing.assert_allclose(ax_snr.lines[0].get_ydata(), snr_closed_form(mean_e, IMX273.dark_noise_e, gains),
                               rtol=1e-12)
    np.testing.assert_allclose(ax_dn.lines[0].get_ydata(),
                               gains * np.sqrt(IMX273.dark_noise_e ** 2 + mean_e) * np.sqrt(1 + 1 / 12 / (
                                   gains ** 2 * (IMX273.dark_noise_e ** 2 + mean_e))), rtol=1e-12)
    np.testing.assert_allclose(ax_snr.lines[0].get_xdata(), exposures_s * 1e3)
    plt.close(fig)


# --- the samplers, as drawn for speed -----------------------------------------------------------


# Poisson means for the sampler test: a fraction of an electron up to the shortcut's threshold, and
# one above the inversion's limit (numpy's own sampler draws it; the test checks it reaches its pixels).
POISSON_MEANS_E = (0.3, 3.7, 13.6, 57.2, 199.0, 20_000.0)


def _chi_square_p(draws: np.ndarray, mean: float) -> float:
    """Pearson's χ² p-value of integer ``draws`` against Poisson(``mean``) (scipy.stats.poisson):
    one bin per count with at least 5 expected, each tail pooled into the bin next to it."""
    from scipy.stats import chisquare, poisson

    counts = np.arange(int(poisson.ppf(1e-9, mean)), int(poisson.isf(1e-9, mean)) + 1)
    counts = counts[draws.size * poisson.pmf(counts, mean) >= 5]
    expected = draws.size * poisson.pmf(counts, mean)
    expected[0], expected[-1] = draws.size * poisson.cdf(counts[0], mean), draws.size * poisson.sf(counts[-1] - 1, mean)
    observed = np.bincount(np.clip(draws, counts[0], counts[-1]) - counts[0], minlength=counts.size).astype(float)
    return float(chisquare(observed, expected * observed.sum() / expected.sum()).pvalue)


def test_poisson_sampler_against_scipy():
    """The full model's shot noise (inversion per grey level, numpy's sampler above 10⁴ e⁻) against
    scipy.stats.poisson: Pearson's χ² per mean at level 10⁻³ (0.6 % over the six), 400,000 draws
    each, the levels shuffled so each pixel must find its own level's table.

    Power: a mean off by 1 % shifts the χ² by about N·(0.01 λ)²/λ (the Poisson's Fisher
    information 1/λ): 148 at λ = 3.7 and more above, where the 10⁻³ critical value for the ~10 to
    ~150 bins is 30 to 200: a 1 % error fails from 3.7 e⁻ up (0.3 e⁻ checks the shape only).
    """
    from gimbal_lab.sensor import _electrons

    n = 400_000
    levels_used = np.arange(10, 10 + 40 * len(POISSON_MEANS_E), 40, dtype=np.uint8)
    mean_e = np.zeros(256)
    mean_e[levels_used] = POISSON_MEANS_E
    levels = np.random.default_rng(20).permutation(np.repeat(levels_used, n))
    draws = _electrons(levels, mean_e, np.random.default_rng(21))
    assert draws.shape == levels.shape
    for level, mean in zip(levels_used, POISSON_MEANS_E):
        p = _chi_square_p(draws[levels == level], mean)
        assert p > 1e-3, (mean, p)


def test_normal_path_bit_for_bit_as_its_formula():
    """Above the shortcut's threshold a pixel is its formula in float32, bit for bit, whatever the
    speed-ups: y = clip(rint(min(m_v + s_v·z, K·μ_e.sat) + b), 0, 255), with m_v = float32(K·η μ_p(v)),
    s_v = float32(K·sqrt(η μ_p(v) + σ_d²)) and z the normals of :func:`_standard_normals`, drawn first.
    Cases: the auto-gain, a gain whose full well reads below 255 DN, a black level, and a gain so
    large that the values leave int32's range."""
    from gimbal_lab.sensor import _standard_normals

    image = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    model = SensorModel(IMX273, light_lux=3000.0, f_number=2.8)
    exposure_s = 0.004
    mean_e = model.electrons_at_full_reflectance(exposure_s) * np.arange(256) / 255.0
    for kwargs in ({}, {"gain_dn_per_e": 0.01}, {"black_level_dn": 12.0}, {"gain_dn_per_e": 1e6}):
        gain = kwargs.get("gain_dn_per_e", model.auto_gain(image, exposure_s))
        z = _standard_normals(np.random.default_rng(5), image.size).reshape(image.shape)
        mean_dn = (gain * mean_e).astype(np.float32)[image]
        sd_dn = (gain * np.sqrt(mean_e + IMX273.dark_noise_e ** 2)).astype(np.float32)[image]
        signal = np.minimum(mean_dn + sd_dn * z, np.float32(gain * IMX273.saturation_e))
        signal = signal + np.float32(kwargs.get("black_level_dn", 0.0))
        expected = np.clip(np.rint(signal), 0, 255).astype(np.uint8)
        y = model.record(image, exposure_s, np.random.default_rng(5), **kwargs)
        normal = mean_e[image] >= NORMAL_ABOVE_E
        assert normal.mean() > 0.9
        assert np.array_equal(y[normal], expected[normal]), kwargs


@pytest.mark.parametrize("dim_share", [0.1, 0.7], ids=["few-dim", "most-dim"])
def test_dim_pixels_draw_the_full_model_beside_bright_ones(dim_share):
    """In a frame that mixes levels below and above :data:`NORMAL_ABOVE_E` (10 e⁻ and 2,550 e⁻), the
    dim pixels' grey levels follow the full model (``exact=True``), however many of them there are
    (few are picked by index, most by mask): two-sample Kolmogorov distance within the Monte Carlo
    noise 1.95·sqrt(2/n) (99.9 %). The normal shortcut at 10 e⁻ is 0.01 away (skewness 0.17), so a
    dim pixel left on it fails. Gain 6 DN/e⁻ and a 40 DN black level resolve the electron counts."""
    model = SensorModel(IMX273, light_lux=1000.0, f_number=2.8)
    exposure_s = 2550.0 / model.electrons_at_full_reflectance(1.0)  # level 1: 10 e⁻, level 255: 2,550 e⁻
    image = np.where(np.random.default_rng(30).random((1000, 1000)) < dim_share, 1, 255).astype(np.uint8)
    dim = image == 1
    kwargs = dict(gain_dn_per_e=6.0, black_level_dn=40.0)
    fast = model.record(image, exposure_s, np.random.default_rng(31), **kwargs)[dim]
    full = model.record(image, exposure_s, np.random.default_rng(32), exact=True, **kwargs)[dim]
    assert fast.mean() == pytest.approx(100.0, abs=0.2)
    assert _ks_distance(fast, full) <= 1.95 * math.sqrt(2 / dim.sum())
