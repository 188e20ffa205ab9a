"""Headless scene synthesis: the lab's replacement for the paper's Gazebo world (§4.1).

A :class:`SceneRenderer` builds one pyrender scene (textured ground, uniform sky, ambient and
directional light, and one target: a matte sphere or an ArUco plate) and one OpenGL context,
then renders many frames by moving two node poses. Frames are RGB ``uint8`` images of the
camera described by :class:`gimbal_lab.camera.Intrinsics` and, optionally,
:class:`gimbal_lab.camera.BrownConrady` lens distortion.

Conventions
-----------
* Poses are 4 × 4 homogeneous transforms ``T_a_b`` mapping points in frame b to frame a.
* ``T_world_cam`` is the camera's OpenCV optical frame (x right, y down, z forward). pyrender's
  camera looks down −z with +y up; :func:`opencv_to_opengl_camera` is the only place that
  converts between the two.
* Pixel centres have integer coordinates (OpenCV). pyrender measures the principal point from
  the image's outer edge, so it is given ``(cx + 0.5, cy + 0.5)``; :func:`_pyrender_camera` is the
  only place that does so. A point on the optical axis lands on ``(cx, cy)`` (tested to 0.1 px).
* ``T_world_target`` places the sphere's centre, or the ArUco marker's centre with OpenCV's
  marker axes: x to the right and y up as seen when facing the marker, z (the plate normal)
  pointing out of the printed face. The corners, in the order ``cv2.aruco`` reports them, are
  (−L/2, L/2, 0), (L/2, L/2, 0), (L/2, −L/2, 0), (−L/2, −L/2, 0); see :func:`marker_corners`.
* Lens distortion: the ideal pinhole image is rendered on a canvas large enough to hold the
  source of every distorted pixel (barrel distortion looks beyond the pinhole frame), then
  resampled with ``cv2.remap``; the maps are computed once per renderer.
* Motion blur: :meth:`SceneRenderer.render_exposure` averages sub-frames in linear light;
  :meth:`SceneRenderer.render_motion` integrates an exposure, global or rolling shutter, from two
  layers and image warps, checked against :meth:`SceneRenderer.render_motion_reference`.
* Occluders (:class:`Occluder`): matte grey boxes standing in the world between the camera and
  the target (docs/design.md, "Occlusion and manoeuvres"). They are part of the background, so
  the windowed anti-aliasing draws them like the ground and the target's window, rendered from
  the whole scene, shows the target cut by them exactly as a full render does. The fast motion
  blur composites the target layer over the background and cannot put a target behind an
  occluder: :meth:`SceneRenderer.render_motion` refuses a scene with occluders (sub-frame
  exposures, :meth:`SceneRenderer.render_exposure`, are exact).
* Shading: every material is matte, so pyrender's physically based fragment shader is replaced
  by a Lambertian one (colour = albedo × (ambient + sun · cos θ), exact sRGB output): about a
  third of the frame time on Mesa's CPU rasteriser.
* Anti-aliasing: a sharp frame is the background (the scene without the target) drawn with one
  sample per pixel, with the target's projected bounding box drawn again, 4× multisampled, on
  top (``antialias="window"``, the default; ``antialias="full"`` multisamples everything). The
  target's pixels are those of the full multisampled render, bit for bit: the box is computed
  from the true poses, which the renderer has anyway. The background is drawn again only when
  the camera moves: a fixed camera's frame costs one small multisampled window, and with a lens
  only the output pixels whose bilinear taps reach that window are remapped again (the rest are
  the distorted background's, bit for bit a full remap). Elsewhere one sample per pixel differs
  where the ground's far edge meets the sky and, over the textured ground (shaded once per
  pixel either way), by rounding: one grey level in about 0.5 % of the values, rarely two.

OpenGL backend
--------------
EGL (headless Mesa, Debian packages ``libegl1 libgl1-mesa-dri``) is the default: importing this
module sets ``PYOPENGL_PLATFORM=egl`` unless the variable is already set or the EGL library is
missing and OSMesa (``libosmesa6``) is present, in which case ``osmesa`` is chosen. The variable
only takes effect if OpenGL has not been imported yet, so import this module (or set the
variable yourself) before anything else imports OpenGL. When no backend can create a context,
:class:`RenderBackendError` names the packages to install. OSMesa is a fallback: pyrender's
shader-program cache is keyed on the OpenGL context handle, which under OSMesa never compares
equal to itself, so it recompiled every program every frame (megabytes leaked per frame); the
renderer here replaces that cache with one keyed on the program alone (one cache per context).

.. warning::
   A process that has created a GL context must never ``fork``: the child hangs (both
   backends). Parallel code that renders must use the ``spawn`` or ``forkserver`` start method
   (``multiprocessing.get_context("spawn")``) and create its renderer inside the worker.

Notes
-----
Paper §4.1 and Figs. 9–10: a red sphere and an ArUco marker moving in front of a camera on a
3-DoF gimbal, with and without radial lens distortion.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import faulthandler
import math
import os
import sys
import threading
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import BrownConrady, Intrinsics, Rational, distort_pixels, undistort_pixels


def _choose_opengl_platform() -> str:
    """Pick the PyOpenGL platform before OpenGL is imported (EGL unless only OSMesa exists)."""
    if "PYOPENGL_PLATFORM" in os.environ:
        return os.environ["PYOPENGL_PLATFORM"]
    platform = "egl"
    if ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa") is not None:
        platform = "osmesa"
    os.environ["PYOPENGL_PLATFORM"] = platform
    return platform


_choose_opengl_platform()

__all__ = [
    "SceneRenderer",
    "RenderBackendError",
    "opencv_to_opengl_camera",
    "marker_corners",
    "aruco_marker_image",
    "srgb_to_linear",
    "linear_to_srgb",
    "add_sensor_noise",
    "ARUCO_DICTIONARY",
    "Occluder",
    "points_visible",
    "sphere_rim_points",
]

#: The study's ArUco dictionary (paper §3.2.2 / docs/design.md): 4 × 4 bits, 50 ids.
ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_50

_BACKEND_HELP = (
    "install the EGL backend with `apt-get install libegl1 libgl1-mesa-dri` (default, "
    "PYOPENGL_PLATFORM=egl), or the OSMesa fallback with `apt-get install libosmesa6` and "
    "PYOPENGL_PLATFORM=osmesa set before Python imports OpenGL"
)

# The scene's fixed look (docs/design.md, the study table): floats, matte materials.
_SKY_RGB = (0.55, 0.72, 0.92)
_AMBIENT_RGB = (0.30, 0.30, 0.30)
_SUN_INTENSITY = 0.75  # weight of the sun's cos θ term in the matte shader
_GROUND_SIZE_M = 1000.0
_GROUND_TILE_M = 1.0
_GROUND_TEXTURE_SEED = 20240202
_SPHERE_SUBDIVISIONS = 4  # icosphere: 2562 vertices; silhouette sag < 0.06 % of the radius
_Z_NEAR_M = 0.05
_Z_FAR_M = 2000.0
_MAX_CANVAS_SCALE = 3.0  # a distortion needing a larger pinhole canvas is refused
_LINEAR_LEVELS = 65535  # resolution of the linear-light encoder's lookup table


class RenderBackendError(RuntimeError):
    """No OpenGL backend could create an offscreen context."""


# --------------------------------------------------------------------------------------------
# Conventions: the one home of each conversion
# --------------------------------------------------------------------------------------------

_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def opencv_to_opengl_camera(T_world_cam: np.ndarray) -> np.ndarray:
    """Convert a camera pose from the OpenCV optical frame to pyrender's (OpenGL) camera frame.

    Parameters
    ----------
    T_world_cam : ndarray, shape (4, 4)
        Camera pose, OpenCV axes (x right, y down, z forward).

    Returns
    -------
    ndarray, shape (4, 4)
        The same pose with OpenGL camera axes (x right, y up, looking down −z):
        ``T_world_cam @ diag(1, −1, −1, 1)``. The conversion is its own inverse.
    """
    return np.asarray(T_world_cam, dtype=float) @ _CV_TO_GL


def _pyrender_camera(pyrender, intrinsics: Intrinsics):
    """pyrender camera for ``intrinsics``; the one place that maps the principal point.

    OpenCV puts pixel centres on integers, so the image's left edge is u = −0.5; pyrender's
    projection measures cx from that edge. Hence cx_gl = cx + 0.5 and cy_gl = cy + 0.5 (rows
    counted from the top in both).
    """
    return pyrender.IntrinsicsCamera(
        fx=intrinsics.fx,
        fy=intrinsics.fy,
        cx=intrinsics.cx + 0.5,
        cy=intrinsics.cy + 0.5,
        znear=_Z_NEAR_M,
        zfar=_Z_FAR_M,
    )


def marker_corners(T_world_marker: np.ndarray, marker_length_m: float) -> np.ndarray:
    """World coordinates of an ArUco marker's four corners, in ``cv2.aruco``'s order.

    Parameters
    ----------
    T_world_marker : ndarray, shape (4, 4)
        Marker pose (centre, OpenCV marker axes; see the module docstring).
    marker_length_m : float
        Side of the black square, metres.

    Returns
    -------
    ndarray, shape (4, 3)
        Top-left, top-right, bottom-right, bottom-left corners (as seen facing the marker):
        (−L/2, L/2, 0), (L/2, L/2, 0), (L/2, −L/2, 0), (−L/2, −L/2, 0) mapped to the world.
    """
    half = 0.5 * float(marker_length_m)
    local = np.array([[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]])
    T = np.asarray(T_world_marker, dtype=float)
    return local @ T[:3, :3].T + T[:3, 3]


def aruco_marker_image(
    marker_id: int = 0, marker_length_m: float = 0.30, plate_size_m: float = 0.40, marker_px: int = 384
) -> np.ndarray:
    """The plate's texture: an ArUco marker (DICT_4X4_50) centred on a white square plate.

    Parameters
    ----------
    marker_id : int
        Marker id in DICT_4X4_50 (0–49).
    marker_length_m, plate_size_m : float
        Side of the black square and of the plate, metres; only their ratio matters here.
    marker_px : int
        Texture pixels across the marker (a multiple of 6, the marker's width in cells).

    Returns
    -------
    ndarray, shape (S, S, 3), uint8
        RGB texture with S ≈ marker_px·plate_size_m/marker_length_m; the image's top row is the
        plate's top edge (+y of the marker frame), as ``cv2.aruco.generateImageMarker`` draws it.
    """
    dictionary = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY)
    marker = cv2.aruco.generateImageMarker(dictionary, int(marker_id), int(marker_px))
    size = int(round(marker_px * plate_size_m / marker_length_m))
    size += (size - marker_px) % 2  # an even margin keeps the marker exactly centred
    plate = np.full((size, size), 255, dtype=np.uint8)
    start = (size - marker_px) // 2
    plate[start : start + marker_px, start : start + marker_px] = marker
    return np.repeat(plate[:, :, None], 3, axis=2)


# --------------------------------------------------------------------------------------------
# Linear light
# --------------------------------------------------------------------------------------------


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """sRGB transfer function inverse (IEC 61966-2-1): encoded values in [0, 1] → linear light."""
    c = np.asarray(srgb, dtype=float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function (IEC 61966-2-1): linear light in [0, 1] → encoded values."""
    c = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


_DECODE_LUT = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)  # uint8 → linear
_ENCODE_LUT = np.round(255.0 * linear_to_srgb(np.arange(_LINEAR_LEVELS + 1) / _LINEAR_LEVELS)).astype(
    np.uint8
)  # linear quantised to 1/65535 → uint8; encode(decode(x)) == x for every code (tested)


# --------------------------------------------------------------------------------------------
# Backend
# --------------------------------------------------------------------------------------------


def _import_pyrender():
    try:
        import pyrender
    except Exception as exc:  # ImportError, or PyOpenGL failing to load the platform library
        raise RenderBackendError(
            f"cannot load pyrender/OpenGL with PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r} "
            f"({exc}); {_BACKEND_HELP}"
        ) from exc
    return pyrender


#: Seconds an OpenGL context may take to appear before the process gives up (creating one takes
#: well under a second; a driver that blocks would otherwise idle until an outer timeout).
GL_START_TIMEOUT_S = float(os.environ.get("GIMBAL_LAB_GL_TIMEOUT_S", "120"))


@contextlib.contextmanager
def _fail_if_stuck(what: str, timeout_s: float):
    """Exit the process with a message and every thread's traceback if the block outlasts ``timeout_s``.

    A GL driver call that never returns cannot be interrupted from Python; this watchdog thread
    turns such a stall into a prompt, explained failure (exit status 70) instead of an idle
    process.
    """

    def give_up():
        sys.stderr.write(
            f"gimbal-lab: {what} has not finished after {timeout_s:g} s; the OpenGL driver seems stuck. "
            "Check the EGL/Mesa installation (docs in README, 'Rendering notes'), or raise "
            "GIMBAL_LAB_GL_TIMEOUT_S on a very loaded machine. Tracebacks of every thread follow.\n"
        )
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        os._exit(70)

    timer = threading.Timer(timeout_s, give_up)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def _create_platform(width: int, height: int):
    """Create and make current an offscreen GL context of the chosen backend."""
    name = os.environ.get("PYOPENGL_PLATFORM", "egl")
    try:
        if name == "egl":
            from pyrender.platforms import egl

            class _EGLPlatform(egl.EGLPlatform):
                def delete_context(self):
                    # Destroy this context only. pyrender also calls eglTerminate, but every
                    # renderer on a device shares one EGL display, so that would invalidate the
                    # contexts of all other live renderers in the process.
                    from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

                    if self._egl_context is not None:
                        eglMakeCurrent(self._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
                        eglDestroyContext(self._egl_display, self._egl_context)
                        self._egl_context = None

            device = egl.get_device_by_index(int(os.environ.get("EGL_DEVICE_ID", "0")))
            platform = _EGLPlatform(width, height, device=device)
        elif name == "osmesa":
            from pyrender.platforms.osmesa import OSMesaPlatform

            platform = OSMesaPlatform(width, height)
        else:
            raise RenderBackendError(
                f"PYOPENGL_PLATFORM={name!r} is not supported for headless rendering; use 'egl' or 'osmesa'"
            )
        platform.init_context()
        platform.make_current()
    except RenderBackendError:
        raise
    except Exception as exc:
        raise RenderBackendError(f"cannot create an OpenGL context with backend {name!r} ({exc!r}); {_BACKEND_HELP}") from exc
    return platform


# Matte (Lambertian) fragment shader replacing pyrender's physically based one: the lab's
# materials are all matte (metallic 0, roughness 1), and on a CPU rasteriser the PBR shader
# costs about three times the frame time of this one. Colour = albedo × (ambient + Σ sun·cos θ),
# sRGB-encoded exactly (IEC 61966-2-1), so linear-light averaging can invert it.
_MATTE_FRAGMENT_SHADER = """#version 330 core
struct DirectionalLight { vec3 color; float intensity; vec3 direction; };
struct Material {
    vec4 base_color_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};
uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 ambient_light;
in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
out vec4 frag_color;

vec3 decode_srgb(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), c));
}
vec3 encode_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() {
    vec3 albedo = material.base_color_factor.rgb;
#ifdef HAS_BASE_COLOR_TEX
    albedo *= decode_srgb(texture(material.base_color_texture, uv_0).rgb);
#endif
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
#else
    vec3 n = vec3(0.0, 0.0, 1.0);
#endif
    vec3 irradiance = ambient_light;
    for (int i = 0; i < n_directional_lights; i++) {
        float cos_theta = max(dot(n, -directional_lights[i].direction), 0.0);
        irradiance += directional_lights[i].intensity * directional_lights[i].color * cos_theta;
    }
    frag_color = vec4(encode_srgb(albedo * irradiance), 1.0);
}
"""


def _make_renderer_class(pyrender):
    """A pyrender Renderer with the matte shader, one program cache and colour-only read-back."""
    from OpenGL import GL as gl
    from pyrender.shader_program import ShaderProgram, ShaderProgramCache

    class _Program(ShaderProgram):
        # Source either from pyrender's shader folder or, for the matte shader, from the string
        # above; defines become real GLSL #define lines after the #version line.
        def _load(self, shader_filename):
            if os.path.basename(shader_filename) == "mesh.frag":
                text = _MATTE_FRAGMENT_SHADER
            else:
                with open(shader_filename) as f:
                    text = f.read()
            version, _, body = text.partition("\n")
            defines = "".join(f"#define {k} {v}\n" for k, v in self.defines.items())
            return f"{version}\n{defines}{body}"

        def set_uniform(self, name, value, unsigned=False):
            # pyrender looks every location up again, and raises and swallows an exception for
            # each uniform the shader does not use (several per draw with the matte shader). A
            # uniform keeps its value in its program, so a value already set is not sent again
            # (the projection, the light and the materials never change).
            locations = self.__dict__.setdefault("_lab_locations", {})
            sent = self.__dict__.setdefault("_lab_sent", {})
            loc = locations.get(name)
            if loc is None:
                loc = locations[name] = int(gl.glGetUniformLocation(self._program_id, name))
            if loc == -1:
                return
            if isinstance(value, np.ndarray):
                if value.ndim == 1:
                    if unsigned or np.issubdtype(value.dtype, np.unsignedinteger):
                        kind, value = "u", value.astype(np.uint32)
                    elif np.issubdtype(value.dtype, np.integer):
                        kind, value = "i", value.astype(np.int32)
                    else:
                        kind, value = "f", value.astype(np.float32)
                    key = (kind, value.tobytes())
                    if sent.get(name) != key:
                        self._FUNC_MAP[(value.shape[0], kind)](loc, 1, value)
                else:
                    key = ("m", value.shape, value.astype(np.float32).tobytes())
                    if sent.get(name) != key:
                        self._FUNC_MAP[value.shape](loc, 1, gl.GL_TRUE, value)
            elif isinstance(value, (bool, int, float, np.integer, np.floating)):
                key = (type(value), value, unsigned)
                if sent.get(name) != key:
                    if isinstance(value, (float, np.floating)):
                        gl.glUniform1f(loc, float(value))
                    elif unsigned:
                        gl.glUniform1ui(loc, int(value))
                    else:
                        gl.glUniform1i(loc, int(value))
            else:
                raise TypeError(f"uniform {name}: unsupported value type {type(value).__name__}")
            sent[name] = key

    class _ProgramCache(ShaderProgramCache):
        # One renderer owns one context, so the context handle is not needed in the key; under
        # OSMesa that handle never compares equal to itself and pyrender's cache never hit.
        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            defines = dict(defines or {})
            files = [f for f in (vertex_shader, fragment_shader, geometry_shader) if f is not None]
            key = (tuple(files), tuple(sorted(defines.items())))
            if key not in self._program_cache:
                paths = [os.path.join(self.shader_dir, f) for f in files] + [None] * (3 - len(files))
                self._program_cache[key] = _Program(
                    vertex_shader=paths[0], fragment_shader=paths[1], geometry_shader=paths[2], defines=defines
                )
            return self._program_cache[key]

    class _ColourRenderer(pyrender.Renderer):
        def __init__(self, width, height):
            super().__init__(width, height)
            self._program_cache = _ProgramCache()
            self._rgba = np.empty((height, width, 4), dtype=np.uint8)
            # (x0, y0, w, h) in image pixels (rows from the top): when set, only that rectangle is
            # cleared and drawn (scissor test). The pixels inside are those of a full render.
            self.region = None
            # True: draw into the 4× multisampled buffer and resolve ``region`` (or everything)
            # into the single-sample one; False: draw straight into the single-sample buffer,
            # on top of what an earlier pass left there outside ``region``.
            self.multisample = True
            # What a render returns: "auto" (``region`` as RGBA when set, else the whole buffer
            # as RGB), "all" (the whole single-sample buffer as RGB) or "none" (an empty array).
            self.readback = "auto"

        def _forward_pass(self, scene, flags, seg_node_map=None):
            # pyrender's colour pass for this lab's scenes, without the per-draw work whose result
            # never changes here: a primitive's program is found once, and the lighting (one sun,
            # ambient light, no shadows) is bound once per program. Any other kind of pass is
            # pyrender's own.
            if flags != pyrender.RenderFlags.OFFSCREEN or seg_node_map is not None:
                return super()._forward_pass(scene, flags, seg_node_map)
            self._configure_forward_pass_viewport(flags)
            gl.glClearColor(*scene.bg_color)
            gl.glClear(gl.GL_COLOR_BUFFER_BIT | gl.GL_DEPTH_BUFFER_BIT)
            gl.glEnable(gl.GL_MULTISAMPLE)
            V, P = self._get_camera_matrices(scene)
            programs = self.__dict__.setdefault("_lab_programs", {})
            lit = self.__dict__.setdefault("_lab_lit", set())
            program = None
            for node in self._sorted_mesh_nodes(scene):
                if not node.mesh.is_visible:
                    continue
                for primitive in node.mesh.primitives:
                    program = programs.get(id(primitive))
                    if program is None:
                        program = programs[id(primitive)] = self._get_primitive_program(
                            primitive, flags, pyrender.constants.ProgramFlags.USE_MATERIAL)
                    program._bind()
                    program.set_uniform("V", V)
                    program.set_uniform("P", P)
                    if id(program) not in lit:
                        self._bind_lighting(scene, program, node, flags)
                        lit.add(id(program))
                    self._bind_and_draw_primitive(primitive=primitive, pose=scene.get_pose(node), program=program,
                                                  flags=flags)
                    self._reset_active_textures()
            if program is not None:
                program._unbind()
            gl.glFlush()
            return self._read_main_framebuffer(scene, flags)

        def _configure_forward_pass_viewport(self, flags):
            super()._configure_forward_pass_viewport(flags)
            if not self.multisample:
                gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, self._main_fb)
            if self.region is None:
                gl.glDisable(gl.GL_SCISSOR_TEST)
            else:
                x0, y0, w, h = self.region
                gl.glEnable(gl.GL_SCISSOR_TEST)
                gl.glScissor(x0, self._rgba.shape[0] - y0 - h, w, h)

        def __del__(self):
            # pyrender's finaliser frees GL objects, possibly with no context current (at
            # interpreter exit); SceneRenderer.close frees them explicitly instead.
            pass

        def _read_main_framebuffer(self, scene, flags):
            # Resolve the 4× multisampled colour buffer and read it into a reused array; the
            # stock method also reads and linearises depth, which the lab never uses.
            width, height = self._main_fb_dims
            if self.multisample:
                x0, y0, w, h = self.region if self.region is not None else (0, 0, width, height)
                y0 = height - y0 - h  # GL rows run bottom-up
                gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, self._main_fb_ms)
                gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, self._main_fb)
                gl.glBlitFramebuffer(x0, y0, x0 + w, y0 + h, x0, y0, x0 + w, y0 + h, gl.GL_COLOR_BUFFER_BIT,
                                     gl.GL_LINEAR)
            gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, self._main_fb)
            if self.readback == "none":
                return np.empty((0, 0, 3), dtype=np.uint8)
            if self.readback == "all" or self.region is None:
                return self._read_rgb()
            return self._read_region()

        def read_color_buf(self):  # path of backends without framebuffer objects (OSMesa)
            gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, 0)
            gl.glReadBuffer(gl.GL_FRONT)
            return self._read_rgb() if self.region is None else self._read_region()

        def _read_region(self):
            x0, y0, w, h = self.region
            rgba = np.empty((h, w, 4), dtype=np.uint8)
            gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
            gl.glReadPixels(x0, self._rgba.shape[0] - y0 - h, w, h, gl.GL_RGBA, gl.GL_UNSIGNED_BYTE, rgba)
            return cv2.flip(rgba, 0)

        def _read_rgb(self):
            # RGBA is the rasteriser's native layout: reading it is ~10x faster than RGB.
            height, width = self._rgba.shape[:2]
            gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
            gl.glReadPixels(0, 0, width, height, gl.GL_RGBA, gl.GL_UNSIGNED_BYTE, self._rgba)
            return cv2.flip(cv2.cvtColor(self._rgba, cv2.COLOR_RGBA2RGB), 0)  # GL rows run bottom-up

    return _ColourRenderer


# --------------------------------------------------------------------------------------------
# Scene content
# --------------------------------------------------------------------------------------------


def _matte(pyrender, rgb, texture=None):
    return pyrender.MetallicRoughnessMaterial(
        baseColorFactor=[float(c) for c in rgb] + [1.0],
        metallicFactor=0.0,
        roughnessFactor=1.0,
        baseColorTexture=texture,
    )


def _quad(pyrender, half_x, half_y, material, uv_scale=1.0, flip=False):
    """A z = 0 rectangle facing +z (−z when ``flip``), UV (0, 0) at its bottom-left corner."""
    positions = np.array([[-half_x, -half_y, 0], [half_x, -half_y, 0], [half_x, half_y, 0], [-half_x, half_y, 0]], dtype=np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32) * uv_scale
    normal = -1.0 if flip else 1.0
    normals = np.tile(np.array([0, 0, normal], dtype=np.float32), (4, 1))
    faces = np.array([[0, 2, 1], [0, 3, 2]] if flip else [[0, 1, 2], [0, 2, 3]], dtype=np.uint32)
    prim = pyrender.Primitive(positions=positions, normals=normals, texcoord_0=uv, indices=faces, material=material)
    return pyrender.Mesh([prim])


def _ground_texture() -> np.ndarray:
    """A grass-like 2 × 2-tile checker (two greens with seeded speckle), RGB uint8 256 × 256."""
    rng = np.random.default_rng(_GROUND_TEXTURE_SEED)
    n = 256
    ij = np.indices((n, n)) // (n // 2)
    checker = (ij[0] + ij[1]) % 2
    dark, light = np.array([0.25, 0.42, 0.16]), np.array([0.36, 0.55, 0.22])
    rgb = np.where(checker[:, :, None] == 1, light, dark)
    rgb = rgb * (1.0 + 0.12 * rng.standard_normal((n, n, 1)))
    return np.clip(255.0 * rgb, 0, 255).astype(np.uint8)


def _sun_pose() -> np.ndarray:
    """Directional light from behind and above the home camera (light travels along −z of its node)."""
    travel = np.array([1.0, -0.4, -1.2])  # from behind-left, above, towards +x and down
    z = -travel / np.linalg.norm(travel)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack((x, y, z))
    return T


# --------------------------------------------------------------------------------------------
# Occluders
# --------------------------------------------------------------------------------------------

#: The occluders' matte grey (linear albedo): far from the sphere's red and the marker's black.
OCCLUDER_RGB = (0.35, 0.35, 0.35)


@dataclass(frozen=True)
class Occluder:
    """A matte box standing in the world, its faces parallel to the world's axes.

    Parameters
    ----------
    name : str
        What it is ("pole", "panel"), for labels.
    centre_m : (3,) floats
        Centre of the box, world frame, m.
    size_m : (3,) floats
        Extents along world x, y and z, m, each > 0 (a pole 0.15 m wide and square is
        (0.15, 0.15, height); a panel facing a camera that looks along +x is (thickness, width,
        height)).

    Examples
    --------
    >>> pole = Occluder("pole", centre_m=(1.0, 0.0, 1.0), size_m=(0.15, 0.15, 2.0))
    >>> pole.blocks((0.0, 0.0, 1.0), [(3.0, 0.0, 1.0), (3.0, 1.0, 1.0)]).tolist()
    [True, False]
    """

    name: str
    centre_m: tuple
    size_m: tuple

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        for field_name in ("centre_m", "size_m"):
            value = np.asarray(getattr(self, field_name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise ValueError(f"{field_name} must be three finite numbers (m), got {getattr(self, field_name)!r}")
            object.__setattr__(self, field_name, tuple(float(v) for v in value))
        if min(self.size_m) <= 0:
            raise ValueError(f"size_m must be > 0 on every axis, got {self.size_m!r}")

    @property
    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """The box's lowest and highest corners, world frame, m."""
        c, half = np.asarray(self.centre_m), 0.5 * np.asarray(self.size_m)
        return c - half, c + half

    def blocks(self, origin_m, points_m) -> np.ndarray:
        """Whether the segment from ``origin_m`` to each point passes through the box.

        The slab test: the segment o + t(p − o), t ∈ [0, 1], meets the box when the intervals of
        t inside each pair of parallel faces overlap. A point inside the box is blocked.

        Parameters
        ----------
        origin_m : (3,) floats
            The viewpoint (a camera's optical centre), m.
        points_m : array_like, shape (3,) or (N, 3)

        Returns
        -------
        ndarray of bool, shape () or (N,)
        """
        o = np.asarray(origin_m, dtype=float)
        p = np.asarray(points_m, dtype=float)
        if o.shape != (3,) or p.shape[-1:] != (3,):
            raise ValueError(f"origin_m must have shape (3,) and points_m (..., 3), got {o.shape} and {p.shape}")
        lo, hi = self.bounds_m
        d = p - o
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        t_near, t_far = np.minimum(t1, t2), np.maximum(t1, t2)
        parallel = d == 0.0  # a segment parallel to a pair of faces: inside that slab or not at all
        inside = (o >= lo) & (o <= hi)
        t_near = np.where(parallel, np.where(inside, -np.inf, np.inf), t_near)
        t_far = np.where(parallel, np.where(inside, np.inf, -np.inf), t_far)
        enter, leave = np.max(t_near, axis=-1), np.min(t_far, axis=-1)
        return (enter <= leave) & (leave >= 0.0) & (enter <= 1.0)


def sphere_rim_points(camera_m, centre_m, radius_m: float, n: int = 32) -> np.ndarray:
    """``n`` points of a sphere's outline as seen from ``camera_m``: its tangent circle, (n, 3), m.

    From a viewpoint at distance D > r the sphere's outline is the circle where the tangent cone
    touches it: radius r·√(1 − (r/D)²), centred r²/D from the sphere's centre towards the viewpoint.
    """
    o, c = np.asarray(camera_m, float), np.asarray(centre_m, float)
    axis = o - c
    D = float(np.linalg.norm(axis))
    r = _positive("radius_m", radius_m)
    if not D > r:
        raise ValueError(f"the viewpoint must lie outside the sphere (distance {D:.3g} m <= radius {r:.3g} m)")
    axis /= D
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi = 2.0 * np.pi * np.arange(n) / n
    rim_radius = r * math.sqrt(1.0 - (r / D) ** 2)
    return c + (r * r / D) * axis + rim_radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def points_visible(occluders, camera_m, points_m) -> np.ndarray:
    """Whether each point is seen from ``camera_m`` past every occluder, shape (N,) (or ())."""
    points = np.asarray(points_m, dtype=float)
    visible = np.ones(points.shape[:-1], dtype=bool)
    for occluder in occluders:
        visible &= ~occluder.blocks(camera_m, points)
    return visible


# --------------------------------------------------------------------------------------------
# The renderer
# --------------------------------------------------------------------------------------------


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
# np.allclose's test |a − b| <= atol + rtol·|b|, written out (it is called for every pose)
_LAST_ROW_TOL = 1e-8 + 1e-5 * _LAST_ROW
_ORTHONORMAL_TOL = 1e-6 + 1e-5 * np.eye(3)


def _check_pose(name: str, T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"{name} must be a finite 4x4 homogeneous transform, got shape {T.shape}")
    R = T[:3, :3]
    last_row_ok = (np.abs(T[3] - _LAST_ROW) <= _LAST_ROW_TOL).all()
    if not last_row_ok or not (np.abs(R @ R.T - np.eye(3)) <= _ORTHONORMAL_TOL).all():
        raise ValueError(f"{name} must be a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return T


def _check_poses(name: str, T) -> np.ndarray:
    """:func:`_check_pose` for a stack of poses, (N, 4, 4)."""
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"{name} must be finite 4x4 homogeneous transforms, got shape {T.shape}")
    R = T[:, :3, :3]
    last_row_ok = (np.abs(T[:, 3] - _LAST_ROW) <= _LAST_ROW_TOL).all()
    if not last_row_ok or not (np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)) <= _ORTHONORMAL_TOL).all():
        raise ValueError(f"{name} must be rigid transforms (orthonormal rotation, last row 0 0 0 1)")
    return T


def _positive(name: str, value) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


# --------------------------------------------------------------------------------------------
# Motion blur by warping layers (SceneRenderer.render_motion)
# --------------------------------------------------------------------------------------------

# Time slices are cut so that along each the target's image moves at most _TARGET_STEP_PX and
# the background's at most _BACKGROUND_STEP_PX, and so that each path gets at least
# _MIN_SLICES of them (short paths are cheap to cut finer, and a sharp marker or ground texture
# needs it). The target layer is warped at every slice (bilinear warps overlap, so a streak
# shows no gaps); the background at most _BACKGROUND_WARPS times, slices being grouped by image
# position (a vibration's repeated loops share warps; a long path is a strongly blurred
# background, on which a coarser grouping costs little). Steps and budgets were chosen by
# measuring error against cost on the study's motions: 1-px steps and 12 background warps
# instead lower the worst frame's mean error against the reference by 0.35 grey level at most
# (1.17 → 0.83, rolling shutter with vibration), leave the sphere's rim within 0.03 px, and cost
# about 0.3–0.4 of a sharp frame more.
_TARGET_STEP_PX = 1.5
_BACKGROUND_STEP_PX = 2.0
_MIN_SLICES = 16
_BACKGROUND_WARPS = 8
_LAYER_MARGIN_PX = 2  # the target layer's box beyond its projected bounds: rim and bilinear taps
# A target window larger than this share of the canvas is not worth a second pass: the whole
# canvas is multisampled in one (measured: one pass 4× multisampled costs about two single-sample ones).
_WINDOW_MAX_SHARE = 0.4
# Beyond the preimage of a blurred target's region in the background layer: a bilinear tap, the
# floor/ceil of its corners and one pixel to spare.
_BACKGROUND_WINDOW_MARGIN_PX = 3
_FEATHER_PX = 4  # blend between the target region's own background and the groups' one
# pose_fn is sampled at knots _FIRST_KNOT_SPACING_S apart or closer, halved while the quintic
# and a cubic spline through them disagree by more than _MOTION_TOL_PX somewhere on the image
# (the cubic's error; the quintic's is a few times smaller, 0.3 px at most for 120 Hz vibration
# at 2.1 ms, tests/test_motion_blur.py).
_MOTION_TOL_PX = 1.0
_FIRST_KNOT_SPACING_S = 2.5e-3
_MAX_KNOTS = 513
_DENSE_STEPS_PER_KNOT = 32  # time steps per knot interval on which image paths are measured


# Side of the canvas tiles by which the output pixels a target window reaches through the lens
# are looked up (SceneRenderer._output_rect): a box is rounded out to whole tiles.
_TAP_TILE_PX = 16


def _tap_tile_table(map1: np.ndarray, canvas_size, tile_px: int) -> tuple[np.ndarray, np.ndarray]:
    """For fixed-point remap maps (``cv2.CV_16SC2``: integer source x, y per output pixel), the
    output rectangle reading each canvas tile: (lo, hi) of shape (tiles_y, tiles_x, 2) holding
    (u0, v0) and (u1, v1), ends excluded; an unread tile has lo > hi.

    A bilinear tap of output pixel (u, v) reads canvas pixels x, x + 1 and y, y + 1 around its
    source's integer part, clamped to the canvas (``BORDER_REPLICATE``).
    """
    width, height = canvas_size
    rows, cols = map1.shape[:2]
    v, u = np.divmod(np.arange(rows * cols), cols)
    sx = map1[..., 0].ravel().astype(np.int64)
    sy = map1[..., 1].ravel().astype(np.int64)
    tiles_x, tiles_y = -(-width // tile_px), -(-height // tile_px)
    lo = np.full((tiles_y * tiles_x, 2), np.iinfo(np.int64).max, dtype=np.int64)
    hi = np.full((tiles_y * tiles_x, 2), np.iinfo(np.int64).min, dtype=np.int64)
    for dx in (0, 1):
        tx = np.clip(sx + dx, 0, width - 1) // tile_px
        for dy in (0, 1):
            tile = (np.clip(sy + dy, 0, height - 1) // tile_px) * tiles_x + tx
            np.minimum.at(lo[:, 0], tile, u)
            np.minimum.at(lo[:, 1], tile, v)
            np.maximum.at(hi[:, 0], tile, u + 1)
            np.maximum.at(hi[:, 1], tile, v + 1)
    return lo.reshape(tiles_y, tiles_x, 2), hi.reshape(tiles_y, tiles_x, 2)


def _rigid_inverse(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _rigid_inverses(T: np.ndarray) -> np.ndarray:
    """:func:`_rigid_inverse` of a stack of poses (N, 4, 4), by the same products."""
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.tile(np.eye(4), (len(T), 1, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -(Rt @ T[:, :3, 3:4])[:, :, 0]
    return out


def _projected_box(corners_cam: np.ndarray, K: np.ndarray, size, margin_px: int):
    """The pixel rectangle (x0, y0, w, h) of an image of ``size`` = (width, height) holding the
    projection of every point inside the convex hull of ``corners_cam`` (camera frame, (n, 3)),
    grown by ``margin_px``; None when that hull is behind the camera or projects outside the
    image, "all" when it straddles the near plane (its projection is unbounded)."""
    width, height = size
    in_front = corners_cam[:, 2] > _Z_NEAR_M
    if not np.all(in_front):
        return "all" if np.any(in_front) else None
    uv = (corners_cam @ K.T)[:, :2] / corners_cam[:, 2:3]
    x0 = max(0, int(np.floor(uv[:, 0].min())) - margin_px)
    y0 = max(0, int(np.floor(uv[:, 1].min())) - margin_px)
    x1 = min(width, int(np.ceil(uv[:, 0].max())) + margin_px + 1)
    y1 = min(height, int(np.ceil(uv[:, 1].max())) + margin_px + 1)
    return (x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else None


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def _plane_homographies(K: np.ndarray, R: np.ndarray, p: np.ndarray, normal, offset) -> np.ndarray:
    """K (R + p nᵀ/d) K⁻¹ for stacked rigid motions (R: (N, 3, 3), p: (N, 3)): the image motion of
    the plane nᵀX = d (reference camera frame) under X → R X + p. ``normal=None``: rotation only."""
    M = R.copy()
    if normal is not None:
        M += p[:, :, None] * (np.asarray(normal)[None, None, :] / offset)
    return np.einsum("ij,njk,kl->nil", K, M, np.linalg.inv(K))


def _apply_homographies(H: np.ndarray, points_h: np.ndarray) -> np.ndarray:
    """Pixels (N, P, 2) of homogeneous points (3, P) under homographies (N, 3, 3)."""
    q = H @ points_h
    return np.moveaxis(q[:, :2] / q[:, 2:3], 1, 2)


def _overlap_weights(a: np.ndarray, b: np.ndarray, row_start_s: np.ndarray, exposure_s: float) -> np.ndarray:
    """Weight (n, R) of the time slices [a_k, b_k) in rows that integrate [T, T + exposure_s).

    The fraction of a row's exposure each slice covers; with a zero exposure, 1 for the slice
    holding the row's instant (the last slice is closed).
    """
    a, b, T = a[:, None], b[:, None], row_start_s[None, :]
    if exposure_s > 0:
        return np.clip(np.minimum(b, T + exposure_s) - np.maximum(a, T), 0.0, None) / exposure_s
    inside = (T >= a) & (T < b)
    inside[-1] |= T[0] >= b[-1, 0]
    return inside.astype(float)


class _ExposureMotion:
    """Camera and target motion over [t_lo, t_hi], relative to the instant in its middle.

    ``pose_fn`` is sampled on a uniform grid of knots, one spacing beyond each end (each new set of
    knots in one call of ``pose_fn.many(times) -> (T_world_cam (N, 4, 4), T_world_target (N, 4, 4))``
    when it has that method; ``pose_calls`` counts the calls, ``pose_instants`` the instants); the relative
    motions (rotation vectors and translations of the camera and of the target, both relative to
    the reference instant) are interpolated by quintic splines. The grid halves while the
    quintic and a cubic spline through the same knots disagree by more than ``_MOTION_TOL_PX`` at
    the mid-points (the cubic's error bounds the quintic's). Image motion is expressed as plane
    homographies of the reference canvas: the ground plane z = 0 for the background, for the
    target the marker's plane or, for a sphere, the plane through its centre facing the camera.
    """

    def __init__(self, pose_fn, t_lo: float, t_hi: float, K: np.ndarray, canvas_size, target_points_m, plane):
        from scipy.spatial.transform import Rotation

        self._Rotation = Rotation
        self._pose_fn = pose_fn
        self.K = K
        self.t_lo, self.t_hi = t_lo, t_hi
        self.t_ref = 0.5 * (t_lo + t_hi)
        self.T_cam_ref, self.T_target_ref = self._pose(self.t_ref)
        self.pose_calls = self.pose_instants = 1
        self._cam_ref = self.T_cam_ref
        self._S_ref_inv = _rigid_inverse(_rigid_inverse(self.T_cam_ref) @ self.T_target_ref)
        # ground z = 0 in the reference camera frame: n·X = d with n = world z seen from the camera
        height = self.T_cam_ref[2, 3]
        self.ground = (self.T_cam_ref[2, :3].copy(), -height) if abs(height) > 1e-9 else (None, 1.0)
        # the target's plane in the reference camera frame
        S_ref = _rigid_inverse(self.T_cam_ref) @ self.T_target_ref
        centre = S_ref[:3, 3]
        normal = S_ref[:3, 2] if plane == "plate" else centre / max(np.linalg.norm(centre), 1e-12)
        offset = float(normal @ centre)
        if abs(offset) < 1e-9 * max(np.linalg.norm(centre), 1e-12):  # plate seen edge-on
            normal = centre / max(np.linalg.norm(centre), 1e-12)
            offset = float(normal @ centre)
        self.target_plane = (normal, offset)
        # the layer's rectangle on the canvas (None: the target is not in front of the camera)
        width, height_px = canvas_size
        corners = (S_ref[:3, :3] @ np.asarray(target_points_m, float).T).T + centre
        self.layer_box = _projected_box(corners, K, canvas_size, _LAYER_MARGIN_PX)
        if self.layer_box == "all":  # partly behind the camera: the layer is the canvas
            self.layer_box = (0, 0, width, height_px)
        self.bg_points = np.array([[0, width - 1, 0, width - 1, 0.5 * (width - 1)],
                                   [0, 0, height_px - 1, height_px - 1, 0.5 * (height_px - 1)],
                                   [1, 1, 1, 1, 1]], dtype=float)
        if self.layer_box is not None:
            x0, y0, w, h = self.layer_box
            self.target_points = np.array([[x0, x0 + w - 1, x0, x0 + w - 1], [y0, y0, y0 + h - 1, y0 + h - 1],
                                           [1, 1, 1, 1]], dtype=float)
        self._fit_knots()

    # ------------------------------------------------------------------------------------------
    def _pose(self, t: float):
        T_cam, T_target = self._pose_fn(t)
        return _check_pose("T_world_cam", T_cam), _check_pose("T_world_target", T_target)

    def _poses(self, times) -> tuple[np.ndarray, np.ndarray]:
        """``_pose`` at each time, stacked (N, 4, 4) each: through ``pose_fn.many(times)`` in one
        call when it has one."""
        self.pose_instants += len(times)
        many = getattr(self._pose_fn, "many", None)
        if many is None:
            self.pose_calls += len(times)
            pairs = [self._pose(t) for t in times]
            return np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])
        self.pose_calls += 1
        T_cam, T_target = many(np.asarray(times, dtype=float))
        if len(T_cam) != len(times) or len(T_target) != len(times):
            raise ValueError(f"pose_fn.many gave {len(T_cam)} and {len(T_target)} poses for {len(times)} times")
        return _check_poses("T_world_cam", T_cam), _check_poses("T_world_target", T_target)

    def _relative(self, times) -> np.ndarray:
        """(len(times), 12): rotation vector and translation of the camera motion, then of the
        target motion, at each time."""
        T_cam, T_target = self._poses(times)
        out = np.empty((len(times), 12))
        cam_inv = _rigid_inverses(T_cam)
        C = cam_inv @ self._cam_ref
        D = cam_inv @ T_target @ self._S_ref_inv
        rotations = np.stack((C[:, :3, :3], D[:, :3, :3]), axis=1)
        out[:, 3:6], out[:, 9:12] = C[:, :3, 3], D[:, :3, 3]
        rv = self._Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_rotvec().reshape(-1, 2, 3)
        out[:, 0:3], out[:, 6:9] = rv[:, 0], rv[:, 1]
        return out

    def _fit_knots(self) -> None:
        from scipy.interpolate import CubicSpline, make_interp_spline

        span = self.t_hi - self.t_lo
        n = 2 * max(2, int(np.ceil(span / (2.0 * _FIRST_KNOT_SPACING_S))))  # even: t_ref is a knot
        values = {self.t_ref: np.zeros(12)}
        while True:
            h = span / n  # halving n keeps every earlier knot on the grid, bit for bit
            new = [t for t in (float(self.t_ref + h * j) for j in range(-n // 2 - 1, n // 2 + 2)) if t not in values]
            values.update(zip(new, self._relative(new)))
            knots = np.array(sorted(values))
            data = np.array([values[k] for k in knots])
            spline = make_interp_spline(knots, data, k=5)
            inside = (knots >= self.t_lo - 0.5 * h) & (knots <= self.t_hi + 0.5 * h)
            mids = 0.5 * (knots[inside][:-1] + knots[inside][1:])
            error = self._pixel_difference(spline(mids), CubicSpline(knots, data)(mids))
            if error <= _MOTION_TOL_PX or len(knots) + n + 2 > _MAX_KNOTS:
                break
            n *= 2
        self.knot_spacing_s = h
        self.n_knots = len(knots)
        self.interpolation_error_px = error
        self._spline = spline

    def _pixel_difference(self, v1: np.ndarray, v2: np.ndarray) -> float:
        G1, T1 = self._homographies(v1)
        G2, T2 = self._homographies(v2)
        diff = np.abs(_apply_homographies(G1, self.bg_points) - _apply_homographies(G2, self.bg_points)).max()
        if self.layer_box is not None:
            diff = max(diff, np.abs(_apply_homographies(T1, self.target_points)
                                    - _apply_homographies(T2, self.target_points)).max())
        return float(diff)

    def _homographies(self, values: np.ndarray):
        R = self._Rotation.from_rotvec(values[:, [0, 1, 2, 6, 7, 8]].reshape(-1, 3)).as_matrix()
        R = R.reshape(-1, 2, 3, 3)
        ground = _plane_homographies(self.K, R[:, 0], values[:, 3:6], *self.ground)
        target = _plane_homographies(self.K, R[:, 1], values[:, 9:12], *self.target_plane)
        return ground, target

    def homographies(self, t: np.ndarray):
        """Background (ground-plane) and target homographies, reference canvas → canvas at ``t``."""
        return self._homographies(self._spline(np.asarray(t, float)))

    def dense_times(self) -> np.ndarray:
        steps = _DENSE_STEPS_PER_KNOT * max(1, int(round((self.t_hi - self.t_lo) / self.knot_spacing_s)))
        return np.linspace(self.t_lo, self.t_hi, steps + 1)


_SKY_U8 = np.rint(255.0 * np.array(_SKY_RGB)).astype(np.uint8)  # the clear colour as the framebuffer stores it


def _check_motion_args(pose_fn, t_start_s, exposure_s, readout_s) -> tuple[float, float, float]:
    if not callable(pose_fn):
        raise TypeError(
            f"pose_fn must be callable as pose_fn(t_s) -> (T_world_cam, T_world_target), got {type(pose_fn).__name__}"
        )
    values = []
    checks = (("t_start_s", t_start_s, None), ("exposure_s", exposure_s, 0.0), ("readout_s", readout_s, 0.0))
    for name, value, low in checks:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise TypeError(f"{name} must be a number of seconds, got {type(value).__name__} {value!r}")
        v = float(value)
        if not np.isfinite(v) or (low is not None and v < low):
            allowed = "" if low is None else " >= 0"
            raise ValueError(f"{name} must be a finite number of seconds{allowed}, got {value!r}")
        values.append(v)
    return tuple(values)


def _count(name: str, value, low: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _leader_clusters(points: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy clusters of time slices by image motion: (labels, leader index of each cluster).

    ``points`` (N, P, 2): the background's test points at each slice. A slice joins the first
    leader whose points all lie within ``radius_px`` of its own, else leads a new cluster.
    """
    flat = points.reshape(len(points), -1, 2)
    labels = np.empty(len(flat), dtype=np.int64)
    leaders: list[int] = []
    current = -1
    for k in range(len(flat)):
        if current >= 0 and np.max(np.hypot(*(flat[k] - flat[leaders[current]]).T)) <= radius_px:
            labels[k] = current
            continue
        if leaders:
            d = np.linalg.norm(flat[k][None] - flat[leaders], axis=2).max(axis=1)
            j = int(np.argmin(d))
            if d[j] <= radius_px:
                labels[k] = current = j
                continue
        leaders.append(k)
        labels[k] = current = len(leaders) - 1
    return labels, np.array(leaders, dtype=np.int64)


# Coverages at which the rim deficit is sampled, and the inverse of the fit's Vandermonde matrix.
_RIM_COVERAGES = np.array([0.25, 0.5, 0.75])
_RIM_FIT = np.linalg.inv(np.vander(_RIM_COVERAGES, 3, increasing=True))


def _rim_deficit(colour: np.ndarray, coverage: np.ndarray, background: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """What encoded mixing takes from the linear composite on the target's rims, (h, w, 3).

    The renderer resolves a pixel a fraction a of which the target covers to
    decode(a·C + (1 − a)·B) (C, B encoded), darker than the linear mix a·c + (1 − a)·b by the
    deficit Δ(a) = a·c + (1 − a)·b − decode(a·C + (1 − a)·B), zero at a = 0 and 1. Per pixel
    and channel Δ(a) = a(1 − a)(d0 + d1·a + d2·a²) is fitted at a = ¼, ½, ¾, with c the mean
    colour the target brought to the pixel (``colour`` Σ w·P over ``coverage`` Σ w·α) and b the
    blurred background (``background`` Σ w·B, all linear); ``rim`` (3, h, w) holds
    Σ w·a(1 − a)·aʲ over the slices.
    """
    out = np.zeros(background.shape, dtype=np.float32)
    touched = rim[0] > 1e-6
    if not np.any(touched):
        return out
    c = np.clip(colour[touched] / np.maximum(coverage[touched], 1e-6)[:, None], 0.0, 1.0).astype(np.float64)
    b = np.clip(background[touched], 0.0, 1.0).astype(np.float64)
    c_enc, b_enc = linear_to_srgb(c), linear_to_srgb(b)
    a = _RIM_COVERAGES[:, None, None]
    deficit = a * c + (1.0 - a) * b - srgb_to_linear(a * c_enc + (1.0 - a) * b_enc)
    d = np.einsum("ij,jnc->inc", _RIM_FIT, deficit / (a * (1.0 - a)))
    out[touched] = np.einsum("inc,in->nc", d, rim[:, touched].astype(np.float64))
    return out


def _background_groups(points: np.ndarray, travel_px: np.ndarray, step_px: float) -> tuple[np.ndarray, int, float]:
    """Group time slices by the background's image position, at most ``_BACKGROUND_WARPS`` groups.

    ``points`` (N, P, 2): the background's test points at each slice; ``travel_px`` (N,): the
    image path travelled before each slice. Slices are cut into runs of 2r of path (all within
    r of the run's middle slice), and runs whose middle slices lie within r of a leader's join
    it. r is the smallest (in steps of 1.5×, not below half the slices' step ``step_px``) whose
    groups fit the budget.

    Returns the group of each slice, the number of groups, and the largest distance (px, 2r) of
    a slice's background from its group's leader.
    """
    def group(radius):
        run = np.floor(travel_px / (2.0 * radius)).astype(np.int64)
        starts = np.flatnonzero(np.diff(run, prepend=run[0] - 1))
        middles = starts + np.diff(np.append(starts, len(run))) // 2
        return (run, middles) + _leader_clusters(points[middles], radius)

    # Runs alone give about travel/(2r) groups, loops that revisit places fewer: start where runs
    # would just fit the budget, grow r until the groups fit, then shrink it while they still do.
    smallest = 0.5 * step_px
    radius = max(smallest, float(travel_px[-1] - travel_px[0]) / (2.0 * _BACKGROUND_WARPS))
    found = group(radius)
    while len(found[3]) > _BACKGROUND_WARPS:
        radius *= 1.5
        found = group(radius)
    while radius > smallest:
        trial = group(max(smallest, radius / 1.5))
        if len(trial[3]) > _BACKGROUND_WARPS:
            break
        radius, found = max(smallest, radius / 1.5), trial
    run, middles, run_labels, run_leaders = found
    of_run = np.cumsum(np.diff(run, prepend=run[0] - 1) != 0) - 1
    return run_labels[of_run], len(run_leaders), 2.0 * radius


def _feather(region, canvas_size) -> np.ndarray:
    """Weight (h, w) of the groups' background in the target region: 1 on its edge, falling
    linearly to 0 at ``_FEATHER_PX`` inside (edges on the canvas border have nothing to join)."""
    x0, y0, x1, y1 = region
    width, height = canvas_size
    far = float(_FEATHER_PX)
    x, y = np.arange(x0, x1, dtype=np.float32), np.arange(y0, y1, dtype=np.float32)
    dx = np.minimum(x - x0 if x0 > 0 else far, x1 - 1 - x if x1 < width else far)
    dy = np.minimum(y - y0 if y0 > 0 else far, y1 - 1 - y if y1 < height else far)
    distance = np.minimum(dx[None, :], dy[:, None])
    return np.clip(1.0 - distance / far, 0.0, 1.0).astype(np.float32)


def _add_row_weighted(acc: np.ndarray, r0: int, image: np.ndarray, row_weights: np.ndarray) -> None:
    """acc[r0 + i] += row_weights[i] · image[i]: one scaled add per long run of equal weight, one
    broadcast product per block of rows between them (``image`` is overwritten there)."""
    change = np.flatnonzero(np.diff(row_weights)) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [len(row_weights)]))
    block = None  # [first, last) of rows awaiting the broadcast product
    for s, e in zip(starts, ends):
        w = float(row_weights[s])
        if w != 0.0 and e - s < 8:
            block = (s if block is None else block[0], e)
            continue
        if block is not None:
            _add_rows(acc, r0, image, row_weights, *block)
            block = None
        if w != 0.0:
            dst = acc[r0 + s : r0 + e]
            cv2.scaleAdd(image[s:e], w, dst, dst=dst)
    if block is not None:
        _add_rows(acc, r0, image, row_weights, *block)


def _add_rows(acc, r0, image, row_weights, s, e):
    block = image[s:e]  # a scratch buffer: scaled in place (a temporary would cost page faults)
    np.multiply(block, row_weights[s:e, None, None].astype(np.float32), out=block)
    dst = acc[r0 + s : r0 + e]
    cv2.add(dst, block, dst=dst)


class SceneRenderer:
    """Render the study's world through one camera, reusing a single scene and GL context.

    Parameters
    ----------
    intrinsics : Intrinsics
        The output camera (image size, K).
    distortion : BrownConrady or Rational, optional
        Lens distortion of the output camera; None or all-zero renders the pinhole image.
    target : {"sphere", "aruco"}
        The one target placed in the scene.
    sphere_radius_m : float
        Sphere radius (> 0), metres. Default 0.10 (docs/design.md).
    sphere_rgb : tuple of 3 floats
        Sphere base colour in [0, 1] (linear). Default saturated red.
    marker_length_m : float
        Side of the ArUco black square (> 0), metres. Default 0.30.
    plate_size_m : float
        Side of the white plate (> marker_length_m), metres. Default 0.40.
    marker_id : int
        ArUco id in DICT_4X4_50 (0–49). Default 0.
    noise_std : float
        Standard deviation of additive Gaussian sensor noise, in 8-bit grey levels (≥ 0).
        Zero (default) makes frames a pure function of the poses.
    seed : int or numpy.random.Generator, optional
        Noise source; the same seed gives the same noisy frames.
    antialias : {"window", "full"}
        Where a sharp frame is 4× multisampled: around the target only (default, about half
        the cost) or everywhere. The target's pixels are the same either way (module notes).
    occluders : sequence of Occluder
        Matte grey boxes in the world that can hide the target (none by default).

    Notes
    -----
    The scene is built once; :meth:`render` only moves the camera and target nodes. The target
    is 4× multisampled (anti-aliased edges keep centroids and corners sub-pixel accurate).
    A renderer owns an OpenGL context: call :meth:`close` or use it as a context manager, and
    never fork a process that holds one (see the module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> from gimbal_lab.camera import Intrinsics
    >>> T_world_cam = np.array([[0., 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 2], [0, 0, 0, 1]])
    >>> T_world_target = np.eye(4); T_world_target[:3, 3] = (3.0, 0.0, 2.0)
    >>> with SceneRenderer(Intrinsics.default(), target="sphere") as scene:
    ...     image = scene.render(T_world_cam, T_world_target)
    >>> image.shape, image.dtype.name
    ((480, 640, 3), 'uint8')
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        distortion: BrownConrady | Rational | None = None,
        target: str = "sphere",
        sphere_radius_m: float = 0.10,
        sphere_rgb: tuple[float, float, float] = (1.0, 0.0, 0.0),
        marker_length_m: float = 0.30,
        plate_size_m: float = 0.40,
        marker_id: int = 0,
        noise_std: float = 0.0,
        seed: int | np.random.Generator | None = None,
        antialias: str = "window",
        occluders=(),
    ):
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        if distortion is not None and not isinstance(distortion, (BrownConrady, Rational)):
            raise TypeError(f"distortion must be a BrownConrady, a Rational or None, got {type(distortion).__name__}")
        if target not in ("sphere", "aruco"):
            raise ValueError(f"target must be 'sphere' or 'aruco', got {target!r}")
        self.intrinsics = intrinsics
        self.distortion = None if distortion is None or distortion.is_identity else distortion
        self.target = target
        self.sphere_radius_m = _positive("sphere_radius_m", sphere_radius_m)
        self.sphere_rgb = tuple(float(c) for c in sphere_rgb)
        if len(self.sphere_rgb) != 3 or not all(0.0 <= c <= 1.0 for c in self.sphere_rgb):
            raise ValueError(f"sphere_rgb must be three floats in [0, 1], got {sphere_rgb!r}")
        self.marker_length_m = _positive("marker_length_m", marker_length_m)
        self.plate_size_m = _positive("plate_size_m", plate_size_m)
        if self.plate_size_m <= self.marker_length_m:
            raise ValueError(
                f"plate_size_m must exceed marker_length_m ({self.marker_length_m} m), got {self.plate_size_m}"
            )
        if not 0 <= int(marker_id) < 50 or int(marker_id) != marker_id:
            raise ValueError(f"marker_id must be an integer in 0..49 (DICT_4X4_50), got {marker_id!r}")
        self.marker_id = int(marker_id)
        self.noise_std = float(noise_std)
        if not np.isfinite(self.noise_std) or self.noise_std < 0:
            raise ValueError(f"noise_std must be >= 0 grey levels, got {noise_std}")
        self._rng = np.random.default_rng(seed)
        if antialias not in ("window", "full"):
            raise ValueError(f"antialias must be 'window' or 'full', got {antialias!r}")
        self.antialias = antialias
        self.occluders = tuple(occluders)
        for occluder in self.occluders:
            if not isinstance(occluder, Occluder):
                raise TypeError(f"occluders must be Occluder objects, got {type(occluder).__name__}")

        self._setup_distortion()
        self._pyrender = _import_pyrender()
        self._platform = None
        self._renderer = None
        self._build_scene()
        width, height = self.canvas_intrinsics.size
        with _fail_if_stuck("creating the OpenGL context", GL_START_TIMEOUT_S):
            self._platform = _create_platform(width, height)
            self._renderer = _make_renderer_class(self._pyrender)(width, height)
        self._flags = self._pyrender.RenderFlags.OFFSCREEN if self._platform.supports_framebuffers() else 0
        self._linear_sum = None  # float32 accumulator for render_exposure, allocated on first use
        self._noise = None
        self._motion_acc = None  # float32 accumulator for render_motion, allocated on first use
        self._motion_stats = None  # what the last render_motion did (slices, warps, pose calls)
        self._output_rows = None  # output row of each canvas pixel (rolling shutter), on first use
        self._background = None  # (camera pose bytes, canvas without the target) of the last sharp frame
        self._last_window = None  # the last sharp canvas: None (drawn whole), "none" or the window on the background
        self._distorted_background = None  # (camera pose bytes, the background remapped through the lens)
        self._tap_tiles = None  # per canvas tile, the output pixels reading it (_output_rect), on first use
        self._last_background_window = None  # the multisampled window of the last blurred frame's background
        self.background_renders = 0  # how many sharp frames drew the background (the rest reused it)

    # ---------------------------------------------------------------------------------------
    def _setup_distortion(self) -> None:
        """Pinhole canvas covering every distorted pixel's source, and the remap maps (once)."""
        K = self.intrinsics
        if self.distortion is None:
            self.canvas_intrinsics = K
            self._map1 = self._map2 = None
            return
        u, v = np.meshgrid(np.arange(K.width, dtype=float), np.arange(K.height, dtype=float))
        src = undistort_pixels(np.column_stack((u.ravel(), v.ravel())), K, self.distortion)
        # One pixel of margin beyond the extreme sources keeps bilinear taps inside the canvas.
        left = max(0, int(np.ceil(-src[:, 0].min())) + 1)
        top = max(0, int(np.ceil(-src[:, 1].min())) + 1)
        right = max(0, int(np.ceil(src[:, 0].max() - (K.width - 1))) + 1)
        bottom = max(0, int(np.ceil(src[:, 1].max() - (K.height - 1))) + 1)
        width, height = K.width + left + right, K.height + top + bottom
        if width > _MAX_CANVAS_SCALE * K.width or height > _MAX_CANVAS_SCALE * K.height:
            raise ValueError(
                f"distortion {self.distortion} needs a {width}x{height} pinhole canvas, more than "
                f"{_MAX_CANVAS_SCALE}x the {K.width}x{K.height} image; use a milder distortion"
            )
        self.canvas_intrinsics = Intrinsics(K.fx, K.fy, K.cx + left, K.cy + top, width, height)
        map_x = (src[:, 0] + left).reshape(K.height, K.width).astype(np.float32)
        map_y = (src[:, 1] + top).reshape(K.height, K.width).astype(np.float32)
        # Fixed-point maps (1/32 px interpolation grid) remap about twice as fast as float maps.
        self._map1, self._map2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)

    def _build_scene(self) -> None:
        pr = self._pyrender
        scene = pr.Scene(bg_color=list(_SKY_RGB) + [1.0], ambient_light=list(_AMBIENT_RGB))
        ground_tex = pr.Texture(source=_ground_texture(), source_channels="RGB")
        tiles = _GROUND_SIZE_M / (2.0 * _GROUND_TILE_M)  # the texture holds 2 × 2 tiles
        self._ground_node = scene.add(
            _quad(pr, _GROUND_SIZE_M / 2, _GROUND_SIZE_M / 2, _matte(pr, (1, 1, 1), ground_tex), uv_scale=tiles)
        )
        scene.add(pr.DirectionalLight(color=np.ones(3), intensity=_SUN_INTENSITY), pose=_sun_pose())
        if self.occluders:
            import trimesh

            for occluder in self.occluders:
                box = pr.Mesh.from_trimesh(trimesh.creation.box(extents=occluder.size_m),
                                           material=_matte(pr, OCCLUDER_RGB), smooth=False)
                pose = np.eye(4)
                pose[:3, 3] = occluder.centre_m
                scene.add(box, pose=pose)
        if self.target == "sphere":
            import trimesh

            mesh = trimesh.creation.icosphere(subdivisions=_SPHERE_SUBDIVISIONS, radius=self.sphere_radius_m)
            target_mesh = pr.Mesh.from_trimesh(mesh, material=_matte(pr, self.sphere_rgb), smooth=True)
        else:
            texture = aruco_marker_image(self.marker_id, self.marker_length_m, self.plate_size_m)
            plate_tex = pr.Texture(
                source=texture,
                source_channels="RGB",
                sampler=pr.Sampler(wrapS=pr.constants.GLTF.CLAMP_TO_EDGE, wrapT=pr.constants.GLTF.CLAMP_TO_EDGE),
            )
            half = self.plate_size_m / 2
            front = _quad(pr, half, half, _matte(pr, (1, 1, 1), plate_tex)).primitives[0]
            back = _quad(pr, half, half, _matte(pr, (0.5, 0.5, 0.5)), flip=True).primitives[0]
            target_mesh = pr.Mesh([front, back])
        self._scene = scene
        self._target_node = scene.add(target_mesh, pose=np.eye(4))
        self._camera_node = scene.add(_pyrender_camera(pr, self.canvas_intrinsics), pose=np.eye(4))

    # ---------------------------------------------------------------------------------------
    def _render_canvas(self, T_world_cam: np.ndarray, T_world_target: np.ndarray) -> np.ndarray:
        """The pinhole canvas image, RGB uint8 (H_canvas, W_canvas, 3), as the GL renderer's
        ``region``/``multisample``/``readback`` settings ask (by default 4× multisampled)."""
        T_world_cam = _check_pose("T_world_cam", T_world_cam)
        T_world_target = _check_pose("T_world_target", T_world_target)
        if self._renderer is None:
            raise RuntimeError("the renderer is closed")
        self._scene.set_pose(self._camera_node, opencv_to_opengl_camera(T_world_cam))  # a new array
        self._scene.set_pose(self._target_node, T_world_target.copy())
        self._platform.make_current()
        image = self._renderer.render(self._scene, self._flags)
        if image is None:  # backends without framebuffer objects render to the front buffer
            image = self._renderer.read_color_buf()
        return image

    def _target_bounds_m(self) -> np.ndarray:
        """Corners of a box holding the target, in the target's frame, (n, 3)."""
        if self.target == "sphere":
            r = self.sphere_radius_m
            return np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (-r, r)])
        s = 0.5 * self.plate_size_m
        return np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])

    def _target_box(self, T_world_cam: np.ndarray, T_world_target: np.ndarray):
        """The canvas rectangle (x0, y0, w, h) holding every pixel the target touches, with a
        margin; None when the target is wholly out of the canvas or behind the camera, "all"
        when it is partly behind the camera."""
        T_cam_target = _rigid_inverse(T_world_cam) @ T_world_target
        corners = self._target_bounds_m() @ T_cam_target[:3, :3].T + T_cam_target[:3, 3]
        C = self.canvas_intrinsics
        return _projected_box(corners, C.K, C.size, _LAYER_MARGIN_PX)

    def _render_sharp_canvas(self, T_world_cam, T_world_target) -> np.ndarray:
        """The sharp canvas, anti-aliased as ``self.antialias`` says (see the module notes)."""
        self._last_window = None
        if self.antialias == "full" or not self._flags:
            return self._render_canvas(T_world_cam, T_world_target)
        T_world_cam = _check_pose("T_world_cam", T_world_cam)
        T_world_target = _check_pose("T_world_target", T_world_target)
        box = self._target_box(T_world_cam, T_world_target)
        width, height = self.canvas_intrinsics.size
        self._last_window = None
        if isinstance(box, str) or (box is not None and box[2] * box[3] > _WINDOW_MAX_SHARE * width * height):
            return self._render_canvas(T_world_cam, T_world_target)
        image = self._background_canvas(T_world_cam, T_world_target).copy()
        if box is not None:
            x0, y0, w, h = box
            renderer = self._renderer
            try:
                renderer.region = box
                image[y0 : y0 + h, x0 : x0 + w] = self._render_canvas(T_world_cam, T_world_target)[:, :, :3]
            finally:
                renderer.region = None
        self._last_window = box if box is not None else "none"
        return image

    def _background_canvas(self, T_world_cam: np.ndarray, T_world_target: np.ndarray) -> np.ndarray:
        """The canvas without the target, one sample per pixel; rendered again only when the
        camera pose differs (bit for bit) from the last one's. Outside the target's box it is the
        scene's single-sample image: the target casts no shadow and reflects nothing."""
        key = T_world_cam.tobytes()
        if self._background is None or self._background[0] != key:
            renderer, target_mesh = self._renderer, self._target_node.mesh
            try:
                renderer.multisample, renderer.readback, target_mesh.is_visible = False, "all", False
                canvas = self._render_canvas(T_world_cam, T_world_target)
            finally:
                renderer.multisample, renderer.readback, target_mesh.is_visible = True, "auto", True
            self._background = (key, canvas)
            self.background_renders += 1
        return self._background[1]

    def _remap_rect(self, canvas: np.ndarray, rect=None) -> np.ndarray:
        """The distorted image (or its output rectangle ``rect`` = (u0, v0, u1, v1), ends
        excluded) of a canvas: each output pixel reads only its own bilinear taps."""
        map1, map2 = self._map1, self._map2
        if rect is not None:
            u0, v0, u1, v1 = rect
            map1, map2 = map1[v0:v1, u0:u1], map2[v0:v1, u0:u1]
        return cv2.remap(canvas, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _output_rect(self, box) -> tuple[int, int, int, int] | None:
        """The output rectangle (u0, v0, u1, v1), ends excluded, holding every output pixel one of
        whose bilinear taps lies in the canvas box (x0, y0, w, h); None when no pixel's does.

        From a table built once: for each _TAP_TILE_PX square tile of the canvas, the bounding
        rectangle of the output pixels with a tap in it (taps at the source's integer part and
        one pixel right and below, clamped to the canvas as ``BORDER_REPLICATE`` reads them).
        The rectangle of the tiles the box touches therefore holds the box's, and may be larger.
        """
        if self._tap_tiles is None:
            self._tap_tiles = _tap_tile_table(self._map1, self.canvas_intrinsics.size, _TAP_TILE_PX)
        lo, hi = self._tap_tiles
        x0, y0, w, h = box
        tiles = (slice(y0 // _TAP_TILE_PX, (y0 + h - 1) // _TAP_TILE_PX + 1),
                 slice(x0 // _TAP_TILE_PX, (x0 + w - 1) // _TAP_TILE_PX + 1))
        u0, v0 = lo[tiles].reshape(-1, 2).min(axis=0)
        u1, v1 = hi[tiles].reshape(-1, 2).max(axis=0)
        return (int(u0), int(v0), int(u1), int(v1)) if u1 > u0 and v1 > v0 else None

    def _distort_sharp(self, canvas: np.ndarray) -> np.ndarray:
        """The distorted image of the canvas :meth:`_render_sharp_canvas` just returned. When that
        canvas is the reused background with the target's window on top, only the output pixels
        whose taps reach the window are remapped; the rest come from the distorted background,
        kept while the background is. Bit-equal to remapping the whole canvas."""
        window = self._last_window
        if window is None:
            return self._remap_rect(canvas)
        key, background = self._background
        if self._distorted_background is None or self._distorted_background[0] != key:
            self._distorted_background = (key, self._remap_rect(background))
        image = self._distorted_background[1].copy()
        rect = None if isinstance(window, str) else self._output_rect(window)
        if rect is not None:
            u0, v0, u1, v1 = rect
            image[v0:v1, u0:u1] = self._remap_rect(canvas, rect)
        return image

    def _finish(self, canvas: np.ndarray, sharp: bool = False) -> np.ndarray:
        """Canvas → output image: lens distortion, then sensor noise. ``sharp``: the canvas is the
        one :meth:`_render_sharp_canvas` just returned (its reused background need not be
        remapped again)."""
        if self._map1 is not None:
            image = self._distort_sharp(canvas) if sharp else self._remap_rect(canvas)
        else:
            image = np.ascontiguousarray(canvas)
        if self.noise_std > 0:
            if self._noise is None:
                self._noise = np.empty(image.shape, dtype=np.float32)
            self._rng.standard_normal(out=self._noise, dtype=np.float32)
            noisy = image + self._noise * np.float32(self.noise_std)
            image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        return image

    def render(self, T_world_cam, T_world_target) -> np.ndarray:
        """Render one sharp frame.

        Parameters
        ----------
        T_world_cam : array_like, shape (4, 4)
            Camera pose in the world, OpenCV optical axes (x right, y down, z forward).
        T_world_target : array_like, shape (4, 4)
            Sphere centre, or marker centre and axes (module docstring), in the world.

        Returns
        -------
        ndarray, shape (H, W, 3), uint8
            sRGB image of the output camera (distorted if the renderer has a distortion).
        """
        return self._finish(self._render_sharp_canvas(T_world_cam, T_world_target), sharp=True)

    def render_exposure(self, pose_fn, t_start_s: float, exposure_s: float, n_subframes: int) -> np.ndarray:
        """Render a frame whose exposure integrates motion of camera and target (motion blur).

        Parameters
        ----------
        pose_fn : callable
            ``pose_fn(t_s) -> (T_world_cam, T_world_target)`` for a time in seconds.
        t_start_s : float
            Start of the exposure, seconds.
        exposure_s : float
            Exposure duration (≥ 0), seconds.
        n_subframes : int
            Number of sub-frames (≥ 1).

        Returns
        -------
        ndarray, shape (H, W, 3), uint8
            The mean of the sub-frames in linear light, re-encoded as sRGB, then distorted and
            noised like :meth:`render`.

        Notes
        -----
        The exposure is split into ``n_subframes`` equal slices, each sampled at its middle:
        t_k = t_start_s + (k + ½)·exposure_s/n_subframes. The frame's time centroid is therefore
        always mid-exposure, and ``n_subframes=1`` gives exactly ``render(*pose_fn(t_start_s +
        exposure_s/2))``. A sphere moving at constant image speed leaves a streak whose centres
        span (n − 1)/n of the exposure's motion (the continuous limit is the whole motion).
        Averaging happens on the pinhole canvas, before distortion (remap is linear).
        """
        n = int(n_subframes)
        if n != n_subframes or n < 1:
            raise ValueError(f"n_subframes must be an integer >= 1, got {n_subframes!r}")
        exposure_s = float(exposure_s)
        if not np.isfinite(exposure_s) or exposure_s < 0:
            raise ValueError(f"exposure_s must be >= 0 s, got {exposure_s}")
        t_start_s = float(t_start_s)
        if self._linear_sum is None:
            w, h = self.canvas_intrinsics.size
            self._linear_sum = np.empty((h, w, 3), dtype=np.float32)
        acc = self._linear_sum
        for k in range(n):
            T_world_cam, T_world_target = pose_fn(t_start_s + (k + 0.5) * exposure_s / n)
            linear = cv2.LUT(self._render_sharp_canvas(T_world_cam, T_world_target), _DECODE_LUT)
            if k == 0:
                acc[...] = linear
            else:
                cv2.add(acc, linear, dst=acc)
        levels = (acc * np.float32(_LINEAR_LEVELS / n) + np.float32(0.5)).astype(np.uint16)
        canvas = _ENCODE_LUT[levels]
        return self._finish(canvas)

    # ---------------------------------------------------------------------------------------
    # Motion blur: a fast frame from two layers, and its brute-force reference
    # ---------------------------------------------------------------------------------------
    def render_motion(self, pose_fn, t_start_s: float, exposure_s: float, readout_s: float = 0.0) -> np.ndarray:
        """Render a motion-blurred frame, global or rolling shutter, from two renders and image warps.

        Parameters
        ----------
        pose_fn : callable
            ``pose_fn(t_s) -> (T_world_cam, T_world_target)``, 4 × 4 each, continuous in time. It is
            called at a few knots (about every 1–2.5 ms, see Notes), including up to one knot
            spacing before ``t_start_s`` and after the last row's exposure ends. When it has a
            method ``pose_fn.many(times) -> (T_world_cam, T_world_target)``, shapes (N, 4, 4) each,
            the knots are sampled through it, all those of a grid at once.
        t_start_s : float
            Start of the exposure of the first row, seconds.
        exposure_s : float
            Exposure of each row (≥ 0), seconds.
        readout_s : float
            Rolling-shutter readout (≥ 0), seconds: output row r integrates
            [t_r, t_r + exposure_s] with t_r = t_start_s + r·readout_s/H (H the output height).
            0 is a global shutter.

        Returns
        -------
        ndarray, shape (H, W, 3), uint8
            Like :meth:`render`: the time average in linear light, sRGB-encoded, then distorted and
            noised. ``exposure_s = readout_s = 0`` returns exactly ``render(*pose_fn(t_start_s))``.

        Notes
        -----
        *Layers.* Two renders at t_ref, the middle of [t_start_s, t_start_s + readout_s +
        exposure_s]: the background (target hidden) and the target alone on a transparent
        background, in its bounding box only (scissored; its alpha is the 4× multisample
        coverage). Within the exposure each layer moves by a homography of the reference
        canvas: the ground z = 0 by its plane-induced homography K(R + p nᵀ/d)K⁻¹, exact for any
        camera motion (the sky is uniform and the ground's horizon moves with the rotation
        alone, as the sky's points at infinity do, so one homography serves the whole
        background); a marker by its plate's plane, exact; the sphere by the plane through its
        centre facing the camera.

        *Motion.* pose_fn is sampled at knots (2.5 ms apart or closer, halved while a cubic and
        the quintic spline through them disagree by more than 1 px; 11 instants for 1/60 s of the
        study's 120 Hz vibration, 19 with a 20 ms readout), and the camera's and target's
        motions relative to t_ref are interpolated between them.

        *Slices and warps.* The time span is cut into slices along which the target's image
        moves at most 1.5 px and the background's at most 2 px (finer for short paths: at least
        16 slices along each). The target layer is warped at every slice inside the region
        it sweeps. Background slices are grouped by image position into at most 8 groups, each
        warped once (by its members' mean homography) over the rows that can hold ground (rows
        above the horizon in every warp are sky); a vibration's repeated loops share groups.
        Warps interpolate sRGB-encoded values, as the renderer's multisample resolve and
        texture filtering do, and are decoded before the average, which is in linear light.
        Inside the target's region the background behind the target is taken at each slice's
        own position (to a slice step), and the renderer's encoded mixing on the target's rims is
        modelled from coverage moments (exact for a sharp frame, tested).

        *Rolling shutter.* Each slice adds to each canvas row the fraction of that row's
        exposure it covers, so the row times are exact (to a slice) without lens distortion.
        With distortion, canvas row v takes the time of the output row it lands on at the
        target region's centre column (exact there); elsewhere on that row the time is off by
        the lens's bending of rows, at most 16 rows (0.67 ms at a 20 ms readout) at the image
        corners for the default lens.

        *Approximations* (measured against :meth:`render_motion_reference` in
        ``tests/test_motion_blur.py`` and ``benchmarks/bench_blur.py``): bilinear warps of one
        render instead of fresh renders (the distant, grazing ground at the horizon is where
        this shows most); background groups up to a few pixels wide on long vibration paths;
        parts of the target outside the canvas at t_ref are missing when they come into view;
        the target keeps the appearance it has at t_ref (its own rotation and shading changes
        are not re-rendered).

        The blur of a moving, vibrating drone is the paper's argument for a gimbal (abstract,
        §4.1.3); parameters and bounds in docs/design.md, "Moving drone" and "Speed".
        """
        t0, exposure, readout = _check_motion_args(pose_fn, t_start_s, exposure_s, readout_s)
        if exposure == 0 and readout == 0:
            return self.render(*pose_fn(t0))
        if self.occluders:
            raise ValueError("render_motion composites the target over the background and cannot hide it behind "
                             "occluders: use render_exposure (blur='subframes') in a scene with occluders")
        if self._renderer is None:
            raise RuntimeError("the renderer is closed")
        return self._finish(self._motion_canvas(pose_fn, t0, exposure, readout))

    def render_motion_reference(
        self,
        pose_fn,
        t_start_s: float,
        exposure_s: float,
        readout_s: float = 0.0,
        n_subframes: int = 64,
        n_bands: int | None = None,
    ) -> np.ndarray:
        """The brute-force motion-blurred frame that :meth:`render_motion` is checked against.

        Parameters
        ----------
        pose_fn, t_start_s, exposure_s, readout_s
            As in :meth:`render_motion`.
        n_subframes : int
            Full renders per exposure (≥ 1), at the middles of equal slices, averaged in linear
            light (global shutter: exactly :meth:`render_exposure`, sub-frames drawn as
            :meth:`render` draws a frame; rolling shutter: bands multisampled everywhere, which
            differ from those only where the ground's far edge meets the sky).
        n_bands : int, optional
            Rolling shutter only: split the output rows into this many bands of equal height,
            each integrating the exposure of its middle row with its own ``n_subframes`` renders
            (scissored to the band). None (default): bands one sub-frame spacing
            ``exposure_s/n_subframes`` apart in time (every row joins the band whose start time
            is nearest its own), so the renders fall on one time grid and each serves every band
            it belongs to: (readout_s + exposure_s)·n_subframes/exposure_s renders in all (141 for
            1/60 s, 20 ms and 64). A row's time is then off by at most half a sub-frame spacing,
            the time resolution the sub-frames themselves have (0.13 ms, three rows, at 1/60 s
            and 64 sub-frames with a 20 ms readout). With a zero exposure every row is a band.

        Returns
        -------
        ndarray, shape (H, W, 3), uint8

        Notes
        -----
        With lens distortion a canvas pixel belongs to the band of the output row it lands on
        (exact per pixel). Averaging is on the canvas in linear light, then one encode, remap
        and noise, as in :meth:`render_exposure`.
        """
        t0, exposure, readout = _check_motion_args(pose_fn, t_start_s, exposure_s, readout_s)
        n = _count("n_subframes", n_subframes, 1)
        if n_bands is not None:
            n_bands = _count("n_bands", n_bands, 1)
        if readout == 0:
            if exposure == 0:
                return self.render(*pose_fn(t0))
            return self.render_exposure(pose_fn, t0, exposure, n)
        if self._renderer is None:
            raise RuntimeError("the renderer is closed")
        height = self.intrinsics.height
        rows = np.clip(self._canvas_output_rows(), 0.0, height - 1.0)  # output row of each canvas pixel
        if exposure == 0:
            n = 1
        if n_bands is None:
            band_step_s = exposure / n if exposure > 0 else readout / height
            band = np.rint(rows * (readout / height) / band_step_s).astype(np.int32)
            band_start = t0 + band_step_s * np.arange(int(band.max()) + 1)
            # grid render j serves bands j − n + 1 .. j
            jobs = [(t0 + j * band_step_s + (0.5 * exposure / n), j - n + 1, j) for j in range(len(band_start) + n - 1)]
        else:
            band = np.minimum((rows * (n_bands / height)).astype(np.int32), n_bands - 1)
            middle_row = (np.arange(n_bands) + 0.5) * height / n_bands - 0.5
            band_start = t0 + middle_row * readout / height
            jobs = [(band_start[b] + (k + 0.5) * exposure / n, b, b) for b in range(n_bands) for k in range(n)]
        w, h = self.canvas_intrinsics.size
        acc = np.zeros((h, w, 3), dtype=np.float32)
        for t, first, last in jobs:
            mask = (band >= first) & (band <= last)
            ys, xs = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
            if ys.size == 0:
                continue
            region = (int(xs[0]), int(ys[0]), int(xs[-1] - xs[0] + 1), int(ys[-1] - ys[0] + 1))
            T_world_cam, T_world_target = pose_fn(t)
            self._renderer.region = region
            try:
                rgba = self._render_canvas(T_world_cam, T_world_target)
            finally:
                self._renderer.region = None
            x0, y0, rw, rh = region
            linear = cv2.LUT(np.ascontiguousarray(rgba[:, :, :3]), _DECODE_LUT)
            acc[y0 : y0 + rh, x0 : x0 + rw] += linear * mask[y0 : y0 + rh, x0 : x0 + rw, None]
        np.clip(acc * np.float32(1.0 / n), 0.0, 1.0, out=acc)
        levels = (acc * np.float32(_LINEAR_LEVELS) + np.float32(0.5)).astype(np.uint16)
        return self._finish(_ENCODE_LUT[levels])

    # ---------------------------------------------------------------------------------------
    def _render_layer(self, T_world_cam, T_world_target, layer: str, region=None) -> np.ndarray:
        """The background alone (target hidden; RGB canvas) or the target alone on a transparent
        background (RGBA of ``region`` = (x0, y0, w, h); alpha is the 4× multisample coverage).
        Both are 4× multisampled everywhere (:meth:`_motion_background` multisamples only the
        part of the background that the target's composite reads: the rest of a single-sample
        background under the warped rim changed it by a grey level here and there, which moved
        a passive sphere's estimate by up to 27 mm on single frames)."""
        scene, target_mesh, ground_mesh = self._scene, self._target_node.mesh, self._ground_node.mesh
        bg_color = scene.bg_color
        try:
            if layer == "background":
                target_mesh.is_visible = False
            else:
                ground_mesh.is_visible = False
                scene.bg_color = np.zeros(4)
            self._renderer.region = region
            return self._render_canvas(T_world_cam, T_world_target)
        finally:
            self._renderer.region = None
            target_mesh.is_visible = True
            ground_mesh.is_visible = True
            scene.bg_color = bg_color

    def _motion_background(self, motion, region, G_group, G_k) -> np.ndarray:
        """The background layer of :meth:`render_motion` at the reference instant.

        With ``antialias="window"``: one sample per pixel (the sharp frames' background, reused
        while the camera does not move), 4× multisampled in the window the target's composite
        reads (``region``'s preimage under every slice's and group's background warp, plus the
        bilinear taps), so that every pixel of the target's region is the one a background
        multisampled everywhere gives, bit for bit. Elsewhere the blurred frame is background
        alone and differs as a sharp frame's background does (module notes)."""
        T_cam, T_target = motion.T_cam_ref, motion.T_target_ref
        self._last_background_window = None
        if self.antialias == "full" or not self._flags:
            return self._render_layer(T_cam, T_target, "background")
        background = self._background_canvas(T_cam, T_target).copy()
        if region is None:
            return background
        width, height = self.canvas_intrinsics.size
        x0, y0, x1, y1 = region
        corners = np.array([[x0, x1 - 1, x0, x1 - 1], [y0, y0, y1 - 1, y1 - 1], [1.0, 1.0, 1.0, 1.0]])
        inverses = np.linalg.inv(np.concatenate((G_group, G_k)))
        sources = _apply_homographies(inverses, corners).reshape(-1, 2)
        if not np.all(np.isfinite(sources)):
            return self._render_layer(T_cam, T_target, "background")
        wx0 = max(0, int(np.floor(sources[:, 0].min())) - _BACKGROUND_WINDOW_MARGIN_PX)
        wy0 = max(0, int(np.floor(sources[:, 1].min())) - _BACKGROUND_WINDOW_MARGIN_PX)
        wx1 = min(width, int(np.ceil(sources[:, 0].max())) + _BACKGROUND_WINDOW_MARGIN_PX + 1)
        wy1 = min(height, int(np.ceil(sources[:, 1].max())) + _BACKGROUND_WINDOW_MARGIN_PX + 1)
        if wx1 <= wx0 or wy1 <= wy0:
            return background
        if (wx1 - wx0) * (wy1 - wy0) > _WINDOW_MAX_SHARE * width * height:
            return self._render_layer(T_cam, T_target, "background")
        window = (wx0, wy0, wx1 - wx0, wy1 - wy0)
        target_mesh, renderer = self._target_node.mesh, self._renderer
        try:
            target_mesh.is_visible, renderer.region = False, window
            background[wy0:wy1, wx0:wx1] = self._render_canvas(T_cam, T_target)[:, :, :3]
        finally:
            target_mesh.is_visible, renderer.region = True, None
        self._last_background_window = window
        return background

    def _canvas_output_rows(self) -> np.ndarray:
        """The output-image row (float, unclipped) each canvas pixel lands on, (H_canvas, W_canvas)."""
        if self._output_rows is None:
            K, C = self.intrinsics, self.canvas_intrinsics
            if self._map1 is None:
                rows = np.repeat(np.arange(C.height, dtype=np.float32)[:, None], C.width, axis=1)
            else:
                u, v = np.meshgrid(np.arange(C.width, dtype=float), np.arange(C.height, dtype=float))
                uv = np.column_stack((u.ravel() - (C.cx - K.cx), v.ravel() - (C.cy - K.cy)))
                rows = distort_pixels(uv, K, self.distortion)[:, 1].reshape(C.height, C.width).astype(np.float32)
            self._output_rows = rows
        return self._output_rows

    def _target_layer(self, T_world_cam, T_world_target, box) -> np.ndarray:
        """The target alone in ``box``: encoded colour (0–1) and coverage, (h, w, 4) float32.

        The multisample resolve averages sRGB-encoded colour with the transparent black
        background, so colour/coverage is the target's own encoded colour. It is kept encoded
        (warps then interpolate it as the renderer's texture filtering does, in encoded values)
        and carried two pixels beyond the rim, so that interpolation there never mixes in black.
        """
        rgba = self._render_layer(T_world_cam, T_world_target, "target", region=box)
        alpha = rgba[:, :, 3].astype(np.float32) * np.float32(1.0 / 255.0)
        straight = rgba[:, :, :3] / np.maximum(alpha, np.float32(1.0 / 255.0))[:, :, None]
        covered = (alpha > 0).astype(np.float32)
        for _ in range(2):
            total = cv2.blur(straight * covered[:, :, None], (3, 3), borderType=cv2.BORDER_REPLICATE)
            count = cv2.blur(covered, (3, 3), borderType=cv2.BORDER_REPLICATE)
            grow = (covered == 0) & (count > 0)
            straight[grow] = total[grow] / count[grow][:, None]
            covered[grow] = 1.0
        return np.dstack((np.clip(straight * np.float32(1.0 / 255.0), 0.0, 1.0), alpha)).astype(np.float32)

    def _motion_canvas(self, pose_fn, t0: float, exposure: float, readout: float) -> np.ndarray:
        """The blurred pinhole canvas (uint8) of :meth:`render_motion`."""
        C = self.canvas_intrinsics
        width, height = C.size
        out_height = self.intrinsics.height
        bounds_m = self._target_bounds_m()
        t_lo, t_hi = t0, t0 + readout + exposure
        motion = _ExposureMotion(pose_fn, t_lo, t_hi, C.K, (width, height), bounds_m,
                                 "sphere" if self.target == "sphere" else "plate")
        box = motion.layer_box

        # Image paths on a dense time grid: the region the target sweeps, and the slicing.
        dense_t = motion.dense_times()
        G_dense, H_dense = motion.homographies(dense_t)
        bg_path = _apply_homographies(G_dense, motion.bg_points)
        region = None
        if box is not None:
            tg_path = _apply_homographies(H_dense, motion.target_points)
            if np.all(np.isfinite(tg_path)):
                pad = 1 + _FEATHER_PX  # a bilinear tap, then the feather (see below)
                x0 = max(0, int(np.floor(tg_path[:, :, 0].min())) - pad)
                y0 = max(0, int(np.floor(tg_path[:, :, 1].min())) - pad)
                x1 = min(width, int(np.ceil(tg_path[:, :, 0].max())) + pad + 1)
                y1 = min(height, int(np.ceil(tg_path[:, :, 1].max())) + pad + 1)
                if x1 > x0 and y1 > y0:
                    region = (x0, y0, x1, y1)
        if readout > 0:
            column = int(round(C.cx)) if region is None else (region[0] + region[2]) // 2
            rows = np.clip(self._canvas_output_rows()[:, column], 0.0, out_height - 1.0)
            row_start = t0 + rows.astype(float) * (readout / out_height)
        else:
            row_start = np.full(height, t0)
        bg_moves = np.linalg.norm(np.diff(bg_path, axis=0), axis=2).max(axis=1)
        bg_step_px = min(_BACKGROUND_STEP_PX, max(float(bg_moves.sum()) / _MIN_SLICES, 1e-3))
        step = bg_moves / bg_step_px
        if region is not None:
            seen_from = row_start[region[1] : region[3]].min()
            seen_until = row_start[region[1] : region[3]].max() + exposure
            live = (dense_t[1:] >= seen_from) & (dense_t[:-1] <= seen_until)
            tg_moves = np.where(live, np.linalg.norm(np.diff(tg_path, axis=0), axis=2).max(axis=1), 0.0)
            tg_step_px = min(_TARGET_STEP_PX, max(float(tg_moves.sum()) / _MIN_SLICES, 1e-3))
            step = np.maximum(step, tg_moves / tg_step_px)
        path = np.concatenate(([0.0], np.cumsum(step + 1e-9)))
        n_slices = max(1, int(np.ceil(path[-1] - 1e-6)))
        edges = np.interp(np.linspace(0.0, path[-1], n_slices + 1), path, dense_t)
        edges[0], edges[-1] = t_lo, t_hi
        a, b = edges[:-1], edges[1:]
        G_k, H_k = motion.homographies(0.5 * (a + b))

        # Slices whose background images lie close together share one warp.
        bg_travel = np.interp(0.5 * (a + b), dense_t, np.concatenate(([0.0], np.cumsum(bg_moves))))
        labels, n_groups, bg_spread_px = _background_groups(_apply_homographies(G_k, motion.bg_points), bg_travel,
                                                            bg_step_px)
        per_row = readout > 0 or exposure == 0
        weights = _overlap_weights(a, b, row_start, exposure) if per_row else (b - a) / exposure
        # Each group is warped by its members' mean homography, weighted by their share of the
        # exposure: what the group leaves out of the blur is then centred on the right place.
        share = weights.sum(axis=1) if per_row else weights
        G_group = np.empty((n_groups, 3, 3))
        for g in range(n_groups):
            members = labels == g
            G_norm = G_k[members] / G_k[members][:, 2:3, 2:3]
            G_group[g] = np.average(G_norm, axis=0, weights=share[members] + 1e-12)

        # Layers at t_ref.
        if self._motion_acc is None:  # reused: fresh 4 MB buffers cost page faults every frame
            self._motion_acc = (np.empty((2, height, width, 3), dtype=np.float32),
                                np.empty((height, width, 3), dtype=np.uint8))
        (acc, warp_buffer), warp_u8 = self._motion_acc
        bg_u8 = self._motion_background(motion, region, G_group, G_k)
        if region is not None:
            layer = self._target_layer(motion.T_cam_ref, motion.T_target_ref, box)
            if not np.any(layer[:, :, 3] > 0):
                region = None

        # Rows that hold ground in some warp; the rest is sky in every slice.
        not_sky = np.flatnonzero(np.any(bg_u8.reshape(height, -1) != np.tile(_SKY_U8, width), axis=1))
        if not_sky.size:
            top, bottom = int(not_sky[0]), int(not_sky[-1])
            ends = np.array([[0.0, width - 1.0, 0.0, width - 1.0], [top, top, bottom, bottom], [1.0, 1.0, 1.0, 1.0]])
            ys = _apply_homographies(G_group, ends)[:, :, 1]
            u0 = 0 if top == 0 else int(np.floor(np.nanmin(ys[:, :2]))) - 2
            u1 = height if bottom == height - 1 else int(np.ceil(np.nanmax(ys[:, 2:]))) + 3
            u0, u1 = max(0, u0), min(height, u1)
        else:
            u0, u1 = height, 0
        if region is not None:
            u0, u1 = min(u0, region[1]), max(u1, region[3])

        if u1 > u0:
            acc[u0:u1] = 0.0

        # The background: one warp per group, added with each row's share of the group's slices.
        n_warps = 0
        for g in range(n_groups if u1 > u0 else 0):
            members = np.flatnonzero(labels == g)
            if per_row:
                w_rows = weights[members].sum(axis=0)
                live_rows = np.flatnonzero(w_rows[u0:u1] > 0) + u0
                if live_rows.size == 0:
                    continue
                r0, r1 = int(live_rows[0]), int(live_rows[-1]) + 1
            else:
                r0, r1 = u0, u1
            # warped in encoded values, like the renderer's resolve and texture filtering, then decoded
            cv2.warpPerspective(bg_u8, _translation(0.0, -r0) @ G_group[g], (width, r1 - r0),
                                dst=warp_u8[: r1 - r0], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            warped = cv2.LUT(warp_u8[: r1 - r0], _DECODE_LUT, dst=warp_buffer[: r1 - r0])
            n_warps += 1
            if per_row:
                _add_row_weighted(acc, r0, warped, w_rows[r0:r1])
            else:
                cv2.scaleAdd(warped, float(weights[members].sum()), acc[r0:r1], dst=acc[r0:r1])

        # The target, slice by slice inside the region it sweeps: Σ_k w_k·(P_k + (1 − α_k)·B_k), its
        # colour P and coverage α warped by its own homography, B the background at slice k's own
        # position (to within a background step; slices within one step at the region's centre
        # share a small warp), not at its group's.
        if region is not None:
            x0, y0, x1, y1 = region
            size = (x1 - x0, y1 - y0)
            live = np.flatnonzero(weights[:, y0:y1].max(axis=1) > 0) if per_row else np.arange(n_slices)
            to_region, from_layer = _translation(-x0, -y0), _translation(box[0], box[1])
            centre = np.array([[0.5 * (x0 + x1 - 1)], [0.5 * (y0 + y1 - 1)], [1.0]])
            cells = np.floor(_apply_homographies(G_k[live], centre)[:, 0] / bg_step_px).astype(np.int64)
            _, first, cell_of = np.unique(cells, axis=0, return_index=True, return_inverse=True)
            cell_of = cell_of.reshape(-1)
            colour = np.zeros((size[1], size[0] * 3), dtype=np.float32)  # Σ w·P
            cover = np.zeros((len(first), size[1] * size[0]), dtype=np.float32)  # Σ w·α per cell
            rim = np.zeros((3,) + size[::-1], dtype=np.float32)  # Σ w·α(1 − α)·αʲ, j = 0, 1, 2
            for chunk in np.array_split(np.arange(len(live)), max(1, int(np.ceil(len(live) / 32)))):
                n = len(chunk)
                stack = np.empty((n,) + size[::-1] + (4,), dtype=np.float32)
                for i, k in enumerate(live[chunk]):
                    cv2.warpPerspective(layer, to_region @ H_k[k] @ from_layer, size, dst=stack[i],
                                        flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
                # each slice's colour, interpolated in encoded values, to 8 bits (as a render is), decoded
                codes = cv2.convertScaleAbs(stack.reshape(n * size[1], size[0], 4), alpha=255.0)
                linear = cv2.LUT(codes, _DECODE_LUT).reshape(n, size[1], size[0], 4)
                A = np.ascontiguousarray(stack[:, :, :, 3])
                w = weights[live[chunk]].astype(np.float32)
                wA = A * (w[:, y0:y1, None] if per_row else w[:, None, None])
                colour += (linear * wA[:, :, :, None]).sum(axis=0)[:, :, :3].reshape(colour.shape)
                members = np.zeros((len(first), n), dtype=np.float32)
                members[cell_of[chunk], np.arange(n)] = 1.0
                cover += members @ wA.reshape(n, -1)
                term = wA * (1.0 - A)
                for j in range(3):
                    rim[j] += term.sum(axis=0)
                    if j < 2:
                        term *= A
            colour = colour.reshape(size[::-1] + (3,))
            cover = cover.reshape((len(first),) + size[::-1])
            # the background at each cell, warped (in encoded values) from a window of the render
            corners = np.array([[x0, x1 - 1, x0, x1 - 1], [y0, y0, y1 - 1, y1 - 1], [1.0, 1.0, 1.0, 1.0]])
            sources = _apply_homographies(np.linalg.inv(G_k[live[first]]), corners).reshape(-1, 2)
            wx0, wy0 = (max(0, int(np.floor(v)) - 2) for v in sources.min(axis=0))
            wx1 = min(width, int(np.ceil(sources[:, 0].max())) + 3)
            wy1 = min(height, int(np.ceil(sources[:, 1].max())) + 3)
            window = cv2.cvtColor(bg_u8[wy0:wy1, wx0:wx1], cv2.COLOR_RGB2RGBA).astype(np.float32)
            cells_bg = np.empty((len(first),) + size[::-1] + (4,), dtype=np.float32)
            for c, k in enumerate(live[first]):
                cv2.warpPerspective(window, to_region @ G_k[k] @ _translation(wx0, wy0), size, dst=cells_bg[c],
                                    flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            cells_bg = cv2.LUT(cv2.convertScaleAbs(cells_bg.reshape(-1, size[0], 4)), _DECODE_LUT)
            cells_bg = cells_bg.reshape((len(first),) + size[::-1] + (4,))[:, :, :, :3]
            if per_row:
                w_cells = np.zeros((len(first), size[1]), dtype=np.float32)
                np.add.at(w_cells, cell_of, weights[live, y0:y1].astype(np.float32))
                behind = (cells_bg * w_cells[:, :, None, None]).sum(axis=0)  # Σ w·B
            else:
                w_cells = np.bincount(cell_of, weights=weights[live], minlength=len(first)).astype(np.float32)
                behind = np.tensordot(w_cells, cells_bg, axes=1)  # Σ w·B
            hidden = (cells_bg * cover[:, :, :, None]).sum(axis=0)  # Σ w·α·B
            # The groups' background outside is up to background_spread_px off, which shows on sharp
            # edges such as the horizon behind a rim; a feather of _FEATHER_PX at the region's edge,
            # where the target never comes, joins the two. The rim deficit is the renderer's
            # sRGB-encoded mixing on the target's rims (see _rim_deficit).
            coverage = cover.sum(axis=0)[:, :, None]
            feather = _feather(region, (width, height))[:, :, None]
            patch = acc[y0:y1, x0:x1]
            patch -= behind
            patch *= feather
            patch += behind
            patch += colour
            patch -= hidden
            patch -= _rim_deficit(colour, coverage[:, :, 0], behind, rim)
        canvas = np.empty((height, width, 3), dtype=np.uint8)
        canvas[:u0] = _SKY_U8
        canvas[max(u0, u1):] = _SKY_U8
        if u1 > u0:
            part = acc[u0:u1]
            np.clip(part, 0.0, 1.0, out=part)
            part *= np.float32(_LINEAR_LEVELS)
            part += np.float32(0.5)
            canvas[u0:u1] = _ENCODE_LUT.take(part.astype(np.uint16))
        self._motion_stats = {
            "pose_calls": motion.pose_calls,
            "pose_instants": motion.pose_instants,
            "knot_spacing_s": motion.knot_spacing_s,
            "interpolation_error_px": motion.interpolation_error_px,
            "slices": n_slices,
            "background_warps": n_warps,
            "background_spread_px": bg_spread_px,
            "warped_rows": (u0, u1),
            "target_region": region,
            "background_window": self._last_background_window,
        }
        return canvas

    # ---------------------------------------------------------------------------------------
    def close(self) -> None:
        """Free the OpenGL context and its resources (idempotent)."""
        if self._renderer is not None:
            try:
                self._platform.make_current()
                self._renderer.delete()
            finally:
                self._platform.delete_context()
                self._renderer = None
                self._platform = None
                self._background = self._distorted_background = None

    def __enter__(self) -> "SceneRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


# ----------------------------------------------------------------------------------------------
# sensor noise
# ----------------------------------------------------------------------------------------------
_NOISE_LEVELS = 1 << 16
_NOISE_TABLES: dict = {}


def _rounded_gaussian_table(std: float) -> np.ndarray:
    """Inverse CDF of N(0, std²) at the 2¹⁶ mid-quantiles, rounded to integers (int16)."""
    table = _NOISE_TABLES.get(std)
    if table is None:
        from scipy.stats import norm

        quantiles = (np.arange(_NOISE_LEVELS) + 0.5) / _NOISE_LEVELS
        table = np.rint(norm.ppf(quantiles) * std).astype(np.int16)
        _NOISE_TABLES[std] = table
    return table


def add_sensor_noise(image: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """The 8-bit image a sensor with Gaussian read noise of ``std`` grey levels would record.

    Every pixel and channel independently becomes clip(round(value + n), 0, 255) with
    n ~ N(0, std²). For integer ``value`` that is value + round(n), so the rounded Gaussian is drawn
    directly: 16 random bits per sample index a table of its inverse CDF at the 2¹⁶ mid-quantiles
    (tails beyond ±4.2 σ, probability 3·10⁻⁵, are cut). The bits are the bit generator's raw
    64-bit words, four samples to a word, taken in little-endian order (for numpy's default
    PCG64 the same bytes as ``rng.bytes``, several times faster). It costs about a tenth of
    drawing floating-point normals for a 640 × 480 RGB frame, and is exact in distribution.

    Parameters
    ----------
    image : ndarray of uint8, any shape
    std : float
        Noise standard deviation in grey levels, >= 0 (0 returns the image unchanged).
    rng : numpy.random.Generator
        The source of randomness (same generator state → same noise).

    Returns
    -------
    ndarray of uint8, same shape.
    """
    if isinstance(std, bool) or not np.isfinite(std) or std < 0:
        raise ValueError(f"std must be a finite number >= 0 grey levels, got {std!r}")
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise TypeError(f"image must be uint8, got {image.dtype}")
    if std == 0:
        return image
    table = _rounded_gaussian_table(float(std))
    words = rng.bit_generator.random_raw(-(-image.size // 4))
    draws = words.astype("<u8", copy=False).view(np.uint16)[: image.size].reshape(image.shape)
    noisy = np.take(table, draws)
    noisy += image
    np.clip(noisy, 0, 255, out=noisy)
    return noisy.astype(np.uint8)
