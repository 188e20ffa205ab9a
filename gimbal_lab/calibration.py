"""Camera calibration files: read exactly, or refused with the reason.

One reader, :func:`load_calibration`, for the two formats cameras come with:

* **OpenCV FileStorage** YAML, XML or JSON, as ``gimbal-lab calibrate`` (:func:`save_calibration`)
  and OpenCV's calibration samples write it: ``image_width``, ``image_height``, ``camera_matrix``
  and ``distortion_coefficients`` as ``!!opencv-matrix`` (rows, cols, dt, data), optionally
  ``distortion_model`` (a string, as ROS) or ``fisheye_model`` (0 or 1, as OpenCV's
  camera-calibration sample writes for a ``cv2.fisheye`` calibration).
* **ROS camera_info** YAML: the same node names with plain ``{rows, cols, data}`` maps and a
  ``distortion_model``.

Rules (each violation is a ValueError naming the file, the node and what is allowed):

* ``distortion_model``: ``plumb_bob``, ``rational_polynomial`` and ``radtan`` are OpenCV's pinhole
  lens (order k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, τx, τy]]]]: 4, 5, 8, 12 or
  14 numbers), read as Brown–Conrady, or as the rational lens (:class:`~gimbal_lab.camera.Rational`)
  when k4, k5, k6 are not all 0; ``equidistant`` (or ``fisheye_model: 1``) is Kannala–Brandt (``cv2.fisheye``:
  exactly k1, k2, k3, k4); any other model is refused by name. Without either node the
  coefficients are OpenCV's pinhole ones (Brown–Conrady), except a list of exactly 4, which is
  refused as ambiguous: OpenCV writes both its pinhole k1, k2, p1, p2 and its fisheye
  k1, k2, k3, k4 as 4 numbers, so the file must say which (``distortion_model`` or
  ``fisheye_model``).
* The lab models k1, k2, p1, p2, k3 and the rational k4–k6: the thin-prism (s1–s4) and tilt
  (τx, τy) terms of 12- and 14-number lists must be exactly 0, else they are refused by name.
* Every entry is a finite number (a quoted string, NaN or inf is refused); ``camera_matrix`` is
  3 × 3 with zero skew, a zero (2, 1) entry, bottom row (0, 0, 1) and fx, fy > 0 (the principal
  point may be anywhere); the image size is two positive integers.
* Each node appears once (a second ``camera_matrix``, or a second ``rows`` inside one, is
  refused); each image side is at most :data:`MAX_IMAGE_SIDE_PX` pixels.
* The lens is invertible over the image: its radial map (r ↦ r·L(r), or θ ↦ θ_d(θ) for a fisheye)
  must rise up to the normalised radius of the image corner farthest from the principal point
  (for a fisheye, whose image circle may leave the corners dark, up to the nearest image edge),
  else two image radii would come from one, and the lens is refused as folding inside the image
  (e.g. k1 = 1e300).
* A missing ``distortion_coefficients`` is refused: the file must say the lens is ideal, by
  all-zero coefficients or by a pinhole ``distortion_model`` with an empty list. An ideal lens
  is read as None.

Notes
-----
Paper §4.1.3 (Fig. 15): the real-camera experiment needs the camera's intrinsics and lens as
calibrated. Layer: like :mod:`gimbal_lab.camera`, this module imports only numpy, OpenCV, the
standard library and :mod:`gimbal_lab.camera`, so the simulation can build a camera from a file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import cv2
import numpy as np

from .camera import LENS_TYPES, BrownConrady, Intrinsics, KannalaBrandt, Rational, UndistortionError, undistort

__all__ = [
    "Calibration",
    "load_calibration",
    "save_calibration",
    "BROWN_CONRADY_MODELS",
    "KANNALA_BRANDT_MODELS",
    "MAX_IMAGE_SIDE_PX",
]

#: ``distortion_model`` names read as OpenCV's pinhole lens: Brown–Conrady, or rational when k4..k6 ≠ 0.
BROWN_CONRADY_MODELS = ("plumb_bob", "rational_polynomial", "radtan")
#: ``distortion_model`` names read as Kannala–Brandt (``cv2.fisheye``).
KANNALA_BRANDT_MODELS = ("equidistant",)

# OpenCV's distortion vector, in order; the lab models the first eight.
_OPENCV_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
_OPENCV_COUNTS = (4, 5, 8, 12, 14)

#: Largest image side a calibration may state, pixels (2^15: beyond any camera's sensor).
MAX_IMAGE_SIDE_PX = 32768


@dataclass(frozen=True)
class Calibration:
    """A camera's intrinsics and lens, with how well they fit the board views.

    Attributes
    ----------
    intrinsics : Intrinsics
        Focal lengths, principal point and image size (pixels).
    distortion : BrownConrady, Rational, KannalaBrandt or None
        The lens; None (or an all-zero Brown–Conrady lens) is the ideal pinhole.
    rms_px : float
        RMS reprojection error over every board corner of every view, pixels (NaN when
        unknown, e.g. read from a ROS file).
    views : int
        Number of board views used (0 when unknown).

    Examples
    --------
    >>> cal = Calibration(Intrinsics.default(), BrownConrady.default(), rms_px=0.2, views=12)
    >>> cal.image_size, cal.lens == BrownConrady.default()
    ((640, 480), True)
    """

    intrinsics: Intrinsics
    distortion: BrownConrady | Rational | KannalaBrandt | None
    rms_px: float = float("nan")
    views: int = 0

    def __post_init__(self):
        if not isinstance(self.intrinsics, Intrinsics):
            raise TypeError(f"intrinsics must be an Intrinsics, got {type(self.intrinsics).__name__}")
        if self.distortion is not None and not isinstance(self.distortion, LENS_TYPES):
            raise TypeError("distortion must be a BrownConrady, a Rational, a KannalaBrandt or None, "
                            f"got {type(self.distortion).__name__}")
        try:
            rms = float(self.rms_px)
        except (TypeError, ValueError):
            raise TypeError(f"rms_px must be a number of pixels, got {self.rms_px!r}") from None
        if not (math.isnan(rms) or (math.isfinite(rms) and rms >= 0)):
            raise ValueError(f"rms_px must be >= 0 px or NaN (unknown), got {self.rms_px!r}")
        object.__setattr__(self, "rms_px", rms)
        if isinstance(self.views, bool) or not isinstance(self.views, (int, np.integer)) or self.views < 0:
            raise ValueError(f"views must be an integer >= 0, got {self.views!r}")
        object.__setattr__(self, "views", int(self.views))

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.intrinsics.size

    @property
    def lens(self) -> BrownConrady | Rational | KannalaBrandt | None:
        """The lens for :mod:`gimbal_lab.camera`'s functions: None for an ideal one."""
        d = self.distortion
        return None if d is None or d.is_identity else d


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def save_calibration(path, calibration: Calibration) -> Path:
    """Write a calibration as OpenCV FileStorage (YAML for .yml/.yaml, XML for .xml, JSON for .json).

    Nodes: ``image_width``, ``image_height``, ``camera_matrix`` (3 × 3), ``distortion_model``
    (``plumb_bob``, ``rational_polynomial`` for a rational lens, or ``equidistant`` for a
    Kannala–Brandt lens), ``distortion_coefficients`` (5 × 1 Brown–Conrady, all zero for an ideal
    lens; 8 × 1 rational; 4 × 1 Kannala–Brandt),
    ``avg_reprojection_error`` (px, .Nan when unknown), ``views``, and ``max_field_rad`` for a
    fisheye whose field limit is not the one its coefficients imply. Numbers are written with 17
    significant digits, so :func:`load_calibration` gives back the same doubles.

    Returns
    -------
    Path
        The file written (its folder is created).
    """
    if not isinstance(calibration, Calibration):
        raise TypeError(f"calibration must be a Calibration, got {type(calibration).__name__}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lens = calibration.distortion if calibration.distortion is not None else BrownConrady()
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise ValueError(f"cannot write a calibration to {str(path)!r}")
    try:
        cam = calibration.intrinsics
        fs.write("image_width", cam.width)
        fs.write("image_height", cam.height)
        fs.write("camera_matrix", cam.K)
        model = {KannalaBrandt: "equidistant", Rational: "rational_polynomial"}.get(type(lens), "plumb_bob")
        fs.write("distortion_model", model)
        fs.write("distortion_coefficients", lens.coefficients.reshape(-1, 1))
        if isinstance(lens, KannalaBrandt) and lens.max_field_rad != KannalaBrandt(*lens.coefficients).max_field_rad:
            fs.write("max_field_rad", float(lens.max_field_rad))
        fs.write("avg_reprojection_error", float(calibration.rms_px))
        fs.write("views", int(calibration.views))
    finally:
        fs.release()
    return path


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


class _File:
    """An opened calibration file: nodes by name, and errors that name the file and the node."""

    def __init__(self, path: Path):
        self.path = path
        text = path.read_text(errors="replace")
        head = text.lstrip()
        if not head.startswith(("<", "{", "%YAML")):
            text = "%YAML:1.0\n" + text  # ROS files carry no directive; FileStorage wants one
        try:
            self.fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except (cv2.error, SystemError) as exc:  # the binding raises SystemError on some parse errors
            reason = exc.err if isinstance(exc, cv2.error) else "parse error"
            raise ValueError(f"{str(path)!r} is not a readable YAML/XML/JSON calibration: {reason}") from None
        if not self.fs.isOpened() or not self.fs.root().isMap():
            self.fs.release()
            raise ValueError(f"{str(path)!r} is not a calibration: expected a map of named nodes at the top level")
        try:
            self.once(self.fs.root(), "")
        except ValueError:
            self.fs.release()
            raise

    def once(self, node, prefix: str) -> None:
        """Refuse a map in which a name appears twice (FileStorage would read the first silently)."""
        seen = set()
        for name in node.keys():
            if name in seen:
                self.fail(prefix + name, "appears twice", "each node once")
            seen.add(name)

    def fail(self, node: str, problem: str, allowed: str) -> NoReturn:
        raise ValueError(f"{str(self.path)!r}: {node}: {problem}; allowed: {allowed}")

    def node(self, name: str):
        """The node ``name``, or None when the file has none (or an empty one)."""
        node = self.fs.getNode(name)
        return None if node.empty() or node.isNone() else node

    def number(self, node, where: str, allowed: str = "a finite number") -> float:
        if not (node.isInt() or node.isReal()):
            shown = repr(node.string()) if node.isString() else "not a number"
            self.fail(where, f"{shown} is not a number", allowed)
        value = node.real()
        if not math.isfinite(value):
            self.fail(where, f"{value} is not finite", allowed)
        return value

    def integer(self, name: str, allowed: str, node=None) -> int | None:
        """The integer at top-level node ``name`` (or at ``node``, reported as ``name``); None if missing."""
        node = self.node(name) if node is None else node
        if node is None or node.empty() or node.isNone():
            return None
        value = self.number(node, name, allowed)
        if not value.is_integer():
            self.fail(name, f"{value!r} is not an integer", allowed)
        return int(value)

    def matrix(self, name: str) -> tuple[np.ndarray, tuple[int, int] | None] | None:
        """Entries of a matrix node (an opencv-matrix or ROS {rows, cols, data} map, or a flat
        list) and its (rows, cols) when stated; None when the node is missing."""
        node = self.node(name)
        if node is None:
            return None
        shape = None
        if node.isMap():
            self.once(node, f"{name}/")
            data = node.getNode("data")
            if data.empty() or not (data.isSeq() or data.isNone()):
                self.fail(name, "the map has no data list", "rows, cols and data: [numbers]")
            rows, cols = (self.integer(f"{name}/{key}", "an integer >= 0", node.getNode(key)) for key in ("rows", "cols"))
            if (rows is None) != (cols is None) or (rows is not None and (rows < 0 or cols < 0)):
                self.fail(name, f"rows = {rows}, cols = {cols}", "both rows and cols as integers >= 0, or neither")
            shape = None if rows is None else (rows, cols)
            node = data
        elif not node.isSeq():
            self.fail(name, "is neither a matrix nor a list", "a matrix (rows, cols, data) or a list of numbers")
        count = 0 if node.isNone() else node.size()
        values = np.array([self.number(node.at(i), f"{name} entry {i}") for i in range(count)], dtype=float)
        if shape is not None and shape[0] * shape[1] != count:
            self.fail(name, f"rows x cols = {shape[0]} x {shape[1]} but data holds {count} numbers",
                      "data with rows x cols numbers")
        return values, shape


def _camera_matrix(f: _File) -> np.ndarray:
    read = f.matrix("camera_matrix")
    if read is None:
        f.fail("camera_matrix", "missing", "a 3 x 3 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    values, shape = read
    if values.size != 9 or (shape is not None and shape != (3, 3)):
        f.fail("camera_matrix", f"{shape[0]} x {shape[1]}" if shape else f"{values.size} numbers",
               "3 x 3 (9 numbers)")
    K = values.reshape(3, 3)
    if K[0, 1] != 0:
        f.fail("camera_matrix", f"skew K[0][1] = {float(K[0, 1])!r}", "0 (the lab's camera model has no skew)")
    if K[1, 0] != 0:
        f.fail("camera_matrix", f"K[1][0] = {float(K[1, 0])!r}", "0")
    if tuple(K[2]) != (0.0, 0.0, 1.0):
        f.fail("camera_matrix", f"bottom row {tuple(float(v) for v in K[2])}", "(0, 0, 1)")
    for name, value in (("fx = K[0][0]", K[0, 0]), ("fy = K[1][1]", K[1, 1])):
        if not value > 0:
            f.fail("camera_matrix", f"{name} = {float(value)!r}", "a focal length > 0 px")
    return K


def _image_size(f: _File, image_size) -> tuple[int, int]:
    allowed = "a positive integer number of pixels"
    width, height = f.integer("image_width", allowed), f.integer("image_height", allowed)
    for name, value in (("image_width", width), ("image_height", height)):
        if value is not None and value <= 0:
            f.fail(name, f"{value}", allowed)
        if value is not None and value > MAX_IMAGE_SIDE_PX:
            f.fail(name, f"{value} px", f"at most {MAX_IMAGE_SIDE_PX} px")
    if (width is None) != (height is None):
        f.fail("image_width" if width is None else "image_height", "missing", "both image_width and image_height")
    if image_size is not None:
        given = tuple(image_size) if isinstance(image_size, (tuple, list)) else ()
        if len(given) != 2 or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0 for v in given):
            raise ValueError(f"image_size must be (width, height) in positive whole pixels, got {image_size!r}")
        given = (int(given[0]), int(given[1]))
        if width is not None and (width, height) != given:
            f.fail("image_width/image_height", f"{width}x{height} px, but image_size = {given[0]}x{given[1]} was given",
                   "the same size, or omit image_size")
        return given
    if width is None:
        f.fail("image_width/image_height", "missing",
               "both nodes (positive integers), or the image_size argument for a file that has none")
    return width, height


def _model(f: _File) -> str | None:
    """'brown_conrady', 'kannala_brandt', or None when the file names no model."""
    node = f.node("distortion_model")
    named = None
    if node is not None:
        if not node.isString():
            f.fail("distortion_model", "is not a string",
                   ", ".join(BROWN_CONRADY_MODELS + KANNALA_BRANDT_MODELS))
        named = node.string().strip()
        if named in BROWN_CONRADY_MODELS:
            named = "brown_conrady"
        elif named in KANNALA_BRANDT_MODELS:
            named = "kannala_brandt"
        else:
            f.fail("distortion_model", f"{named!r} is not a lens model the lab has",
                   f"{', '.join(BROWN_CONRADY_MODELS)} (Brown–Conrady) or {', '.join(KANNALA_BRANDT_MODELS)} "
                   "(Kannala–Brandt)")
    fisheye = f.integer("fisheye_model", "0 (pinhole lens) or 1 (cv2.fisheye lens)")
    if fisheye is not None and fisheye not in (0, 1):
        f.fail("fisheye_model", f"{fisheye}", "0 (pinhole lens) or 1 (cv2.fisheye lens)")
    if fisheye is not None:
        flagged = "kannala_brandt" if fisheye else "brown_conrady"
        if named is not None and named != flagged:
            f.fail("fisheye_model", f"{fisheye} contradicts distortion_model {node.string().strip()!r}",
                   "a fisheye_model that agrees with distortion_model")
        named = flagged
    return named


def _lens(f: _File) -> BrownConrady | Rational | KannalaBrandt | None:
    model = _model(f)
    read = f.matrix("distortion_coefficients")
    if read is None:
        f.fail("distortion_coefficients", "missing (a missing lens is not read as an ideal one)",
               "the coefficients; for an ideal lens all zeros, or a pinhole distortion_model with an empty list")
    values, shape = read
    if shape is not None and values.size and 1 not in shape:
        f.fail("distortion_coefficients", f"a {shape[0]} x {shape[1]} matrix", "a row or column of numbers")
    if model == "kannala_brandt":
        if values.size != 4:
            f.fail("distortion_coefficients", f"{values.size} numbers for a Kannala–Brandt (equidistant) lens",
                   "exactly 4: k1, k2, k3, k4 (cv2.fisheye)")
        field = f.node("max_field_rad")
        kwargs = {} if field is None else {"max_field_rad": f.number(field, "max_field_rad", "an angle in (0, pi] rad")}
        try:
            return KannalaBrandt(*values, **kwargs)
        except ValueError as exc:
            f.fail("distortion_coefficients" if field is None else "max_field_rad", str(exc), "a lens whose θ_d(θ) rises")
    if values.size == 0:
        if model is None:
            f.fail("distortion_coefficients", "an empty list with no distortion_model says nothing about the lens",
                   "all-zero coefficients, or distortion_model: plumb_bob with the empty list, for an ideal lens")
        return None
    if values.size == 4 and model is None:
        f.fail("distortion_coefficients", "4 numbers with no distortion_model or fisheye_model: they may be "
               "Brown–Conrady k1, k2, p1, p2 (OpenCV's pinhole lens) or Kannala–Brandt k1, k2, k3, k4 "
               "(OpenCV's fisheye lens), which project differently",
               "a node saying which: distortion_model: plumb_bob (or fisheye_model: 0) for Brown–Conrady, "
               "distortion_model: equidistant (or fisheye_model: 1) for Kannala–Brandt")
    if values.size not in _OPENCV_COUNTS:
        f.fail("distortion_coefficients", f"{values.size} numbers",
               "4, 5, 8, 12 or 14 (OpenCV's k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tau_x, tau_y]]]])")
    extra = {name: float(v) for name, v in zip(_OPENCV_NAMES[8:], values[8:]) if v != 0}
    if extra:
        shown = ", ".join(f"{name} = {v!r}" for name, v in extra.items())
        f.fail("distortion_coefficients", f"{shown} not zero",
               "k1, k2, p1, p2, k3 (Brown–Conrady) and k4, k5, k6 (rational); OpenCV's thin-prism s1-s4 "
               "and tilt tau_x, tau_y terms must be exactly 0")
    named = dict(zip(_OPENCV_NAMES[:8], np.concatenate((values[:8], np.zeros(8 - min(values.size, 8))))))
    try:
        if any(named[k] != 0 for k in ("k4", "k5", "k6")):
            lens = Rational(**named)
        else:
            lens = BrownConrady(**{k: named[k] for k in ("k1", "k2", "p1", "p2", "k3")})
    except ValueError as exc:
        f.fail("distortion_coefficients", str(exc), "coefficients whose fold radius is computable")
    return None if lens.is_identity else lens


def _fold_inside_image(intrinsics: Intrinsics, lens) -> str | None:
    """Why ``lens`` is not invertible over the image of ``intrinsics``, or None when it is.

    A pinhole lens's radial map r ↦ r·L(r) rises from 0 to its fold radius
    (:meth:`BrownConrady.radial_limit`), where it reaches distorted radius r_max; every pixel
    needs a preimage there, so the image corner farthest from the principal point, at normalised
    radius ((u − cx)/fx, (v − cy)/fy) with the image spanning −0.5 … W − 0.5 px, must lie below
    r_max. A fisheye's θ_d(θ) rises up to its field limit; its image circle may leave the corners
    dark, so only a fold nearer than the nearest image edge is refused.
    """
    if lens is None:
        return None
    cam = intrinsics
    us, vs = (-0.5 - cam.cx, cam.width - 0.5 - cam.cx), (-0.5 - cam.cy, cam.height - 0.5 - cam.cy)
    if isinstance(lens, KannalaBrandt):
        edges = [abs(u) / cam.fx for u in us] + [abs(v) / cam.fy for v in vs]
        inside = (us[0] < 0 < us[1]) and (vs[0] < 0 < vs[1])
        reach = min(edges) if inside else 0.0
        field = KannalaBrandt(*lens.coefficients).max_field_rad  # where θ_d(θ) stops rising, or π
        top = float(lens.theta_d(field))
        if field < math.pi and top < reach:
            return (f"the fisheye's θ_d(θ) stops rising at {math.degrees(field):.4g}° off the axis, at normalised "
                    f"radius {top:.6g}, inside the image (its nearest edge lies at {reach:.6g})")
        return None
    corner = max(math.hypot(u / cam.fx, v / cam.fy) for u in us for v in vs)
    r_fold = lens.radial_limit()
    top = lens.disc_image()
    if top <= corner:
        return (f"the lens folds inside the image: its radial map stops rising at undistorted radius {r_fold:.6g}, "
                f"distorted radius {top:.6g}, but the image corner lies at distorted radius {corner:.6g} "
                "(normalised)")
    # rising in exact arithmetic is not enough: the inverse must be computable in doubles
    border = np.array([(u, v) for u in (*us, 0.5 * (us[0] + us[1])) for v in (*vs, 0.5 * (vs[0] + vs[1]))])
    xy_d = border / (cam.fx, cam.fy)
    try:
        with np.errstate(all="ignore"):
            xy = undistort(xy_d, lens)
    except UndistortionError:
        xy = np.full_like(xy_d, np.nan)
    if not np.all(np.isfinite(xy)):
        return ("the lens cannot be inverted over the image in double precision (its image corners and edges "
                "have no computable undistorted position)")
    return None


def _optional_number(f: _File, name: str, allowed: str) -> float | None:
    node = f.node(name)
    if node is None:
        return None
    if node.isReal() and math.isnan(node.real()):
        return math.nan
    return f.number(node, name, allowed)


def load_calibration(path, image_size: tuple[int, int] | None = None) -> Calibration:
    """Read a calibration exactly, or refuse it (rules: module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        OpenCV FileStorage YAML/XML/JSON or ROS camera_info YAML.
    image_size : (int, int), optional
        (width, height) in pixels, for a file that states none (as OpenCV's ArUco samples);
        when the file states one, it must agree.

    Returns
    -------
    Calibration
        ``distortion`` is a BrownConrady, a KannalaBrandt, or None for an ideal lens;
        ``rms_px`` is NaN and ``views`` 0 when the file does not say.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Naming the file, the node and what is allowed (module docstring).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such calibration file: {str(path)!r}")
    f = _File(path)
    try:
        K = _camera_matrix(f)
        width, height = _image_size(f, image_size)
        lens = _lens(f)
        rms = _optional_number(f, "avg_reprojection_error", "an RMS error >= 0 px, or .Nan")
        if rms is not None and rms < 0:
            f.fail("avg_reprojection_error", f"{rms}", "an RMS error >= 0 px, or .Nan")
        views = f.integer("views", "an integer >= 0")
        if views is not None and views < 0:
            f.fail("views", f"{views}", "an integer >= 0")
        intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height)
        fold = _fold_inside_image(intrinsics, lens)
        if fold is not None:
            f.fail("distortion_coefficients", fold,
                   "a lens invertible over the image (a radial map that rises out to the image's edges)")
        return Calibration(intrinsics, lens, math.nan if rms is None else rms, views or 0)
    finally:
        f.fs.release()
