"""Pinhole camera with Brown–Conrady, rational or Kannala–Brandt (fisheye) lens distortion.

Conventions (stated once, pinned by tests against ``cv2.projectPoints``):

* Camera optical frame as OpenCV: x right, y down, z forward (along the optical axis).
* Pixel centres have integer coordinates; the image centre of a W×H image is
  ((W − 1)/2, (H − 1)/2).
* Normalised image coordinates are (x/z, y/z); the paper's (û, v̂, 1)ᵀ = K⁻¹(u, v, 1)ᵀ.
* Distortion coefficients follow OpenCV's normalised convention and order
  (k1, k2, p1, p2, k3)::

      r² = x² + y²
      x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
      y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y

* The rational lens (:class:`Rational`, OpenCV's ``CALIB_RATIONAL_MODEL``, ROS's
  ``rational_polynomial``) divides the radial factor by a second polynomial, with OpenCV's order
  (k1, k2, p1, p2, k3, k4, k5, k6)::

      L(r) = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
      x_d = x L(r) + 2 p1 x y + p2 (r² + 2 x²),  y_d = y L(r) + p1 (r² + 2 y²) + 2 p2 x y

* Fisheye lenses follow OpenCV's ``cv2.fisheye`` (Kannala–Brandt) convention: a ray at angle θ
  from the optical axis lands at distance θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) from the
  principal point (normalised), along the ray's own azimuth. θ may exceed 90° (a 185° lens), so
  :func:`project` takes it from the 3-D direction, θ = atan2(√(x² + y²), z), and
  :func:`backproject` returns unit rays for such a lens.

Every lens model is accepted wherever a lens is: :func:`distort`, :func:`undistort`,
:func:`project`, :func:`backproject`, :func:`undistort_pixels`, :func:`distort_pixels`.

Notes
-----
Paper §3.2 (pinhole model, K) and §4.1 (Brown–Conrady radial distortion of the simulated camera);
§4.1.2 (end) and §5 ask how far rectification can go with fisheye lenses.
"""

from __future__ import annotations

import functools
import math
import struct
import sys
from dataclasses import dataclass

import numpy as np

_EPS = float(np.finfo(float).eps)

__all__ = [
    "Intrinsics",
    "BrownConrady",
    "KannalaBrandt",
    "Rational",
    "LENS_TYPES",
    "project",
    "distort",
    "undistort",
    "backproject",
    "undistort_pixels",
    "distort_pixels",
    "UndistortionError",
]


class UndistortionError(ValueError):
    """Raised when a distorted point has no preimage in the model's monotonic region."""


def _finite_float(name: str, value) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out}")
    return out


def _check_pixels(name: str, value) -> int:
    """A positive whole number of pixels (an int, or a float with no fraction), as an int."""
    try:
        whole = not isinstance(value, bool) and float(value).is_integer() and value > 0
    except (TypeError, ValueError):
        whole = False
    if not whole:
        raise ValueError(f"{name} must be a positive integer number of pixels, got {value!r}")
    return int(value)


def _float_bits(value: float) -> int:
    """The IEEE-754 bit pattern of a float ≥ 0 as an integer: it rises with the value."""
    return struct.unpack("<q", struct.pack("<d", value))[0]


def _bits_float(bits: int) -> float:
    return struct.unpack("<d", struct.pack("<q", bits))[0]


def _polyval(coeffs: tuple[float, ...], s: float) -> float:
    """Σ coeffs[i]·s^i by Horner's rule (overflow gives ±inf, never NaN for s > 0)."""
    value = 0.0
    for c in reversed(coeffs):
        value = value * s + c
    return value


def _positive_roots(coeffs: tuple[float, ...]) -> list[float]:
    """Every positive root of Σ coeffs[i]·s^i (ascending powers), sorted, each to the last bit.

    Between consecutive positive roots of the derivative (found the same way) the polynomial is
    monotonic, so each stretch holds at most one root, bracketed by a change of sign and found by
    bisecting the floats' bit patterns (64 steps, whatever the magnitudes). Unlike eigenvalues of
    the companion matrix (``np.roots``), this neither loses small roots beside huge ones nor fails
    when the highest coefficient is tiny. A root where the polynomial only touches zero is found
    when it evaluates to exactly zero there.
    """
    coeffs = tuple(coeffs)
    while coeffs and coeffs[-1] == 0.0:
        coeffs = coeffs[:-1]
    while coeffs and coeffs[0] == 0.0:  # s^m·q(s): q has the same positive roots
        coeffs = coeffs[1:]
    if len(coeffs) < 2:
        return []
    derivative = tuple(i * c for i, c in enumerate(coeffs) if i)
    ends = [0.0, *_positive_roots(derivative)]
    sign_at_infinity = math.copysign(1.0, coeffs[-1])
    top = max(ends[-1], 1.0)
    while math.isfinite(top) and math.copysign(1.0, _polyval(coeffs, top)) != sign_at_infinity:
        top *= 2.0
    ends.append(top)
    roots = []
    for lo, hi in zip(ends[:-1], ends[1:]):
        f_lo, f_hi = _polyval(coeffs, lo), _polyval(coeffs, hi)
        if f_hi == 0.0 and hi > 0.0:
            roots.append(hi)
            continue
        if f_lo == 0.0 or (f_lo > 0.0) == (f_hi > 0.0):
            continue
        a, b = _float_bits(lo), _float_bits(hi)
        while b - a > 1:
            mid = (a + b) // 2
            if (_polyval(coeffs, _bits_float(mid)) > 0.0) == (f_lo > 0.0):
                a = mid
            else:
                b = mid
        roots.append(_bits_float(b))
    return sorted(set(r for r in roots if r > 0.0))


@functools.lru_cache(maxsize=256)
def _first_positive_root(terms: tuple[tuple[str, float, int], ...]) -> float:
    """Smallest positive root s of 1 + Σ w·c·s^i over ``terms`` = ((name, c, w), ...) for i = 1, 2, …

    Used for where a lens's radial map stops rising. Returns ``inf`` when there is none.

    Raises
    ------
    ValueError
        A coefficient so large that w·c overflows a double; the message names it.
    """
    poly = [1.0]
    for name, value, weight in terms:
        poly.append(weight * value)
        if not math.isfinite(poly[-1]):
            raise ValueError(f"lens coefficient {name} = {value!r} is too large: {weight}·{name} overflows a double; "
                             f"allowed: |{name}| < {sys.float_info.max / weight:.3g}")
    roots = _positive_roots(tuple(poly))
    return roots[0] if roots else math.inf


def _as_points(name: str, array, dim: int) -> np.ndarray:
    """Return ``array`` as a float (N, dim) array; a single point of shape (dim,) is accepted."""
    arr = np.asarray(array, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}) or ({dim},), got {np.shape(array)}")
    return arr


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a camera without skew.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in pixels (OpenCV convention: pixel centres are integers).
    width, height : int
        Image size in pixels (> 0).

    Examples
    --------
    >>> cam = Intrinsics.from_fov(640, 480, math.radians(60))
    >>> round(cam.fx, 2), cam.cx, cam.cy
    (554.26, 319.5, 239.5)
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            value = _finite_float(name, getattr(self, name))
            object.__setattr__(self, name, value)
        for name in ("fx", "fy"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0 px, got {getattr(self, name)}")
        for name in ("width", "height"):
            object.__setattr__(self, name, _check_pixels(name, getattr(self, name)))

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_rad: float) -> "Intrinsics":
        """Square pixels, principal point at the image centre, horizontal field of view ``hfov_rad``.

        fx = fy = (W/2) / tan(hfov/2), cx = (W − 1)/2, cy = (H − 1)/2.

        Raises
        ------
        ValueError
            ``hfov_rad`` is not a normal positive float below π (0, a subnormal, inf, NaN, ≥ π),
            or is so small that the focal length overflows; a size that is not a positive integer.
        """
        hfov_rad = _finite_float("hfov_rad", hfov_rad)
        if not sys.float_info.min <= hfov_rad < math.pi:
            raise ValueError(f"hfov_rad must be a normal positive float below pi rad (180°), got {hfov_rad!r}")
        for name, value in (("width", width), ("height", height)):
            _check_pixels(name, value)
        f = (width / 2.0) / math.tan(hfov_rad / 2.0)
        if not math.isfinite(f):
            raise ValueError(f"hfov_rad = {hfov_rad!r} is too small: the focal length (W/2)/tan(hfov/2) overflows "
                             f"for width {width} px")
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)

    @classmethod
    def default(cls) -> "Intrinsics":
        """The study's camera: 640 × 480 px, 60° horizontal field of view (fx = fy ≈ 554.26 px)."""
        return cls.from_fov(640, 480, math.radians(60.0))

    @property
    def K(self) -> np.ndarray:
        """The 3 × 3 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels, the order OpenCV expects."""
        return (self.width, self.height)

    def to_normalised(self, uv_px) -> np.ndarray:
        """Pixel coordinates (N, 2) → normalised coordinates (N, 2): ((u − cx)/fx, (v − cy)/fy)."""
        uv = _as_points("uv_px", uv_px, 2)
        return np.column_stack(((uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy))

    def to_pixels(self, xy_norm) -> np.ndarray:
        """Normalised coordinates (N, 2) → pixel coordinates (N, 2)."""
        xy = _as_points("xy_norm", xy_norm, 2)
        return np.column_stack((self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy))


@dataclass(frozen=True)
class BrownConrady:
    """Brown–Conrady lens distortion in OpenCV's normalised convention and order.

    Parameters
    ----------
    k1, k2, k3 : float
        Radial coefficients (k1 < 0: barrel, k1 > 0: pincushion).
    p1, p2 : float
        Tangential (decentring) coefficients.

    Notes
    -----
    The model acts on normalised coordinates (x/z, y/z); see the module docstring for the
    formula. Paper §4.1 uses the radial part; the study's default adds a small tangential term.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self):
        for name in ("k1", "k2", "p1", "p2", "k3"):
            object.__setattr__(self, name, _finite_float(name, getattr(self, name)))
        self.radial_limit()  # refuses coefficients whose fold radius cannot be computed, naming them

    @classmethod
    def default(cls) -> "BrownConrady":
        """The study's distorted camera (docs/design.md): mild barrel with a small tangential term."""
        return cls(k1=-0.25, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.0)

    @classmethod
    def from_gazebo_legacy(cls, k1, k2, k3, p1, p2, intrinsics: Intrinsics) -> "BrownConrady":
        """Convert Gazebo-classic "legacy" coefficients to OpenCV's normalised convention.

        Gazebo's legacy mode distorts texture-space coordinates ``(u − cx)/S`` with
        S = max(W, H) instead of normalised coordinates ``(u − cx)/f``. Writing the legacy
        coordinate as x·(f/S) and matching powers gives, exactly,
        k1·(f/S)², k2·(f/S)⁴, k3·(f/S)⁶ and p·(f/S).

        Parameters
        ----------
        k1, k2, k3, p1, p2 : float
            Legacy coefficients, in Gazebo's SDF order.
        intrinsics : Intrinsics
            The camera; needs square pixels (fx == fy), as Gazebo's cameras have.
        """
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError("intrinsics must be an Intrinsics")
        if not math.isclose(intrinsics.fx, intrinsics.fy, rel_tol=1e-12):
            raise ValueError(
                f"from_gazebo_legacy needs square pixels (fx == fy), got fx={intrinsics.fx}, fy={intrinsics.fy}"
            )
        s = intrinsics.fx / max(intrinsics.width, intrinsics.height)
        vals = {n: _finite_float(n, v) for n, v in dict(k1=k1, k2=k2, k3=k3, p1=p1, p2=p2).items()}
        return cls(
            k1=vals["k1"] * s**2,
            k2=vals["k2"] * s**4,
            p1=vals["p1"] * s,
            p2=vals["p2"] * s,
            k3=vals["k3"] * s**6,
        )

    @property
    def coefficients(self) -> np.ndarray:
        """(k1, k2, p1, p2, k3) as an array of shape (5,), ready for OpenCV."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def is_identity(self) -> bool:
        """True when every coefficient is zero."""
        return not np.any(self.coefficients)

    def radial_limit(self) -> float:
        """Largest undistorted radius r (normalised) up to which the radial map r ↦ r·L(r) rises.

        The radial part folds over where d/dr [r (1 + k1 r² + k2 r⁴ + k3 r⁶)] = 0, i.e. at the
        smallest positive root of 1 + 3 k1 s + 5 k2 s² + 7 k3 s³ (s = r²). Returns ``inf`` when
        the map rises everywhere.
        """
        return math.sqrt(_first_positive_root((("k1", self.k1, 3), ("k2", self.k2, 5), ("k3", self.k3, 7))))

    def radial_image(self, r: float) -> float:
        """Distorted radius r·L(r) of undistorted radius ``r`` (normalised; the radial part alone)."""
        return float(_radial_map(np.asarray(float(r)), self)[0])

    def disc_image(self) -> float:
        """The largest distorted radius with a preimage in the monotonic disc: r·L(r) at
        :meth:`radial_limit` (``inf`` when the map rises everywhere)."""
        return _disc_image(self)


def _polymul(a, b) -> list[float]:
    """Coefficients (ascending powers) of the product of two polynomials."""
    out = [0.0] * (len(a) + len(b) - 1)
    for i, u in enumerate(a):
        for j, v in enumerate(b):
            out[i + j] += u * v
    return out


@functools.lru_cache(maxsize=256)
def _rational_fold(k: tuple[float, ...]) -> float:
    """Smallest s = r² > 0 where the rational radial map r·N(s)/D(s) stops rising, or its denominator
    D(s) reaches 0; ``inf`` when neither happens. ``k`` = (k1, k2, k3, k4, k5, k6).

    d/dr [r N/D] = [N D + 2 s (N' D − N D')] / D² (primes: d/ds), so the map turns where the
    polynomial N D + 2 s (N' D − N D') has its first positive root, and has a pole where D has.
    """
    k1, k2, k3, k4, k5, k6 = k
    num, den = [1.0, k1, k2, k3], [1.0, k4, k5, k6]
    dnum, dden = [k1, 2.0 * k2, 3.0 * k3], [k4, 2.0 * k5, 3.0 * k6]
    turn = _polymul(num, den)
    for i, (a, b) in enumerate(zip(_polymul(dnum, den), _polymul(num, dden))):
        turn[i + 1] += 2.0 * (a - b)
    if not all(math.isfinite(c) for c in turn):
        names = ("k1", "k2", "k3", "k4", "k5", "k6")
        largest = max(range(6), key=lambda i: abs(k[i]))
        raise ValueError(f"lens coefficient {names[largest]} = {k[largest]!r} is too large: the rational map's "
                         "slope polynomial overflows a double")
    roots = _positive_roots(tuple(turn)) + _positive_roots(tuple(den))
    return min(roots) if roots else math.inf


@dataclass(frozen=True)
class Rational:
    """OpenCV's rational lens (``CALIB_RATIONAL_MODEL``; ROS ``rational_polynomial``), in its order.

    The radial factor is a ratio of two polynomials in r², which follows the strong distortion of
    wide phone and action-camera lenses better than Brown–Conrady's single polynomial; the
    tangential terms are Brown–Conrady's (module docstring).

    Parameters
    ----------
    k1, k2, k3 : float
        Numerator coefficients of the radial factor (as Brown–Conrady's k1, k2, k3).
    p1, p2 : float
        Tangential (decentring) coefficients.
    k4, k5, k6 : float
        Denominator coefficients: L(r) = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶).

    Notes
    -----
    With k4 = k5 = k6 = 0 the lens is the Brown–Conrady lens of the same k1, k2, p1, p2, k3.
    Paper §4.1.3 (real cameras): calibrations of wide phone lenses often use this model.

    Examples
    --------
    >>> lens = Rational(k1=0.5, k4=0.6)
    >>> lens.coefficients.tolist()
    [0.5, 0.0, 0.0, 0.0, 0.0, 0.6, 0.0, 0.0]
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0

    def __post_init__(self):
        for name in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"):
            object.__setattr__(self, name, _finite_float(name, getattr(self, name)))
        self.radial_limit()  # refuses coefficients whose fold radius cannot be computed, naming them

    @property
    def coefficients(self) -> np.ndarray:
        """(k1, k2, p1, p2, k3, k4, k5, k6), shape (8,), as ``cv2.projectPoints`` takes them."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3, self.k4, self.k5, self.k6])

    @property
    def is_identity(self) -> bool:
        """True when every coefficient is zero."""
        return not np.any(self.coefficients)

    def radial_limit(self) -> float:
        """Largest undistorted radius r (normalised) up to which the radial map r ↦ r·L(r) rises
        (and its denominator stays positive); ``inf`` when it rises everywhere."""
        return math.sqrt(_rational_fold((self.k1, self.k2, self.k3, self.k4, self.k5, self.k6)))

    def radial_image(self, r: float) -> float:
        """Distorted radius r·L(r) of undistorted radius ``r`` (normalised; the radial part alone);
        ``inf`` at a pole of L."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return float(_radial_map(np.asarray(float(r)), self)[0])

    def disc_image(self) -> float:
        """The largest distorted radius with a preimage in the monotonic disc: r·L(r) at
        :meth:`radial_limit`; ``inf`` when the map rises everywhere or up to a pole of L."""
        return _disc_image(self)


@dataclass(frozen=True)
class KannalaBrandt:
    """Fisheye lens in OpenCV's ``cv2.fisheye`` (Kannala–Brandt, equidistant base) convention.

    A ray at angle θ from the optical axis is imaged at normalised radius
    θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), along its own azimuth; pixels are
    u = fx·x_d + cx, v = fy·y_d + cy (no skew).

    Parameters
    ----------
    k1, k2, k3, k4 : float
        OpenCV's fisheye coefficients D = (k1, k2, k3, k4); all zero is the equidistant lens
        θ_d = θ.
    max_field_rad : float or None
        Largest field angle θ the lens images, rad, in (0, π]. None: where θ_d(θ) stops rising
        (first zero of dθ_d/dθ), or π. Points beyond it are rejected with a clear error.

    Notes
    -----
    Paper §4.1.2 (end) and §5 hypothesise that rectifying fisheye images hurts tracking; this model
    lets the lab render and detect through such lenses (notebook on the lens sweep).

    Examples
    --------
    >>> lens = KannalaBrandt()             # equidistant
    >>> round(float(lens.theta_d(np.pi / 2)), 6)
    1.570796
    """

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    max_field_rad: float | None = None

    def __post_init__(self):
        for name in ("k1", "k2", "k3", "k4"):
            object.__setattr__(self, name, _finite_float(name, getattr(self, name)))
        rising = self._rising_limit()
        if self.max_field_rad is None:
            object.__setattr__(self, "max_field_rad", rising)
        else:
            limit = _finite_float("max_field_rad", self.max_field_rad)
            if not 0.0 < limit <= math.pi:
                raise ValueError(f"max_field_rad must be in (0, π], got {self.max_field_rad!r}")
            if limit > rising + 1e-12:
                raise ValueError(f"max_field_rad {limit:.6g} rad lies beyond where θ_d(θ) stops rising "
                                 f"({rising:.6g} rad): the lens would image two angles at one radius")
            object.__setattr__(self, "max_field_rad", limit)

    def _rising_limit(self) -> float:
        # dθ_d/dθ = 1 + 3 k1 θ² + 5 k2 θ⁴ + 7 k3 θ⁶ + 9 k4 θ⁸, a polynomial in s = θ²
        s = _first_positive_root((("k1", self.k1, 3), ("k2", self.k2, 5), ("k3", self.k3, 7), ("k4", self.k4, 9)))
        return min(math.sqrt(s), math.pi)

    @classmethod
    def equidistant_for_fov(cls, width_px: int, hfov_rad: float) -> tuple["KannalaBrandt", float]:
        """The equidistant lens (all k = 0) and the focal length that maps ``hfov_rad`` onto the width.

        With θ_d = θ the image radius is f·θ, so the image's half width W/2 is reached at
        θ = hfov/2 when f = (W/2)/(hfov/2). Returns (lens, f_px); the lens images up to
        max(hfov/2, its own limit) so a wide image circle stays valid.
        """
        width = _finite_float("width_px", width_px)
        hfov = _finite_float("hfov_rad", hfov_rad)
        if width <= 0 or not 0.0 < hfov <= 2 * math.pi:
            raise ValueError(f"need width_px > 0 and hfov_rad in (0, 2π], got {width_px!r}, {hfov_rad!r}")
        return cls(), (width / 2.0) / (hfov / 2.0)

    @property
    def coefficients(self) -> np.ndarray:
        """(k1, k2, k3, k4), shape (4,), as ``cv2.fisheye`` takes them."""
        return np.array([self.k1, self.k2, self.k3, self.k4])

    @property
    def is_identity(self) -> bool:
        """Always False: even the equidistant fisheye is not a pinhole."""
        return False

    def theta_d(self, theta):
        """Normalised image radius of rays at angle(s) ``theta`` from the axis (rad)."""
        t = np.asarray(theta, dtype=float)
        t2 = t * t
        return t * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))

    def _dtheta_d(self, t):
        t2 = t * t
        return 1.0 + t2 * (3 * self.k1 + t2 * (5 * self.k2 + t2 * (7 * self.k3 + t2 * 9 * self.k4)))

    def theta(self, theta_d, tol: float = 1e-14, max_iter: int = 60) -> np.ndarray:
        """Invert θ_d(θ) on [0, max_field_rad] (safeguarded Newton); errors name the valid range."""
        td = np.asarray(theta_d, dtype=float)
        if not np.all(np.isfinite(td)) or np.any(td < 0):
            raise ValueError("theta_d must be finite and >= 0")
        top = float(self.theta_d(self.max_field_rad))
        beyond = td > top * (1 + 1e-12)
        if beyond.any():
            raise UndistortionError(
                f"{int(beyond.sum())} point(s) lie outside the lens's image circle: normalised radius "
                f"{float(td[beyond].max()):.6g} > {top:.6g}, the image of the largest field angle "
                f"{math.degrees(self.max_field_rad):.2f}°")
        lo, hi = np.zeros_like(td), np.full_like(td, self.max_field_rad)
        t = np.minimum(td, self.max_field_rad)
        for _ in range(max_iter):
            f = self.theta_d(t) - td
            lo = np.where(f < 0, t, lo)
            hi = np.where(f > 0, t, hi)
            step = f / self._dtheta_d(t)
            t_new = t - step
            out = (t_new <= lo) | (t_new >= hi)
            t_new = np.where(out, 0.5 * (lo + hi), t_new)
            if np.all(np.abs(t_new - t) < tol):
                t = t_new
                break
            t = t_new
        return t


#: The lens models every function of this module accepts (besides None, the ideal pinhole).
LENS_TYPES = (BrownConrady, Rational, KannalaBrandt)


def _check_distortion(distortion):
    if distortion is None:
        return None
    if not isinstance(distortion, LENS_TYPES):
        raise TypeError(
            f"distortion must be a BrownConrady, a Rational, a KannalaBrandt or None, got {type(distortion).__name__}")
    return None if distortion.is_identity else distortion


def _fisheye_distort(xy: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    r = np.hypot(xy[:, 0], xy[:, 1])
    theta = np.arctan(r)
    _check_field(theta, d)
    scale = np.where(r > 0, d.theta_d(theta) / np.where(r > 0, r, 1.0), 1.0)
    return xy * scale[:, None]


def _check_field(theta: np.ndarray, d: KannalaBrandt) -> None:
    beyond = theta > d.max_field_rad + 1e-12
    if beyond.any():
        raise ValueError(
            f"{int(beyond.sum())} point(s) lie at {math.degrees(float(theta[beyond].max())):.2f}° from the "
            f"optical axis, beyond the lens's field limit {math.degrees(d.max_field_rad):.2f}°")


def _fisheye_undistort(xy_d: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    """Distorted normalised points → unit rays, shape (N, 3)."""
    rd = np.hypot(xy_d[:, 0], xy_d[:, 1])
    theta = d.theta(rd)
    safe = np.where(rd > 0, rd, 1.0)
    s = np.where(rd > 0, np.sin(theta) / safe, 0.0)
    return np.column_stack((xy_d[:, 0] * s, xy_d[:, 1] * s, np.cos(theta)))


def distort(xy_norm, distortion) -> np.ndarray:
    """Apply a lens model to normalised coordinates.

    Parameters
    ----------
    xy_norm : array_like, shape (N, 2) or (2,)
        Undistorted normalised coordinates (x/z, y/z).
    distortion : BrownConrady, Rational, KannalaBrandt or None
        None (or all zeros) returns the input unchanged. A fisheye accepts normalised points
        in front of the camera only (field angle < 90°); use :func:`project` beyond.

    Returns
    -------
    ndarray, shape (N, 2)
        Distorted normalised coordinates.
    """
    xy = _as_points("xy_norm", xy_norm, 2)
    d = _check_distortion(distortion)
    if d is None:
        return xy.copy()
    if isinstance(d, KannalaBrandt):
        return _fisheye_distort(xy, d)
    return np.column_stack(_brown_conrady(xy[:, 0], xy[:, 1], d))


def _radial(r2, d: BrownConrady | Rational):
    """The radial factor L and its derivative dL/ds at s = r² (arrays), for a pinhole lens."""
    num = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
    dnum = d.k1 + r2 * (2.0 * d.k2 + 3.0 * d.k3 * r2)
    if isinstance(d, BrownConrady):
        return num, dnum
    den = 1.0 + r2 * (d.k4 + r2 * (d.k5 + r2 * d.k6))
    dden = d.k4 + r2 * (2.0 * d.k5 + 3.0 * d.k6 * r2)
    return num / den, (dnum * den - num * dden) / (den * den)


def _brown_conrady(x: np.ndarray, y: np.ndarray, d: BrownConrady | Rational) -> tuple[np.ndarray, np.ndarray]:
    """The map of a pinhole lens (Brown–Conrady or rational, module docstring) on coordinate arrays:
    (x_d, y_d)."""
    r2 = x * x + y * y
    radial = _radial(r2, d)[0]
    xd = x * radial + 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y
    return xd, yd


def _distort_jacobian(x, y, d: BrownConrady | Rational):
    """Partial derivatives of (x_d, y_d) with respect to (x, y), each of shape (N,).

    Returns (∂x_d/∂x, ∂x_d/∂y, ∂y_d/∂x, ∂y_d/∂y); the two mixed ones are equal.
    """
    r2 = x * x + y * y
    radial, dradial = _radial(r2, d)
    two_dradial = 2.0 * dradial
    dxx = radial + x * (x * two_dradial + 6.0 * d.p2) + 2.0 * d.p1 * y
    dyy = radial + y * (y * two_dradial + 6.0 * d.p1) + 2.0 * d.p2 * x
    dxy = x * (y * two_dradial + 2.0 * d.p1) + 2.0 * d.p2 * y
    return dxx, dxy, dxy, dyy


def _radial_map(r, d: BrownConrady | Rational):
    """r·L(r) and its derivative d/dr, for the radial part of ``d`` (arrays of radii)."""
    r2 = r * r
    if isinstance(d, BrownConrady):
        value = r * (1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3)))
        slope = 1.0 + r2 * (3.0 * d.k1 + r2 * (5.0 * d.k2 + r2 * 7.0 * d.k3))
        return value, slope
    radial, dradial = _radial(r2, d)
    return r * radial, radial + 2.0 * r2 * dradial


def _disc_edge(d: BrownConrady | Rational, r_limit: float) -> float:
    """The largest radius ≤ ``r_limit`` (finite) where the radial map evaluates to a finite value > 0.

    At a fold that is ``r_limit`` itself; at a rational lens's pole, where the denominator's
    rounding can make r·L(r) ±inf or negative, it is the first radius below it (stepping down by
    doubling multiples of ε) where the map is still finite and positive.
    """
    r = r_limit
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for k in range(52):  # down to r_limit / 2 at most
            value = float(_radial_map(np.asarray(r), d)[0])
            if math.isfinite(value) and value > 0:
                break
            r = r_limit * (1.0 - 2.0**k * _EPS)
    return r


def _disc_image(d: BrownConrady | Rational) -> float:
    """Distorted radius the monotonic disc reaches: r·L(r) at its edge; ``inf`` when the map rises
    everywhere, or up to a pole."""
    r_limit = d.radial_limit()
    if not math.isfinite(r_limit):
        return math.inf
    if isinstance(d, Rational):
        den = 1.0 + r_limit**2 * (d.k4 + r_limit**2 * (d.k5 + r_limit**2 * d.k6))
        if abs(den) <= 1e-8:  # the edge is a pole: the map rises without bound towards it
            return math.inf
    image = d.radial_image(_disc_edge(d, r_limit))
    return image if math.isfinite(image) else math.inf  # overflowed: beyond every double


def _radial_preimage(rd: np.ndarray, d: BrownConrady | Rational, r_limit: float, max_iter: int = 200) -> np.ndarray:
    """Radius r in [0, r_limit] with r·L(r) = rd for the radial part alone (safeguarded Newton).

    r·L(r) rises on [0, r_limit], so the root is unique there; a radius beyond the image of the
    disc, r_limit·L(r_limit), comes back as r_limit. The iteration keeps a bracket [lo, hi] and
    bisects whenever a Newton step leaves it (or is not finite), so it cannot leave the disc;
    it stops when a step moves r by at most 2 ε r. A rational lens's bracket is found by doubling
    up to the disc's edge (which may be a pole), and a tiny step counts only once
    |r·L(r) − rd| ≤ 1e-6 rd: beside a pole Newton's steps are tiny long before the root.
    """
    rational = isinstance(d, Rational)
    if math.isfinite(r_limit) and not rational:
        hi = np.full_like(rd, r_limit)
    else:  # the map rises without bound (or, rational, towards a pole or past overflow): double until it passes rd
        edge = _disc_edge(d, r_limit) if math.isfinite(r_limit) else math.inf
        hi = np.minimum(np.maximum(rd, 1.0), edge)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for _ in range(2100):
                below = (_radial_map(hi, d)[0] < rd) & (hi < edge)
                if not below.any():
                    break
                hi = np.where(below, np.minimum(2.0 * hi, edge), hi)
    out = np.empty_like(rd)
    active = np.arange(len(rd))
    lo, r, target = np.zeros_like(rd), np.minimum(rd, hi), rd
    for _ in range(max_iter):
        value, slope = _radial_map(r, d)
        f = value - target
        lo = np.where(f <= 0, r, lo)
        hi = np.where(f >= 0, r, hi)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            r_new = r - f / slope
        out_of_bracket = ~np.isfinite(r_new) | (r_new <= lo) | (r_new >= hi)
        r_new = np.where(out_of_bracket, 0.5 * (lo + hi), r_new)
        converged = (np.abs(r_new - r) <= 2.0 * _EPS * r_new) | (f == 0)
        if rational:  # beside a pole a Newton step is tiny though far from the root: trust it once f is small
            converged &= (f == 0) | (np.abs(f) <= 1e-6 * target)
        out[active[converged]] = r_new[converged]
        keep = ~converged
        active, r, lo, hi, target = active[keep], r_new[keep], lo[keep], hi[keep], target[keep]
        if active.size == 0:
            break
    out[active] = r  # not converged within max_iter: the caller's residual test refuses these
    return out


def _residual_floor(x: np.ndarray, y: np.ndarray, d: BrownConrady | Rational) -> np.ndarray:
    """Rounding bound of |distort(x) − x_d| in double precision, per point (N,).

    Horner's rule and the tangential sums take about a dozen roundings, each at most ε times
    the sum of the terms' magnitudes r (1 + |k1| r² + |k2| r⁴ + |k3| r⁶) + 4 (|p1| + |p2|) r²;
    16 ε times that sum bounds the residual's own error, below which no iteration can go. A
    rational lens's quotient N/D carries ε (N̄ + |L| D̄)/|D| (bars: sums of the terms' magnitudes),
    which takes the place of N̄.
    """
    r2 = x * x + y * y
    radial = abs(d.k1) + r2 * (abs(d.k2) + r2 * abs(d.k3))
    magnitude = 1.0 + r2 * radial
    if isinstance(d, Rational):
        den_terms = 1.0 + r2 * (abs(d.k4) + r2 * (abs(d.k5) + r2 * abs(d.k6)))
        den = np.abs(1.0 + r2 * (d.k4 + r2 * (d.k5 + r2 * d.k6)))
        num = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
        magnitude = (magnitude + np.abs(num / den) * den_terms) / den
    return 16.0 * _EPS * (np.sqrt(r2) * magnitude + 4.0 * (abs(d.p1) + abs(d.p2)) * r2)


def _newton_in_disc(x, y, xd, yd, d: BrownConrady | Rational, r_limit: float, tol: float, max_iter: int):
    """Damped Newton iteration for distort(x, y) = (xd, yd) from starts inside the disc |x| < r_limit.

    A step is halved until it stays inside the disc and lowers the residual; a point whose step
    cannot do both (or whose Jacobian is singular) stops there. Works on copies of the coordinate
    arrays; returns (x, y, done) with done where |distort − target| ≤ max(tol, :func:`_residual_floor`).
    """
    x, y = x.copy(), y.copy()
    r2_limit = r_limit * r_limit
    fx, fy = _brown_conrady(x, y, d)
    ex, ey = fx - xd, fy - yd
    err = np.hypot(ex, ey)

    def converged(e, u, v):  # e ≤ max(tol, floor); the floor is evaluated only where e > tol
        ok = e <= tol
        rest = np.flatnonzero(~ok)
        if rest.size:
            ok[rest] = np.isfinite(e[rest]) & (e[rest] <= _residual_floor(u[rest], v[rest], d))
        return ok

    done = converged(err, x, y)
    active = np.flatnonzero(~done)
    for _ in range(max_iter):
        if active.size == 0:
            break
        arrays = (x, y, ex, ey, err, xd, yd)
        xa, ya, exa, eya, erra, xda, yda = arrays if active.size == len(x) else (a[active] for a in arrays)
        dxx, dxy, dyx, dyy = _distort_jacobian(xa, ya, d)
        det = dxx * dyy - dxy * dyx
        regular = np.abs(det) > 1e-300
        det[~regular] = 1.0
        sx, sy = (dyy * exa - dxy * eya) / det, (dxx * eya - dyx * exa) / det
        tx, ty = xa - sx, ya - sy
        fx, fy = _brown_conrady(tx, ty, d)
        etx, ety = fx - xda, fy - yda
        et = np.hypot(etx, ety)
        ok = regular & (tx * tx + ty * ty < r2_limit) & (et < erra)
        retry, alpha = np.flatnonzero(regular & ~ok), 1.0
        for _ in range(60):  # rare: halve the step until it stays inside and lowers the residual
            if retry.size == 0:
                break
            alpha *= 0.5
            hx, hy = xa[retry] - alpha * sx[retry], ya[retry] - alpha * sy[retry]
            fx, fy = _brown_conrady(hx, hy, d)
            hex_, hey = fx - xda[retry], fy - yda[retry]
            he = np.hypot(hex_, hey)
            good = (hx * hx + hy * hy < r2_limit) & (he < erra[retry])
            took = retry[good]
            tx[took], ty[took], etx[took], ety[took], et[took] = hx[good], hy[good], hex_[good], hey[good], he[good]
            ok[took] = True
            retry = retry[~good]
        moved = active[ok]
        x[moved], y[moved], ex[moved], ey[moved], err[moved] = tx[ok], ty[ok], etx[ok], ety[ok], et[ok]
        finished = converged(et[ok], tx[ok], ty[ok])
        done[moved[finished]] = True
        active = moved[~finished]  # points that could not move stop there, not done
    return x, y, done


def undistort(xy_norm, distortion, tol: float = 1e-12, max_iter: int = 50) -> np.ndarray:
    """Invert the lens model on normalised coordinates.

    Parameters
    ----------
    xy_norm : array_like, shape (N, 2) or (2,)
        Distorted normalised coordinates.
    distortion : BrownConrady, Rational, KannalaBrandt or None
        None (or all zeros) returns the input unchanged.
    tol : float
        Brown–Conrady and rational: the iteration stops when |distort(x) − x_d| ≤ max(tol, the residual's
        own rounding bound 16 ε Σ|terms|) (normalised units). An answer is then within about
        that residual times ‖J⁻¹‖ of the exact preimage (J: the model's Jacobian there).
    max_iter : int
        Newton iterations at most (each is damped: its step is halved until it stays inside the
        monotonic disc and lowers the residual).

    Returns
    -------
    ndarray, shape (N, 2)
        Undistorted coordinates x with distort(x) = x_d, inside the model's monotonic disc.

    Raises
    ------
    UndistortionError
        When a point has no preimage inside the monotonic disc |x| < the lens's ``radial_limit()``
        (the model folds over there), or the iteration does not converge. The message counts the
        failing points.

    Notes
    -----
    Brown–Conrady and rational: the radial part alone is inverted first, per point, by a bracketed Newton
    iteration on [0, radial_limit] (the map r ↦ r·L(r) rises there, so the root is unique and
    exists exactly when the distorted radius is below the image of the disc,
    radial_limit·L(radial_limit)). That start lies inside the disc, where the full model
    (with its tangential terms) is then solved by damped Newton steps that never leave it.
    Starting at x_d itself, as OpenCV's fixed-point iteration does, fails for pincushion
    lenses whose distorted radius exceeds the disc.
    """
    xd = _as_points("xy_norm", xy_norm, 2)
    d = _check_distortion(distortion)
    if d is None:
        return xd.copy()
    if not np.all(np.isfinite(xd)):
        raise ValueError("xy_norm must be finite")
    if isinstance(d, KannalaBrandt):
        rays = _fisheye_undistort(xd, d)
        behind = rays[:, 2] <= 1e-12
        if behind.any():
            raise UndistortionError(
                f"{int(behind.sum())} point(s) image rays at 90° or more from the optical axis, which have "
                "no normalised pinhole coordinates; use backproject for unit rays")
        return rays[:, :2] / rays[:, 2:3]
    r_limit = d.radial_limit()
    rd = np.hypot(xd[:, 0], xd[:, 1])
    r0 = _radial_preimage(rd, d, r_limit)
    scale = np.where(rd > 0, r0 / np.where(rd > 0, rd, 1.0), 0.0)
    x, y, done = _newton_in_disc(xd[:, 0] * scale, xd[:, 1] * scale, xd[:, 0], xd[:, 1], d, r_limit, tol, max_iter)
    dxx, dxy, dyx, dyy = _distort_jacobian(x, y, d)
    bad = ~(done & (x * x + y * y < r_limit * r_limit) & (dxx * dyy - dxy * dyx > 0))
    if bad.any():
        worst = float(rd[bad].max())
        image = d.disc_image()
        raise UndistortionError(
            f"{int(bad.sum())} of {len(xd)} points have no preimage in the distortion model's "
            f"monotonic disc (undistorted radius < {r_limit:.6g}, whose radial image reaches distorted "
            f"radius {image:.6g}); largest distorted radius among them {worst:.6g} (normalised). "
            "The model folds over there."
        )
    return np.column_stack((x, y))


def project(points_cam, intrinsics: Intrinsics, distortion=None) -> np.ndarray:
    """Project 3-D points in the camera optical frame to pixels.

    Parameters
    ----------
    points_cam : array_like, shape (N, 3) or (3,)
        Points in the OpenCV camera frame (x right, y down, z forward), metres.
    intrinsics : Intrinsics
    distortion : BrownConrady, Rational or KannalaBrandt, optional

    Returns
    -------
    ndarray, shape (N, 2)
        Pixel coordinates (u, v); rows for points with z ≤ 0 (behind the camera) are NaN, except
        for a fisheye lens, which images every direction up to its field limit (beyond it: a
        ValueError naming the limit).

    Notes
    -----
    Paper §3.2: u = f_u x/z + u0, v = f_v y/z + v0, with Brown–Conrady distortion applied to
    (x/z, y/z) first when given. Agrees with ``cv2.projectPoints`` (tested).
    """
    pts = _as_points("points_cam", points_cam, 3)
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError("intrinsics must be an Intrinsics")
    d = _check_distortion(distortion)
    if isinstance(d, KannalaBrandt):
        rho = np.hypot(pts[:, 0], pts[:, 1])
        theta = np.arctan2(rho, pts[:, 2])
        _check_field(theta, d)
        safe = np.where(rho > 0, rho, 1.0)
        scale = np.where(rho > 0, d.theta_d(theta) / safe, 0.0)
        return intrinsics.to_pixels(pts[:, :2] * scale[:, None])
    z = pts[:, 2]
    front = z > 0
    xy = np.full((len(pts), 2), np.nan)
    xy[front] = pts[front, :2] / z[front, None]
    out = np.full((len(pts), 2), np.nan)
    if front.any():
        out[front] = intrinsics.to_pixels(distort(xy[front], distortion))
    return out


def backproject(uv_px, intrinsics: Intrinsics, distortion=None) -> np.ndarray:
    """Rays through pixels, as (û, v̂, 1): K⁻¹(u, v, 1)ᵀ after undistortion when a model is given.

    Parameters
    ----------
    uv_px : array_like, shape (N, 2) or (2,)
        Pixel coordinates.
    intrinsics : Intrinsics
    distortion : BrownConrady, Rational or KannalaBrandt, optional

    Returns
    -------
    ndarray, shape (N, 3)
        Rays in the camera frame with z = 1 (the paper's normalised image coordinates, §3.2.1);
        for a fisheye lens, unit rays (a wide lens sees directions with z ≤ 0).
    """
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError("intrinsics must be an Intrinsics")
    d = _check_distortion(distortion)
    if isinstance(d, KannalaBrandt):
        return _fisheye_undistort(intrinsics.to_normalised(uv_px), d)
    xy = undistort(intrinsics.to_normalised(uv_px), d)
    return np.column_stack((xy, np.ones(len(xy))))


def undistort_pixels(uv_px, intrinsics: Intrinsics, distortion) -> np.ndarray:
    """Pixels of the distorted camera → pixels of the ideal pinhole camera with the same K.

    Returns an array of shape (N, 2).
    """
    return intrinsics.to_pixels(undistort(intrinsics.to_normalised(uv_px), distortion))


def distort_pixels(uv_px, intrinsics: Intrinsics, distortion) -> np.ndarray:
    """Pixels of the ideal pinhole camera → pixels of the distorted camera with the same K.

    Returns an array of shape (N, 2).
    """
    return intrinsics.to_pixels(distort(intrinsics.to_normalised(uv_px), distortion))
