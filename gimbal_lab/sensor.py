"""The EMVA 1288 linear camera model tied to light: what a real sensor records of a rendered frame.

A rendered frame says how bright each pixel is relative to the scene's light; it says nothing of
how many photons reach the pixel. This module turns the scene's illuminance, the lens and the
exposure into photons per pixel and records them as the EMVA 1288 linear camera model says
(EMVA Standard 1288, release 3.1, "Linear Signal Model" and "Noise Model"): quantum efficiency,
shot noise (Poisson), read noise, full well, a system gain set by an auto-gain, 8-bit
quantisation and clipping. docs/design.md, "Sensor and light", gives the sensor's figures with
their sources and every assumption below.

Light to photons
----------------
A Lambertian surface of reflectance ρ under illuminance E_v (lux) has luminance ρ·E_v/π; a lens
of f-number N and transmission T images it on axis with illuminance ρ·E_v·T/(4N²) (a distant
object; no cos⁴ fall-off, no vignetting). At one wavelength λ = 555 nm, where 1 W of light is
683 lm, that is an irradiance ρ·E_v·T/(4N²·683) W/m², and a pixel of area A collects

    μ_p = ρ · E_v · T / (4 N² · 683 lm/W) · A · t_exp · λ / (h c)   photons in an exposure t_exp.

*Reflectance shortcut*: the rendered grey value v ∈ [0, 1] (uint8 / 255) is read as the
reflectance the pixel sees under unit light, ρ = v, in every channel.

Photons to grey levels
----------------------
Electrons n_e ~ Poisson(η μ_p) plus read noise N(0, σ_d²) (no dark current: the cited figures
give none), clipped at the full well μ_e.sat; y = clip(round(K·n_e + b), 0, 255) with system gain
K (DN/e⁻) and black level b (DN). The mean is K·η·μ_p + b and, away from the clips, the
variance K²(σ_d² + η μ_p) + 1/12 (EMVA 1288's quantisation noise σ_q² = 1/12 DN²), so

    SNR = η μ_p / sqrt(σ_d² + η μ_p + σ_q²/K²)                       (:func:`snr_closed_form`).

*Auto-gain*: unless a gain is given, K brings the frame's mean grey level to the rendered frame's
own mean (computed from the expected signal, not the noisy one: an ideal auto-gain that settles
within the frame), within [K_min, K_max]: K_min = 255/μ_e.sat (0 dB: the full well fills the
8-bit range) and K_max = K_min · 10^(max gain dB / 20). Below the light K_max needs the image is
darker than rendered; above the light K_min allows it is brighter, and saturates where the full
well clips.

*Normal shortcut*: a pixel whose mean count η μ_p is at least :data:`NORMAL_ABOVE_E` electrons
draws n_e ~ N(η μ_p, η μ_p + σ_d²) instead of Poisson plus Gaussian (same mean and variance; the
Kolmogorov distance between the two grey-level distributions is at most 0.006 there, by the
Edgeworth term 0.0665·γ with skewness γ = η μ_p/(η μ_p + σ_d²)^{3/2}; tested against the full
model). The standard normals come from 16 raw random bits each through a table of the normal's
inverse CDF at the 2¹⁶ mid-quantiles (tails beyond ±4.2 σ cut), as
:func:`gimbal_lab.scene.add_sensor_noise` draws its noise. Pixels below the threshold draw the
full model. ``exact=True`` draws the full model everywhere.

*Poisson sampler*: the full model's shot noise is drawn by inversion per grey level (a frame has at
most 256 distinct means): one uniform per pixel against the Poisson CDF of its level's mean, found
through a guide table (:func:`_poisson_by_level`); exact up to the CDF's float64 rounding and tails
beyond 12 σ + 12 (below 10⁻³⁰). Means above :data:`_INVERSION_MAX_E` (only with ``exact=True``)
draw numpy's own sampler.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "LENS_TRANSMISSION",
    "LUMINOUS_EFFICACY_LM_PER_W",
    "NORMAL_ABOVE_E",
    "QUANTISATION_VAR_DN2",
    "SENSORS",
    "WAVELENGTH_M",
    "SensorFigures",
    "SensorModel",
    "grey_noise_closed_form",
    "photons_per_pixel",
    "snr_closed_form",
]

#: Planck's constant, J·s, and the speed of light, m/s (exact SI values).
_PLANCK_J_S = 6.62607015e-34
_LIGHT_M_S = 299_792_458.0
#: The wavelength the model is taken at, m (555 nm, the peak of the photopic response).
WAVELENGTH_M = 555e-9
#: Luminous efficacy of monochromatic light at 555 nm, lm/W (the SI definition of the candela).
LUMINOUS_EFFICACY_LM_PER_W = 683.0
#: Lens transmission T assumed for every lens (the lab's choice; multi-coated lenses pass 0.8–0.95).
LENS_TRANSMISSION = 0.9
#: Mean count, e⁻, from which a pixel draws the normal approximation (see the module's Notes).
NORMAL_ABOVE_E = 200.0
#: EMVA 1288's quantisation noise variance, DN².
QUANTISATION_VAR_DN2 = 1.0 / 12.0

_LEVELS = 1 << 16
_NORMAL_TABLE: list = []


@dataclass(frozen=True)
class SensorFigures:
    """One real sensor's published figures (docs/design.md, "Sensor and light", cites each).

    Parameters
    ----------
    name : str
        The sensor, e.g. "IMX273".
    pixel_pitch_m : float
        Pixel pitch, m (square pixels; area pitch²).
    quantum_efficiency : float
        η at 555 nm, in (0, 1].
    dark_noise_e : float
        Temporal dark (read) noise σ_d, e⁻.
    saturation_e : float
        Saturation capacity (full well) μ_e.sat, e⁻.
    max_gain_db : float
        Largest analogue-plus-digital gain above 0 dB, dB (the auto-gain's cap).
    """

    name: str
    pixel_pitch_m: float
    quantum_efficiency: float
    dark_noise_e: float
    saturation_e: float
    max_gain_db: float

    def __post_init__(self):
        for field_name, low, high in (("pixel_pitch_m", 0.0, 1e-4), ("quantum_efficiency", 0.0, 1.0),
                                      ("dark_noise_e", 0.0, 1e3), ("saturation_e", 1.0, 1e7),
                                      ("max_gain_db", 0.0, 80.0)):
            value = getattr(self, field_name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not low < value <= high:
                raise ValueError(f"sensor {self.name!r}: {field_name} must be a number in ({low:g}, {high:g}], "
                                 f"got {value!r}")

    @property
    def pixel_area_m2(self) -> float:
        """Pixel area, m²."""
        return self.pixel_pitch_m ** 2

    @property
    def min_gain_dn_per_e(self) -> float:
        """K at 0 dB, DN/e⁻: the full well fills the 8-bit range (255/μ_e.sat)."""
        return 255.0 / self.saturation_e

    @property
    def max_gain_dn_per_e(self) -> float:
        """K at the largest gain, DN/e⁻."""
        return self.min_gain_dn_per_e * 10.0 ** (self.max_gain_db / 20.0)


#: Built-in sensors by name. IMX273 (Sony Pregius, 3.45 µm, 1/2.9"): saturation capacity from the
#: EMVA 1288 maximum SNR 40.2 dB (μ_e.sat = 10^(40.2/10)), dark noise from the dynamic range
#: 71.4 dB (σ_d = μ_e.sat/10^(71.4/20) − ½), both measured on a monochrome mvBlueFOX3-2016;
#: 48 dB gain as the Pregius 3.45 µm cameras give; η = 0.65 at 555 nm assumed (docs/design.md,
#: "Sensor and light").
SENSORS: dict[str, SensorFigures] = {
    "IMX273": SensorFigures(
        name="IMX273",
        pixel_pitch_m=3.45e-6,
        quantum_efficiency=0.65,
        dark_noise_e=round(10.0 ** (40.2 / 10.0) / 10.0 ** (71.4 / 20.0) - 0.5, 2),
        saturation_e=round(10.0 ** (40.2 / 10.0)),
        max_gain_db=48.0,
    ),
}


def photons_per_pixel(illuminance_lux, reflectance, f_number: float, pixel_area_m2: float, exposure_s: float,
                      lens_transmission: float = LENS_TRANSMISSION):
    """Mean photons a pixel collects from a Lambertian surface in one exposure.

    μ_p = ρ·E_v·T/(4N²·683) · A · t_exp · λ/(hc) at λ = 555 nm (on axis, a distant object, no
    cos⁴ fall-off).

    Parameters
    ----------
    illuminance_lux : float or ndarray
        Illuminance E_v on the surface, lx.
    reflectance : float or ndarray
        Lambertian reflectance ρ in [0, 1].
    f_number : float
        The lens's f-number N.
    pixel_area_m2 : float
        Pixel area A, m².
    exposure_s : float
        Exposure t_exp, s.
    lens_transmission : float
        T (:data:`LENS_TRANSMISSION`).

    Returns
    -------
    float or ndarray
        Photons per pixel (broadcast of the inputs).

    Examples
    --------
    >>> round(photons_per_pixel(300.0, 1.0, 2.8, (3.45e-6) ** 2, 1e-3))
    419
    """
    image_lux = np.multiply(illuminance_lux, reflectance) * lens_transmission / (4.0 * f_number ** 2)
    irradiance_w_m2 = image_lux / LUMINOUS_EFFICACY_LM_PER_W
    photon_energy_j = _PLANCK_J_S * _LIGHT_M_S / WAVELENGTH_M
    return irradiance_w_m2 * pixel_area_m2 * exposure_s / photon_energy_j


def snr_closed_form(mean_electrons, dark_noise_e: float, gain_dn_per_e: float):
    """EMVA 1288's SNR of a pixel: η μ_p / sqrt(σ_d² + η μ_p + σ_q²/K²).

    Parameters
    ----------
    mean_electrons : float or ndarray
        η μ_p, e⁻.
    dark_noise_e : float
        σ_d, e⁻.
    gain_dn_per_e : float
        K, DN/e⁻.
    """
    mean_electrons = np.asarray(mean_electrons, dtype=float)
    return mean_electrons / np.sqrt(dark_noise_e ** 2 + mean_electrons + QUANTISATION_VAR_DN2 / gain_dn_per_e ** 2)


def grey_noise_closed_form(mean_electrons, dark_noise_e: float, gain_dn_per_e: float):
    """Temporal noise of a pixel in grey levels: sqrt(K²(σ_d² + η μ_p) + σ_q²), DN (away from the clips).

    Parameters as :func:`snr_closed_form`.
    """
    mean_electrons = np.asarray(mean_electrons, dtype=float)
    return np.sqrt(gain_dn_per_e ** 2 * (dark_noise_e ** 2 + mean_electrons) + QUANTISATION_VAR_DN2)


def _normal_table() -> np.ndarray:
    """Standard normal inverse CDF at the 2¹⁶ mid-quantiles (float32)."""
    if not _NORMAL_TABLE:
        from scipy.stats import norm

        _NORMAL_TABLE.append(norm.ppf((np.arange(_LEVELS) + 0.5) / _LEVELS).astype(np.float32))
    return _NORMAL_TABLE[0]


def _standard_normals(rng: np.random.Generator, size: int) -> np.ndarray:
    """``size`` standard normals from 16 raw bits each (tails beyond ±4.2 σ cut)."""
    words = rng.bit_generator.random_raw(-(-size // 4))
    draws = words.astype("<u8", copy=False).view(np.uint16)[:size]
    return np.take(_normal_table(), draws)


def _level_table(values: np.ndarray) -> np.ndarray:
    """256 values as a lookup table :func:`cv2.LUT` reads (shape (1, 256))."""
    return np.ascontiguousarray(values).reshape(1, 256)


def _lookup(levels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``table[levels]`` for a flat uint8 ``levels``, as a flat array of the table's dtype."""
    return cv2.LUT(levels.reshape(-1, 1), table).reshape(-1)


def _to_uint8(signal: np.ndarray) -> np.ndarray:
    """clip(round(signal), 0, 255) as uint8, halves to even (numpy's rint), in one pass."""
    if signal.size <= 4:  # OpenCV would read an array this small as a scalar
        return np.clip(np.rint(signal), 0, 255).astype(np.uint8)
    return cv2.add(signal.reshape(-1, 1), 0.0, dtype=cv2.CV_8U).reshape(-1)


def _mean(image: np.ndarray) -> float:
    """Mean grey level of a uint8 image: the exact integer sum over the count, as ``np.mean`` gives it."""
    if image.size <= 4:
        return float(np.mean(image, dtype=np.float64))
    return cv2.sumElems(image.reshape(-1, 1))[0] / image.size


def _electrons(levels: np.ndarray, mean_e: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Poisson electrons for pixels of grey ``levels`` with means ``mean_e[level]``: by inversion
    (:func:`_poisson_by_level`) up to :data:`_INVERSION_MAX_E`, then numpy's sampler above."""
    by_inversion = mean_e <= _INVERSION_MAX_E
    if by_inversion.all():
        return _poisson_by_level(levels, mean_e, rng)
    low = np.take(by_inversion, levels)
    shot = np.empty(levels.size, np.int64)
    shot[low] = _poisson_by_level(levels[low], np.where(by_inversion, mean_e, 0.0), rng)
    shot[~low] = rng.poisson(mean_e[levels[~low]])
    return shot


@dataclass(frozen=True)
class _PoissonTables:
    """Per grey level, the Poisson CDF the inversion sampler reads (:func:`_poisson_by_level`).

    Level v's row holds P(K ≤ k) at its mean for the counts k = lo_v ... hi_v (``cdf``, the last
    entry set to 1; ``count`` holds each entry's k). ``guide[base_v + j]`` covers the draws
    u ∈ [j/M, (j + 1)/M): the count they all give where no CDF value lies in that cell, else
    −1 − the global index of the row's first entry above j/M, from which a draw searches on.
    """

    guide: np.ndarray    # int32, shape (rows·M,)
    cdf: np.ndarray      # float64, all rows end to end
    count: np.ndarray    # int32, the count k of each CDF entry
    base: np.ndarray     # int32, shape (1, 256): the first of level v's guide cells (levels of one mean share a row)


_GUIDE_CELLS = 4096
#: Largest Poisson mean, e⁻, drawn by inversion (a row of about 2,400 counts); numpy's sampler above.
_INVERSION_MAX_E = 1e4


@functools.lru_cache(maxsize=16)
def _poisson_tables(mean_e_bytes: bytes) -> _PoissonTables:
    """The inversion tables for the Poisson means in ``mean_e_bytes`` (256 float64, e⁻), cached by value.

    A row spans mean ± (12 σ + 12) counts (σ = sqrt(mean)); the probability beyond, below 10⁻³⁰,
    goes to the row's first and last count.
    """
    from scipy.stats import poisson

    mean_e = np.frombuffer(mean_e_bytes, dtype=np.float64)
    cells = np.arange(_GUIDE_CELLS) / _GUIDE_CELLS
    cdf_rows, count_rows, guide_rows, start = [], [], [], 0
    base, row_of_mean = np.zeros(256, np.int32), {}
    for level, mean in enumerate(mean_e):
        if mean in row_of_mean:  # levels of one mean (0 for those the caller leaves out) share a row
            base[level] = row_of_mean[mean] * _GUIDE_CELLS
            continue
        row_of_mean[mean] = len(guide_rows)
        base[level] = row_of_mean[mean] * _GUIDE_CELLS
        half = 12.0 * math.sqrt(mean) + 12.0
        counts = np.arange(max(0.0, math.floor(mean - half)), math.ceil(mean + half) + 1.0)
        cdf = np.maximum.accumulate(poisson.cdf(counts, mean))
        cdf[-1] = 1.0
        first_above = np.searchsorted(cdf, cells, side="right")
        first_at_next = np.searchsorted(cdf, cells + 1.0 / _GUIDE_CELLS, side="left")
        guide_rows.append(np.where(first_above == first_at_next, counts[first_above],
                                   -1 - (start + first_above)))
        cdf_rows.append(cdf)
        count_rows.append(counts)
        start += counts.size
    return _PoissonTables(guide=np.concatenate(guide_rows).astype(np.int32), cdf=np.concatenate(cdf_rows),
                          count=np.concatenate(count_rows).astype(np.int32),
                          base=_level_table(base))


def _poisson_by_level(levels: np.ndarray, mean_e: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Poisson counts with mean ``mean_e[v]`` for each v in ``levels``, by inversion.

    One uniform u in [0, 1) per sample (``rng.random``, 53 bits), in the samples' order; the count
    is the least k with P(K ≤ k) > u, read from a guide table of 4096 cells per level (Chen and
    Asau's indexed search) or, for a draw in a cell that holds a CDF step, searched from there.
    Exact up to the CDF's float64 rounding and the tails beyond 12 σ + 12 (docs/design.md,
    "Sensor and light").

    Parameters
    ----------
    levels : ndarray of uint8, shape (N,)
        Each sample's grey level.
    mean_e : ndarray, shape (256,)
        The Poisson mean of each grey level, e⁻ (>= 0).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of int32, shape (N,)
        The counts, e⁻.
    """
    tables = _poisson_tables(np.ascontiguousarray(mean_e, dtype=np.float64).tobytes())
    u = rng.random(levels.size)
    u *= _GUIDE_CELLS  # exact: a power of two only shifts the exponent
    cell = u.astype(np.intp)
    cell += _lookup(levels, tables.base)
    count = np.take(tables.guide, cell)
    todo = np.flatnonzero(count < 0)
    if todo.size:
        at = -1 - count[todo].astype(np.intp)
        u_todo = u[todo] / _GUIDE_CELLS
        step = np.flatnonzero(np.take(tables.cdf, at) <= u_todo)
        while step.size:
            at[step] += 1
            step = step[np.take(tables.cdf, at[step]) <= u_todo[step]]
        count[todo] = np.take(tables.count, at)
    return count


@dataclass(frozen=True)
class SensorModel:
    """A sensor behind a lens in a scene's light: the EMVA 1288 linear model (module docstring).

    Parameters
    ----------
    figures : SensorFigures or str
        The sensor, or the name of one in :data:`SENSORS`.
    light_lux : float
        The scene's illuminance, lx (> 0).
    f_number : float
        The lens's f-number N (>= 0.5).
    lens_transmission : float
        T in (0, 1] (:data:`LENS_TRANSMISSION`).

    Examples
    --------
    >>> model = SensorModel("IMX273", light_lux=300.0, f_number=2.8)
    >>> image = np.full((4, 4), 128, np.uint8)
    >>> model.record(image, 0.004, np.random.default_rng(0)).dtype
    dtype('uint8')
    """

    figures: SensorFigures | str
    light_lux: float
    f_number: float
    lens_transmission: float = LENS_TRANSMISSION

    def __post_init__(self):
        if isinstance(self.figures, str):
            if self.figures not in SENSORS:
                raise ValueError(f"sensor must be one of {sorted(SENSORS)}, got {self.figures!r}")
            object.__setattr__(self, "figures", SENSORS[self.figures])
        if not isinstance(self.figures, SensorFigures):
            raise TypeError(f"figures must be a SensorFigures or a name, got {type(self.figures).__name__}")
        for name, low, high in (("light_lux", 0.0, 1e6), ("f_number", 0.5, 64.0), ("lens_transmission", 0.0, 1.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not (low < value <= high):
                raise ValueError(f"{name} must be a number in ({low:g}, {high:g}], got {value!r}")

    def electrons_at_full_reflectance(self, exposure_s: float) -> float:
        """η μ_p of a pixel that sees reflectance 1 over ``exposure_s``, e⁻."""
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"exposure_s must be a finite number > 0 s, got {exposure_s!r}")
        photons = photons_per_pixel(self.light_lux, 1.0, self.f_number, self.figures.pixel_area_m2, exposure_s,
                                    self.lens_transmission)
        return float(self.figures.quantum_efficiency * photons)

    def auto_gain(self, image: np.ndarray, exposure_s: float) -> float:
        """The auto-gain's K, DN/e⁻: the rendered mean over the expected electrons, within [K_min, K_max]."""
        low, high = self.figures.min_gain_dn_per_e, self.figures.max_gain_dn_per_e
        mean_dn = _mean(image)
        mean_e = self.electrons_at_full_reflectance(exposure_s) * mean_dn / 255.0
        if mean_e <= 0:
            return high
        return min(max(mean_dn / mean_e, low), high)

    def record(self, image: np.ndarray, exposure_s: float, rng: np.random.Generator, *,
               gain_dn_per_e: float | None = None, black_level_dn: float = 0.0, exact: bool = False) -> np.ndarray:
        """The 8-bit image the sensor records of a rendered ``image`` over ``exposure_s``.

        Parameters
        ----------
        image : ndarray of uint8, any shape
            The rendered frame; v/255 is each pixel's reflectance under unit light.
        exposure_s : float
            Exposure, s (> 0).
        rng : numpy.random.Generator
            The source of randomness (same state → same image).
        gain_dn_per_e : float, optional
            A fixed system gain K, DN/e⁻; None: the auto-gain (:meth:`auto_gain`).
        black_level_dn : float
            Offset b added before quantisation, DN (0).
        exact : bool
            Draw Poisson shot noise for every pixel instead of the normal shortcut above
            :data:`NORMAL_ABOVE_E`.

        Returns
        -------
        ndarray of uint8, same shape.
        """
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise TypeError(f"image must be uint8, got {image.dtype}")
        if gain_dn_per_e is None:
            gain = self.auto_gain(image, exposure_s)
        else:
            if not (math.isfinite(gain_dn_per_e) and gain_dn_per_e > 0):
                raise ValueError(f"gain_dn_per_e must be a finite number > 0 DN/e-, got {gain_dn_per_e!r}")
            gain = float(gain_dn_per_e)
        if not (math.isfinite(black_level_dn) and 0 <= black_level_dn < 255):
            raise ValueError(f"black_level_dn must be in [0, 255) DN, got {black_level_dn!r}")
        figures = self.figures
        mean_e = self.electrons_at_full_reflectance(exposure_s) * np.arange(256) / 255.0
        dark_var = figures.dark_noise_e ** 2
        z = _standard_normals(rng, image.size)
        flat = image.reshape(-1)
        # the full model (Poisson shot noise plus Gaussian read noise) below the shortcut's threshold;
        # mean_e grows with the level, so its levels are those below full_levels
        full_levels = 256 if exact else int(np.count_nonzero(mean_e < NORMAL_ABOVE_E))
        if full_levels == 256:
            signal = (gain * (_electrons(flat, mean_e, rng) + figures.dark_noise_e * z)).astype(np.float32)
        else:
            # the normal shortcut: electrons = mean + sqrt(mean + σ_d²)·z, as grey levels before the clips
            mean_dn = _level_table((gain * mean_e).astype(np.float32))
            sd_dn = _level_table((gain * np.sqrt(mean_e + dark_var)).astype(np.float32))
            full = flat < full_levels
            n_full = int(np.count_nonzero(full)) if full_levels else 0
            many = 4 * n_full > flat.size  # then masks cost less than the pixels' indices
            pick = None if many else np.flatnonzero(full)
            read_e = figures.dark_noise_e * (z if many else z[pick])  # a new array: z is used up below
            signal = z
            signal *= _lookup(flat, sd_dn)
            signal += _lookup(flat, mean_dn)
            means_e = np.where(mean_e < NORMAL_ABOVE_E, mean_e, 0.0)
            if many:  # every pixel draws a count (0 above the threshold), the full model's replace the shortcut's
                np.copyto(signal, gain * (_electrons(flat, means_e, rng) + read_e), where=full, casting="same_kind")
            elif n_full:
                signal[pick] = gain * (_electrons(flat[pick], means_e, rng) + read_e)
        saturation_dn = np.float32(gain * figures.saturation_e)
        black_dn = np.float32(black_level_dn)
        if saturation_dn + black_dn < 255:  # else the 8-bit clip reads 255 wherever the full well would
            np.minimum(signal, saturation_dn, out=signal)
        if black_dn:
            signal += black_dn
        return _to_uint8(signal).reshape(image.shape)
