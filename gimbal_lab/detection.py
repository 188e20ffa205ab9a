"""Target detection and 3-D localisation: the HSV sphere detector and ArUco marker pose.

Images are RGB ``uint8`` arrays of shape (H, W, 3) throughout, as the scene renderer produces
them; OpenCV receives the colour order it needs inside each function.

Sphere (paper §3.2.1, Figs. 2–4)
    RGB → HSV → threshold (one or more ranges; red wraps around hue 0/180) → optional light
    morphology → ``cv2.findContours`` (Suzuki–Abe) → largest contour → ``cv2.minEnclosingCircle``
    (Welzl). Two localisations from one detection:

    * :func:`locate_sphere_circle`, the paper's estimate, exactly as published:
      d = r·f/R and x₀ = d·(û, v̂, 1)ᵀ with (û, v̂, 1)ᵀ = K⁻¹(u, v, 1)ᵀ.
    * :func:`locate_sphere_ellipse`, the exact cone method the paper names but does not use:
      fit a conic to the contour and decompose the cone it spans with the centre of projection.
    * :func:`locate_sphere_streak`, the lab's blur-aware addition: range from the solid angle of
      the pixels' coverage (:func:`sphere_coverage`), which a streak does not change, and the
      centre at mid-exposure; the cone fit on a sharp frame.

    An occluder or the image border that cuts the silhouette makes the detection
    :attr:`~SphereDetection.partial`; the cone method then fits the visible arc only
    (:func:`arc_points`), while the enclosing circle stays the disc's own.

Marker (paper §3.2.2)
    ``cv2.aruco.ArucoDetector`` then ``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)``
    (:class:`ArucoTracker`).

Lenses
    Every function and class that takes ``distortion`` accepts a
    :class:`~gimbal_lab.camera.BrownConrady` lens, a :class:`~gimbal_lab.camera.KannalaBrandt`
    fisheye or None (pinhole). The lens sweep compares three ways of handling a lens:

    * ignore it (``distortion=None`` on the raw frame, the paper's setting);
    * detect on the raw frame and undistort the detected points (``distortion=lens``;
      :func:`locate_sphere_circle_undistorted` for the paper's circle method);
    * rectify first with a :class:`Rectifier` (``cv2.remap`` to an ideal pinhole image: the same
      K for a Brown–Conrady lens, a 90° pinhole of the same size for a fisheye) and detect with
      the pinhole model of ``rectifier.out_intrinsics``.

A frame without a target yields ``None`` (sphere) or an empty dict (markers), never an exception.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import (
    LENS_TYPES,
    BrownConrady,
    Intrinsics,
    KannalaBrandt,
    UndistortionError,
    backproject,
    project,
    undistort,
    undistort_pixels,
)

__all__ = [
    "SphereDetection",
    "SpherePipelineSteps",
    "SphereDetector",
    "locate_sphere_circle",
    "locate_sphere_ellipse",
    "locate_sphere_streak",
    "sphere_coverage",
    "SphereCoverage",
    "STREAK_MIN_PX",
    "SMOOTH_BACKGROUND",
    "locate_sphere_circle_undistorted",
    "circle_method_estimate",
    "sphere_silhouette_px",
    "fit_conic",
    "conic_to_ellipse",
    "Rectifier",
    "FISHEYE_RECTIFIED_HFOV_RAD",
    "MarkerPose",
    "ArucoTracker",
    "REFINEMENT_MODES",
    "CONTOUR_EDGE_INSET_PX",
    "ARC_TOLERANCE_PX",
    "ARC_CONIC_TOLERANCE_PX",
    "PARTIAL_ARC_FRACTION",
    "arc_points",
    "refine_edge_points",
    "EDGE_MIXING",
]

#: Mean distance (px) by which the centres of a binary blob's boundary pixels lie inside the
#: blob's true (sub-pixel) edge, for a chain of 8-connected boundary pixels as
#: ``cv2.findContours`` returns it. An edge with unit normal n keeps as boundary pixels those
#: whose centre lies less than m = max(|n_x|, |n_y|) inside it (a 4-neighbour is outside), so
#: their mean depth is m/2; the chain holds m pixels per unit of edge length. Averaged over edge
#: directions with that weight: ∫cos²φ dφ / (2∫cos φ dφ) over [0, π/4] = (π/8 + 1/4)/√2 ≈ 0.4545.
CONTOUR_EDGE_INSET_PX = (math.pi / 8 + 0.25) / math.sqrt(2)

#: How far (px) inside the minimum enclosing circle an outline point may lie and still count as
#: on it. A boundary pixel's centre lies up to m = max(|n_x|, |n_y|) ≤ 1 px inside the true
#: edge (see :data:`CONTOUR_EDGE_INSET_PX`) and the circle rests on the outermost ones (depth
#: ≈ 0), so an uncut disc's outline stays within 1 px of its circle (measured: at most 1.02 px
#: over radii 3–80 px with sensor noise of std 2 grey levels); the other 0.5 px is margin for
#: noise and for the colour threshold's position on the rim. A straight occluder edge is seen
#: once the depth of the cut (its sagitta) exceeds this.
ARC_TOLERANCE_PX = 1.5

#: How far (px) from the conic fitted to the arc an outline point may lie and join it. Around a
#: curve through their mean depth (≈ 0.45 px), boundary-pixel centres scatter by ±0.55 px at
#: most; 0.8 px leaves margin for noise but stays well inside :data:`ARC_TOLERANCE_PX`, so the
#: points of a cut, already more than 1.5 px inside the circle, do not come back.
ARC_CONIC_TOLERANCE_PX = 0.8

#: A detection whose :attr:`SphereDetection.arc_fraction` is below this is
#: :attr:`~SphereDetection.partial`. Measured with :class:`SphereDetector` on anti-aliased red
#: discs and spheres with sensor noise of std 2 grey levels: an uncut outline gives exactly 1
#: (tested: discs of radius 3–80 px at any sub-pixel centre on four backgrounds, spheres
#: anywhere in 60° and 90° pinhole views; also measured on raw frames through a Brown–Conrady
#: lens and 120° and 185° fisheyes), so one stray point in 33 is tolerated. A straight cut
#: 2.5 px deep or deeper gives at most 0.945 (radius 5–80 px), i.e. every cut hiding ≥ 10 % of
#: the disc's area from a radius of 8 px, and every cut hiding ≥ 10 % of its rim from 40 px
#: (≤ 0.951 there). A cut shallower than :data:`ARC_TOLERANCE_PX` cannot be told from the
#: staircase of the pixel outline.
PARTIAL_ARC_FRACTION = 0.97

# Saturated red, two hue ranges because red wraps around 0/180. The bounds put the blob's edge
# near half coverage of the anti-aliased rim on the study's backgrounds: a rim pixel half red,
# half sky has hue ≈ 168–170 and saturation ≈ 100; half red, half grass has hue ≈ 10.
_RED_LOWER = ((0, 100, 50), (169, 100, 50))
_RED_UPPER = ((9, 255, 255), (180, 255, 255))


def _check_rgb(rgb) -> np.ndarray:
    if not isinstance(rgb, np.ndarray):
        raise TypeError(f"rgb must be a numpy array, got {type(rgb).__name__}")
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be a uint8 array of shape (H, W, 3), got {rgb.dtype} {rgb.shape}")
    if rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"rgb must hold at least one pixel, got shape {rgb.shape}")
    return rgb


def _check_intrinsics(intrinsics, name: str = "intrinsics") -> Intrinsics:
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError(f"{name} must be an Intrinsics, got {type(intrinsics).__name__}")
    return intrinsics


def _check_distortion(distortion) -> BrownConrady | KannalaBrandt | None:
    if distortion is not None and not isinstance(distortion, LENS_TYPES):
        raise TypeError(
            f"distortion must be a BrownConrady, a KannalaBrandt or None, got {type(distortion).__name__}"
        )
    return distortion


def _check_radius(radius_m) -> float:
    value = float(radius_m)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"radius_m must be a finite length > 0 m, got {radius_m!r}")
    return value


# --------------------------------------------------------------------------------------------
# Rectification
# --------------------------------------------------------------------------------------------


#: Horizontal field of view of the pinhole image a fisheye is rectified to by default, rad (90°).
#: A pinhole cannot show 180°, and its image stretches radially like 1/cos²θ; at 90° the
#: rectified image keeps the central part of a fisheye frame: 45° either side across, about 51°
#: in the corners of a 4:3 frame.
FISHEYE_RECTIFIED_HFOV_RAD = math.radians(90.0)


class Rectifier:
    """Resample a distorted image into an ideal pinhole image.

    The maps are computed once, fixed point (``CV_16SC2``, 1/32 px): for a Brown–Conrady lens
    ``cv2.initUndistortRectifyMap``, for a fisheye ``cv2.fisheye.initUndistortRectifyMap``, each
    with the new camera matrix of ``out_intrinsics`` and no rotation. :meth:`rectify` is one
    ``cv2.remap`` with bilinear interpolation. After rectification a detector's pixel coordinates
    obey the pinhole model of :attr:`out_intrinsics`: localise and estimate poses with those
    intrinsics, not the source camera's.

    Parameters
    ----------
    intrinsics : Intrinsics
        The source camera (the size of the images :meth:`rectify` accepts).
    distortion : BrownConrady or KannalaBrandt
        The lens model to remove.
    out_intrinsics : Intrinsics, optional
        The pinhole camera of the rectified image (its K and size). Default: ``intrinsics``
        itself for a Brown–Conrady lens (the same K and size); for a fisheye,
        ``Intrinsics.from_fov(width, height, FISHEYE_RECTIFIED_HFOV_RAD)``, a 90° pinhole of the
        source size (with the fisheye's own, shorter focal length the pinhole image would
        stretch its edges several times over: 3.6× radially at the 185° lens's frame edge).

    Attributes
    ----------
    out_intrinsics : Intrinsics
        The rectified image's pinhole camera.

    Notes
    -----
    Paper §4.1.2 (end) and §5: rectifying fisheye images is the third strategy of the lens sweep.

    Examples
    --------
    >>> lens, f = KannalaBrandt.equidistant_for_fov(640, math.radians(185.0))
    >>> rectifier = Rectifier(Intrinsics(f, f, 319.5, 239.5, 640, 480), lens)
    >>> round(rectifier.out_intrinsics.fx, 2), rectifier.out_intrinsics.size
    (320.0, (640, 480))
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        distortion: BrownConrady | KannalaBrandt,
        out_intrinsics: Intrinsics | None = None,
    ):
        self.intrinsics = _check_intrinsics(intrinsics)
        if not isinstance(distortion, LENS_TYPES):
            raise TypeError(
                f"distortion must be a BrownConrady or a KannalaBrandt (None: nothing to rectify), "
                f"got {type(distortion).__name__}"
            )
        self.distortion = distortion
        fisheye = isinstance(distortion, KannalaBrandt)
        if out_intrinsics is None:
            out_intrinsics = (
                Intrinsics.from_fov(intrinsics.width, intrinsics.height, FISHEYE_RECTIFIED_HFOV_RAD)
                if fisheye
                else intrinsics
            )
        self.out_intrinsics = _check_intrinsics(out_intrinsics, "out_intrinsics")
        out = self.out_intrinsics
        if fisheye:
            self._map1, self._map2 = cv2.fisheye.initUndistortRectifyMap(
                intrinsics.K, distortion.coefficients, np.eye(3), out.K, out.size, cv2.CV_16SC2
            )
        else:
            self._map1, self._map2 = cv2.initUndistortRectifyMap(
                intrinsics.K, distortion.coefficients, None, out.K, out.size, cv2.CV_16SC2
            )

    def rectify(self, rgb: np.ndarray) -> np.ndarray:
        """Return the rectified image of ``rgb``.

        Parameters
        ----------
        rgb : ndarray, shape (H, W, 3), uint8
            A frame of the source camera (its size).

        Returns
        -------
        ndarray, shape (H_out, W_out, 3), uint8
            The image of :attr:`out_intrinsics`; pixels whose ray falls outside the source frame
            are black.
        """
        rgb = _check_rgb(rgb)
        if rgb.shape[:2] != (self.intrinsics.height, self.intrinsics.width):
            raise ValueError(
                f"rgb must be {self.intrinsics.height}×{self.intrinsics.width} like the rectifier's camera, "
                f"got {rgb.shape[0]}×{rgb.shape[1]}"
            )
        return cv2.remap(rgb, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def to_source_px(self, uv_rect) -> np.ndarray:
        """Source (distorted) image pixels at which rectified pixels' rays land.

        The rectified pixel is back-projected through :attr:`out_intrinsics` (a pinhole) and the
        ray projected through ``intrinsics`` and the lens with :func:`gimbal_lab.camera.project`:
        the position that :meth:`rectify` samples (its fixed-point maps round it to 1/32 px).

        Parameters
        ----------
        uv_rect : array_like, shape (N, 2) or (2,)
            Pixels of the rectified image.

        Returns
        -------
        ndarray, shape (N, 2)
            Pixels of the source image.

        Raises
        ------
        ValueError
            When ``uv_rect`` has another shape, or a ray lies beyond a fisheye's field limit.
        """
        rays = backproject(uv_rect, self.out_intrinsics, None)
        return project(rays, self.intrinsics, self.distortion)

    def __repr__(self) -> str:
        return f"Rectifier({self.intrinsics!r}, {self.distortion!r}, out_intrinsics={self.out_intrinsics!r})"


def _check_rectifier(rectifier) -> Rectifier | None:
    if rectifier is not None and not isinstance(rectifier, Rectifier):
        raise TypeError(f"rectifier must be a Rectifier or None, got {type(rectifier).__name__}")
    return rectifier


# --------------------------------------------------------------------------------------------
# Sphere detection
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SphereDetection:
    """One detected blob.

    Attributes
    ----------
    center_px : ndarray, shape (2,)
        Centre (u, v) of the minimum enclosing circle, pixels.
    radius_px : float
        Radius R of the minimum enclosing circle, pixels (> 0).
    contour_px : ndarray, shape (N, 2)
        The blob's outer contour, pixels. From :class:`SphereDetector` these are the centres of
        the boundary pixels, which lie ``edge_inset_px`` inside the true edge on average.
    area_px : float
        Area enclosed by the contour polygon (``cv2.contourArea``), px².
    edge_inset_px : float
        Mean distance by which ``contour_px`` lies inside the silhouette's true edge (px, ≥ 0);
        :func:`locate_sphere_ellipse` pushes the contour outward by this much before the fit.
        0 for a contour sampled on the edge itself (an analytic silhouette).
    touches_border : bool
        Whether the contour touches the image border (the target may be cut off).
    outline_px : ndarray, shape (M, 2), optional
        The outline ``center_px`` and ``radius_px`` were taken from (from :class:`SphereDetector`:
        the boundary pixels' centres, before any edge refinement replaced ``contour_px``). None:
        ``contour_px``. :func:`locate_sphere_circle_undistorted` undistorts it, so that it fits the
        same outline as the paper's circle.
    arc_fraction : float
        Fraction (0–1) of ``outline_px`` on the visible arc of the sphere's own outline (see
        :func:`arc_points`); the rest lies along an occluder's edge or the image border.
        :class:`SphereDetector` measures it; a detection built by hand is taken as uncut (1).

    Notes
    -----
    An occluder that hides less than half of the disc leaves a blob that still holds a diameter
    of it, so its enclosing circle is the disc's own (``center_px`` and ``radius_px`` are not
    biased; off axis see :func:`locate_sphere_circle`), but its contour runs along the
    occluder's edge as well as along the arc.
    """

    center_px: np.ndarray
    radius_px: float
    contour_px: np.ndarray
    area_px: float
    edge_inset_px: float = 0.0
    touches_border: bool = False
    outline_px: np.ndarray | None = None
    arc_fraction: float = 1.0

    def __post_init__(self):
        center = np.array(self.center_px, dtype=float).reshape(-1)
        if center.shape != (2,) or not np.all(np.isfinite(center)):
            raise ValueError(f"center_px must be 2 finite numbers, got {self.center_px!r}")
        contour = np.array(self.contour_px, dtype=float)
        if contour.ndim != 2 or contour.shape[1] != 2 or not np.all(np.isfinite(contour)):
            raise ValueError(f"contour_px must be a finite (N, 2) array, got shape {np.shape(self.contour_px)}")
        radius = float(self.radius_px)
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"radius_px must be finite and > 0 px, got {self.radius_px!r}")
        inset = float(self.edge_inset_px)
        if not (math.isfinite(inset) and inset >= 0):
            raise ValueError(f"edge_inset_px must be finite and >= 0 px, got {self.edge_inset_px!r}")
        outline = contour if self.outline_px is None else np.array(self.outline_px, dtype=float)
        if outline.ndim != 2 or outline.shape[1] != 2 or not np.all(np.isfinite(outline)):
            raise ValueError(f"outline_px must be a finite (M, 2) array, got shape {np.shape(self.outline_px)}")
        arc_fraction = float(self.arc_fraction)
        if not (math.isfinite(arc_fraction) and 0.0 <= arc_fraction <= 1.0):
            raise ValueError(f"arc_fraction must be a fraction in [0, 1], got {self.arc_fraction!r}")
        center.setflags(write=False)
        contour.setflags(write=False)
        outline.setflags(write=False)
        object.__setattr__(self, "outline_px", outline)
        object.__setattr__(self, "center_px", center)
        object.__setattr__(self, "contour_px", contour)
        object.__setattr__(self, "radius_px", radius)
        object.__setattr__(self, "area_px", float(self.area_px))
        object.__setattr__(self, "edge_inset_px", inset)
        object.__setattr__(self, "touches_border", bool(self.touches_border))
        object.__setattr__(self, "arc_fraction", arc_fraction)

    @property
    def partial(self) -> bool:
        """Whether the silhouette is cut: ``arc_fraction`` < :data:`PARTIAL_ARC_FRACTION`.

        :func:`locate_sphere_ellipse` then fits the visible arc only (:func:`arc_points`).
        """
        return self.arc_fraction < PARTIAL_ARC_FRACTION


@dataclass(frozen=True, eq=False)
class SpherePipelineSteps:
    """Every intermediate of :meth:`SphereDetector.pipeline`, for figures and teaching.

    Attributes
    ----------
    rgb : ndarray, shape (H, W, 3)
        The (rectified, if configured) input image.
    hsv : ndarray, shape (H, W, 3)
        OpenCV 8-bit HSV (H in 0–179, S and V in 0–255).
    mask : ndarray, shape (H, W)
        Binary mask (0 or 255) after thresholding and morphology.
    contours : list of ndarray, each shape (N_i, 2)
        Every outer contour found, pixels.
    chosen : int or None
        Index into ``contours`` of the blob that was kept, or None.
    detection : SphereDetection or None
    """

    rgb: np.ndarray
    hsv: np.ndarray
    mask: np.ndarray
    contours: list
    chosen: int | None
    detection: SphereDetection | None


def _hsv_ranges(name: str, value) -> tuple[tuple[int, int, int], ...]:
    arr = np.asarray(value)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1:
        raise ValueError(f"{name} must be an (H, S, V) triple or a sequence of triples, got {value!r}")
    if not np.all(np.isfinite(arr.astype(float))) or arr.min() < 0 or arr.max() > 255:
        raise ValueError(f"{name} entries must lie in 0–255 (hue in OpenCV's 0–180), got {value!r}")
    return tuple(tuple(int(x) for x in row) for row in arr)


@dataclass(frozen=True)
class SphereDetector:
    """Colour-blob sphere detector, the pipeline of paper §3.2.1 (Fig. 4).

    Parameters
    ----------
    hsv_lower, hsv_upper : (H, S, V) triple or sequence of triples
        Inclusive threshold ranges in OpenCV's 8-bit HSV (H 0–180, S and V 0–255); a pixel is
        foreground when it lies in any of the ranges. The default selects a saturated red with
        two ranges, H ∈ [0, 9] ∪ [169, 180] (S ≥ 100, V ≥ 50), because red wraps around hue 0.
        The bounds also decide where the blob's edge falls on the anti-aliased rim (a rim pixel
        half red, half sky has H ≈ 168–170, S ≈ 100): they are set near half coverage on the
        study's sky and ground. The enclosing circle's radius rests on two or three extreme
        pixels, so the circle method is sensitive to them (a few tenths of a pixel).
    min_area_px : float
        Smallest contour area (px², > 0) accepted as a target; smaller blobs mean "no target".
    reject_border : bool
        If True, blobs whose contour touches the image border are not candidates (a cut-off
        sphere biases both localisations).
    morphology_px : int
        Side of the elliptical kernel of a morphological opening applied to the mask (removes
        speckle); 0 or 1 disables it (the default: rendered images need none).
    rectifier : Rectifier, optional
        Rectify each frame first; the detection is then in the ideal pinhole pixels of
        ``rectifier.out_intrinsics``, the intrinsics to localise it with.
    min_fill : float
        Smallest fill of the enclosing circle, area/(πR²), for a blob not touching the border
        (0–1). A sphere seen anywhere in a 60° view fills ≥ 0.8; two touching equal balls fill
        0.5, a square poster 0.64, a ball that leaked into a red-brown desk much less.
    min_convexity : float
        Smallest area / convex-hull area (0–1); any blob a sphere makes is convex (≈ 1), a ball
        with a leak or a dent where a shadow or a hand cuts it is not. Applies to border blobs too.
    refine_edges : bool
        Move the contour onto the half-coverage edge with :func:`refine_edge_points` (used by
        :func:`locate_sphere_ellipse`; ``edge_inset_px`` is then 0). The circle's centre and
        radius stay those of the pixel contour, the paper's method as published.
    edge_mixing : {"srgb", "linear"}
        How a rim pixel mixes ball and background (see :func:`refine_edge_points`): "srgb" for
        the lab's rendered frames (the default; the study renders), "linear" for real cameras
        (``gimbal-lab track`` uses it).

    Notes
    -----
    Blobs are tried from the largest down; the first that passes the shape checks is the
    detection, and when none passes the answer is None: a red poster, two touching balls or a
    ball merged with a brown desk is "no sphere", never a wrong one. Two separate balls: the
    larger wins. A ball partly hidden by an occluder passes while its fill and convexity do
    (a straight cut hiding up to about 15 % of it) and comes out
    :attr:`~SphereDetection.partial`.

    Examples
    --------
    >>> img = np.zeros((120, 160, 3), np.uint8)
    >>> _ = cv2.circle(img, (80, 60), 20, (230, 20, 20), -1)   # red in RGB order
    >>> det = SphereDetector().detect(img)
    >>> [round(float(x)) for x in det.center_px], round(det.radius_px)
    ([80, 60], 20)
    """

    hsv_lower: tuple = _RED_LOWER
    hsv_upper: tuple = _RED_UPPER
    min_area_px: float = 20.0
    reject_border: bool = False
    morphology_px: int = 0
    rectifier: Rectifier | None = None
    min_fill: float = 0.75
    min_convexity: float = 0.92
    refine_edges: bool = True
    edge_mixing: str = "srgb"
    _bounds: tuple = field(init=False, repr=False, compare=False)
    _kernel: object = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        lower = _hsv_ranges("hsv_lower", self.hsv_lower)
        upper = _hsv_ranges("hsv_upper", self.hsv_upper)
        if len(lower) != len(upper):
            raise ValueError(f"hsv_lower and hsv_upper must hold as many ranges, got {len(lower)} and {len(upper)}")
        for lo, hi in zip(lower, upper):
            if any(a > b for a, b in zip(lo, hi)):
                raise ValueError(f"each hsv_lower must be <= its hsv_upper, got {lo} > {hi}")
        area = float(self.min_area_px)
        if not (math.isfinite(area) and area > 0):
            raise ValueError(f"min_area_px must be finite and > 0 px², got {self.min_area_px!r}")
        if isinstance(self.morphology_px, bool) or int(self.morphology_px) != self.morphology_px or self.morphology_px < 0:
            raise ValueError(f"morphology_px must be an integer >= 0, got {self.morphology_px!r}")
        _check_rectifier(self.rectifier)
        for name in ("min_fill", "min_convexity"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (math.isfinite(float(value)) and 0.0 <= float(value) <= 1.0):
                raise ValueError(f"{name} must be a fraction in [0, 1], got {value!r}")
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "refine_edges", bool(self.refine_edges))
        if self.edge_mixing not in EDGE_MIXING:
            raise ValueError(f"edge_mixing must be one of {sorted(EDGE_MIXING)}, got {self.edge_mixing!r}")
        object.__setattr__(self, "hsv_lower", lower)
        object.__setattr__(self, "hsv_upper", upper)
        object.__setattr__(self, "min_area_px", area)
        object.__setattr__(self, "reject_border", bool(self.reject_border))
        object.__setattr__(self, "morphology_px", int(self.morphology_px))
        bounds = tuple((np.array(lo, np.uint8), np.array(hi, np.uint8)) for lo, hi in zip(lower, upper))
        object.__setattr__(self, "_bounds", bounds)
        kernel = (
            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (self.morphology_px, self.morphology_px))
            if self.morphology_px > 1
            else None
        )
        object.__setattr__(self, "_kernel", kernel)

    def _mask(self, hsv: np.ndarray) -> np.ndarray:
        (lo, hi), *rest = self._bounds
        mask = cv2.inRange(hsv, lo, hi)
        for lo, hi in rest:
            cv2.bitwise_or(mask, cv2.inRange(hsv, lo, hi), dst=mask)
        if self._kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
        return mask

    def shape_measures(self, contour) -> tuple[float, float]:
        """Fill of the enclosing circle and convexity of one contour (both in [0, 1]).

        fill = area / (π R²) with R the minimum enclosing circle's radius (1 for a disc, 1/2 for
        two touching equal discs, 2/π ≈ 0.64 for a square); convexity = area / area of the convex
        hull (1 for any convex blob). Areas are of the polygon through the boundary-pixel
        centres, which is what ``cv2.findContours`` returns; the staircase costs small discs
        some fill: 0.77 at a radius of 3 px, 0.86–0.92 at 4–10 px, 0.97 at 30 px (tested
        against the default ``min_fill``).
        """
        contour = np.asarray(contour, np.float32).reshape(-1, 1, 2)
        area = cv2.contourArea(contour)
        _, radius = cv2.minEnclosingCircle(contour)
        hull = cv2.contourArea(cv2.convexHull(contour))
        fill = area / (math.pi * radius**2) if radius > 0 else 0.0
        convexity = area / hull if hull > 0 else 0.0
        return float(fill), float(convexity)

    def _choose(self, contours, shape, rgb=None) -> tuple[int | None, SphereDetection | None]:
        height, width = shape
        order = sorted(range(len(contours)), key=lambda i: -cv2.contourArea(contours[i]))
        for i in order:
            contour = contours[i]
            area = cv2.contourArea(contour)
            if area < self.min_area_px:
                break
            x, y, w, h = cv2.boundingRect(contour)
            border = x == 0 or y == 0 or x + w == width or y + h == height
            if border and self.reject_border:
                continue
            fill, convexity = self.shape_measures(contour)
            # a blob cut by the border has an unknown outline beyond it: only convexity applies
            if convexity < self.min_convexity or (not border and fill < self.min_fill):
                continue
            (u, v), radius = cv2.minEnclosingCircle(contour)
            points = contour.reshape(-1, 2)
            inset = CONTOUR_EDGE_INSET_PX
            if self.refine_edges and rgb is not None and len(points) >= 8:
                refined = refine_edge_points(rgb, points, self.edge_mixing)
                if refined is not None:
                    points, inset = refined, 0.0
            outline = contour.reshape(-1, 2)
            detection = SphereDetection(
                center_px=(u, v),
                radius_px=radius,
                contour_px=points,
                area_px=area,
                edge_inset_px=inset,
                touches_border=border,
                outline_px=outline,
                arc_fraction=float(np.mean(_arc_mask(outline, (u, v), radius))),
            )
            return i, detection
        return None, None

    def detect(self, rgb: np.ndarray) -> SphereDetection | None:
        """Detect the sphere in one RGB frame.

        Parameters
        ----------
        rgb : ndarray, shape (H, W, 3), uint8
            The frame, RGB channel order.

        Returns
        -------
        SphereDetection or None
            None when no blob of the target colour with area ≥ ``min_area_px`` is seen (or only
            border-touching ones while ``reject_border``).
        """
        rgb = _check_rgb(rgb)
        if self.rectifier is not None:
            rgb = self.rectifier.rectify(rgb)
        mask = self._mask(cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV))
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        return self._choose(contours, mask.shape, rgb)[1]

    def pipeline(self, rgb: np.ndarray) -> SpherePipelineSteps:
        """Run :meth:`detect` and keep every intermediate (HSV, mask, contours) for figures."""
        rgb = _check_rgb(rgb)
        if self.rectifier is not None:
            rgb = self.rectifier.rectify(rgb)
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        mask = self._mask(hsv)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        chosen, detection = self._choose(contours, mask.shape, rgb)
        return SpherePipelineSteps(
            rgb=rgb,
            hsv=hsv,
            mask=mask,
            contours=[c.reshape(-1, 2) for c in contours],
            chosen=chosen,
            detection=detection,
        )


def _srgb_decode_table() -> np.ndarray:
    c = np.arange(256) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


#: uint8 → the space in which an edge pixel is the coverage-weighted mean of its two colours
EDGE_MIXING = {
    "linear": _srgb_decode_table(),  # light: camera sensors, optical blur
    "srgb": (np.arange(256) / 255.0).astype(np.float32),  # encoded values: the lab's renderer
}


def refine_edge_points(
    rgb: np.ndarray, contour_px, mixing: str = "linear", reach_px: float = 3.0, min_contrast: float = 0.02
) -> np.ndarray | None:
    """Move a blob's boundary pixels onto the half-coverage edge, whatever the background colour.

    For each point, the colour is sampled (bilinear, in linear light) along the contour's local
    normal at offsets −reach … +reach px. With c_in and c_out the mean colours of the inner and
    outer ends of that profile, each sample's coverage is its projection
    α = (c − c_out)·(c_in − c_out)/|c_in − c_out|², and the edge is where α crosses 1/2. A pixel
    that is part target, part background is the coverage-weighted mean of the two colours in
    linear light (an anti-aliased render, a defocused edge or a sensor pixel), so the crossing
    is the edge's position for any pair of colours, not only the study's sky and grass. Points
    whose profile has no contrast (|c_in − c_out| < ``min_contrast``) or no crossing are moved
    by :data:`CONTOUR_EDGE_INSET_PX` along the normal instead.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        The image (sRGB-encoded).
    contour_px : array_like, shape (N, 2)
        Ordered boundary-pixel centres of the blob (``cv2.findContours``), N ≥ 8.
    mixing : {"linear", "srgb"}
        Where an edge pixel mixes its two colours: "linear" light (a camera: sensor pixels and
        optical blur integrate light), or the "srgb"-encoded values (the lab's renderer resolves
        its multisampling on encoded values). Measured on shaded synthetic balls the wrong
        choice costs about 1–2 % of range with the exact method.
    reach_px : float
        Half-length of each normal profile, pixels; shortened to 0.4 × the blob's radius for
        small blobs so that the inner end stays inside.
    min_contrast : float
        Smallest colour difference (linear RGB, 0–1 per channel) that places an edge.

    Returns
    -------
    ndarray, shape (N, 2) or None
        Edge points, pixels; None for fewer than 8 points.
    """
    points = np.asarray(contour_px, dtype=float).reshape(-1, 2)
    if len(points) < 8:
        return None
    # local tangent from neighbours two steps away on the closed contour; outward normal from
    # the contour's orientation (signed area)
    tangent = np.roll(points, -2, axis=0) - np.roll(points, 2, axis=0)
    length = np.linalg.norm(tangent, axis=1)
    length[length == 0] = 1.0
    tangent /= length[:, None]
    x, y = points.T
    signed_area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    normal = np.column_stack((tangent[:, 1], -tangent[:, 0])) * (1.0 if signed_area > 0 else -1.0)
    radius = 0.5 * max(np.ptp(x), np.ptp(y))
    reach = float(min(reach_px, max(1.0, 0.4 * radius)))
    offsets = np.linspace(-reach, reach, 2 * int(math.ceil(reach / 0.5)) + 1)
    samples_xy = points[:, None, :] + offsets[None, :, None] * normal[:, None, :]
    height, width = rgb.shape[:2]
    x0 = int(max(0, math.floor(samples_xy[..., 0].min()) - 1))
    y0 = int(max(0, math.floor(samples_xy[..., 1].min()) - 1))
    x1 = int(min(width, math.ceil(samples_xy[..., 0].max()) + 2))
    y1 = int(min(height, math.ceil(samples_xy[..., 1].max()) + 2))
    if mixing not in EDGE_MIXING:
        raise ValueError(f"mixing must be one of {sorted(EDGE_MIXING)}, got {mixing!r}")
    roi = EDGE_MIXING[mixing][rgb[y0:y1, x0:x1]]
    profile = cv2.remap(
        roi,
        (samples_xy[..., 0] - x0).astype(np.float32),
        (samples_xy[..., 1] - y0).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).astype(float)  # (N, M, 3)
    end = max(1, len(offsets) // 4)
    inside = profile[:, :end].mean(axis=1)
    outside = profile[:, -end:].mean(axis=1)
    contrast = inside - outside
    norm2 = np.sum(contrast**2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = np.einsum("nmc,nc->nm", profile - outside[:, None, :], contrast) / norm2[:, None]
        # Shading changes the target's brightness, not its chromaticity: where the background's
        # colour is not a shade of the target's, write each sample as a·ĉ + β·c_out (ĉ the unit
        # inside colour) and take α = 1 − β, which no longer assumes c_in holds up to the edge.
        hue = inside / np.linalg.norm(inside, axis=1, keepdims=True)
        across = outside - np.sum(outside * hue, axis=1, keepdims=True) * hue
        chroma = np.linalg.norm(across, axis=1) >= min_contrast
        if np.any(chroma):
            basis = np.stack((hue[chroma], outside[chroma]), axis=2)  # (n, 3, 2)
            pinv = np.linalg.pinv(basis)  # (n, 2, 3)
            beta = np.einsum("nc,nmc->nm", pinv[:, 1, :], profile[chroma])
            alpha[chroma] = 1.0 - beta
    shift = np.full(len(points), CONTOUR_EDGE_INSET_PX)
    ok = norm2 >= min_contrast**2
    # last sample (from the inside out) still at coverage ≥ 1/2, and the one after it
    above = alpha >= 0.5
    crossing = np.where(above[:, :-1] & ~above[:, 1:], 1, 0)
    has = crossing.any(axis=1) & ok
    k = np.argmax(crossing[:, ::-1], axis=1)  # outermost crossing
    k = crossing.shape[1] - 1 - k
    rows = np.flatnonzero(has)
    a0, a1 = alpha[rows, k[rows]], alpha[rows, k[rows] + 1]
    t0, t1 = offsets[k[rows]], offsets[k[rows] + 1]
    shift[rows] = t0 + (a0 - 0.5) / (a0 - a1) * (t1 - t0)
    return points + shift[:, None] * normal


# --------------------------------------------------------------------------------------------
# Visible arc of a cut silhouette
# --------------------------------------------------------------------------------------------

#: Most conic fits :func:`arc_points` makes while it grows the arc along an elliptical outline.
_ARC_FITS = 3


def _conic_distance_px(conic: np.ndarray, points: np.ndarray) -> np.ndarray:
    """First-order (Sampson) distance |pᵀCp| / |∇(pᵀCp)| of points from a conic, in their units."""
    homogeneous = np.column_stack((points, np.ones(len(points))))
    value = np.einsum("ni,ij,nj->n", homogeneous, conic, homogeneous)
    gradient = 2.0 * (homogeneous @ conic)[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.abs(value) / np.linalg.norm(gradient, axis=1)
    return np.where(np.isfinite(distance), distance, np.inf)


def _arc_mask(points, center_px, radius_px: float) -> np.ndarray:
    """Which points of a closed outline lie on the visible arc (the rule of :func:`arc_points`)."""
    # relative to the circle's centre: the conic fits stay well conditioned in pixel units
    offsets = np.asarray(points, dtype=float).reshape(-1, 2) - np.asarray(center_px, dtype=float).reshape(2)
    on_arc = np.hypot(offsets[:, 0], offsets[:, 1]) >= float(radius_px) - ARC_TOLERANCE_PX
    if on_arc.all():  # the whole outline is on its circle: nothing can grow (and no fit to pay for)
        return on_arc
    for _ in range(_ARC_FITS):
        conic = fit_conic(offsets[on_arc])
        if conic is None:
            break
        grown = on_arc | (_conic_distance_px(conic, offsets) <= ARC_CONIC_TOLERANCE_PX)
        if np.array_equal(grown, on_arc):
            break
        on_arc = grown
    return on_arc


def arc_points(detection: SphereDetection, points=None) -> np.ndarray:
    """The points of a detection's contour that lie on the visible arc of the sphere's outline.

    A point of ``detection.outline_px`` is on the arc when it lies less than
    :data:`ARC_TOLERANCE_PX` inside the enclosing circle (distance from ``center_px`` ≥
    ``radius_px`` − tolerance). The image of a sphere off the optical axis is an ellipse, which
    touches its enclosing circle only at the ends of its major axis; so the arc then grows by
    the points within :data:`ARC_CONIC_TOLERANCE_PX` of the conic fitted to it, refitted while
    it grows (at most three fits). An uncut ellipse is then all arc, while the points along a
    straight occluder edge, more than :data:`ARC_TOLERANCE_PX` inside the circle and off the
    arc's conic, stay out. Only the few points of the cut nearest its ends, within the
    tolerance of the circle, count as arc.

    Parameters
    ----------
    detection : SphereDetection
    points : array_like, shape (K, 2), optional
        The contour to select from, pixels; default ``detection.contour_px``. Points as many as
        ``detection.outline_px`` are taken to correspond to it one to one, in order (the
        ``contour_px`` of :class:`SphereDetector`, whose edge refinement moves each boundary
        pixel along its normal), and take the selection made on the outline; any other closed
        contour around the enclosing circle is judged by the same rule applied to itself.

    Returns
    -------
    ndarray, shape (K_arc, 2)
        The points on the arc, pixels, in their original order.

    Notes
    -----
    The visible arc is what :func:`locate_sphere_ellipse` fits when ``detection.partial``; the
    cone through a straight edge is not the sphere's.

    Examples
    --------
    >>> img = np.zeros((120, 160, 3), np.uint8)
    >>> _ = cv2.circle(img, (80, 60), 30, (230, 20, 20), -1)
    >>> img[:, 100:] = (128, 128, 128)                        # a grey pole hides the right side
    >>> det = SphereDetector().detect(img)
    >>> det.partial, len(arc_points(det)) < len(det.contour_px)
    (True, True)
    """
    selected = _arc_mask(detection.outline_px, detection.center_px, detection.radius_px)
    points = detection.contour_px if points is None else np.asarray(points, dtype=float).reshape(-1, 2)
    if len(points) != len(selected):
        selected = _arc_mask(points, detection.center_px, detection.radius_px)
    return points[selected]


# --------------------------------------------------------------------------------------------
# Sphere localisation
# --------------------------------------------------------------------------------------------


def locate_sphere_circle(detection: SphereDetection, intrinsics: Intrinsics, radius_m: float) -> np.ndarray:
    """The paper's sphere position estimate from the enclosing circle (§3.2.1), as published.

    d = r·f/R and x₀ = d·(û, v̂, 1)ᵀ, (û, v̂, 1)ᵀ = K⁻¹(u, v, 1)ᵀ, where (u, v) and R are the
    enclosing circle's centre and radius (px), r the sphere radius (m) and f = (fx + fy)/2
    (the paper has one focal length; the study camera has fx = fy). No lens model is used.

    Parameters
    ----------
    detection : SphereDetection
    intrinsics : Intrinsics
    radius_m : float
        True sphere radius r, metres.

    Returns
    -------
    ndarray, shape (3,)
        Estimated sphere centre in the camera optical frame, metres.

    Notes
    -----
    d is treated as the depth (z) of the centre. On the optical axis the enclosing circle has
    R = f·tan α with sin α = r/D, so d = D·cos α: the estimate is short by D(1 − cos α) ≈ r²/(2D).
    Off axis the error grows like D(1 − cos θ); see :func:`circle_method_estimate`.

    A partial detection (``detection.partial``: an occluder or the image border cuts the
    silhouette) needs no special handling while less than half of it is hidden: what remains
    still holds a diameter of the disc, so its enclosing circle is the disc's own (tested to
    0.6 px up to 30 % hidden). Off axis the image is an ellipse, semi-axes a > b, touching its
    circle only at the ends of its major axis; a cut hiding one of those ends shrinks the
    circle to between b and a, i.e. by up to a − b ≈ a(1 − cos θ) (tested).
    """
    _check_intrinsics(intrinsics)
    radius_m = _check_radius(radius_m)
    focal_px = 0.5 * (intrinsics.fx + intrinsics.fy)
    depth_m = radius_m * focal_px / detection.radius_px
    ray = np.append(intrinsics.to_normalised(detection.center_px)[0], 1.0)
    return depth_m * ray


def locate_sphere_circle_undistorted(
    detection: SphereDetection,
    intrinsics: Intrinsics,
    radius_m: float,
    distortion: BrownConrady | KannalaBrandt | None,
) -> np.ndarray:
    """The paper's circle method applied after undistorting the contour through the lens.

    The outline the enclosing circle was taken from (``detection.outline_px``: the boundary
    pixels' centres, not the refined edge points of ``contour_px``, so that the strategies compare
    the same outline) is undistorted to normalised pinhole coordinates
    (:func:`gimbal_lab.camera.undistort` with ``distortion``) and mapped back to pixels with the
    same K, i.e. the outline the ideal
    pinhole camera with ``intrinsics`` would see; its minimum enclosing circle
    (``cv2.minEnclosingCircle``) then goes through :func:`locate_sphere_circle` unchanged (same
    focal length rule, f = (fx + fy)/2). This is "undistort the detected points" for the paper's
    estimate: it removes the lens but keeps the method's own off-axis bias.

    Parameters
    ----------
    detection : SphereDetection
        A detection on the raw (distorted) image; its ``outline_px`` is used (≥ 3 points).
    intrinsics : Intrinsics
        The camera that took the image.
    radius_m : float
        True sphere radius r, metres.
    distortion : BrownConrady, KannalaBrandt or None
        The lens. None (or a Brown–Conrady lens with all coefficients zero) returns
        ``locate_sphere_circle(detection, intrinsics, radius_m)`` exactly.

    Returns
    -------
    ndarray, shape (3,)
        Estimated sphere centre in the camera optical frame, metres.

    Raises
    ------
    UndistortionError
        (a ValueError) When a contour point cannot be undistorted: outside a fisheye's image
        circle, imaging a ray 90° or more off the optical axis (no pinhole coordinates), or
        where a Brown–Conrady model folds over.
    ValueError
        When the contour holds fewer than 3 points.

    Notes
    -----
    Paper §3.2.1 (d = r·f/R, x₀ = d·K⁻¹(u, v, 1)ᵀ) on the undistorted outline; the lens sweep
    (paper §4.1.2, §5). On an exact silhouette the result equals the circle method on the
    pinhole camera's silhouette of the same sphere, to the resolution of
    ``cv2.minEnclosingCircle`` (float32; tested). A partial detection is handled like the
    whole one, for the reason :func:`locate_sphere_circle` gives: the undistorted outline of a
    silhouette hidden by less than half still holds a diameter of it.
    """
    _check_intrinsics(intrinsics)
    radius_m = _check_radius(radius_m)
    distortion = _check_distortion(distortion)
    if distortion is None or distortion.is_identity:
        return locate_sphere_circle(detection, intrinsics, radius_m)
    contour = detection.outline_px
    if len(contour) < 3:
        raise ValueError(f"detection.outline_px must hold at least 3 points to undistort, got {len(contour)}")
    try:
        points = undistort_pixels(contour, intrinsics, distortion)
    except UndistortionError as error:
        raise UndistortionError(f"cannot undistort the sphere's contour through {distortion!r}: {error}") from None
    # minEnclosingCircle works in float32: hand it coordinates relative to the mean
    mean = points.mean(axis=0)
    centre, radius = cv2.minEnclosingCircle((points - mean).astype(np.float32))
    undistorted = SphereDetection(
        center_px=mean + np.asarray(centre, dtype=float),
        radius_px=radius,
        contour_px=points,
        area_px=abs(cv2.contourArea((points - mean).astype(np.float32))),
    )
    return locate_sphere_circle(undistorted, intrinsics, radius_m)


def circle_method_estimate(distance_m, radius_m: float, off_axis_rad) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form result of the circle method on an ideal (pinhole, noise-free) silhouette.

    A sphere of radius r whose centre lies at range D and angle θ from the optical axis is seen
    as an ellipse whose major axis points away from the principal point. With sin α = r/D, the
    two extreme rays in the plane of the axis make angles θ ± α with the axis, so in normalised
    coordinates (f = 1) the major semi-axis and the centre of the ellipse are

        a = [tan(θ+α) − tan(θ−α)]/2 = sin α cos α / (cos²θ − sin²α),
        û = [tan(θ+α) + tan(θ−α)]/2 = sin θ cos θ / (cos²θ − sin²α).

    The minimum enclosing circle of an ellipse is its major-axis circle (centre û, radius a), so
    the paper's estimate is depth d = r/a = D (cos²θ − sin²α)/cos α, lateral d·û = D sin θ cos θ/cos α,
    and its range is

        |x₀| = D √(cos²θ − 2 sin²α cos²θ + sin⁴α) / cos α ≈ D cos θ (1 − sin²α/2).

    The range error D − |x₀| is therefore ≈ r²/(2D) on axis and ≈ D(1 − cos θ) off axis.

    Parameters
    ----------
    distance_m : float or array_like
        Range D from the optical centre to the sphere centre, metres (> r).
    radius_m : float
        Sphere radius r, metres.
    off_axis_rad : float or array_like
        Angle θ between the optical axis and the direction to the centre, radians (θ + α < π/2).

    Returns
    -------
    range_m, depth_m : ndarray
        The estimate's range |x₀| and depth z₀ (broadcast shape of the inputs), metres.
    """
    radius_m = _check_radius(radius_m)
    distance = np.asarray(distance_m, dtype=float)
    theta = np.asarray(off_axis_rad, dtype=float)
    if np.any(distance <= radius_m):
        raise ValueError(f"distance_m must exceed radius_m = {radius_m} m")
    sin2_alpha = (radius_m / distance) ** 2
    cos_alpha = np.sqrt(1.0 - sin2_alpha)
    cos2_theta = np.cos(theta) ** 2
    if np.any(cos2_theta - sin2_alpha <= 0):
        raise ValueError("off_axis_rad + the sphere's angular radius must stay below pi/2")
    depth = distance * (cos2_theta - sin2_alpha) / cos_alpha
    range_ = distance * np.sqrt(cos2_theta - 2 * sin2_alpha * cos2_theta + sin2_alpha**2) / cos_alpha
    return range_, depth


def sphere_silhouette_px(
    center_cam_m,
    radius_m: float,
    intrinsics: Intrinsics,
    distortion: BrownConrady | KannalaBrandt | None = None,
    n_points: int = 720,
) -> np.ndarray:
    """The exact image outline of a sphere: the projection of its circle of tangency.

    Rays from the optical centre tangent to a sphere (centre C, range D = |C|, radius r) touch it
    on a circle centred at C·(1 − r²/D²), of radius r·√(D² − r²)/D, in the plane normal to C.
    Sampling that circle and projecting it (with the lens model, when given) gives points exactly
    on the silhouette's edge.

    Parameters
    ----------
    center_cam_m : array_like, shape (3,)
        Sphere centre in the camera optical frame, metres (in front of the camera).
    radius_m : float
    intrinsics : Intrinsics
    distortion : BrownConrady or KannalaBrandt, optional
    n_points : int
        Number of samples (≥ 5).

    Returns
    -------
    ndarray, shape (n_points, 2)
        Silhouette points, pixels.
    """
    center = np.asarray(center_cam_m, dtype=float).reshape(3)
    radius_m = _check_radius(radius_m)
    distance = float(np.linalg.norm(center))
    if not distance > radius_m:
        raise ValueError("center_cam_m must lie farther than radius_m from the camera")
    if n_points < 5:
        raise ValueError(f"n_points must be >= 5, got {n_points}")
    axis = center / distance
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    ring_radius = radius_m * math.sqrt(distance**2 - radius_m**2) / distance
    ring_center = center * (1.0 - radius_m**2 / distance**2)
    phi = np.linspace(0.0, 2 * math.pi, n_points, endpoint=False)
    points = ring_center + ring_radius * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    return project(points, intrinsics, _check_distortion(distortion))


def fit_conic(points) -> np.ndarray | None:
    """Algebraic least-squares conic through 2-D points.

    Finds the symmetric 3 × 3 C (unit Frobenius norm) minimising Σ (pᵢᵀ C pᵢ)², pᵢ = (xᵢ, yᵢ, 1),
    as the smallest right singular vector of the design matrix [x², xy, y², x, y, 1], after
    moving the points' centroid to the origin and scaling their mean radius to √2 (Hartley's
    conditioning). Exact for points on a conic.

    Parameters
    ----------
    points : array_like, shape (N, 2)

    Returns
    -------
    ndarray, shape (3, 3) or None
        The conic, sign chosen so that the centroid of the points is inside (pᵀCp < 0 there);
        None when fewer than 5 points or the fit is not an ellipse.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 5 or not np.all(np.isfinite(pts)):
        return None
    mean = pts.mean(axis=0)
    spread = np.mean(np.hypot(*(pts - mean).T))
    if not spread > 0:
        return None
    scale = math.sqrt(2.0) / spread
    x, y = ((pts - mean) * scale).T
    design = np.column_stack((x * x, x * y, y * y, x, y, np.ones_like(x)))
    _, _, vt = np.linalg.svd(design, full_matrices=False)
    a, b, c, d, e, f = vt[-1]
    if 4 * a * c - b * b <= 0:
        return None
    conic_n = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    norm = np.array([[scale, 0.0, -scale * mean[0]], [0.0, scale, -scale * mean[1]], [0.0, 0.0, 1.0]])
    conic = norm.T @ conic_n @ norm
    centroid = np.append(mean, 1.0)
    if centroid @ conic @ centroid > 0:
        conic = -conic
    return conic / np.linalg.norm(conic)


def conic_to_ellipse(conic) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre, semi-axes and orientation of the ellipse xᵀCx = 0 (C from :func:`fit_conic`).

    Parameters
    ----------
    conic : array_like, shape (3, 3)
        Symmetric conic matrix of a real ellipse.

    Returns
    -------
    center : ndarray, shape (2,)
    semi_axes : ndarray, shape (2,)
        Major then minor semi-axis, in the units of the points.
    angle_rad : float
        Direction of the major axis from the +x axis, radians in [0, π).
    """
    C = np.asarray(conic, dtype=float)
    A = C[:2, :2]
    center = np.linalg.solve(A, -C[:2, 2])
    # Translated to its centre the conic is yᵀ A y + k = 0 with k = C(center) (homogeneous value).
    k = C[2, 2] + C[:2, 2] @ center
    eigenvalues, eigenvectors = np.linalg.eigh(A)
    semi = np.sqrt(-k / eigenvalues)
    order = np.argsort(semi)[::-1]
    major = eigenvectors[:, order[0]]
    angle = math.atan2(major[1], major[0]) % math.pi
    return center, semi[order], angle


def _push_outward(points: np.ndarray, distance_px: float) -> np.ndarray | None:
    """Move points by ``distance_px`` along the outward normal of the conic fitted to them."""
    conic = fit_conic(points)
    if conic is None:
        return None
    homogeneous = np.column_stack((points, np.ones(len(points))))
    gradient = (homogeneous @ conic)[:, :2]
    length = np.linalg.norm(gradient, axis=1)
    if not np.all(length > 0):
        return None
    return points + distance_px * gradient / length[:, None]


def locate_sphere_ellipse(
    detection: SphereDetection,
    intrinsics: Intrinsics,
    radius_m: float,
    distortion: BrownConrady | KannalaBrandt | None = None,
) -> np.ndarray | None:
    """Exact sphere centre from the cone through its image outline (paper §3.2.1, ref. [27]).

    0. When ``detection.partial``, keep only the contour points on the visible arc
       (:func:`arc_points`): the points along an occluder's straight edge (or the image border)
       are not on the sphere's outline and would bend the conic towards them.
    1. When ``detection.edge_inset_px`` > 0, move the contour that far outward along the normal
       of a first conic fit (boundary-pixel centres lie inside the true edge).
    2. Undistort the contour with ``distortion`` (when given) and take normalised coordinates
       x = K⁻¹p; fit a conic Q to them. Q equals KᵀCK for the conic C in pinhole pixels, and
       is the cone of rays through the outline: Xᵀ Q X = 0.
    3. For a sphere the cone is (d·X)² = cos²α |X|², i.e. Q ∝ d dᵀ − cos²α I with d the unit
       direction to the centre and sin α = r/D. Its eigenvalues are k·sin²α (eigenvector d) and
       −k·cos²α twice. Take λ∥ as the eigenvalue whose sign differs from the other two and
       λ⊥ as their mean: sin²α = λ∥/(λ∥ − λ⊥), D = r/sin α, centre = D·d with d_z > 0.

    Parameters
    ----------
    detection : SphereDetection
    intrinsics : Intrinsics
    radius_m : float
        True sphere radius r, metres.
    distortion : BrownConrady or KannalaBrandt, optional
        Lens model of the image the contour comes from (None: pinhole, or already rectified).
        Through a fisheye the contour must image rays less than 90° off the optical axis (the
        cone is fitted in normalised pinhole coordinates).

    Returns
    -------
    ndarray, shape (3,) or None
        Sphere centre in the camera optical frame, metres; None when the contour (of a partial
        detection: its visible arc) has fewer than 5 points, does not fit an ellipse, cannot be
        undistorted, or the cone is not one a sphere could make.

    Notes
    -----
    Exact (to rounding) on noise-free outline points, anywhere in the image. On spheres hidden
    10–16 % by a pole or a panel edge (radius 11–63 px, noise std 2 grey levels) the distance
    error is 0.5 % (median; at most 1.6 %) from the visible arc, against 6.9 % (at least 5.4 %)
    from every contour point; 0.9 % against 18 % at 20–45 % hidden (tested).
    """
    _check_intrinsics(intrinsics)
    radius_m = _check_radius(radius_m)
    distortion = _check_distortion(distortion)
    points = detection.contour_px
    if detection.partial:
        points = arc_points(detection)
        if len(points) < 5:
            return None
    if detection.edge_inset_px > 0:
        points = _push_outward(points, detection.edge_inset_px)
        if points is None:
            return None
    try:
        xy = undistort(intrinsics.to_normalised(points), distortion)
    except UndistortionError:
        return None
    return _sphere_from_cone(fit_conic(xy), radius_m)


def _sphere_from_cone(cone: np.ndarray | None, radius_m: float) -> np.ndarray | None:
    """Step 3 of :func:`locate_sphere_ellipse`: the sphere's centre (m) from the conic Q fitted in
    normalised coordinates; None when there is no conic or it is not a cone a sphere makes."""
    if cone is None:
        return None
    eigenvalues, eigenvectors = np.linalg.eigh(cone)
    positive = eigenvalues > 0
    if positive.sum() == 2:
        eigenvalues = -eigenvalues
        positive = ~positive
    if positive.sum() != 1:
        return None
    i = int(np.flatnonzero(positive)[0])
    lam_par = eigenvalues[i]
    lam_perp = np.delete(eigenvalues, i).mean()
    sin2_alpha = lam_par / (lam_par - lam_perp)
    if not 0.0 < sin2_alpha < 1.0:
        return None
    direction = eigenvectors[:, i]
    if direction[2] < 0:
        direction = -direction
    return (radius_m / math.sqrt(sin2_alpha)) * direction


# --------------------------------------------------------------------------------------------
# Motion-blurred sphere
# --------------------------------------------------------------------------------------------

#: Below this streak (px, :attr:`SphereCoverage.streak_px`) :func:`locate_sphere_streak` returns
#: the exact cone fit of the outline (:func:`locate_sphere_ellipse`): a sharp silhouette's edge
#: places the sphere better than its coverage does, and the coverage's own estimate of the streak
#: reads 1.2–1.5 px on a sharp sphere under sensor noise of std 2 grey levels (measured, radius
#: 28 px), so a pixel's streak cannot be told from none. The cone fit errs by about a millimetre
#: at 3 m on a 2 px streak (measured, same sphere).
STREAK_MIN_PX = 2.0

#: Above this :attr:`SphereCoverage.background_rms` the background is not the smooth one the
#: coverage needs and :func:`locate_sphere_streak` returns the cone fit. Measured on the lab's
#: blurred frames: 0.000 with the sky behind (no noise; sensor noise of std 2 grey levels gives
#: 0.0125 on grass-coloured ground, tested), 0.046–0.073 on the checkered grass and 0.27–0.35 where
#: the horizon crosses the region, whose coverage then errs by 0.1–1.9 m and 1–6 m.
SMOOTH_BACKGROUND = 0.03

#: Pixels of lower coverage are left out of the second moments of :func:`sphere_coverage` (not out
#: of its solid angle): a background pixel's noise in α (about 0.04 for sensor noise of std 2 grey
#: levels) is weighted there by its squared distance, ≈ σ·√N·ρ²/A px² from N pixels at ρ px around
#: a blob of area A: 1 px² and more, against L²/12 for a streak of L px. Leaving out the soft ends'
#: slivers below it reads a streak up to about 10 % short (measured over 5–40 px).
_MOMENT_COVERAGE = 0.15

#: A pixel whose coverage α reaches this counts as wholly target when the target's colour is
#: estimated (:func:`sphere_coverage`); 1 − this is about 2.5 times the noise of α for a
#: sensor noise of std 2 grey levels on the study's sky and grass.
_PURE_COVERAGE = 0.95


@dataclass(frozen=True, eq=False)
class SphereCoverage:
    """A sphere's image read as coverage: the fraction of the exposure each pixel saw the sphere
    (:func:`sphere_coverage`).

    Attributes
    ----------
    ray : ndarray, shape (3,)
        Unit direction d to the sphere's centre at mid-exposure: the coverage-weighted mean of
        the pixels' unit rays (camera optical frame).
    solid_angle_sr : float
        Ω = Σ αᵢ ωᵢ, the silhouette's solid angle (steradians), with ωᵢ the pixel's own.
    half_angle_rad : float
        The sphere's angular radius α₀, from Ω = 2π(1 − cos α₀), radians.
    streak_px : float
        The streak's length L in the camera turned toward d (√(12 (λ₁ − λ₂)) from the
        coverage's second moments, up to 10 % short), pixels.
    direction : ndarray, shape (2,)
        Unit vector along the streak in that turned camera (its sign is arbitrary).
    background_rms : float
        RMS distance of the ring's colours from the background plane, as a fraction of the
        target's contrast with it (|ĉ·a − b| over the wholly covered pixels): how far the
        background departs from the smooth one the coverage assumes.
    """

    ray: np.ndarray
    solid_angle_sr: float
    half_angle_rad: float
    streak_px: float
    direction: np.ndarray
    background_rms: float


def _coverage(colours: np.ndarray, inside: np.ndarray, behind: np.ndarray) -> np.ndarray:
    """α = 1 − β with each colour c written a·ĉ + β·b (least squares over the channels), ĉ the
    target's unit colour and b the background behind that pixel; shape of ``colours[..., 0]``."""
    hue = inside / np.linalg.norm(inside)
    hh, hb, bb = 1.0, np.einsum("...c,c->...", behind, hue), np.einsum("...c,...c->...", behind, behind)
    hc, bc = np.einsum("...c,c->...", colours, hue), np.einsum("...c,...c->...", colours, behind)
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = (hh * bc - hb * hc) / (hh * bb - hb * hb)
    return np.where(np.isfinite(beta), 1.0 - beta, 0.0)


class _HalfPixelGrid:
    """The undistorted normalised coordinates of one camera's half-pixel grid, u, v = −½, 0, ½, …,
    size − ½, filled tile by tile as windows ask for them and kept.

    Each point is the one :func:`~gimbal_lab.camera.undistort` gives for it alone: for a
    Brown–Conrady or rational lens that function works point by point (its iterations stop each
    point on its own test; a fisheye's does not, and is not kept), so a window read from
    the grid is bit for bit the window undistorted afresh (tested). A tile with a point that has
    no preimage is marked, and a window that touches it is undistorted afresh, so that it fails
    as it did (:class:`~gimbal_lab.camera.UndistortionError`).
    """

    TILE = 64  # grid points per tile side (32 px)

    def __init__(self, intrinsics: Intrinsics, distortion):
        self.intrinsics, self.distortion = intrinsics, distortion
        rows, cols = 2 * intrinsics.height + 1, 2 * intrinsics.width + 1
        self.x = np.empty((rows, cols))
        self.y = np.empty((rows, cols))
        self.state = np.zeros((-(-rows // self.TILE), -(-cols // self.TILE)), np.int8)  # 0 to do, 1 done, −1 fails

    def window(self, u0: int, v0: int, u1: int, v1: int):
        """(x, y), each (2(v1 − v0) + 1, 2(u1 − u0) + 1), of the grid points u0 − ½ … u1 − ½ by
        v0 − ½ … v1 − ½; None when the box leaves the image or touches a failing tile."""
        K = self.intrinsics
        if not (0 <= u0 < u1 <= K.width and 0 <= v0 < v1 <= K.height):
            return None
        rows, cols = slice(2 * v0, 2 * v1 + 1), slice(2 * u0, 2 * u1 + 1)
        T = self.TILE
        tiles = (slice(rows.start // T, (rows.stop - 1) // T + 1), slice(cols.start // T, (cols.stop - 1) // T + 1))
        for ti, tj in zip(*np.nonzero(self.state[tiles] == 0)):
            self._fill(tiles[0].start + ti, tiles[1].start + tj)
        if np.any(self.state[tiles] < 0):
            return None
        return self.x[rows, cols], self.y[rows, cols]

    def _fill(self, ti: int, tj: int) -> None:
        T = self.TILE
        r0, c0 = ti * T, tj * T
        r1, c1 = min(r0 + T, self.x.shape[0]), min(c0 + T, self.x.shape[1])
        # the grid's values as np.arange(u0 − 0.5, u1, 0.5) makes them: exact halves
        uu, vv = np.meshgrid(-0.5 + 0.5 * np.arange(c0, c1), -0.5 + 0.5 * np.arange(r0, r1))
        try:
            xy = undistort(self.intrinsics.to_normalised(np.column_stack((uu.ravel(), vv.ravel()))), self.distortion)
        except UndistortionError:
            self.state[ti, tj] = -1
            return
        self.x[r0:r1, c0:c1] = xy[:, 0].reshape(uu.shape)
        self.y[r0:r1, c0:c1] = xy[:, 1].reshape(uu.shape)
        self.state[ti, tj] = 1


_HALF_PIXEL_GRIDS: dict = {}  # (intrinsics, distortion) → _HalfPixelGrid; the last few cameras only
_HALF_PIXEL_GRIDS_KEPT = 4


def _half_pixel_grid(intrinsics: Intrinsics, distortion) -> _HalfPixelGrid:
    key = (intrinsics, distortion)
    grid = _HALF_PIXEL_GRIDS.pop(key, None) or _HalfPixelGrid(intrinsics, distortion)
    _HALF_PIXEL_GRIDS[key] = grid  # most recent last
    while len(_HALF_PIXEL_GRIDS) > _HALF_PIXEL_GRIDS_KEPT:
        del _HALF_PIXEL_GRIDS[next(iter(_HALF_PIXEL_GRIDS))]
    return grid


def _window_rays(box, intrinsics: Intrinsics, distortion):
    """Unit rays (h, w, 3) and solid angles (h, w), sr, of the pixels in ``box`` = (u0, v0, u1, v1)."""
    u0, v0, u1, v1 = box
    # pixel centres and the half-pixel points around them, undistorted to normalised coordinates
    # (read from the camera's kept grid: the same numbers, computed once per camera)
    kept = None
    if distortion is not None and not isinstance(distortion, KannalaBrandt):  # its inverse iterates batch-wise
        kept = _half_pixel_grid(intrinsics, distortion).window(u0, v0, u1, v1)
    if kept is not None:
        x, y = kept
    else:
        uu, vv = np.meshgrid(np.arange(u0 - 0.5, u1, 0.5), np.arange(v0 - 0.5, v1, 0.5))
        xy = undistort(intrinsics.to_normalised(np.column_stack((uu.ravel(), vv.ravel()))), distortion)
        x, y = (c.reshape(uu.shape) for c in xy.T)
    centre = np.s_[1::2, 1::2]
    # Jacobian of pixel → normalised coordinates by central differences over one pixel
    dx_du, dy_du = x[1::2, 2::2] - x[1::2, :-1:2], y[1::2, 2::2] - y[1::2, :-1:2]
    dx_dv, dy_dv = x[2::2, 1::2] - x[:-1:2, 1::2], y[2::2, 1::2] - y[:-1:2, 1::2]
    rays = np.stack((x[centre], y[centre], np.ones_like(x[centre])), axis=-1)
    norm = np.linalg.norm(rays, axis=-1)
    # the solid angle of a patch dA of the plane z = 1 at a ray of length n is dA/n³
    omega = np.abs(dx_du * dy_dv - dx_dv * dy_du) / norm**3
    return rays / norm[..., None], omega


def sphere_coverage(
    rgb: np.ndarray,
    detection: SphereDetection,
    intrinsics: Intrinsics,
    distortion: BrownConrady | KannalaBrandt | None = None,
    mixing: str = "linear",
) -> SphereCoverage | None:
    """Direction and solid angle of a sphere from its pixels' coverage, motion blur or not.

    A frame integrates light over the exposure, so a pixel's colour is the mean over the
    exposure of the sphere's and the background's colours weighted by whether the sphere covered
    it: c = α·c_in + (1 − α)·c_out, with α the fraction of the exposure it did (its coverage,
    including the part of the pixel's area: anti-aliasing). Summed over pixels, the coverage is
    the time average of the silhouette: blur moves it but does not change its amount. Hence,
    with ωᵢ each pixel's solid angle and r̂ᵢ its unit ray,

    * Ω = Σ αᵢ ωᵢ = the mean over the exposure of the silhouette's solid angle 2π(1 − cos α₀)
      (sin α₀ = R/D for a sphere of radius R at range D), whatever the streak's length, shape or
      direction: cos α₀ = 1 − Ω/(2π);
    * a cap of half-angle α₀ about the direction d sums its rays to ∫ r̂ dΩ = π sin²α₀ · d, so
      the coverage-weighted sum Σ αᵢ ωᵢ r̂ᵢ lies along the time average of d(t): the
      mid-exposure direction for a uniform, straight sweep;
    * in the camera turned toward d (where the silhouette is a disc of radius f·tan α₀) the
      coverage's second moments are the disc's, r²/4 in every direction, plus L²/12 along a
      straight uniform streak of length L: L = √(12 (λ₁ − λ₂)) from their eigenvalues (taken
      over the pixels of coverage ≥ 0.15, which reads L up to 10 % short; see
      :data:`_MOMENT_COVERAGE`). The range does not use L.

    The width of the blob's outline across the streak does not give the disc's size: a
    detector thresholding at coverage t sees |y| ≤ √(r² − t²L²/4) across it and r + L(1/2 − t)
    along it, both depending on t (docs/design.md, "The paper's methods as equations").

    Steps: the region is the detection's blob dilated by 1.25 × its enclosing radius + 3 px
    (to hold the soft ends of a streak up to about 2R), cut by the image's border; the
    background b behind each of its pixels is a plane per channel (c₀ + c_u·u + c_v·v) fitted to
    a 2-px ring around it; the target's unit colour ĉ is that of the blob's interior pixels
    (eroded by 2 px) that are wholly target (coverage ≥ 0.95, found twice over from the 10 % of
    them most unlike their background). Each pixel is then written c = a·ĉ + β·b (least squares
    over the three channels, in the ``mixing`` space) and α = 1 − β, which holds for a shaded
    sphere, whose brightness varies but not its hue.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        The frame the detection came from.
    detection : SphereDetection
        The blob, from :class:`SphereDetector` on ``rgb`` (its ``outline_px`` is used).
    intrinsics : Intrinsics
    distortion : BrownConrady or KannalaBrandt, optional
        Lens model of ``rgb``: each pixel's ray and solid angle are taken through it.
    mixing : {"linear", "srgb"}
        Where a pixel mixes its two colours (see :func:`refine_edge_points`): "linear" light
        for a camera and for the lab's motion blur, which averages in linear light.

    Returns
    -------
    SphereCoverage or None
        None when the blob touches the image border (``detection.touches_border``), when no
        interior pixel is left after the erosion, or when a pixel's ray cannot be undistorted.
        A region that reaches the border is cut there: a streak's soft end beyond it is lost.

    Notes
    -----
    The lab's addition, not the paper's. Assumes the background around the sphere is smooth
    (a plane in colour across the region: the study's sky is): a textured one (the study's
    checkered grass, whose stripes change its brightness by tens of percent) is read as coverage
    and the range is then off by 5–10 % (measured on the lab's frames), and a second object in
    the region adds its own coverage. On the lab's blurred frames with the sky behind, the range
    is 1.5–1.8 % short (47–54 mm at 3.1 m, tested), against 0.1 % on the analytic frames; the
    renderer's anti-aliased rim, resolved in sRGB on a sharp frame (where "linear" reads 0.8 %
    short and "srgb" 0.1 % long), is the likely part. It also assumes that some pixel saw the
    sphere for the whole exposure (a streak shorter than the silhouette's diameter, L < 2r):
    otherwise the target's colour is
    never seen pure and Ω is overestimated by up to L/(2r). The direction is the mid-exposure
    one for a straight, uniform sweep; a curved sweep gives the mean of the path (off its
    middle by up to the path's sagitta), a non-uniform one the time-weighted mean. Ω is the
    time-mean of the solid angle, which differs from the mid-exposure one by the second-order
    change of range within the exposure.
    """
    rgb = _check_rgb(rgb)
    _check_intrinsics(intrinsics)
    distortion = _check_distortion(distortion)
    if mixing not in EDGE_MIXING:
        raise ValueError(f"mixing must be one of {sorted(EDGE_MIXING)}, got {mixing!r}")
    height, width = rgb.shape[:2]
    outline = np.asarray(detection.outline_px, dtype=float)
    margin = int(math.ceil(1.25 * detection.radius_px)) + 3
    if detection.touches_border:
        return None
    lo = np.maximum(np.floor(outline.min(axis=0)).astype(int) - margin - 2, 0)
    hi = np.minimum(np.ceil(outline.max(axis=0)).astype(int) + margin + 3, (width, height))
    box = (int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))
    window = EDGE_MIXING[mixing][rgb[box[1] : box[3], box[0] : box[2]]].astype(float)
    blob = np.zeros(window.shape[:2], np.uint8)
    cv2.fillPoly(blob, [np.round(outline - lo).astype(np.int32)], 1)
    interior = cv2.erode(blob, np.ones((3, 3), np.uint8), iterations=2).astype(bool)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    region = cv2.dilate(blob, disc)
    ring = cv2.dilate(region, np.ones((5, 5), np.uint8)).astype(bool) & ~region.astype(bool)
    region = region.astype(bool)
    if not interior.any() or not ring.any():
        return None
    # the background behind the region: a plane per channel through the ring around it
    rows, cols = np.indices(region.shape, dtype=float)
    design = np.stack((np.ones_like(rows), cols, rows), axis=-1)
    plane = np.linalg.lstsq(design[ring], window[ring], rcond=None)[0]  # (3, 3): terms × channels
    behind = design @ plane
    colours, backgrounds = window[interior], behind[interior]
    unlike = np.einsum("nc,nc->n", colours, backgrounds) / (
        np.linalg.norm(colours, axis=1) * np.linalg.norm(backgrounds, axis=1) + 1e-12)
    inside = colours[unlike <= np.quantile(unlike, 0.1)].mean(axis=0)
    for _ in range(2):
        pure = colours[_coverage(colours, inside, backgrounds) >= _PURE_COVERAGE]
        if len(pure) == 0:
            return None
        inside = pure.mean(axis=0)
    alpha = np.where(region, _coverage(window, inside, behind), 0.0)
    pure = _coverage(colours, inside, backgrounds) >= _PURE_COVERAGE
    contrast = float(np.mean(np.linalg.norm(colours[pure] - backgrounds[pure], axis=1)))
    roughness = float(np.sqrt(np.mean(np.sum((window[ring] - behind[ring]) ** 2, axis=1))))
    try:
        rays, omega = _window_rays(box, intrinsics, distortion)
    except UndistortionError:
        return None
    weight = alpha * omega
    solid_angle = float(weight.sum())
    if not 0.0 < solid_angle < 2 * math.pi:
        return None
    mean_ray = np.einsum("hw,hwk->k", weight, rays)
    ray = mean_ray / np.linalg.norm(mean_ray)
    if ray[2] <= 0:
        return None
    # second moments in the camera turned toward the ray (there the silhouette is a disc)
    e1 = np.array([1.0, 0.0, 0.0]) - ray[0] * ray
    e1 /= np.linalg.norm(e1)
    turn = np.vstack((e1, np.cross(ray, e1), ray))
    turned = rays[region] @ turn.T
    focal_px = 0.5 * (intrinsics.fx + intrinsics.fy)
    q = focal_px * turned[:, :2] / turned[:, 2:3]
    # pixels of coverage below _MOMENT_COVERAGE are left out of the moments: a background pixel's
    # noise is weighted by its squared distance there, which the soft ends' slivers are not worth
    w = np.where(alpha[region] >= _MOMENT_COVERAGE, np.minimum(alpha[region], 1.0), 0.0) * omega[region]
    w /= w.sum()
    q -= w @ q
    moments = (q * w[:, None]).T @ q
    eigenvalues, eigenvectors = np.linalg.eigh(moments)
    return SphereCoverage(
        ray=ray,
        solid_angle_sr=solid_angle,
        half_angle_rad=math.acos(1.0 - solid_angle / (2 * math.pi)),
        streak_px=math.sqrt(12.0 * max(eigenvalues[1] - eigenvalues[0], 0.0)),
        direction=eigenvectors[:, 1],
        background_rms=roughness / contrast,
    )


def locate_sphere_streak(
    rgb: np.ndarray,
    detection: SphereDetection,
    intrinsics: Intrinsics,
    radius_m: float,
    distortion: BrownConrady | KannalaBrandt | None = None,
    mixing: str = "linear",
) -> np.ndarray | None:
    """Sphere centre at mid-exposure, blur-aware: range from the silhouette's solid angle.

    :func:`sphere_coverage` gives the direction d (the coverage-weighted mean ray) and the
    angular radius α₀ (Ω = 2π(1 − cos α₀)); the range is D = r/sin α₀, the same exact geometry
    as the cone fit (:func:`locate_sphere_ellipse`: sin α = r/D), and the centre D·d. On the
    optical axis this is the disc's angular diameter: tan α₀ = ρ/f for a disc of radius ρ px.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        The frame the detection came from.
    detection : SphereDetection
    intrinsics : Intrinsics
    radius_m : float
        True sphere radius r, metres.
    distortion : BrownConrady or KannalaBrandt, optional
        Lens model of ``rgb`` (None: pinhole, or already rectified).
    mixing : {"linear", "srgb"}
        See :func:`sphere_coverage`.

    Returns
    -------
    ndarray, shape (3,) or None
        Sphere centre at mid-exposure in the camera optical frame, metres; None only where the
        fallback gives None.

    Notes
    -----
    The lab's addition (docs/design.md, "The paper's methods as equations"); the derivation and
    the assumptions are :func:`sphere_coverage`'s. Falls back to :func:`locate_sphere_ellipse`
    on the same detection (the exact cone fit of its outline) when the coverage cannot be read
    (the blob touches the border, a ray cannot be undistorted), when the background around the
    blob is not smooth (:attr:`SphereCoverage.background_rms` above :data:`SMOOTH_BACKGROUND`: a
    textured ground or the horizon is read as coverage), and when the streak is shorter than
    :data:`STREAK_MIN_PX`: on a sharp frame the outline's edge is the better measure (no
    background colour to estimate).
    """
    radius_m = _check_radius(radius_m)
    coverage = sphere_coverage(rgb, detection, intrinsics, distortion, mixing)
    if coverage is None or coverage.streak_px < STREAK_MIN_PX or coverage.background_rms > SMOOTH_BACKGROUND:
        return locate_sphere_ellipse(detection, intrinsics, radius_m, distortion=distortion)
    return (radius_m / math.sin(coverage.half_angle_rad)) * coverage.ray


# --------------------------------------------------------------------------------------------
# ArUco markers
# --------------------------------------------------------------------------------------------

REFINEMENT_MODES = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
}
"""Corner refinement names accepted by :class:`ArucoTracker` and their OpenCV constants."""


_FLIP_YZ = np.diag([1.0, -1.0, -1.0])
#: A pose whose corners reproject within this RMS (px) is kept without trying the other frame.
_POSE_ACCEPT_PX = 0.5


@dataclass(frozen=True, eq=False)
class MarkerPose:
    """Pose of one marker in the camera optical frame.

    Attributes
    ----------
    marker_id : int
    corners_px : ndarray, shape (4, 2)
        Image corners in the dictionary's order (top-left, top-right, bottom-right, bottom-left
        of the marker), pixels.
    rvec : ndarray, shape (3,)
        Rotation vector (Rodrigues) of ``R_cam_marker``, radians.
    R_cam_marker : ndarray, shape (3, 3)
        Rotation mapping marker-frame vectors to the camera frame.
    t_cam_marker_m : ndarray, shape (3,)
        Marker centre in the camera frame, metres.
    center_px : ndarray, shape (2,)
        Mean of the four corners, pixels.
    reprojection_error_px : float
        RMS distance between the corners and the model corners reprojected with the pose.
    """

    marker_id: int
    corners_px: np.ndarray
    rvec: np.ndarray
    R_cam_marker: np.ndarray
    t_cam_marker_m: np.ndarray
    center_px: np.ndarray
    reprojection_error_px: float

    @property
    def T_cam_marker(self) -> np.ndarray:
        """4 × 4 homogeneous transform marker → camera."""
        transform = np.eye(4)
        transform[:3, :3] = self.R_cam_marker
        transform[:3, 3] = self.t_cam_marker_m
        return transform

    @property
    def distance_m(self) -> float:
        """Range from the optical centre to the marker centre, metres."""
        return float(np.linalg.norm(self.t_cam_marker_m))


class ArucoTracker:
    """ArUco marker detection and pose (paper §3.2.2).

    ``cv2.aruco.ArucoDetector`` (adaptive threshold, Suzuki–Abe contours, Douglas–Peucker
    quadrilaterals, code read through a homography), then per marker
    ``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)`` with the object corners (−L/2, L/2, 0),
    (L/2, L/2, 0), (L/2, −L/2, 0), (−L/2, −L/2, 0) in the marker frame (x right, y up on the
    printed marker, z out of its face).

    A marker facing the camera is rotated by about π from the camera (its z axis points back at
    the camera), and a marker turned only about its vertical axis is rotated by exactly π. There
    OpenCV 5.0's IPPE solvers return a wrong rotation (tested: reprojection errors of tens of
    pixels; the translation stays right). The pose is therefore solved for the marker frame
    turned by π about its x axis, F (y down, z into the marker), which sees the camera with a
    rotation near identity: the same IPPE-square call with the image corners in the order
    (3, 2, 1, 0), which are F's corners in IPPE-square's order, then
    R_cam_marker = R_cam_F · diag(1, −1, −1); the translation is common to both frames. A marker
    turned upside down in its plane brings F's rotation near π in turn; so when F's pose
    reprojects its corners worse than 0.5 px RMS, the marker frame is solved directly (IPPE-square,
    then Levenberg–Marquardt from a homography start, which also covers a marker upside down and
    square to the axis) and the pose with the smallest reprojection error is kept.

    Parameters
    ----------
    intrinsics : Intrinsics
        The camera of the frames the detector sees: the raw camera, or
        ``rectifier.out_intrinsics`` when a rectifier is given.
    marker_length_m : float
        Side L of the black square, metres.
    dictionary : str or int
        Predefined dictionary, by name ("DICT_4X4_50") or OpenCV constant.
    refinement : {"none", "subpix", "contour", "apriltag"}
        Corner refinement; the paper does not say which it used. The default, "subpix", was
        chosen by measurement: on real photographs of a ChArUco board (markers 18–50 px, truth
        from the board's chessboard corners) unrefined corners make markers 4–5 % too small
        (range 4–5 % too long), "subpix" 2–3 %, "apriltag" 1 % but it loses a third of the
        markers under 50 px on synthetic photos and runs 6× slower; on synthetic photos with
        known truth (``realworld.PlanarTargetCamera``) "subpix" has the smallest corner error
        from 80 px up; on rendered frames all modes are within 1.5 px and "subpix" keeps range
        within 1 % (``tests/test_detection.py``).
    distortion : BrownConrady or KannalaBrandt, optional
        The lens of the raw frames; markers are detected on the raw frame either way. A
        Brown–Conrady lens is passed to ``solvePnP``, which undistorts the corners. For a fisheye
        the corners are undistorted to normalised coordinates with
        ``cv2.fisheye.undistortPoints`` and the same PnP runs with K = I and no distortion. A
        marker with a corner that images a ray 90° or more off the axis (no pinhole
        coordinates), lies outside the image circle, or lies at a normalised image radius
        θ_d ≥ π/2 (``cv2.fisheye.undistortPoints`` clamps θ_d there; a lens with θ_d(θ) > θ
        reaches it before 90°) gets no pose. None is the paper's setting: the pinhole model is
        assumed even when the lens distorts.
    rectifier : Rectifier, optional
        Rectify each frame before detection (then ``distortion`` must be None, and
        ``intrinsics`` must be ``rectifier.out_intrinsics``: the rectified image's camera).
    threshold_windows_px : (int, int, int)
        (min, max, step) of the adaptive-threshold window sides, pixels ≥ 3, used at every
        pyramid level. The default thresholds with 3- and 13-px windows. Measured
        (``benchmarks/bench_real_aruco.py``): a 7-px window alone missed a strongly
        foreshortened 16-px marker in a real photograph that the 3-px window reads, and a 3-px
        window alone loses 3 of the 5 real 290–650 px markers that (3, 13) finds; OpenCV's
        default (3, 23, 10) thresholds three times per frame and, on 380 synthetic photos, finds
        3 markers (16–40 px, borderline code reads) that (3, 13) misses and misses 1 it finds.
    pyramid_factor : int
        Each pyramid level shrinks the previous one this many times (1: no pyramid). A window
        of a few pixels loses markers whose edges are blurred over more than about half of it
        (large, close, out-of-focus markers); on a level shrunk 4×, the same window spans 28
        full-resolution pixels and the blur shrinks with the image. Measured: on the real
        photographs every marker is found without it; on synthetic photos it adds one heavily
        defocused 400-px marker (blur σ 4.5 px) of 60 over 300 px. Its cost depends on the
        dictionary: about 0.6× the full frame's with DICT_4X4_50, about as much as the full
        frame with DICT_6X6_250 on busy photos (small levels pass many tiny candidates, each
        read against every code).
    min_level_side_px : int
        A level is only used while its longer side is at least this long (≥ 16 px).

    Notes
    -----
    Recall, corner error and speed of these defaults against OpenCV's default detector, on
    synthetic photos with known truth (print, uneven light, vignetting, defocus, noise, JPEG)
    and on a folder of real photographs: ``benchmarks/bench_real_aruco.py``. Markers from
    about 25 px to most of the frame are found when the defocus blur is under about a tenth of
    the marker's side; under 25 px, about 7 in 10 on the synthetic photos (as OpenCV's default).
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        marker_length_m: float = 0.30,
        dictionary: str | int = "DICT_4X4_50",
        refinement: str = "subpix",
        distortion: BrownConrady | KannalaBrandt | None = None,
        rectifier: Rectifier | None = None,
        threshold_windows_px: tuple[int, int, int] = (3, 13, 10),
        pyramid_factor: int = 4,
        min_level_side_px: int = 120,
    ):
        self.intrinsics = _check_intrinsics(intrinsics)
        windows = tuple(threshold_windows_px)
        if (
            len(windows) != 3
            or not all(isinstance(w, (int, np.integer)) and not isinstance(w, bool) for w in windows)
            or windows[0] < 3
            or windows[1] < windows[0]
            or windows[2] < 1
        ):
            raise ValueError(
                f"threshold_windows_px must be integers (min >= 3, max >= min, step >= 1), got {threshold_windows_px!r}"
            )
        self.threshold_windows_px = windows
        for name, value, low in (("pyramid_factor", pyramid_factor, 1), ("min_level_side_px", min_level_side_px, 16)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        self.pyramid_factor = int(pyramid_factor)
        self.min_level_side_px = int(min_level_side_px)
        length = float(marker_length_m)
        if not (math.isfinite(length) and length > 0):
            raise ValueError(f"marker_length_m must be finite and > 0 m, got {marker_length_m!r}")
        self.marker_length_m = length
        if isinstance(dictionary, str):
            if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
                raise ValueError(f"dictionary must name a cv2.aruco predefined dictionary, got {dictionary!r}")
            dictionary_id = getattr(cv2.aruco, dictionary)
        else:
            dictionary_id = int(dictionary)
        self.dictionary = dictionary
        if refinement not in REFINEMENT_MODES:
            raise ValueError(f"refinement must be one of {sorted(REFINEMENT_MODES)}, got {refinement!r}")
        self.refinement = refinement
        self.distortion = _check_distortion(distortion)
        self.rectifier = _check_rectifier(rectifier)
        if self.rectifier is not None and self.distortion is not None:
            raise ValueError("give either rectifier or distortion, not both: a rectified image is already pinhole")
        if self.rectifier is not None and self.rectifier.out_intrinsics != self.intrinsics:
            raise ValueError(
                "the tracker sees the rectified image: build it on rectifier.out_intrinsics "
                f"({self.rectifier.out_intrinsics!r}), got intrinsics {self.intrinsics!r}"
            )
        parameters = cv2.aruco.DetectorParameters()
        parameters.cornerRefinementMethod = REFINEMENT_MODES[refinement]
        (
            parameters.adaptiveThreshWinSizeMin,
            parameters.adaptiveThreshWinSizeMax,
            parameters.adaptiveThreshWinSizeStep,
        ) = (int(w) for w in windows)
        aruco_dict = cv2.aruco.getPredefinedDictionary(dictionary_id)
        self._detector = cv2.aruco.ArucoDetector(aruco_dict, parameters)
        coarse = cv2.aruco.DetectorParameters()
        (
            coarse.adaptiveThreshWinSizeMin,
            coarse.adaptiveThreshWinSizeMax,
            coarse.adaptiveThreshWinSizeStep,
        ) = (int(w) for w in windows)
        self._coarse_detector = cv2.aruco.ArucoDetector(aruco_dict, coarse)
        self._cells = aruco_dict.markerSize + 2
        half = length / 2.0
        self.object_points_m = np.array(
            [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]]
        )
        self._K = intrinsics.K
        self._dist = self.distortion.coefficients if self.distortion is not None else None
        # PnP runs in pixels (K and a Brown–Conrady lens) or, through a fisheye, in normalised
        # coordinates of the undistorted corners (K = I, no distortion)
        self._fisheye = isinstance(self.distortion, KannalaBrandt)
        self._pnp_K = np.eye(3) if self._fisheye else self._K
        self._pnp_dist = None if self._fisheye else self._dist
        if self._fisheye:
            lens = self.distortion
            # corners must image rays < 90° off the axis (inside the image circle), and lie where
            # cv2.fisheye.undistortPoints is right: it clamps θ_d to π/2
            self._max_theta_d = min(0.5 * math.pi, float(lens.theta_d(min(0.5 * math.pi, lens.max_field_rad))))

    def __repr__(self) -> str:
        return (
            f"ArucoTracker(marker_length_m={self.marker_length_m}, dictionary={self.dictionary!r}, "
            f"refinement={self.refinement!r}, distortion={self.distortion!r}, rectifier={self.rectifier!r}, "
            f"threshold_windows_px={self.threshold_windows_px}, pyramid_factor={self.pyramid_factor}, "
            f"min_level_side_px={self.min_level_side_px})"
        )

    def detect(self, rgb: np.ndarray) -> dict[int, MarkerPose]:
        """Detect every marker of the dictionary in one RGB frame and estimate its pose.

        Parameters
        ----------
        rgb : ndarray, shape (H, W, 3), uint8
            The frame, RGB channel order.

        Returns
        -------
        dict of int to MarkerPose
            Keyed by marker id; empty when no marker is seen. If an id appears twice, the
            larger image of it is kept.
        """
        rgb = _check_rgb(rgb)
        if self.rectifier is not None:
            rgb = self.rectifier.rectify(rgb)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        poses: dict[int, MarkerPose] = {}
        for marker_id, quad in self.detect_corners(gray):
            pose = self.pose_from_corners(quad, marker_id)
            if pose is None:
                continue
            previous = poses.get(pose.marker_id)
            if previous is None or _quad_area(pose.corners_px) > _quad_area(previous.corners_px):
                poses[pose.marker_id] = pose
        return poses

    def detect_corners(self, gray: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Marker ids and image corners in one grey frame, at every level of the pyramid.

        Level 0 is the frame itself, with the configured refinement. Each further level is the
        previous one shrunk ``pyramid_factor`` times (area average) while its longer side stays
        ≥ ``min_level_side_px``; a marker found there and not already found below is scaled back
        to full-resolution pixels and its corners refined on the full frame with
        ``cv2.cornerSubPix`` (half window 0.3 of a cell, ≥ 2 px, < half a cell).

        Parameters
        ----------
        gray : ndarray, shape (H, W), uint8

        Returns
        -------
        list of (int, ndarray of shape (4, 2))
            Marker id and corners (``cv2.aruco`` order), full-resolution pixels.
        """
        gray = np.asarray(gray)
        if gray.dtype != np.uint8 or gray.ndim != 2 or gray.size == 0:
            raise ValueError(f"gray must be a non-empty uint8 array of shape (H, W), got {gray.dtype} {gray.shape}")
        found = []
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is not None:
            found += [(int(i), q.reshape(4, 2).astype(float)) for q, i in zip(corners, ids.reshape(-1))]
        height, width = gray.shape
        level = gray
        while self.pyramid_factor > 1:
            size = (level.shape[1] // self.pyramid_factor, level.shape[0] // self.pyramid_factor)
            if max(size) < self.min_level_side_px or min(size) < 8:
                break
            level = cv2.resize(level, size, interpolation=cv2.INTER_AREA)
            corners, ids, _ = self._coarse_detector.detectMarkers(level)
            if ids is None:
                continue
            scale = np.array([width / size[0], height / size[1]])
            for q, marker_id in zip(corners, ids.reshape(-1)):
                quad = (q.reshape(4, 2).astype(float) + 0.5) * scale - 0.5
                centre = quad.mean(axis=0)
                if any(
                    i == marker_id and cv2.pointPolygonTest(other.astype(np.float32), tuple(centre), False) >= 0
                    for i, other in found
                ):
                    continue
                found.append((int(marker_id), self._refine_on_full_frame(gray, quad)))
        return found

    def _refine_on_full_frame(self, gray: np.ndarray, quad: np.ndarray) -> np.ndarray:
        side_px = math.sqrt(max(_quad_area(quad), 1.0))
        cell_px = side_px / self._cells
        half = int(max(2, min(round(0.3 * cell_px), math.ceil(cell_px / 2) - 1)))
        points = quad.astype(np.float32).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        try:
            refined = cv2.cornerSubPix(gray, points, (half, half), (-1, -1), criteria).reshape(4, 2).astype(float)
        except cv2.error:
            return quad
        # keep a corner only if it moved less than a cell (a run-away corner is worse than none)
        moved = np.linalg.norm(refined - quad, axis=1)
        return np.where((moved < cell_px)[:, None], refined, quad)

    def pose_from_corners(self, corners_px, marker_id: int = 0) -> MarkerPose | None:
        """Pose of one marker from its four image corners (the pose step of :meth:`detect`).

        Parameters
        ----------
        corners_px : array_like, shape (4, 2)
            Corners in ``cv2.aruco``'s order, pixels of the image the tracker sees (raw, or
            rectified when a rectifier is configured).
        marker_id : int

        Returns
        -------
        MarkerPose or None
            None when a corner is not finite, the quad is degenerate (coincident or collinear
            corners), a fisheye corner cannot be undistorted (see ``distortion``) or
            ``solvePnP`` fails. ``corners_px``, ``center_px`` and the reprojection error are in
            the pixels of ``corners_px`` (through the lens, when one is given).

        Raises
        ------
        ValueError
            When ``corners_px`` does not hold exactly four (u, v) corners.
        """
        image_points = np.asarray(corners_px, dtype=float)
        if image_points.size != 8:
            raise ValueError(f"corners_px must hold 4 corners, shape (4, 2), got shape {np.shape(corners_px)}")
        image_points = image_points.reshape(4, 2)
        if not np.all(np.isfinite(image_points)):
            return None
        # coincident or collinear corners (zero area) have no pose; solvePnP would raise or guess
        if _quad_area(image_points) < 1e-6 or min(
            np.linalg.norm(image_points - np.roll(image_points, 1, axis=0), axis=1)
        ) < 1e-6:
            return None
        pnp_points = self._undistort_fisheye(image_points) if self._fisheye else image_points
        if pnp_points is None:
            return None
        best = None
        for R_cam_marker, tvec in self._candidate_poses(pnp_points):
            rvec = cv2.Rodrigues(R_cam_marker)[0]
            if self._fisheye:
                reprojected, _ = cv2.fisheye.projectPoints(
                    self.object_points_m.reshape(-1, 1, 3), rvec, tvec, self._K, self._dist
                )
            else:
                reprojected, _ = cv2.projectPoints(self.object_points_m, rvec, tvec, self._K, self._dist)
            residual = float(np.sqrt(np.mean(np.sum((reprojected.reshape(4, 2) - image_points) ** 2, axis=1))))
            if best is None or residual < best[0]:
                best = (residual, R_cam_marker, rvec, tvec)
            if residual < _POSE_ACCEPT_PX:
                break  # consistent with its corners: the next solve cannot do meaningfully better
        if best is None:
            return None
        residual, R_cam_marker, rvec, tvec = best
        return MarkerPose(
            marker_id=int(marker_id),
            corners_px=image_points,
            rvec=rvec.reshape(3),
            R_cam_marker=R_cam_marker,
            t_cam_marker_m=tvec.reshape(3),
            center_px=image_points.mean(axis=0),
            reprojection_error_px=residual,
        )

    def _undistort_fisheye(self, image_points: np.ndarray) -> np.ndarray | None:
        """Fisheye corners (4, 2), pixels → normalised coordinates (4, 2), or None where they have none."""
        theta_d = np.hypot(*self.intrinsics.to_normalised(image_points).T)
        if np.any(theta_d >= self._max_theta_d):
            return None
        normalised = cv2.fisheye.undistortPoints(image_points.reshape(-1, 1, 2), self._K, self._dist).reshape(4, 2)
        return normalised if np.all(np.isfinite(normalised)) else None

    def _pnp(self, image_points, flags):
        """``solvePnP`` of the marker's object corners: (R, t), or None when it fails or returns NaN."""
        try:
            ok, rvec, tvec = cv2.solvePnP(self.object_points_m, image_points, self._pnp_K, self._pnp_dist, flags=flags)
        except cv2.error:  # a degenerate quad that passed the checks of pose_from_corners
            return None
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            return None
        return cv2.Rodrigues(rvec)[0], tvec.reshape(3, 1)

    def _candidate_poses(self, image_points):
        """Poses to try, best first, computed only as far as they are asked for.

        1. IPPE-square in the frame F (the marker turned by π about x; corners (3, 2, 1, 0)):
           right for an upright marker. Where IPPE returns NaN (an exactly fronto-parallel
           square, seen in the study), Levenberg–Marquardt from a homography start in F.
        2. IPPE-square in the marker frame: right where F's rotation is itself near π (a marker
           turned upside down in its plane).
        3. Levenberg–Marquardt in the marker frame: a marker upside down and square to the
           optical axis, where both frames' rotations are near π.
        """
        flipped = image_points[::-1].copy()
        found = self._pnp(flipped, cv2.SOLVEPNP_IPPE_SQUARE) or self._pnp(flipped, cv2.SOLVEPNP_ITERATIVE)
        if found is not None:
            yield found[0] @ _FLIP_YZ, found[1]
        for flags in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_ITERATIVE):
            found = self._pnp(image_points, flags)
            if found is not None:
                yield found


def _quad_area(corners_px: np.ndarray) -> float:
    return abs(cv2.contourArea(corners_px.astype(np.float32)))
