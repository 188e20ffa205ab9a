"""Wide-field (fisheye) frames assembled from pinhole views that share the optical centre.

One pinhole render cannot show a field of 180° or more, and even at 120° its edges would need an
enormous canvas. :class:`WideFieldRenderer` therefore renders the scene as the faces of a cube
map around the camera's optical centre (front, right, left, down, up and, when the lens sees that
far, back), each through its own :class:`gimbal_lab.scene.SceneRenderer`, stacks the faces in one
atlas image and resamples the atlas to the output lens with a single ``cv2.remap`` whose map is
computed once, at construction.

Conventions
-----------
* Poses and axes as in :mod:`gimbal_lab.scene`: ``T_world_cam`` is the output camera's OpenCV
  optical frame (x right, y down, z forward); every face shares its origin.
* A face is a pinhole camera looking along one of ±x, ±y, ±z of the camera frame. A ray belongs
  to the face whose axis it is closest to (largest component; ties go to the face listed first
  in :data:`FACE_NAMES`), so every face sees its rays within 54.7° of its axis and the back face
  is needed only when the lens images rays 125.3° or more off the optical axis (the smallest
  angle of a back-face ray, at the cube's corner directions).
* Output pixels whose ray lies beyond the lens's ``max_field_rad`` (outside the image circle)
  are black (0, 0, 0); :attr:`WideFieldRenderer.valid_mask` marks the others.

Sampling
--------
* Face resolution: a face is sampled at least as densely, in every direction, as the output
  image is in its densest direction at every ray the face serves. A pinhole of focal length f
  has f/cos α pixels per radian (its sparsest direction, tangential) at a ray α off its axis; the
  output lens has f_out·max(θ_d'(θ), θ_d(θ)/sin θ) pixels per radian at a ray θ off the optical
  axis (radial and tangential, f_out = max(fx, fy)). So face j gets
  f_j = max over its rays of f_out·max(θ_d', θ_d/sin θ)·cos α, rounded up to a half pixel
  (a whole-pixel face side 2 f_j). For an equidistant lens, rays in a plane through the axis and a
  side face's axis need f_j equal to their image radius in pixels, so the side faces of any of
  the sweep's 640 × 480 fisheyes need 319.5 px (face side 639 px) and the up/down faces 239.5 px;
  the front face needs f_out.
* Only the part of each face that some output pixel samples is rendered (the face's pinhole
  intrinsics are cropped to that window plus a 2 px margin, which keeps both bilinear taps inside
  the window); a cropped face has the same pixel grid as the whole face.
* Resampling is bilinear in linear light: faces are decoded to 16-bit linear values with the
  renderer's sRGB tables, remapped with fixed-point maps (1/32 px), and re-encoded. Motion blur
  (:meth:`WideFieldRenderer.render_exposure`) averages the decoded atlases before the single
  remap (the remap is linear, so this equals remapping each sub-frame).

Notes
-----
docs/design.md, "Studies beyond the paper", lens sweep: Kannala–Brandt fisheye lenses of 120°,
150° and 185° horizontal field at 640 × 480, assembled from a cube map and remapped. Paper §4.1.2
(end) and §5 hypothesise that rectifying such images hurts tracking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import BrownConrady, Intrinsics, KannalaBrandt, backproject
from .scene import _DECODE_LUT, _ENCODE_LUT, _LINEAR_LEVELS, SceneRenderer, add_sensor_noise

__all__ = ["FACE_NAMES", "CubeFace", "WideFieldRenderer", "face_rotation", "face_focal_lengths_px"]

#: The cube-map faces, in the order they are rendered and break ties between equally close axes.
FACE_NAMES = ("front", "right", "left", "down", "up", "back")

# Each face's optical axis (z) and image-down direction (y) in the camera frame; x = y × z.
_FACE_AXES = {
    "front": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "down": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    "up": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "back": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
}

#: Margin, px, around the window of a face that output pixels sample (bilinear taps need 1).
FACE_MARGIN_PX = 2
#: Largest face side (2·focal length), px, the renderer accepts; also keeps atlas coordinates
#: inside the int16 range of OpenCV's fixed-point maps.
MAX_FACE_PX = 4096
_SCENE_KEYWORDS = (
    "sphere_radius_m", "sphere_rgb", "marker_length_m", "plate_size_m", "marker_id", "noise_std", "seed", "occluders"
)
_LINEAR_LUT16 = (_DECODE_LUT * np.float32(_LINEAR_LEVELS) + np.float32(0.5)).astype(np.uint16)  # uint8 → linear·65535


def face_rotation(name: str) -> np.ndarray:
    """Rotation ``R_cam_face`` (3 × 3) of a cube face: its columns are the face's x, y, z in the camera frame.

    Parameters
    ----------
    name : str
        One of :data:`FACE_NAMES`.

    Examples
    --------
    >>> face_rotation("right") @ np.array([0.0, 0.0, 1.0])   # the right face looks along camera +x
    array([1., 0., 0.])
    """
    if name not in _FACE_AXES:
        raise ValueError(f"face name must be one of {FACE_NAMES}, got {name!r}")
    z, y = (np.array(a) for a in _FACE_AXES[name])
    return np.column_stack((np.cross(y, z), y, z))


def _lens_density_px_per_rad(theta: np.ndarray, lens: KannalaBrandt, f_px: float) -> np.ndarray:
    """Output pixels per radian in the lens's densest direction (radial or tangential) at ray angle θ."""
    radial = lens._dtheta_d(theta)
    sin = np.sin(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        tangential = np.where(theta < 1e-9, radial, np.where(sin > 1e-12, lens.theta_d(theta) / sin, np.inf))
    return f_px * np.maximum(radial, tangential)


def _output_rays(intrinsics: Intrinsics, lens: KannalaBrandt) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (N, 3) of the output pixels inside the image circle, and that mask (H, W)."""
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=float), np.arange(intrinsics.height, dtype=float))
    uv = np.column_stack((u.ravel(), v.ravel()))
    xy = intrinsics.to_normalised(uv)
    valid = np.hypot(xy[:, 0], xy[:, 1]) <= float(lens.theta_d(lens.max_field_rad))
    rays = backproject(uv[valid], intrinsics, lens)
    return rays, valid.reshape(intrinsics.height, intrinsics.width)


def _assign_faces(rays: np.ndarray) -> np.ndarray:
    """Index into :data:`FACE_NAMES` of the face closest to each ray (largest component)."""
    axes = np.array([_FACE_AXES[n][0] for n in FACE_NAMES])
    return np.argmax(rays @ axes.T, axis=1)  # argmax keeps the first of equal values


def face_focal_lengths_px(intrinsics: Intrinsics, lens: KannalaBrandt) -> dict[str, float]:
    """Focal length, px, each needed face must have to sample at least as densely as the output.

    Parameters
    ----------
    intrinsics : Intrinsics
        The output camera.
    lens : KannalaBrandt
        The output lens.

    Returns
    -------
    dict
        Face name → f_j, px (the 90° face's side is 2·f_j), for the faces some pixel inside the
        image circle needs, in :data:`FACE_NAMES` order. The rule is in the module docstring.

    Examples
    --------
    >>> lens, f = KannalaBrandt.equidistant_for_fov(640, math.radians(185.0))
    >>> face_focal_lengths_px(Intrinsics(f, f, 319.5, 239.5, 640, 480), lens)["right"]
    319.5
    """
    _check_fisheye(intrinsics, lens)
    rays, _ = _output_rays(intrinsics, lens)
    return _focal_lengths(rays, _assign_faces(rays), intrinsics, lens)


def _focal_lengths(rays, face_index, intrinsics, lens) -> dict[str, float]:
    theta = np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2])
    need = _lens_density_px_per_rad(theta, lens, max(intrinsics.fx, intrinsics.fy))
    axes = np.array([_FACE_AXES[n][0] for n in FACE_NAMES])
    cos_alpha = np.einsum("ij,ij->i", rays, axes[face_index])
    out = {}
    for j, name in enumerate(FACE_NAMES):
        mine = face_index == j
        if mine.any():
            f = float(np.max(need[mine] * cos_alpha[mine]))
            out[name] = math.ceil(2.0 * f - 1e-9) / 2.0 if math.isfinite(f) else math.inf
    return out


def _check_fisheye(intrinsics, lens) -> None:
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
    if not isinstance(lens, KannalaBrandt):
        raise TypeError(f"lens must be a KannalaBrandt here, got {type(lens).__name__}")


@dataclass(frozen=True, eq=False)
class CubeFace:
    """One rendered cube face: where it looks, how it is sampled and where it sits in the atlas.

    Attributes
    ----------
    name : str
        One of :data:`FACE_NAMES`.
    R_cam_face : ndarray, shape (3, 3)
        The face camera's axes in the output camera frame (OpenCV axes for both).
    focal_px : float
        The face's focal length; its full 90° field would be 2·focal_px pixels wide.
    intrinsics : Intrinsics
        The cropped pinhole actually rendered (focal_px, principal point moved into the window).
    atlas_row : int
        First atlas row of this face; it occupies columns 0 … width − 1.
    n_output_px : int
        Output pixels that sample this face.
    """

    name: str
    R_cam_face: np.ndarray = field(repr=False)
    focal_px: float
    intrinsics: Intrinsics
    atlas_row: int
    n_output_px: int

    @property
    def T_cam_face(self) -> np.ndarray:
        """The face camera's pose in the output camera frame, 4 × 4 (a pure rotation)."""
        T = np.eye(4)
        T[:3, :3] = self.R_cam_face
        return T


def _check_matrix(name: str, T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be a finite 4x4 homogeneous transform, got shape {T.shape}")
    return T


class WideFieldRenderer:
    """Render the study's world through any lens of the sweep, fisheyes included.

    Parameters
    ----------
    intrinsics : Intrinsics
        The output camera (image size, K).
    lens : KannalaBrandt, BrownConrady or None
        A fisheye is rendered from cube faces (module docstring); a Brown–Conrady lens or None is
        handed to one :class:`~gimbal_lab.scene.SceneRenderer`, so every lens of the sweep has
        the same interface.
    target : {"sphere", "aruco"}
        The one target in the scene.
    face_px : int, optional
        Side of every face's full 90° field in pixels (focal length face_px/2). None (default)
        gives each face the focal length of :func:`face_focal_lengths_px`; a smaller value
        renders faster and blurs the output. Fisheye only.
    faces : sequence of str, optional
        The faces that may be rendered (a subset of :data:`FACE_NAMES`). None: whichever the
        lens needs. A lens whose field needs another face raises ``ValueError``. Fisheye only.
    **scene_kwargs
        ``sphere_radius_m``, ``sphere_rgb``, ``marker_length_m``, ``plate_size_m``, ``marker_id``,
        ``noise_std`` and ``seed`` as for :class:`~gimbal_lab.scene.SceneRenderer`. Sensor noise
        is added to the output image (after the remap), inside the image circle only.

    Attributes
    ----------
    valid_mask : ndarray of bool, shape (H, W)
        True where the output pixel's ray lies inside the lens's field (all True for a pinhole or
        Brown–Conrady lens); other pixels are always black.
    faces : tuple of CubeFace
        The rendered faces (empty when a single SceneRenderer is used).

    Notes
    -----
    docs/design.md, lens sweep. Each face owns an OpenGL context (up to six per renderer): call
    :meth:`close` or use the renderer as a context manager, and never fork a process that holds
    one (see :mod:`gimbal_lab.scene`).

    Examples
    --------
    >>> lens, f = KannalaBrandt.equidistant_for_fov(640, math.radians(185.0))
    >>> K = Intrinsics(f, f, 319.5, 239.5, 640, 480)
    >>> T_world_cam = np.array([[0., 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 2], [0, 0, 0, 1]])
    >>> T_world_target = np.eye(4); T_world_target[:3, 3] = (3.0, 1.0, 2.0)
    >>> with WideFieldRenderer(K, lens) as scene:
    ...     image = scene.render(T_world_cam, T_world_target)
    >>> image.shape, [face.name for face in scene.faces]
    ((480, 640, 3), ['front', 'right', 'left', 'down', 'up'])
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        lens: KannalaBrandt | BrownConrady | None = None,
        target: str = "sphere",
        face_px: int | None = None,
        faces=None,
        **scene_kwargs,
    ):
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        if lens is not None and not isinstance(lens, (KannalaBrandt, BrownConrady)):
            raise TypeError(f"lens must be a KannalaBrandt, a BrownConrady or None, got {type(lens).__name__}")
        if target not in ("sphere", "aruco"):
            raise ValueError(f"target must be 'sphere' or 'aruco', got {target!r}")
        unknown = sorted(set(scene_kwargs) - set(_SCENE_KEYWORDS))
        if unknown:
            hint = " (the lens is the `lens` argument)" if "distortion" in unknown else ""
            raise TypeError(f"unknown keyword argument(s) {unknown}{hint}; allowed: {_SCENE_KEYWORDS}")
        self.intrinsics = intrinsics
        self.lens = lens
        self.target = target
        self.faces: tuple[CubeFace, ...] = ()
        self._single = None
        self._face_renderers: list[SceneRenderer] = []
        fisheye = isinstance(lens, KannalaBrandt)
        if not fisheye:
            if face_px is not None or faces is not None:
                raise ValueError("face_px and faces apply to a KannalaBrandt lens only; got lens "
                                 f"{type(lens).__name__}")
            self.valid_mask = np.ones((intrinsics.height, intrinsics.width), dtype=bool)
            self._single = SceneRenderer(intrinsics, lens, target=target, **scene_kwargs)
            return

        self.noise_std = float(scene_kwargs.pop("noise_std", 0.0))
        if not math.isfinite(self.noise_std) or self.noise_std < 0:
            raise ValueError(f"noise_std must be >= 0 grey levels, got {self.noise_std}")
        self._rng = np.random.default_rng(scene_kwargs.pop("seed", None))
        self._build_maps(face_px, faces)
        try:
            for face in self.faces:
                self._face_renderers.append(SceneRenderer(face.intrinsics, None, target=target, **scene_kwargs))
        except BaseException:
            self.close()
            raise
        atlas_h = self.faces[-1].atlas_row + self.faces[-1].intrinsics.height
        atlas_w = max(face.intrinsics.width for face in self.faces)
        self._atlas16 = np.zeros((atlas_h, atlas_w, 3), dtype=np.uint16)
        self._sum = None  # uint32 accumulator for render_exposure, allocated on first use

    # ---------------------------------------------------------------------------------------
    @property
    def distortion(self):
        """The lens (the name :class:`~gimbal_lab.scene.SceneRenderer` uses)."""
        return self.lens

    def _build_maps(self, face_px, allowed) -> None:
        """Faces, their cropped intrinsics, the atlas layout and the fixed-point remap (once)."""
        K, lens = self.intrinsics, self.lens
        if face_px is not None:
            if isinstance(face_px, bool) or not float(face_px).is_integer() or not 8 <= face_px <= MAX_FACE_PX:
                raise ValueError(f"face_px must be an integer number of pixels in 8..{MAX_FACE_PX}, got {face_px!r}")
        if allowed is not None:
            if isinstance(allowed, str):
                raise TypeError("faces must be a sequence of face names, not a single string")
            allowed = tuple(allowed)
            bad = [n for n in allowed if n not in FACE_NAMES]
            if bad or not allowed:
                raise ValueError(f"faces must be a non-empty subset of {FACE_NAMES}, got {allowed!r}")
        rays, self.valid_mask = _output_rays(K, lens)
        face_index = _assign_faces(rays)
        needed_focal = _focal_lengths(rays, face_index, K, lens)
        if allowed is not None:
            missing = [n for n in needed_focal if n not in allowed]
            if missing:
                theta = np.degrees(np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]))
                lacking = np.isin(face_index, [FACE_NAMES.index(n) for n in missing])
                raise ValueError(
                    f"the lens's field is too wide for faces {allowed}: it images rays up to "
                    f"{theta[lacking].max():.1f}° off axis that only face(s) {missing} can show "
                    f"(max_field_rad {math.degrees(lens.max_field_rad):.1f}°)")
        if face_px is None:
            worst = max(needed_focal, key=needed_focal.get)
            if 2.0 * needed_focal[worst] > MAX_FACE_PX:
                raise ValueError(
                    f"the lens's field is too wide for a cube map: matching its pixel density needs a "
                    f"{worst} face of {2.0 * needed_focal[worst]:.0f} px (> {MAX_FACE_PX}); lower "
                    f"max_field_rad (now {math.degrees(lens.max_field_rad):.1f}°) or pass face_px")

        map_x = np.full(K.width * K.height, -100.0, dtype=np.float32)  # outside the atlas: black
        map_y = np.full(K.width * K.height, -100.0, dtype=np.float32)
        flat_valid = np.flatnonzero(self.valid_mask)
        faces, row = [], 0
        for j, name in enumerate(FACE_NAMES):
            mine = face_index == j
            if not mine.any():
                continue
            f = face_px / 2.0 if face_px is not None else needed_focal[name]
            R = face_rotation(name)
            p = rays[mine] @ R  # rays in the face frame: R^T d, row-wise
            a, b = f * p[:, 0] / p[:, 2], f * p[:, 1] / p[:, 2]  # px from the principal point
            u0 = math.floor(a.min()) - FACE_MARGIN_PX
            v0 = math.floor(b.min()) - FACE_MARGIN_PX
            width = math.ceil(a.max()) + FACE_MARGIN_PX - u0 + 1
            height = math.ceil(b.max()) + FACE_MARGIN_PX - v0 + 1
            crop = Intrinsics(f, f, float(-u0), float(-v0), width, height)
            map_x[flat_valid[mine]] = a - u0
            map_y[flat_valid[mine]] = b - v0 + row
            faces.append(CubeFace(name, R, f, crop, row, int(mine.sum())))
            row += height
        if row >= 32767 or max(face.intrinsics.width for face in faces) >= 32767:
            raise ValueError(
                f"the face atlas ({row} rows) exceeds OpenCV's fixed-point map range; pass a smaller face_px")
        self.faces = tuple(faces)
        shape = (K.height, K.width)
        # Fixed-point maps (1/32 px) remap about twice as fast as float maps (as in scene.py).
        self._map1, self._map2 = cv2.convertMaps(map_x.reshape(shape), map_y.reshape(shape), cv2.CV_16SC2)
        self._outside = ~self.valid_mask

    # ---------------------------------------------------------------------------------------
    def _render_faces(self, T_world_cam, T_world_target) -> np.ndarray:
        """Render every face and decode it to linear light into its window of the uint16 atlas; returns the atlas."""
        if not self._face_renderers:
            raise RuntimeError("the renderer is closed")
        T_world_cam = _check_matrix("T_world_cam", T_world_cam)
        for face, renderer in zip(self.faces, self._face_renderers):
            image = renderer.render(T_world_cam @ face.T_cam_face, T_world_target)
            h, w = image.shape[:2]
            window = self._atlas16[face.atlas_row : face.atlas_row + h, :w]
            if cv2.LUT(image, _LINEAR_LUT16, dst=window) is not window:  # OpenCV wrote elsewhere
                window[...] = _LINEAR_LUT16[image]
        return self._atlas16

    def _resample(self, atlas16: np.ndarray) -> np.ndarray:
        """Linear atlas → output sRGB image: one bilinear remap, re-encoding, sensor noise."""
        linear = cv2.remap(atlas16, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=0)
        image = _ENCODE_LUT[linear]
        if self.noise_std > 0:
            image = add_sensor_noise(image, self.noise_std, self._rng)
            image[self._outside] = 0
        return image

    def render(self, T_world_cam, T_world_target) -> np.ndarray:
        """Render one sharp frame.

        Parameters
        ----------
        T_world_cam : array_like, shape (4, 4)
            Output camera pose in the world, OpenCV optical axes (x right, y down, z forward).
        T_world_target : array_like, shape (4, 4)
            Sphere centre, or marker centre and axes (:mod:`gimbal_lab.scene`), in the world.

        Returns
        -------
        ndarray, shape (H, W, 3), uint8
            sRGB image through the lens; black outside :attr:`valid_mask`.
        """
        if self._single is not None:
            return self._single.render(T_world_cam, T_world_target)
        return self._resample(self._render_faces(T_world_cam, T_world_target))

    def render_exposure(self, pose_fn, t_start_s: float, exposure_s: float, n_subframes: int) -> np.ndarray:
        """A motion-blurred frame, as :meth:`gimbal_lab.scene.SceneRenderer.render_exposure`.

        Sub-frame k is taken at t_start_s + (k + ½)·exposure_s/n_subframes; the face atlases are
        averaged in linear light (16-bit levels, rounded) and remapped once. ``n_subframes=1``
        equals ``render`` at mid-exposure exactly.
        """
        if self._single is not None:
            return self._single.render_exposure(pose_fn, t_start_s, exposure_s, n_subframes)
        n = int(n_subframes)
        if n != n_subframes or n < 1:
            raise ValueError(f"n_subframes must be an integer >= 1, got {n_subframes!r}")
        exposure_s = float(exposure_s)
        if not math.isfinite(exposure_s) or exposure_s < 0:
            raise ValueError(f"exposure_s must be >= 0 s, got {exposure_s}")
        t_start_s = float(t_start_s)
        if n == 1:
            return self.render(*pose_fn(t_start_s + 0.5 * exposure_s))
        if self._sum is None:
            self._sum = np.empty(self._atlas16.shape, dtype=np.uint32)
        for k in range(n):
            atlas = self._render_faces(*pose_fn(t_start_s + (k + 0.5) * exposure_s / n))
            if k == 0:
                self._sum[...] = atlas
            else:
                self._sum += atlas
        mean = ((self._sum + n // 2) // n).astype(np.uint16)
        return self._resample(mean)

    # ---------------------------------------------------------------------------------------
    def close(self) -> None:
        """Free every OpenGL context (idempotent)."""
        renderers, self._face_renderers = self._face_renderers, []
        single, self._single = self._single, None
        if single is not None:
            renderers.append(single)
        for renderer in renderers:
            renderer.close()

    def __enter__(self) -> "WideFieldRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    def __repr__(self) -> str:
        names = ", ".join(f"{f.name} f={f.focal_px:g} {f.intrinsics.width}x{f.intrinsics.height}" for f in self.faces)
        return f"WideFieldRenderer({self.intrinsics!r}, {self.lens!r}, target={self.target!r}, faces=[{names}])"
