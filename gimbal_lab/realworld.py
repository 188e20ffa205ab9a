"""Real cameras (paper §4.1.3, Fig. 15): calibration, tracking on recordings, and photo-like test data.

Three parts:

* **Photo-like frames with known truth.** :class:`PlanarTargetCamera` images a flat printed
  target (an ArUco marker, a chessboard, a ChArUco board) through a Brown–Conrady camera by
  sampling every (supersampled) pixel's ray on the target's plane, and :class:`PhotoEffects`
  adds what a real camera adds: paper and ink that are not white and black, uneven light,
  vignetting, defocus, sensor noise and JPEG compression. The true corner positions are the
  target's 3-D corners projected with ``cv2.projectPoints``, so they are known exactly.
* **Calibration.** :func:`calibrate` finds a chessboard or ChArUco board in a sequence of
  frames and runs ``cv2.calibrateCamera``; :func:`save_calibration` writes OpenCV FileStorage
  YAML, :func:`load_calibration` reads that or a ROS ``camera_info`` YAML (both live in
  :mod:`gimbal_lab.calibration`, with the reader's rules).
* **Tracking.** :func:`track` runs the sphere detector or the ArUco tracker over a video file,
  an image folder or a camera index and writes an annotated MP4 and a per-frame CSV.

The command-line front ends are ``gimbal-lab calibrate`` and ``gimbal-lab track``
(:mod:`gimbal_lab.realworld_cli`).
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import queue
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .calibration import Calibration, load_calibration, save_calibration
from .camera import BrownConrady, Intrinsics, KannalaBrandt, Rational, project, undistort
from .scene import linear_to_srgb

__all__ = [
    "Calibration",
    "calibrate",
    "save_calibration",
    "load_calibration",
    "open_frames",
    "track",
    "MAX_FRAME_PIXELS",
    "sphere_photo",
    "PhotoEffects",
    "PlanarTargetCamera",
    "printed_marker_texture",
    "board_texture",
    "board_views",
    "write_video",
    "find_board",
    "charuco_board",
    "FrameSource",
    "TRACK_COLUMNS",
    "look_at_pose",
]


# --------------------------------------------------------------------------------------------
# Photo-like frames of planar targets, with known truth
# --------------------------------------------------------------------------------------------


def look_at_pose(camera_position_m, target_m=(0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """``T_cam_plane``: a camera at ``camera_position_m`` (plane frame) looking at ``target_m``.

    The plane frame has the target in its z = 0 plane; the camera's optical frame is OpenCV's
    (x right, y down, z forward). ``up`` is the plane-frame direction that should appear up in
    the image (−y of the camera).

    Returns
    -------
    ndarray, shape (4, 4)
        Transform mapping plane-frame points (metres) to the camera frame.
    """
    eye = np.asarray(camera_position_m, float)
    z = np.asarray(target_m, float) - eye
    if not np.linalg.norm(z) > 0:
        raise ValueError("camera_position_m must differ from target_m")
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, float), z)  # right = down × forward (x = y × z)
    if not np.linalg.norm(x) > 1e-9:
        raise ValueError("up must not be parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_plane_cam = np.column_stack((x, y, z))
    T = np.eye(4)
    T[:3, :3] = R_plane_cam.T
    T[:3, 3] = -R_plane_cam.T @ eye
    return T


def printed_marker_texture(
    dictionary: str = "DICT_4X4_50",
    marker_id: int = 0,
    cell_px: int = 40,
    margin_cells: float = 1.0,
) -> tuple[np.ndarray, float]:
    """An ArUco marker on white paper, as a grey texture (uint8; ink 0, paper 255).

    Parameters
    ----------
    dictionary : str
        Name of a predefined ``cv2.aruco`` dictionary.
    marker_id : int
    cell_px : int
        Texture pixels per marker cell (bit).
    margin_cells : float
        White margin around the black border, in cells.

    Returns
    -------
    texture : ndarray, shape (S, S), uint8
    marker_px : float
        Side of the black square in texture pixels (its outer edges lie at texture coordinates
        m − 0.5 and m − 0.5 + marker_px with m the margin in pixels, pixel centres integer).
    """
    aruco_dict = cv2.aruco.getPredefinedDictionary(_dictionary_id(dictionary))
    cells = aruco_dict.markerSize + 2
    marker_px = cells * int(cell_px)
    marker = cv2.aruco.generateImageMarker(aruco_dict, int(marker_id), marker_px)
    margin = int(round(margin_cells * cell_px))
    texture = np.full((marker_px + 2 * margin,) * 2, 255, np.uint8)
    texture[margin : margin + marker_px, margin : margin + marker_px] = marker
    return texture, float(marker_px)


def board_texture(board, px_per_m: float = 4000.0) -> np.ndarray:
    """The printed image of a ``cv2.aruco`` board (``CharucoBoard``) or a chessboard.

    Parameters
    ----------
    board : cv2.aruco.CharucoBoard or tuple (squares_x, squares_y, square_m)
        A ChArUco board, or a chessboard given by its number of squares and square side.
    px_per_m : float
        Texture resolution.

    Returns
    -------
    ndarray, shape (H, W), uint8
        Texture coordinate (−0.5, −0.5) is plane point (0, 0), x along the board's x axis. A
        ChArUco board has no margin; a chessboard has a white margin one square wide (the
        detector needs a quiet zone), so it spans (squares + 2) × square_m.
    """
    if isinstance(board, tuple):
        squares_x, squares_y, square_m = board
        cell = int(round(square_m * px_per_m))
        yy, xx = np.mgrid[0 : (squares_y + 2) * cell, 0 : (squares_x + 2) * cell]
        inside = (xx >= cell) & (xx < (squares_x + 1) * cell) & (yy >= cell) & (yy < (squares_y + 1) * cell)
        return np.where(inside & (((xx // cell) + (yy // cell)) % 2 == 0), 0, 255).astype(np.uint8)
    squares_x, squares_y = board.getChessboardSize()
    square_m = board.getSquareLength()
    size = (int(round(squares_x * square_m * px_per_m)), int(round(squares_y * square_m * px_per_m)))
    return board.generateImage(size, marginSize=0, borderBits=1)


@dataclass(frozen=True)
class PhotoEffects:
    """What a real camera does to a printed target: light, lens blur, noise, compression.

    Applied in this order to a linear-light image in [0, 1]: paper/ink levels (the texture's
    0 and 1 become ``ink`` and ``paper`` reflectance), a smooth random illumination field
    (relative amplitude ``uneven_light``), vignetting 1 − ``vignetting``·(r/r_corner)², a
    Gaussian defocus of ``defocus_px`` (σ, pixels), Gaussian sensor noise ``noise_std``
    (grey levels, added after sRGB encoding), then JPEG at ``jpeg_quality`` (0 = no JPEG).

    Parameters
    ----------
    paper, ink : float
        Linear reflectance of the paper and the ink (0 ≤ ink < paper ≤ 1).
    uneven_light : float
        Peak-to-mean amplitude of the illumination field, 0–0.9.
    vignetting : float
        Light lost in the image corners, 0–0.9.
    defocus_px : float
        σ of the Gaussian blur, pixels (≥ 0).
    noise_std : float
        Sensor noise, grey levels (≥ 0).
    jpeg_quality : int
        JPEG quality 1–100, or 0 for none.
    """

    paper: float = 0.75
    ink: float = 0.03
    uneven_light: float = 0.4
    vignetting: float = 0.35
    defocus_px: float = 0.7
    noise_std: float = 3.0
    jpeg_quality: int = 50

    def __post_init__(self):
        if not (0.0 <= self.ink < self.paper <= 1.0):
            raise ValueError(f"need 0 <= ink < paper <= 1, got ink={self.ink}, paper={self.paper}")
        for name in ("uneven_light", "vignetting"):
            value = getattr(self, name)
            if not (0.0 <= value <= 0.9):
                raise ValueError(f"{name} must lie in [0, 0.9], got {value}")
        for name in ("defocus_px", "noise_std"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if not (isinstance(self.jpeg_quality, (int, np.integer)) and 0 <= self.jpeg_quality <= 100):
            raise ValueError(f"jpeg_quality must be an integer in 0..100 (0: none), got {self.jpeg_quality!r}")

    def apply(self, reflectance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Turn a reflectance image (float, [0, 1], shape (H, W) or (H, W, 3)) into an RGB photo (uint8)."""
        image = np.asarray(reflectance, np.float32)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        height, width = image.shape[:2]
        image = self.ink + (self.paper - self.ink) * image
        light = np.ones((height, width), np.float32)
        if self.uneven_light > 0:
            coarse = rng.normal(size=(4, 5)).astype(np.float32)
            field = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
            field /= max(float(np.abs(field).max()), 1e-6)
            light *= 1.0 + self.uneven_light * field
        if self.vignetting > 0:
            yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
            r2 = ((xx - (width - 1) / 2) ** 2 + (yy - (height - 1) / 2) ** 2) / (((width - 1) / 2) ** 2 + ((height - 1) / 2) ** 2)
            light *= 1.0 - self.vignetting * r2
        image = image * np.clip(light, 0.0, None)[:, :, None]
        if self.defocus_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.defocus_px)
        encoded = linear_to_srgb(np.clip(image, 0.0, 1.0)) * 255.0
        if self.noise_std > 0:
            encoded = encoded + rng.normal(0.0, self.noise_std, encoded.shape)
        rgb = np.clip(np.rint(encoded), 0, 255).astype(np.uint8)
        if self.jpeg_quality:
            ok, buffer = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(self.jpeg_quality)])
            rgb = cv2.imdecode(buffer, cv2.IMREAD_COLOR)[..., ::-1].copy()
        return rgb


class PlanarTargetCamera:
    """Image a flat textured target through a pinhole, Brown–Conrady or rational camera, exactly.

    Every output pixel is split into ``supersample``² sub-pixels; each sub-pixel centre is
    undistorted once (the rays are fixed by the camera, computed at construction) and, per frame,
    carried to the target plane by the plane's homography and looked up in the texture
    (bilinear). The sub-pixels are averaged (area filter), which anti-aliases edges. Points on the
    plane then appear where ``cv2.projectPoints`` puts them: use it for the truth.

    Parameters
    ----------
    intrinsics : Intrinsics
    distortion : BrownConrady or Rational, optional
    supersample : int
        Sub-pixels per pixel side (1–8).

    Notes
    -----
    Pixel centres are integer coordinates (OpenCV); sub-pixel (i, j) of the supersampled grid
    sits at ((j + 0.5)/s − 0.5, (i + 0.5)/s − 0.5) in output pixels.
    """

    def __init__(self, intrinsics: Intrinsics, distortion: BrownConrady | Rational | None = None,
                 supersample: int = 3):
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        if distortion is not None and not isinstance(distortion, (BrownConrady, Rational)):
            raise TypeError(f"distortion must be a BrownConrady, a Rational or None, got {type(distortion).__name__}")
        if isinstance(supersample, bool) or int(supersample) != supersample or not 1 <= supersample <= 8:
            raise ValueError(f"supersample must be an integer in 1..8, got {supersample!r}")
        self.intrinsics, self.distortion, self.supersample = intrinsics, distortion, int(supersample)
        s = self.supersample
        width, height = intrinsics.width * s, intrinsics.height * s
        jj, ii = np.meshgrid((np.arange(width) + 0.5) / s - 0.5, (np.arange(height) + 0.5) / s - 0.5)
        normalised = undistort(intrinsics.to_normalised(np.column_stack((jj.ravel(), ii.ravel()))), distortion)
        self._rays = np.concatenate(
            (normalised.reshape(height, width, 2), np.ones((height, width, 1))), axis=2
        ).astype(np.float64)

    def render(self, texture: np.ndarray, px_per_m: float, T_cam_plane, background: np.ndarray | None = None) -> np.ndarray:
        """Reflectance image (float32 in [0, 1], shape (H, W)) of ``texture`` lying on a plane.

        Parameters
        ----------
        texture : ndarray, shape (h, w), uint8
            The print; texture pixel (x, y) (pixel centre) lies at plane point
            ((x + 0.5)/px_per_m, (y + 0.5)/px_per_m, 0) metres.
        px_per_m : float
            Texture resolution.
        T_cam_plane : ndarray, shape (4, 4)
            Plane frame → camera optical frame.
        background : ndarray, shape (H, W), float, optional
            Reflectance where rays miss the print or the plane is behind the camera (default 0.5).
        """
        T = np.asarray(T_cam_plane, float)
        s = self.supersample
        # plane point (a, b, 0) ↦ camera ray (up to scale) = [r1 r2 t] (a, b, 1)ᵀ
        H = np.column_stack((T[:3, 0], T[:3, 1], T[:3, 3]))
        plane = self._rays @ np.linalg.inv(H).T
        w = plane[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            map_x = (plane[..., 0] / w * px_per_m - 0.5).astype(np.float32)
            map_y = (plane[..., 1] / w * px_per_m - 0.5).astype(np.float32)
        ahead = self._plane_ahead(T)
        map_x[~ahead] = -1e6
        map_y[~ahead] = -1e6
        tex = texture.astype(np.float32) / 255.0
        sampled = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        height, width = self.intrinsics.height, self.intrinsics.width
        if background is None:
            background_hi = np.full(sampled.shape, 0.5, np.float32)
        else:
            background_hi = cv2.resize(np.asarray(background, np.float32), (width * s, height * s), interpolation=cv2.INTER_NEAREST)
        # the texture's own border pixels blend with the constant outside: treat < 0 as "off the print"
        off = sampled < 0
        sampled[off] = background_hi[off]
        if s > 1:
            sampled = cv2.resize(sampled, (width, height), interpolation=cv2.INTER_AREA)
        return sampled

    def _plane_ahead(self, T: np.ndarray) -> np.ndarray:
        """Mask of sub-pixels whose ray meets the plane at positive depth."""
        normal, origin = T[:3, 2], T[:3, 3]
        # ray X = λ r hits the plane n·(X − o) = 0 at λ = n·o / n·r
        denom = self._rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (normal @ origin) / denom
        return np.isfinite(lam) & (lam > 0)

    def corners_px(self, points_plane_m, T_cam_plane) -> np.ndarray:
        """Project plane-frame points (N, 2) or (N, 3), metres, to pixels with ``cv2.projectPoints``."""
        pts = np.asarray(points_plane_m, float)
        if pts.shape[-1] == 2:
            pts = np.column_stack((pts, np.zeros(len(pts))))
        T = np.asarray(T_cam_plane, float)
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        dist = self.distortion.coefficients if self.distortion is not None else None
        return cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, T[:3, 3], self.intrinsics.K, dist)[0].reshape(-1, 2)


def _dictionary_id(dictionary) -> int:
    if isinstance(dictionary, str):
        if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
            raise ValueError(f"dictionary must name a cv2.aruco predefined dictionary, got {dictionary!r}")
        return int(getattr(cv2.aruco, dictionary))
    return int(dictionary)


def sphere_photo(
    intrinsics: Intrinsics,
    center_cam_m,
    radius_m: float,
    background,
    colour=(0.6, 0.02, 0.02),
    light_dir=(0.3, -0.8, -0.5),
    ambient: float = 0.25,
    supersample: int = 4,
) -> np.ndarray:
    """Linear-light image (float32, (H, W, 3)) of a matte sphere in front of a background image.

    Each sub-pixel ray is intersected with the sphere analytically; a hit is shaded
    ``colour`` × (``ambient`` + (1 − ambient)·max(0, n·l)) with n the surface normal and l the
    unit direction towards the light (camera frame), so the side away from the light is dark,
    as a real ball's underside is. ``supersample``² sub-pixels are averaged per pixel, so rim
    pixels mix ball and background by their coverage. Pass the result through
    :meth:`PhotoEffects.apply` (it expects linear light when given an (H, W, 3) image whose
    reflectances are already final: set ``paper=1, ink=0``).

    Parameters
    ----------
    intrinsics : Intrinsics
    center_cam_m : array_like, shape (3,)
        Sphere centre in the camera optical frame, metres.
    radius_m : float
    background : ndarray, shape (H, W, 3) or (3,)
        Linear RGB of the background (an image, or one colour).
    colour : (3,) floats
        Linear albedo of the ball.
    light_dir : (3,) floats
        Direction towards the light, camera frame.
    ambient : float
        Share of light reaching every point (0–1).
    supersample : int
        Sub-pixels per pixel side.
    """
    s = int(supersample)
    width, height = intrinsics.width, intrinsics.height
    c = np.asarray(center_cam_m, float)
    # Only sub-pixels whose rays can reach the ball are cast: those inside the image of the cube
    # around it (a perspective image of a convex body lies inside that of any convex body holding
    # it), with a pixel's margin; all of them when a corner of the cube is not in front of the camera.
    rows, cols = slice(0, height * s), slice(0, width * s)
    corners = c + radius_m * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    if np.all(corners[:, 2] > 0):
        u = intrinsics.cx + intrinsics.fx * corners[:, 0] / corners[:, 2]
        v = intrinsics.cy + intrinsics.fy * corners[:, 1] / corners[:, 2]
        # sub-pixel k of a row sits at (k + 0.5) / s − 0.5 px
        first = lambda low, n: int(np.clip(math.floor((low - 1.0 + 0.5) * s), 0, n * s))  # noqa: E731
        last = lambda high, n: int(np.clip(math.ceil((high + 1.0 + 0.5) * s), 0, n * s))  # noqa: E731
        rows, cols = slice(first(v.min(), height), last(v.max(), height)), slice(first(u.min(), width), last(u.max(), width))
    jj, ii = np.meshgrid(((np.arange(width * s) + 0.5) / s - 0.5)[cols], ((np.arange(height * s) + 0.5) / s - 0.5)[rows])
    rays = np.stack(((jj - intrinsics.cx) / intrinsics.fx, (ii - intrinsics.cy) / intrinsics.fy, np.ones_like(jj)), -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    b = rays @ c
    disc = b**2 - (c @ c - radius_m**2)
    hit = disc > 0
    lam = np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), 0.0)
    normal = (rays * lam[..., None] - c) / radius_m
    light = np.asarray(light_dir, float)
    light /= np.linalg.norm(light)
    shade = ambient + (1 - ambient) * np.clip(normal @ light, 0.0, None)
    bg = np.asarray(background, np.float32)
    if bg.ndim == 1:
        bg = np.broadcast_to(bg, (height, width, 3))
    bg_hi = cv2.resize(np.ascontiguousarray(bg, np.float32), (width * s, height * s), interpolation=cv2.INTER_NEAREST)
    ball = shade[..., None] * np.asarray(colour, np.float32)
    image = bg_hi.copy()
    image[rows, cols] = np.where(hit[..., None], ball, bg_hi[rows, cols])
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)



# --------------------------------------------------------------------------------------------
# Frame sources: a video file, a folder of images, a camera index
# --------------------------------------------------------------------------------------------

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: The largest frame :func:`open_frames` gives, in pixels: 40 megapixels (a 7,300 × 5,500 photo; a
#: 4K video frame is 8.3). A larger image or video is refused
#: from its header, before a pixel is decoded: calibrating one 20,000 × 20,000 image (400
#: megapixels) took 21.5 GB, about 54 bytes per pixel: at that rate a 40-megapixel frame takes about
#: 2 GB (extrapolated, not measured).
MAX_FRAME_PIXELS = 40_000_000


def _check_frame_size(width: int, height: int, name: str) -> None:
    """ValueError naming ``name`` when a ``width`` × ``height`` frame exceeds :data:`MAX_FRAME_PIXELS`."""
    if width * height > MAX_FRAME_PIXELS:
        raise ValueError(f"{name} is {width}x{height} px ({width * height / 1e6:.0f} megapixels), more than the "
                         f"{MAX_FRAME_PIXELS / 1e6:.0f} megapixels gimbal-lab reads: scale it down first (a "
                         f"calibration is for one image size: calibrate and track at the same size)")


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from an image file's header, read by Pillow without decoding the pixels;
    None if Pillow does not know the file. An image too large for Pillow's own limit is refused."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                return image.size
    except Image.DecompressionBombError:
        raise ValueError(f"{str(path)!r} has more than {2 * Image.MAX_IMAGE_PIXELS / 1e6:.0f} megapixels, more than the "
                         f"{MAX_FRAME_PIXELS / 1e6:.0f} megapixels gimbal-lab reads: scale it down first") from None
    except (UnidentifiedImageError, OSError, ValueError):
        return None


def _read_image(path: Path) -> np.ndarray:
    """An image file as RGB uint8, its size checked from the header first."""
    size = _image_size(path)
    if size is not None:
        _check_frame_size(*size, f"image {str(path)!r}")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"cannot read image {str(path)!r}")
    _check_frame_size(image.shape[1], image.shape[0], f"image {str(path)!r}")
    return image[..., ::-1].copy()


@dataclass
class FrameSource:
    """An opened source of RGB frames (see :func:`open_frames`).

    Attributes
    ----------
    name : str
    fps : float
        Frame rate of a video or camera (30 when unknown; an image folder has 30).
    count : int or None
        Number of frames when known.
    """

    name: str
    fps: float
    count: int | None
    _frames: object

    def __iter__(self):
        return iter(self._frames)


#: How long :func:`open_frames` waits for a named pipe's writer to start sending a video, s.
PIPE_OPEN_TIMEOUT_S = 20.0
_END = object()  # a pipe reader's last item


def _release_pipe(path: Path) -> None:
    """Let an open of the named pipe ``path`` that waits for a writer return: open it for writing
    and close it at once (refused, and nothing to do, when no reader waits)."""
    with contextlib.suppress(OSError):
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))


def _pipe_frames(items: queue.Queue, stop: threading.Event):
    try:
        while True:
            try:
                item = items.get(timeout=0.1)  # a short wait: Ctrl-C and SIGTERM act between two
            except queue.Empty:
                continue
            if item is _END:
                return
            if isinstance(item, Exception):
                raise item
            yield item
    finally:
        stop.set()


def _open_pipe(path: Path, timeout_s: float) -> FrameSource:
    """A named pipe's video, opened and read by a thread of its own.

    FFmpeg's open of a named pipe blocks until a writer opens it, and its reads block while the
    writer is silent, both in native code where no Python signal handler runs: a thread does both
    here, and the caller waits on a queue in 0.1 s slices, so Ctrl-C and SIGTERM act at once. The
    open waits at most ``timeout_s``; then the thread's own open is released (see
    :func:`_release_pipe`) and a ValueError names the pipe.
    """
    items, stop = queue.Queue(maxsize=4), threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            with contextlib.suppress(queue.Full):
                items.put(item, timeout=0.1)
                return True
        return False

    def read() -> None:
        capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)  # one backend: each would open the pipe again
        try:
            if not capture.isOpened():
                put(ValueError(f"cannot read the named pipe {str(path)!r} as a video (nothing, or not a video, "
                               "was written to it)"))
                return
            size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            try:
                _check_frame_size(*size, f"video {str(path)!r}")
            except ValueError as exc:
                put(exc)
                return
            if not put(capture.get(cv2.CAP_PROP_FPS) or 30.0):
                return
            while not stop.is_set():
                ok, frame = capture.read()
                if not ok or not put(frame[..., ::-1].copy()):
                    break
            put(_END)
        finally:
            capture.release()

    thread = threading.Thread(target=read, name=f"gimbal-lab pipe reader {path.name}", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            try:
                fps = items.get(timeout=0.1)
                break
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise ValueError(f"named pipe {str(path)!r}: no video arrived within {timeout_s:g} s (start the "
                                     "program that writes it first)") from None
    except BaseException:
        stop.set()
        for _ in range(20):  # release the thread's open (1 s at most; a writer that is silent keeps its read)
            _release_pipe(path)
            thread.join(0.05)
            if not thread.is_alive():
                break
        raise
    if isinstance(fps, Exception):
        raise fps
    return FrameSource(str(path), fps, None, _pipe_frames(items, stop))


def open_frames(source, pipe_timeout_s: float | None = None) -> FrameSource:
    """Open a video file, a folder of images or a camera index as an iterator of RGB frames.

    Parameters
    ----------
    source : str, os.PathLike or int
        A camera index (an int, or a string of digits), a folder (its images, sorted by name),
        an image file, a video file or a named pipe a video is written to.
    pipe_timeout_s : float, optional
        How long to wait for a named pipe's video to start, s (:data:`PIPE_OPEN_TIMEOUT_S`). A
        pipe is read by a thread, so Ctrl-C and SIGTERM stop the wait and the reads at once.

    Returns
    -------
    FrameSource
        Iterates over ``uint8`` RGB frames of shape (H, W, 3).

    Raises
    ------
    FileNotFoundError
        The path does not exist.
    ValueError
        The folder holds no image, the video or camera cannot be read, or a frame has more than
        :data:`MAX_FRAME_PIXELS` pixels (checked from the file's header or the video stream's
        size before a frame is decoded).
    """
    if isinstance(source, (int, np.integer)) or (isinstance(source, str) and source.isdigit()):
        index = int(source)
        capture = cv2.VideoCapture(index)
        if not capture.isOpened():
            raise ValueError(f"camera {index} cannot be opened (no such device, or it is busy)")
        return FrameSource(f"camera {index}", capture.get(cv2.CAP_PROP_FPS) or 30.0, None, _video_frames(capture))
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"no such file or folder: {str(path)!r}")
    if stat.S_ISFIFO(path.stat().st_mode):
        return _open_pipe(path, PIPE_OPEN_TIMEOUT_S if pipe_timeout_s is None else float(pipe_timeout_s))
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"folder {str(path)!r} holds no image ({', '.join(IMAGE_SUFFIXES)})")
        return FrameSource(str(path), 30.0, len(files), _image_frames(files))
    if path.suffix.lower() in IMAGE_SUFFIXES and _image_size(path) is not None:  # a one-frame source
        return FrameSource(str(path), 30.0, 1, iter([_read_image(path)]))
    capture = cv2.VideoCapture(str(path))
    if capture.isOpened():
        size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        try:
            _check_frame_size(*size, f"video {str(path)!r}")
        except ValueError:
            capture.release()
            raise
    ok, first = capture.read() if capture.isOpened() else (False, None)
    if not ok:
        capture.release()
        if path.suffix.lower() in IMAGE_SUFFIXES or cv2.haveImageReader(str(path)):
            return FrameSource(str(path), 30.0, 1, iter([_read_image(path)]))
        raise ValueError(f"cannot read {str(path)!r} as a video or an image (unknown format or damaged file)")
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) or None
    return FrameSource(str(path), capture.get(cv2.CAP_PROP_FPS) or 30.0, count, _video_frames(capture, first))


def _video_frames(capture, first=None):
    try:
        if first is not None:
            yield first[..., ::-1].copy()
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield frame[..., ::-1].copy()
    finally:
        capture.release()


def _image_frames(files):
    for file in files:
        yield _read_image(file)


# --------------------------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------------------------


def _parse_pattern(pattern) -> tuple[int, int]:
    if isinstance(pattern, str):
        parts = pattern.lower().split("x")
        if len(parts) != 2 or not all(p.isdigit() for p in parts):
            raise ValueError(f"pattern must be COLSxROWS, e.g. 9x6, got {pattern!r}")
        pattern = tuple(int(p) for p in parts)
    cols, rows = (int(v) for v in pattern)
    if cols < 2 or rows < 2:
        raise ValueError(f"pattern must be at least 2x2, got {cols}x{rows}")
    return cols, rows


def charuco_board(pattern, square_m: float, marker_m: float, dictionary: str = "DICT_5X5_100"):
    """A ``cv2.aruco.CharucoBoard`` of ``pattern`` = (squares_x, squares_y) squares."""
    cols, rows = _parse_pattern(pattern)
    if not (0 < marker_m < square_m):
        raise ValueError(f"marker_m must lie in (0, square_m = {square_m}), got {marker_m}")
    return cv2.aruco.CharucoBoard((cols, rows), float(square_m), float(marker_m),
                                  cv2.aruco.getPredefinedDictionary(_dictionary_id(dictionary)))


def find_board(gray: np.ndarray, board: str, pattern, square_m: float, marker_m: float | None = None,
               dictionary: str = "DICT_5X5_100"):
    """Board corners in one grey image: (object points (N, 3) m, image points (N, 2) px) or None.

    ``board="chessboard"``: ``pattern`` counts inner corners (cols × rows), found with
    ``cv2.findChessboardCornersSB`` (sub-pixel). ``board="charuco"``: ``pattern`` counts squares;
    ChArUco corners are found with ``cv2.aruco.CharucoDetector``; at least 6 are needed.
    """
    cols, rows = _parse_pattern(pattern)
    if board == "chessboard":
        ok, corners = cv2.findChessboardCornersSB(gray, (cols, rows), cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not ok:
            return None
        grid = np.zeros((cols * rows, 3))
        grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
        return grid, corners.reshape(-1, 2).astype(float)
    if board == "charuco":
        if marker_m is None:
            raise ValueError("a ChArUco board needs marker_m (--marker)")
        charuco = charuco_board((cols, rows), square_m, marker_m, dictionary)
        corners, ids, _, _ = cv2.aruco.CharucoDetector(charuco).detectBoard(gray)
        if ids is None or len(ids) < 6:
            return None
        objects = charuco.getChessboardCorners()[ids.reshape(-1)]
        return objects.astype(float), corners.reshape(-1, 2).astype(float)
    raise ValueError(f"board must be 'chessboard' or 'charuco', got {board!r}")


#: Lens models :func:`calibrate` fits.
CALIBRATION_MODELS = ("brown_conrady", "rational")


#: Lens models :func:`calibrate` fits.
CALIBRATION_MODELS = ("brown_conrady", "rational")


def calibrate(frames, board: str = "chessboard", pattern=(9, 6), square_m: float = 0.025,
              marker_m: float | None = None, dictionary: str = "DICT_5X5_100", step: int = 1,
              fix_k3: bool = True, progress: bool = False, model: str = "brown_conrady") -> Calibration:
    """Calibrate a camera from views of a chessboard or ChArUco board (``cv2.calibrateCamera``).

    Parameters
    ----------
    frames : iterable of ndarray, shape (H, W, 3), uint8
        RGB frames (e.g. :func:`open_frames`); all the same size.
    board : {"chessboard", "charuco"}
    pattern : (int, int) or "COLSxROWS"
        Chessboard: inner corners. ChArUco: squares.
    square_m, marker_m : float
        Side of a square and (ChArUco) of a marker, metres.
    dictionary : str
        ChArUco marker dictionary.
    step : int
        Use every ``step``-th frame (consecutive video frames repeat a view).
    fix_k3 : bool
        Brown–Conrady: hold k3 at 0 (a usual choice for ordinary lenses: with few views k3 trades
        off against k1 and k2 and extrapolates badly into the corners).
    progress : bool
        Show a progress bar.
    model : {"brown_conrady", "rational"}
        The lens model fitted: Brown–Conrady (k1, k2, p1, p2, k3), or OpenCV's rational model
        (``CALIB_RATIONAL_MODEL``: k1..k6 with p1, p2; :class:`gimbal_lab.camera.Rational`) for
        wide phone and action-camera lenses. It has three more coefficients to fit: give it many
        varied views reaching into the image's corners.

    Returns
    -------
    Calibration
        With the RMS reprojection error over all corners (pixels).

    Raises
    ------
    ValueError
        Frames of different sizes, or fewer than 3 views where the board was found.
    """
    if isinstance(step, bool) or int(step) != step or step < 1:
        raise ValueError(f"step must be an integer >= 1, got {step!r}")
    if model not in CALIBRATION_MODELS:
        raise ValueError(f"model must be one of {CALIBRATION_MODELS}, got {model!r}")
    for name, value in (("square_m", square_m), ("marker_m", marker_m)):
        if value is not None and not (isinstance(value, (int, float, np.number)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a length > 0 m, got {value!r}")
    if board == "charuco" and marker_m is None:
        raise ValueError("a ChArUco board needs marker_m (--marker)")
    if board == "charuco" and not marker_m < square_m:
        raise ValueError(f"marker_m must be smaller than square_m = {square_m} m, got {marker_m}")
    _parse_pattern(pattern)
    objects, images, size = [], [], None
    iterator = frames
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(frames, desc="calibrate", unit="frame")
    for k, rgb in enumerate(iterator):
        if k % step:
            continue
        if size is None:
            size = (rgb.shape[1], rgb.shape[0])
        elif (rgb.shape[1], rgb.shape[0]) != size:
            raise ValueError(f"frame {k} is {rgb.shape[1]}x{rgb.shape[0]}, the first was {size[0]}x{size[1]}: one camera, one size")
        found = find_board(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), board, pattern, square_m, marker_m, dictionary)
        if found is not None:
            objects.append(found[0].astype(np.float32))
            images.append(found[1].astype(np.float32).reshape(-1, 1, 2))
    if len(objects) < 3:
        raise ValueError(f"the board was found in {len(objects)} frame(s); calibration needs at least 3 varied views")
    if model == "rational":
        flags = cv2.CALIB_RATIONAL_MODEL
    else:
        flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, _, _ = cv2.calibrateCamera(objects, images, size, None, None, flags=flags)
    d = np.asarray(dist, float).reshape(-1)
    intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], size[0], size[1])
    lens = Rational(*d[:8]) if model == "rational" else BrownConrady(k1=d[0], k2=d[1], p1=d[2], p2=d[3],
                                                                      k3=d[4] if len(d) > 4 else 0.0)
    return Calibration(intrinsics, lens, float(rms), len(objects))


# --------------------------------------------------------------------------------------------
# Tracking on recordings
# --------------------------------------------------------------------------------------------

TRACK_COLUMNS = ("frame", "target", "u_px", "v_px", "x_m", "y_m", "z_m", "distance_m", "detect_ms")
"""Columns of the per-frame CSV of :func:`track` (position in the camera optical frame)."""


def _draw_axes(bgr, cam: Intrinsics, lens, rvec, tvec, length_m: float) -> None:
    """Draw a pose's x, y, z axes (red, green, blue) through any lens, as ``cv2.drawFrameAxes`` does."""
    R = cv2.Rodrigues(np.asarray(rvec, float).reshape(3))[0]
    points = np.vstack((np.zeros(3), length_m * np.eye(3))) @ R.T + np.asarray(tvec, float).reshape(3)
    uv = np.round(project(points, cam, lens)).astype(int)
    for tip, colour in zip(uv[1:], ((0, 0, 255), (0, 255, 0), (255, 0, 0))):
        cv2.line(bgr, tuple(int(v) for v in uv[0]), tuple(int(v) for v in tip), colour, 2)


def _make_localiser(target: str, calibration: Calibration, dictionary: str, marker_length_m: float, radius_m: float):
    from . import detection

    cam, lens = calibration.intrinsics, calibration.lens
    if target == "aruco":
        tracker = detection.ArucoTracker(cam, marker_length_m, dictionary=dictionary, distortion=lens)

        def run(rgb):
            poses = tracker.detect(rgb)
            return [(str(i), p.center_px, p.t_cam_marker_m, p) for i, p in sorted(poses.items())]

        def draw(bgr, found):
            for _, centre, _, pose in found:
                cv2.polylines(bgr, [np.round(pose.corners_px).astype(np.int32)], True, (0, 255, 0), 2)
                if isinstance(lens, KannalaBrandt):  # cv2.drawFrameAxes knows pinhole lenses only
                    _draw_axes(bgr, cam, lens, pose.rvec, pose.t_cam_marker_m, 0.5 * marker_length_m)
                else:
                    cv2.drawFrameAxes(bgr, cam.K, None if lens is None else lens.coefficients, pose.rvec,
                                      pose.t_cam_marker_m, 0.5 * marker_length_m, 2)
        return run, draw
    if target == "sphere":
        detector = detection.SphereDetector(edge_mixing="linear", reject_border=True)

        def run(rgb):
            det = detector.detect(rgb)
            if det is None:
                return []
            centre = detection.locate_sphere_ellipse(det, cam, radius_m, lens)
            if centre is None:
                centre = np.full(3, np.nan)
            return [("sphere", det.center_px, centre, det)]

        def draw(bgr, found):
            for _, _, _, det in found:
                cv2.polylines(bgr, [np.round(det.contour_px).astype(np.int32)], True, (0, 255, 0), 2)
        return run, draw
    raise ValueError(f"target must be 'sphere' or 'aruco', got {target!r}")


def track(source, out_dir, target: str, calibration: Calibration, dictionary: str = "DICT_4X4_50",
          marker_length_m: float = 0.30, radius_m: float = 0.10, max_frames: int | None = None,
          progress: bool = True, video: bool = True, gimbal=None, keep_rows: bool = True):
    """Detect and localise the target in every frame of a recording; write ``track.mp4`` and ``track.csv``.

    Parameters
    ----------
    source : str, os.PathLike or int
        Video file, image folder or camera index (:func:`open_frames`).
    out_dir : str or os.PathLike
        Folder for ``track.csv`` (columns :data:`TRACK_COLUMNS`, one row per detection, or one
        row with an empty ``target`` for a frame without one) and ``track.mp4`` (annotated,
        H.264, :mod:`gimbal_lab.video`; a frame with an odd side gets one repeated row or column).
    target : {"sphere", "aruco"}
    calibration : Calibration
        The camera; frames must have its image size.
    dictionary, marker_length_m : str, float
        ArUco dictionary and the side of the black square, metres.
    radius_m : float
        Sphere radius, metres (the exact ellipse method, with the calibrated lens).
    max_frames : int, optional
        Stop after this many frames (>= 1).
    progress, video : bool
        Show a progress bar; write the annotated video.
    gimbal : gimbal_lab.mavlink.steer.GimbalSteer, optional
        A gimbal to steer on the detections: ``gimbal.frame(n, uv_px, fps)`` is called once per
        frame after the frame's rows are written (the first detection's pixel centre, or None; the
        source's frame rate); when it returns False (the link is lost, or the gimbal's attitude
        cannot be steered on) the loop stops as after Ctrl-C. After a Ctrl-C,
        ``gimbal.unsteered(n, uv_px)`` logs the last kept frame if its ``frame`` call did not.
        The caller closes it.
    keep_rows : bool
        Return the rows written as well (True); False streams them to the CSV only and returns an
        empty table, so memory stays flat however long the source (a live camera).

    Returns
    -------
    pandas.DataFrame
        The rows written (none with ``keep_rows=False``); ``df.attrs`` holds ``frames``,
        ``detected`` (frames with a detection), ``seconds``, ``fps`` (frames per second of the
        whole loop: read, detect, annotate, write), ``interrupted`` and ``written`` (the paths).

    Notes
    -----
    Both files are written under temporary names beside them and renamed into place at the end,
    so ``track.csv`` and ``track.mp4`` are always a pair of the same frames, each whole: Ctrl-C
    stops the loop and keeps the frames done so far (a frame's rows and its video frame are
    written together, with Ctrl-C held back meanwhile); an error keeps the files of an earlier
    run as they were. Nothing else in ``out_dir`` is touched; with ``video=False`` an older
    ``track.mp4`` is left in place (it is not of these frames).
    """
    import pandas as pd

    from .outputs import check_writable_folder, deferred_interrupts, remove_leftovers, temporary_name
    from .video import VideoWriter

    if not isinstance(calibration, Calibration):
        raise TypeError(f"calibration must be a Calibration, got {type(calibration).__name__}")
    for name, value in (("marker_length_m", marker_length_m), ("radius_m", radius_m)):
        if not (math.isfinite(float(value)) and float(value) > 0):
            raise ValueError(f"{name} must be a length > 0 m, got {value!r}")
    if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer))
                                   or max_frames < 1):
        raise ValueError(f"max_frames must be an integer >= 1 or None, got {max_frames!r}")
    out = check_writable_folder(out_dir, "out_dir")
    paths = {"csv": out / "track.csv", "video": out / "track.mp4"}
    for path in paths.values():
        if path.is_dir():
            raise ValueError(f"out_dir {out}: {path.name} is a folder; move it away or give another folder")
    run, draw = _make_localiser(target, calibration, dictionary, float(marker_length_m), float(radius_m))
    frames = open_frames(source)
    out.mkdir(parents=True, exist_ok=True)
    remove_leftovers(out)  # the temporary files of a killed earlier run
    cam = calibration.intrinsics
    tmp = {key: temporary_name(path) for key, path in paths.items()}
    rows, writer, interrupted, n, detected = [], None, False, 0, 0
    total = frames.count if max_frames is None else min(frames.count or max_frames, max_frames)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, desc=f"track {target}", unit="frame")
    start = time.perf_counter()
    try:
        with open(tmp["csv"], "w", newline="") as handle:
            table = csv.writer(handle)
            table.writerow(TRACK_COLUMNS)
            try:
                for rgb in frames:
                    if max_frames is not None and n >= max_frames:
                        break
                    if (rgb.shape[1], rgb.shape[0]) != cam.size:
                        raise ValueError(
                            f"frame {n} of {frames.name} is {rgb.shape[1]}x{rgb.shape[0]} px but the calibration is "
                            f"for {cam.width}x{cam.height} px: calibrate this camera at this resolution"
                        )
                    t0 = time.perf_counter()
                    found = run(rgb)
                    detect_ms = 1e3 * (time.perf_counter() - t0)
                    new = [
                        (n, name, float(c[0]), float(c[1]), *(float(x) for x in p), float(np.linalg.norm(p)), detect_ms)
                        for name, c, p, _ in found
                    ] or [(n, "", *(math.nan,) * 6, detect_ms)]
                    if video:
                        bgr = np.ascontiguousarray(rgb[..., ::-1])
                        draw(bgr, found)
                        cv2.putText(bgr, f"{n}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
                        if writer is None:
                            writer = VideoWriter(tmp["video"], float(frames.fps))
                    steer_uv = found[0][1] if found else None
                    with deferred_interrupts():  # the frame's rows and its video frame, or neither
                        if video:
                            writer.write(bgr[..., ::-1])
                        table.writerows(new)
                        if keep_rows:
                            rows += new
                        detected += bool(found)
                        n += 1
                    if bar is not None:
                        bar.update(1)
                    if gimbal is not None and not gimbal.frame(n - 1, steer_uv, float(frames.fps)):
                        interrupted = True
                        break
            except KeyboardInterrupt:
                interrupted = True
                if gimbal is not None and n > 0:  # Ctrl-C between the frame's rows and its steering
                    gimbal.unsteered(n - 1, steer_uv)
        with deferred_interrupts():  # the pair is finished and renamed together
            if writer is not None:
                writer.close()
                os.replace(tmp["video"], paths["video"])
            os.replace(tmp["csv"], paths["csv"])
    finally:
        if writer is not None:
            writer.close()
        for path in tmp.values():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    df = pd.DataFrame(rows, columns=list(TRACK_COLUMNS))
    written = [paths["csv"]] + ([paths["video"]] if writer is not None else [])
    df.attrs.update(frames=n, detected=detected, seconds=seconds, fps=n / seconds if seconds > 0 else math.nan, interrupted=interrupted,
                    written=written)
    return df


# --------------------------------------------------------------------------------------------
# Recordings with known truth (the notebook's and the tests' webcam stand-in)
# --------------------------------------------------------------------------------------------


def write_video(path, frames, fps: float = 30.0) -> Path:
    """Write RGB frames to an MP4 as a camera recording stand-in (``cv2.VideoWriter``, codec
    ``mp4v``, MPEG-4 Part 2); returns the path.

    This is test input, part of the photo-like effects: notebook 12's measured claims (e.g. every
    marker frame read too far) were made on it, and H.264 moves a far marker's edges differently
    (one frame of 48, at 1.9 m, then reads 0.4–1.0 % short). Browsers do not play MPEG-4 Part 2: clips meant to
    be watched go through :func:`gimbal_lab.video.write_video` (H.264).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = None
    try:
        for rgb in frames:
            if writer is None:
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (rgb.shape[1], rgb.shape[0]))
                if not writer.isOpened():
                    raise RuntimeError(f"cannot write {str(path)!r} (codec mp4v unavailable)")
            writer.write(np.ascontiguousarray(rgb[..., ::-1]))
    finally:
        if writer is not None:
            writer.release()
    return path


def board_views(camera: PlanarTargetCamera, texture: np.ndarray, px_per_m: float, board_size_m, n_views: int,
                rng: np.random.Generator, effects: PhotoEffects | None = None, distance_m=(0.35, 0.7),
                max_tilt_rad: float = math.radians(40)) -> list[np.ndarray]:
    """Photos of a flat board from ``n_views`` random viewpoints, as a user waves it before a camera.

    Each view looks at a random point of the board's central half from a random distance and
    a tilt up to ``max_tilt_rad``, rolled at random; views where the board leaves the frame are
    drawn again.

    Returns
    -------
    list of ndarray, shape (H, W, 3), uint8
    """
    effects = effects if effects is not None else PhotoEffects()
    width_m, height_m = board_size_m
    outline = np.array([[0, 0], [width_m, 0], [width_m, height_m], [0, height_m]])
    cam = camera.intrinsics
    frames = []
    while len(frames) < n_views:
        aim = np.array([width_m, height_m]) * rng.uniform(0.25, 0.75, 2)
        tilt, azimuth, distance = rng.uniform(0, max_tilt_rad), rng.uniform(0, 2 * math.pi), rng.uniform(*distance_m)
        eye = np.array([aim[0] + distance * math.sin(tilt) * math.cos(azimuth),
                        aim[1] + distance * math.sin(tilt) * math.sin(azimuth), -distance * math.cos(tilt)])
        roll = rng.uniform(-0.5, 0.5)
        T = look_at_pose(eye, (aim[0], aim[1], 0.0), up=(math.sin(roll), -math.cos(roll), 0.0))
        corners = camera.corners_px(outline, T)
        if corners.min() < 2 or np.any(corners.max(axis=0) > np.array(cam.size) - 3):
            continue
        frames.append(effects.apply(camera.render(texture, px_per_m, T), rng))
    return frames
