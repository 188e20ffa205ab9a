"""The run's configuration: one frozen part per thing the run simulates, nested like the rig.

A :class:`TrackingConfig` holds six parts and the run's own two numbers::

    TrackingConfig(camera=Camera(), gimbal=Gimbal(), platform=Platform(), target=Target(),
                   pointing=Pointing(), estimator=Estimator(), revolutions=2.0, seed=0)

* :class:`Camera`: image size and field of view (or a calibration's intrinsics), lens, frame
  rate, latency, exposure, rolling-shutter readout, how blur is integrated, sensor noise;
* :class:`Gimbal`: the DH geometry with its joint limits, the inner loop's rate, the gyro's noise,
  the joint-rate limit of the outer loops, the axes' plants and rate-loop gains;
* :class:`Platform`: the drone body's motion (still, hover sway, vibration, flight) and height;
* :class:`Target`: sphere or marker, its size, its trajectory and phase, the occluders;
* :class:`Pointing`: what turns the camera: fixed to the body, stabilised, or an active law (the
  paper's image loop, the predictive loop, filter-driven pointing);
* :class:`Estimator`: the sphere's localiser, the lens strategy, the marker's corner refinement.

Each part validates its own fields, naming them ``part.field``. A rule that ties two parts lives
in one place, :func:`check_parts`, and names both. Each part builds what the closed loop needs
from it (:meth:`Camera.make_renderer`, :meth:`Platform.body`, :meth:`Gimbal.mount`,
:meth:`Pointing.build`, :meth:`Estimator.build`, :meth:`Target.path`), so the loop has no branch
on a part's kind.

Parts and the whole config convert to and from plain nested dicts (:meth:`TrackingConfig.to_dict`,
:meth:`TrackingConfig.from_dict`: one table per part, unknown keys name part and key), and change
at two levels: ``config.replace(camera=config.camera.replace(fps=60))`` or, the same,
``config.with_(camera__fps=60)`` (a double underscore steps into a part, and into a part's own
parameter objects: ``platform__sway__yaw_rms_rad``). :attr:`TrackingConfig.key` hashes the nested
dict with :data:`SCHEMA`, so a result stored under another schema is never served.

Notes
-----
docs/design.md, "Configuration"; the study's values are the defaults (paper §4.1).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from .camera import BrownConrady, Intrinsics, KannalaBrandt, Rational, project
from .kinematics import GimbalKinematics
from .platform import BodyMotion, HoverSway, Vibration, WaypointFlight
from .trajectories import Trajectory

# control (python-control, scipy) and scene (OpenCV) are imported where they are used, so that
# importing the config (and the runner) loads neither

__all__ = ["TrackingConfig", "Camera", "Gimbal", "Platform", "Target", "Pointing", "GimbalLink", "Estimator",
           "check_parts",
           "SCHEMA", "CONE_RANGE_M", "CONE_FIELD_FRACTION", "BODY_POSITION_M", "PLATE_TO_MARKER", "world_T_base",
           "make_target_filter", "Measurement", "STREAMS", "seed_stream", "streams"]

#: Version of the config's layout; part of :attr:`TrackingConfig.key` (the flat config of before
#: the parts had no schema, and its keys differ).
SCHEMA = "gimbal-lab/tracking-config/2"

#: The cone trajectory (docs/design.md, "Lens sweep"): the target circles the home optical axis at
#: this range from the home camera, off the axis by this fraction of the half horizontal field.
CONE_RANGE_M = 3.0
CONE_FIELD_FRACTION = 0.7

#: Where the UAV body sits in the world during the study (static, level, facing +x); a platform's
#: ``altitude_m`` replaces the height.
BODY_POSITION_M = (0.0, 0.0, 2.0)

#: Width of the marker's white plate over the marker's own (0.40 m for the study's 0.30 m marker).
PLATE_TO_MARKER = 0.40 / 0.30

#: Upper bounds that keep a config's sizes sane (a run, not a typo, decides the cost).
_MAX_IMAGE_PX = 8192
_MAX_INNER_RATE_HZ = 100_000.0
_MAX_FRAMES = 1_000_000
_MAX_SUBFRAMES = 1024


def _number(name, value, *, low=None, high=None, low_open=False, integer=False):
    """A real number from ``value`` (never a bool, a string or NaN/inf), or a clear error."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    lo = "" if low is None else (f"> {low:g}" if low_open else f">= {low:g}")
    hi = "" if high is None else f"<= {high:g}"
    allowed = " and ".join(t for t in (lo, hi) if t) or "finite"
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite ({allowed}), got {value!r}")
    if (low is not None and (v <= low if low_open else v < low)) or (high is not None and v > high):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    if integer:
        if not v.is_integer():
            raise ValueError(f"{name} must be an integer ({allowed}), got {value!r}")
        return int(v)
    return v


def _choice(name, value, allowed):
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return value


# ----------------------------------------------------------------------------------------------
# a replicate's random streams
# ----------------------------------------------------------------------------------------------
#: The named random streams of a replicate, in the order of ``SeedSequence(seed).spawn``: the
#: target's start phase, the sensor noise, the body's sway and vibration, the gyro noise, the
#: manoeuvring target's plan, the flight's start point (docs/design.md, "Repairs").
STREAMS = ("phase", "noise", "body", "gyro", "plan", "flight_phase")


def seed_stream(seed: int, name: str) -> np.random.SeedSequence:
    """The named child of ``numpy.random.SeedSequence(seed)`` that a replicate's ``name`` draw comes from.

    Child i of ``SeedSequence(seed)`` (``spawn_key=(i,)``, what ``SeedSequence(seed).spawn(n)[i]``
    gives) belongs to ``STREAMS[i]``. Children of one seed differ by their spawn key, and a seed's
    children differ from another seed's by their entropy, so no two (seed, name) pairs share a
    stream. (Before, each draw built its own sequence from a short list of integers, and
    replicate 2's phase, ``default_rng([1, 2])``, was replicate 1's gyro, ``SeedSequence([1, 2])``.)

    Parameters
    ----------
    seed : int
        The replicate's seed, >= 0.
    name : {"phase", "noise", "body", "gyro", "plan", "flight_phase"}
        The draw (:data:`STREAMS`).

    Returns
    -------
    numpy.random.SeedSequence
        Give it to ``numpy.random.default_rng``; the same seed and name always give the same draws.

    Examples
    --------
    >>> seed_stream(3, "gyro").generate_state(2).tolist() == streams(3)["gyro"].generate_state(2).tolist()
    True
    """
    seed = _number("seed", seed, low=0, high=2**63 - 1, integer=True)
    _choice("stream name", name, STREAMS)
    return np.random.SeedSequence(seed, spawn_key=(STREAMS.index(name),))


def streams(seed: int) -> dict[str, np.random.SeedSequence]:
    """Every named stream of replicate ``seed`` (:func:`seed_stream`), by name."""
    return {name: seed_stream(seed, name) for name in STREAMS}


# ----------------------------------------------------------------------------------------------
# what every part shares: validation naming part.field, replace, with_, dicts
# ----------------------------------------------------------------------------------------------
def _plain(value):
    """A dataclass or tuple as plain JSON/TOML values (tuples become lists; None is left to drop)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def _from_table(cls, data, where: str):
    """``cls(**data)`` from a plain dict, unknown keys an error naming ``where`` and the key."""
    if isinstance(data, cls):
        return data
    if not isinstance(data, dict):
        raise TypeError(f"{where} must be a table (dict) of {cls.__name__} fields, got {type(data).__name__} {data!r}")
    allowed = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise ValueError(f"unknown {where} key(s): {', '.join(unknown)} (allowed: {', '.join(allowed)})")
    if issubclass(cls, _Part):  # a part names its own fields
        return cls(**data)
    try:
        return cls(**data)
    except (ValueError, TypeError) as exc:  # name where the bad value sits
        raise type(exc)(f"{where}: {exc}") from None


def _with(obj, changes: dict, where: str):
    """``obj`` with ``changes`` whose keys may step into nested dataclasses with "__"."""
    direct, nested = {}, {}
    for key, value in changes.items():
        head, sep, rest = key.partition("__")
        if sep:
            nested.setdefault(head, {})[rest] = value
        else:
            direct[head] = value
    names = [f.name for f in dataclasses.fields(obj) if f.init]
    for head, sub in nested.items():
        if head not in names:
            raise ValueError(f"{where} has no field {head!r} (fields: {', '.join(names)})")
        if head in direct:
            raise ValueError(f"{where}.{head} is both replaced and changed field by field; give one")
        inner = getattr(obj, head)
        if not (dataclasses.is_dataclass(inner) and not isinstance(inner, type)):
            raise ValueError(f"{where}.{head} is not a part with fields, so {head}__... cannot change it")
        direct[head] = _with(inner, sub, f"{where}.{head}")
    unknown = sorted(set(direct) - set(names))
    if unknown:
        raise ValueError(f"{where} has no field(s) {', '.join(unknown)} (fields: {', '.join(names)})")
    return dataclasses.replace(obj, **direct)


class _Part:
    """Base of the parts: ``replace``, ``with_``, ``to_dict`` and ``from_dict``, and the helpers
    that validate a field naming it ``part.field``."""

    _NAME: ClassVar[str] = ""

    def _set(self, name, value) -> None:
        object.__setattr__(self, name, value)

    def _number(self, name, **limits) -> None:
        self._set(name, _number(f"{self._NAME}.{name}", getattr(self, name), **limits))

    def _choice(self, name, allowed) -> None:
        _choice(f"{self._NAME}.{name}", getattr(self, name), allowed)

    def _table(self, name, cls, optional: bool = False) -> None:
        """Accept a field given as its table (a dict); then require an instance of ``cls``."""
        value = getattr(self, name)
        if value is None and optional:
            return
        if isinstance(value, dict):
            value = _from_table(cls, value, f"{self._NAME}.{name}")
            self._set(name, value)
        if not isinstance(value, cls):
            raise TypeError(f"{self._NAME}.{name} must be a {cls.__name__}{' or None' if optional else ''}, "
                            f"got {type(value).__name__}")

    def _triple(self, name, cls) -> None:
        """A per-joint (yaw, roll, pitch) tuple of ``cls`` (or None)."""
        value = getattr(self, name)
        if value is None:
            return
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) != 3:
            raise ValueError(f"{self._NAME}.{name} must be three {cls.__name__} (yaw, roll, pitch) or None, "
                             f"got {value!r}")
        items = tuple(_from_table(cls, v, f"{self._NAME}.{name}[{i}]") for i, v in enumerate(value))
        self._set(name, items)

    def replace(self, **changes):
        """A copy with some fields changed (validated again); unknown fields name themselves."""
        return _with(self, changes, self._NAME)

    def with_(self, **changes):
        """A copy with fields changed, ``name__field`` stepping into a nested parameter object
        (``Platform().with_(sway__yaw_rms_rad=0.01)``)."""
        return _with(self, changes, self._NAME)

    def to_dict(self) -> dict:
        """The part as a plain dict (one TOML table; fields that are None are left out)."""
        out = {}
        for f in dataclasses.fields(self):
            if not f.init:
                continue
            value = self._encode(f.name, getattr(self, f.name))
            if value is not None:
                out[f.name] = value
        return out

    def _encode(self, name, value):
        return _plain(value)

    @classmethod
    def from_dict(cls, data: dict):
        """The part a :meth:`to_dict` table describes (unknown keys name part and key)."""
        return _from_table(cls, data, cls._NAME)


# ----------------------------------------------------------------------------------------------
# camera
# ----------------------------------------------------------------------------------------------
_LENS_NAMES = ("none", "default")
_BLURS = ("auto", "fast", "subframes", "none")
_NOISES = ("fixed", "sensor")
#: The lens a sensor camera assumes when ``f_number`` is not given.
_DEFAULT_F_NUMBER = 2.8
#: Largest image motion, px, between two sub-frames of an exposure whose count is derived from its
#: streak (:meth:`Camera.subframe_count`): consecutive copies of the target overlap to a pixel.
SUBFRAME_STEP_PX = 1.0
_LENS_MODELS = {"brown_conrady": BrownConrady, "rational": Rational, "kannala_brandt": KannalaBrandt}


def _lens_from_table(value, where: str):
    if not isinstance(value, dict):
        return value
    table = dict(value)
    model = table.pop("model", "brown_conrady")
    if model not in _LENS_MODELS:
        raise ValueError(f"{where}: unknown lens model {model!r} (brown_conrady, rational or kannala_brandt)")
    return _from_table(_LENS_MODELS[model], table, f"{where} ({model})")


@dataclass(frozen=True)
class Camera(_Part):
    """The camera: its image, lens, timing, exposure and noise.

    The focal length comes either from ``hfov_rad`` (the study: 60° across 640 px) or from a
    calibration's ``calibration`` intrinsics (any fx, fy, cx, cy; ``hfov_rad`` must then be None),
    usually read from a calibration file by :meth:`from_calibration`; :attr:`intrinsics` is the one
    the run uses.

    Parameters
    ----------
    width, height : int
        Image size, px (640 × 480); with ``calibration``, its size (None takes it).
    hfov_rad : float or None
        Horizontal field of view, rad (60°). Below 179° for a pinhole or Brown–Conrady lens, up to
        twice the fisheye's ``max_field_rad`` for a Kannala–Brandt lens, whose focal length it sets
        by the equidistant rule f = (W/2)/(hfov/2)
        (:meth:`gimbal_lab.camera.KannalaBrandt.equidistant_for_fov`).
    calibration : Intrinsics or None
        A calibrated camera's intrinsics (its width and height are the image's).
    lens : {"none", "default"}, BrownConrady, Rational or KannalaBrandt
        "default" is :meth:`BrownConrady.default`; a :class:`KannalaBrandt` fisheye is rendered
        through :class:`gimbal_lab.widefield.WideFieldRenderer`. As a table: ``model``
        ("brown_conrady", the default, "rational" or "kannala_brandt") and the lens's coefficients.
    fps : float
        Frame rate, 1/s (30).
    latency_frames : int
        Frames between taking an image and its detection reaching the outer loop (1); >= 1 with
        an exposure (a frame is detected after it).
    exposure_s : float
        Exposure, s, in [0, 1/fps] (0: a sharp instant).
    readout_s : float
        Rolling-shutter readout, s, in [0, 1/fps] (0: global shutter); row r is exposed from
        t + r·readout_s/H. Needs the fast blur (``blur`` "fast", or "auto" where it applies).
    blur : {"auto", "fast", "subframes", "none"}
        How an exposure is integrated (docs/design.md, "Exposure and blur"). A camera that
        exposes integrates its exposure: "auto" (the default) takes the fast path where it applies
        and sub-frames where it does not (:meth:`blur_method`); "fast" is
        :meth:`gimbal_lab.scene.SceneRenderer.render_motion` (warped layers, global or rolling
        shutter); "subframes" averages full renders, ``n_subframes`` of them or as many as the
        frame's streak needs (:meth:`subframe_count`). "none" renders one sharp instant at
        mid-exposure although the camera exposes: an idealisation that must be asked for, and
        that every report naming such a run states. A fisheye integrates from sub-frames only.
    n_subframes : int or None
        Renders averaged over an exposure with ``blur="subframes"``, >= 2; None (the default)
        derives the count of each frame from its streak (:meth:`subframe_count`).
    noise : {"fixed", "sensor"}
        How the sensor records a frame: "fixed" (the default) adds Gaussian noise of ``noise_std``
        grey levels whatever the light and exposure (:func:`gimbal_lab.scene.add_sensor_noise`);
        "sensor" is the EMVA 1288 model tied to light (:class:`gimbal_lab.sensor.SensorModel`;
        docs/design.md, "Sensor and light"): ``light_lux`` on the scene, ``sensor``'s figures
        behind an f/``f_number`` lens, over the camera's ``exposure_s`` (which must be > 0).
    noise_std : float
        The fixed noise, grey levels (2); only with ``noise="fixed"``.
    light_lux : float or None
        The scene's illuminance, lx; required with ``noise="sensor"``, refused otherwise.
    sensor : str or None
        A built-in sensor's name (:data:`gimbal_lab.sensor.SENSORS`: "IMX273", the default with
        ``noise="sensor"``); refused with ``noise="fixed"``.
    f_number : float or None
        The lens's f-number (2.8 by default with ``noise="sensor"``); refused with ``noise="fixed"``.
    """

    width: int | None = None
    height: int | None = None
    hfov_rad: float | None = None
    calibration: Intrinsics | None = None
    lens: object = "none"
    fps: float = 30.0
    latency_frames: int = 1
    exposure_s: float = 0.0
    readout_s: float = 0.0
    blur: str = "auto"
    n_subframes: int | None = None
    noise_std: float = 2.0
    noise: str = "fixed"
    light_lux: float | None = None
    sensor: str | None = None
    f_number: float | None = None

    _NAME = "camera"

    #: Fields a calibration file gives; :meth:`from_calibration` refuses them as keywords.
    _CALIBRATED: ClassVar[tuple] = ("calibration", "lens", "hfov_rad", "width", "height")

    @classmethod
    def from_calibration(cls, path, image_size: tuple[int, int] | None = None, **fields) -> "Camera":
        """A calibrated camera: intrinsics and lens from a calibration file, the rest from ``fields``.

        The file is read by :func:`gimbal_lab.calibration.load_calibration` (OpenCV FileStorage
        YAML/XML/JSON or ROS camera_info; any fx, fy, cx, cy and image size; a Brown–Conrady or
        Kannala–Brandt lens, or an ideal one), the reader ``gimbal-lab track --calibration`` uses.
        The camera keeps the calibration's numbers, not the path: its :meth:`to_dict` (and so a
        run's store key) changes when a number of the file changes, and not when the file moves.

        Parameters
        ----------
        path : str or os.PathLike
            The calibration file.
        image_size : (int, int), optional
            (width, height) in pixels for a file that states none (it must agree when it does).
        **fields
            The camera's other fields (``fps``, ``latency_frames``, ``exposure_s``, ...); the
            calibration gives ``calibration``, ``lens``, ``hfov_rad``, ``width`` and ``height``,
            which are refused here.

        Raises
        ------
        FileNotFoundError, ValueError
            From the reader (naming the file, the node and what is allowed), or a field the
            calibration gives.

        Examples
        --------
        >>> cam = Camera.from_calibration("data/calibration/sample_640x480.yml", fps=60)  # doctest: +SKIP
        >>> cam.intrinsics.fx, cam.lens_label, cam.fps  # doctest: +SKIP
        (554.2562584220408, 'custom', 60.0)
        """
        from .calibration import load_calibration

        given = [name for name in cls._CALIBRATED if name in fields]
        if given:
            raise ValueError(f"camera.{given[0]} comes from the calibration file {str(path)!r}; give only the "
                             f"camera's other fields (not {', '.join(cls._CALIBRATED)})")
        calibration = load_calibration(path, image_size)
        lens = calibration.lens if calibration.lens is not None else "none"
        return cls(calibration=calibration.intrinsics, lens=lens, **fields)

    def __post_init__(self):
        self._set("lens", _lens_from_table(self.lens, "camera.lens"))
        if not isinstance(self.lens, (BrownConrady, Rational, KannalaBrandt)):
            if not isinstance(self.lens, str):
                raise TypeError(f"camera.lens must be one of {_LENS_NAMES}, a BrownConrady, a Rational or a "
                                "KannalaBrandt, "
                                f"got {type(self.lens).__name__}")
            self._choice("lens", _LENS_NAMES)
        self._number("fps", low=0.0, low_open=True)
        self._table("calibration", Intrinsics, optional=True)
        if self.calibration is None:
            if self.hfov_rad is None:
                self._set("hfov_rad", math.radians(60.0))
            for name, default in (("width", 640), ("height", 480)):
                if getattr(self, name) is None:
                    self._set(name, default)
                self._number(name, low=16, high=_MAX_IMAGE_PX, integer=True)
            fisheye = isinstance(self.lens, KannalaBrandt)
            widest = min(2.0 * self.lens.max_field_rad, 2.0 * math.pi) if fisheye else math.radians(179.0)
            self._number("hfov_rad", low=0.0, high=widest, low_open=True)
        else:
            if self.hfov_rad is not None:
                raise ValueError("camera.hfov_rad and camera.calibration both give the focal length: set hfov_rad=None "
                                 "with a calibration (and width=None, height=None: the calibration's size is the "
                                 "image's)")
            K = self.calibration
            for name in ("width", "height"):
                size = getattr(K, name)
                if getattr(self, name) is not None and getattr(self, name) != size:
                    raise ValueError(f"camera.{name}={getattr(self, name)!r} differs from camera.calibration.{name}="
                                     f"{size}: the calibration's image size is the camera's (leave {name}=None)")
                self._set(name, size)
                self._number(name, low=16, high=_MAX_IMAGE_PX, integer=True)
        self._number("latency_frames", low=0, integer=True)
        self._number("exposure_s", low=0.0, high=1.0 / self.fps)
        if self.exposure_s > 0 and self.latency_frames < 1:
            raise ValueError("camera.exposure_s > 0 needs camera.latency_frames >= 1: a frame is detected after its "
                             "exposure, so its detection cannot steer the camera during it")
        self._number("noise_std", low=0.0, high=128.0)
        self._check_noise()
        self._choice("blur", _BLURS)
        self._number("readout_s", low=0.0, high=1.0 / self.fps)
        fisheye = isinstance(self.lens, KannalaBrandt)
        if self.readout_s > 0 and (self.blur not in ("fast", "auto") or fisheye):
            raise ValueError(f"camera.readout_s > 0 (a rolling shutter) needs camera.blur='fast' (or 'auto' without "
                             f"a fisheye), got {self.blur!r}{' and a fisheye lens' if fisheye else ''}")
        if fisheye and self.exposure_s > 0 and self.blur == "fast":
            raise ValueError("camera.lens is a KannalaBrandt fisheye, which integrates exposures from sub-frames: "
                             "use camera.blur='subframes' (or 'auto')")
        if self.n_subframes is not None:
            self._number("n_subframes", low=2, high=_MAX_SUBFRAMES, integer=True)
            if self.blur != "subframes" or self.exposure_s <= 0:
                raise ValueError(f"camera.n_subframes={self.n_subframes} does nothing unless camera.blur='subframes' "
                                 f"and camera.exposure_s > 0 (got blur={self.blur!r}, exposure_s={self.exposure_s:g}); "
                                 "leave it None to derive each frame's count from its streak")

    def _check_noise(self) -> None:
        """The noise fields: each one the chosen model uses, and only those."""
        from .sensor import SENSORS

        self._choice("noise", _NOISES)
        light_fields = ("light_lux", "sensor", "f_number")
        if self.noise == "fixed":
            given = [name for name in light_fields if getattr(self, name) is not None]
            if given:
                raise ValueError(f"camera.{given[0]}={getattr(self, given[0])!r} does nothing with camera.noise='fixed' "
                                 "(a constant noise_std); set camera.noise='sensor' to tie the noise to the light")
            return
        if self.noise_std != Camera.noise_std:
            raise ValueError(f"camera.noise_std={self.noise_std:g} does nothing with camera.noise='sensor' (the noise "
                             "comes from light_lux, the sensor and the exposure); leave it at its default")
        if self.exposure_s <= 0:
            raise ValueError("camera.noise='sensor' needs camera.exposure_s > 0: the sensor collects light over the "
                             f"exposure (got exposure_s={self.exposure_s:g})")
        if self.light_lux is None:
            raise ValueError("camera.noise='sensor' needs camera.light_lux, the scene's illuminance in lux")
        self._number("light_lux", low=0.0, high=1e6, low_open=True)
        if self.sensor is None:
            self._set("sensor", "IMX273")
        self._choice("sensor", tuple(SENSORS))
        if self.f_number is None:
            self._set("f_number", _DEFAULT_F_NUMBER)
        self._number("f_number", low=0.5, high=64.0)

    def _encode(self, name, value):
        if name == "noise" and value == "fixed":
            return None  # the default, left out so that the configs of before the field keep their keys
        if name == "lens" and isinstance(value, (BrownConrady, Rational, KannalaBrandt)):
            model = next(key for key, kind in _LENS_MODELS.items() if isinstance(value, kind))
            return {"model": model, **{k: float(v) for k, v in dataclasses.asdict(value).items()}}
        return _plain(value)

    # derived ---------------------------------------------------------------------------------
    @property
    def intrinsics(self) -> Intrinsics:
        """The intrinsics the run uses: the calibration's, or those of ``hfov_rad`` (for a fisheye,
        the equidistant rule's focal length with the principal point at the image's centre)."""
        if self.calibration is not None:
            return self.calibration
        if isinstance(self.lens, KannalaBrandt):
            f_px = KannalaBrandt.equidistant_for_fov(self.width, self.hfov_rad)[1]
            return Intrinsics(f_px, f_px, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.width, self.height)
        return Intrinsics.from_fov(self.width, self.height, self.hfov_rad)

    @property
    def lens_model(self) -> BrownConrady | Rational | KannalaBrandt | None:
        """The lens model, or None for an ideal pinhole lens."""
        if isinstance(self.lens, KannalaBrandt):
            return self.lens
        if isinstance(self.lens, (BrownConrady, Rational)):
            return None if self.lens.is_identity else self.lens
        return BrownConrady.default() if self.lens == "default" else None

    @property
    def lens_label(self) -> str:
        """"undistorted", "distorted" (the default lens), "custom" (another Brown–Conrady, or a rational
        lens) or "fisheye"."""
        if isinstance(self.lens, KannalaBrandt):
            return "fisheye"
        if isinstance(self.lens, (BrownConrady, Rational)):
            return "custom"
        return "distorted" if self.lens == "default" else "undistorted"

    @property
    def horizontal_field_rad(self) -> float:
        """The horizontal field, rad: ``hfov_rad``, or a calibration's 2·atan(W/(2·fx)) (a fisheye's
        W/fx, the equidistant rule)."""
        if self.calibration is None:
            return self.hfov_rad
        K = self.calibration
        if isinstance(self.lens, KannalaBrandt):
            return K.width / K.fx
        return 2.0 * math.atan(0.5 * K.width / K.fx)

    @property
    def window_s(self) -> float:
        """How long a frame's rows are exposed in all: exposure plus readout, s."""
        return self.exposure_s + self.readout_s

    @property
    def renderer_key(self) -> tuple:
        """What a renderer takes from the camera: its intrinsics and lens."""
        return (self.intrinsics, self.lens_model)

    # what the camera builds and does --------------------------------------------------------
    def make_renderer(self, target: "Target"):
        """The renderer of this camera's frames of ``target``'s scene: a
        :class:`gimbal_lab.widefield.WideFieldRenderer` for a Kannala–Brandt lens (a cube map
        remapped to the lens), a :class:`gimbal_lab.scene.SceneRenderer` for any other."""
        if isinstance(self.lens_model, KannalaBrandt):
            from .widefield import WideFieldRenderer

            return WideFieldRenderer(self.intrinsics, self.lens_model, **target.scene_kwargs())
        from .scene import SceneRenderer

        return SceneRenderer(self.intrinsics, distortion=self.lens_model, **target.scene_kwargs())

    def truth_time(self, t_s: float, camera_fn, target_fn) -> float:
        """The instant a frame exposed from ``t_s`` shows the target: its truth time, s.

        Global shutter: mid-exposure, t_s + exposure_s/2. Rolling shutter: the row v through the
        target's true centre is read from t_s + v·readout_s/H, so the instant is
        t_s + v·readout_s/H + exposure_s/2, with v the row at that instant (a fixed point, found by
        iteration: the target moves a fraction of a row per iteration's change of time).
        """
        t = t_s + 0.5 * self.exposure_s
        if self.readout_s <= 0:
            return t
        K, lens, rows = self.intrinsics, self.lens_model, self.height
        for _ in range(4):
            T_cam = camera_fn(t)[1]
            p = T_cam[:3, :3].T @ (target_fn(t)[:3, 3] - T_cam[:3, 3])
            v = project(p, K, lens)[0, 1] if p[2] > 0 else 0.5 * (rows - 1)
            t = t_s + min(max(v, 0.0), rows - 1) * self.readout_s / rows + 0.5 * self.exposure_s
        return t

    def blur_method(self, occluded: bool = False) -> str:
        """How a frame's exposure is integrated: "sharp" (no exposure), "none" (asked for: one
        sharp instant although the camera exposes), "fast" or "subframes".

        ``blur="auto"`` takes the fast path where it applies and sub-frames where it does not: a
        fisheye (rendered from cube faces) and a scene with occluders (``occluded``; the fast blur
        composites the target over the background and cannot hide it).
        """
        if self.exposure_s <= 0 and self.readout_s <= 0:
            return "sharp"
        if self.blur != "auto":
            return self.blur
        return "subframes" if occluded or isinstance(self.lens, KannalaBrandt) else "fast"

    def exposure_label(self, occluded: bool = False) -> str:
        """The exposure in words, as a report names it: "sharp instants (no exposure)",
        "exposure 16.0 ms, blurred (fast)", or, for ``blur="none"``, a sentence saying the frames
        are rendered sharp although the camera exposes."""
        method = self.blur_method(occluded)
        if method == "sharp":
            return "sharp instants (no exposure)"
        shutter = f", rolling shutter {1000 * self.readout_s:.1f} ms" if self.readout_s > 0 else ""
        if method == "none":
            return (f"exposure {1000 * self.exposure_s:.1f} ms rendered SHARP (blur = \"none\": one instant at "
                    f"mid-exposure, no motion blur){shutter}")
        count = f", {self.n_subframes} sub-frames" if self.n_subframes else ""
        return f"exposure {1000 * self.exposure_s:.1f} ms, blurred ({method}{count}){shutter}"

    def subframe_count(self, pose_fn, t_s: float, n_samples: int = 17) -> int:
        """The sub-frames a frame exposed from ``t_s`` needs: ``n_subframes`` when given, else
        enough that the image moves at most :data:`SUBFRAME_STEP_PX` between two of them.

        The image motion over the exposure is the larger of the target centre's path (``pose_fn``
        sampled at ``n_samples`` instants, projected through the lens) and the camera's rotation
        times the focal length (the background's motion at the image centre; a translating
        camera's parallax is left out, a shortcut that undercounts only for near ground).
        n = clamp(⌈L / step⌉, 2, 1024).
        """
        if self.n_subframes is not None:
            return self.n_subframes
        times = t_s + self.exposure_s * np.linspace(0.0, 1.0, n_samples)
        poses = [pose_fn(t) for t in times]
        T_cam = np.array([p[0] for p in poses])
        x = np.array([p[1][:3, 3] for p in poses])
        R, c = T_cam[:, :3, :3], T_cam[:, :3, 3]
        p = np.einsum("nji,nj->ni", R, x - c)
        front = p[:, 2] > 0
        target_px = 0.0
        if front.sum() >= 2:
            uv = project(p[front], self.intrinsics, self.lens_model)
            target_px = float(np.sum(np.hypot(*np.diff(uv, axis=0).T)))
        cos_angle = (np.trace(R[0].T @ R[1:], axis1=1, axis2=2) - 1.0) / 2.0
        turn_rad = float(np.max(np.arccos(np.clip(cos_angle, -1.0, 1.0)), initial=0.0))
        background_px = turn_rad * max(self.intrinsics.fx, self.intrinsics.fy)
        motion_px = max(target_px, background_px)
        if not math.isfinite(motion_px):
            return _MAX_SUBFRAMES
        return int(min(max(math.ceil(motion_px / SUBFRAME_STEP_PX), 2), _MAX_SUBFRAMES))

    def expose(self, renderer, pose_fn, t_s: float, T_world_cam, T_world_target) -> np.ndarray:
        """The frame exposed from ``t_s`` (before noise): the exposure integrated as
        :meth:`blur_method` says, or the single instant's render (``T_world_cam``,
        ``T_world_target``, the mid-exposure instant) when sharp or ``blur="none"``."""
        method = self.blur_method(occluded=bool(getattr(renderer, "occluders", None)))
        if method == "fast":
            return renderer.render_motion(pose_fn, t_s, self.exposure_s, self.readout_s)
        if method == "subframes":
            return renderer.render_exposure(pose_fn, t_s, self.exposure_s, self.subframe_count(pose_fn, t_s))
        return renderer.render(T_world_cam, T_world_target)

    def add_noise(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``image`` as the sensor records it: the fixed noise
        (:func:`gimbal_lab.scene.add_sensor_noise`) or, with ``noise="sensor"``, the EMVA 1288 model
        over the camera's exposure (:meth:`gimbal_lab.sensor.SensorModel.record`)."""
        if self.noise == "sensor":
            from .sensor import SensorModel

            model = SensorModel(self.sensor, light_lux=self.light_lux, f_number=self.f_number)
            return model.record(image, self.exposure_s, rng)
        from .scene import add_sensor_noise

        return add_sensor_noise(image, self.noise_std, rng)


# ----------------------------------------------------------------------------------------------
# gimbal
# ----------------------------------------------------------------------------------------------
#: The joint-rate limit of the outer loops that follow the image or a filter, rad/s.
MAX_JOINT_RATE_RAD_S = 3.0


def _kinematics_from_table(value, where: str):
    if not isinstance(value, dict):
        return value
    table = dict(value)
    if "joint_limits_rad" in table:
        table["joint_limits_rad"] = tuple(tuple(pair) for pair in table["joint_limits_rad"])
    if "T_body_base" in table:
        table["T_body_base"] = np.array(table["T_body_base"], dtype=float)
    return _from_table(GimbalKinematics, table, where)


def _kinematics_key(kin: GimbalKinematics) -> tuple:
    """What makes two kinematics the same gimbal (:class:`GimbalKinematics` compares by identity)."""
    return (kin.centre_drop_m, kin.camera_offset_m, kin.joint_limits_rad,
            tuple(tuple(float(v) for v in row) for row in kin.T_body_base))


@dataclass(frozen=True)
class Gimbal(_Part):
    """The gimbal: its geometry and joint limits, its axes and their rate loops, its gyro.

    Parameters
    ----------
    kinematics : GimbalKinematics
        The DH chain and its joint limits (:meth:`GimbalKinematics.default`: the study's
        STorM32-size gimbal). Compared by value.
    inner_rate_hz : float
        Rate of the inner loops and of the axis integration, Hz (1 kHz), at least
        1/(2·delay) of every axis plant (the zero-order hold's half step is part of the delay).
    gyro_noise_rad_s_rthz : float
        White-noise density of the camera-platform gyro, rad/s/√Hz (0: ideal; the moving-drone
        study: 0.005 °/s/√Hz).
    max_joint_rate_rad_s : float
        Largest joint-rate reference the image loop and filter-driven pointing give, rad/s (3).
        The predictive loop keeps its own 6 rad/s (:class:`gimbal_lab.tracking.PredictiveLoop`).
    plants : tuple of 3 AxisPlant or None
        The (yaw, roll, pitch) axes; None: :meth:`AxisPlant.storm32` for each joint.
    rate_gains : tuple of 3 PIDGains or None
        The rate loops' gains; None: Ziegler–Nichols PID from each plant's ultimate gain
        (:class:`gimbal_lab.control.RateLoop`).

    Notes
    -----
    Each joint stops at ``kinematics.joint_limits_rad`` (:mod:`gimbal_lab.mount`, "Joint stops");
    limits of ±inf leave a joint free (a slip-ring yaw).
    """

    kinematics: GimbalKinematics = field(default_factory=GimbalKinematics.default, compare=False)
    inner_rate_hz: float = 1000.0
    gyro_noise_rad_s_rthz: float = 0.0
    max_joint_rate_rad_s: float = MAX_JOINT_RATE_RAD_S
    plants: tuple | None = None
    rate_gains: tuple | None = None
    _kinematics_key: tuple = field(init=False, repr=False, default=())

    _NAME = "gimbal"

    def __post_init__(self):
        from .control import AxisPlant, PIDGains

        self._set("kinematics", _kinematics_from_table(self.kinematics, "gimbal.kinematics"))
        self._table("kinematics", GimbalKinematics)
        self._set("_kinematics_key", _kinematics_key(self.kinematics))
        self._triple("plants", AxisPlant)
        self._triple("rate_gains", PIDGains)
        self._number("inner_rate_hz", low=0.0, high=_MAX_INNER_RATE_HZ, low_open=True)
        slowest = 1.0 / (2.0 * min(p.delay_s for p in self.axis_plants))
        if self.inner_rate_hz < slowest:
            raise ValueError(f"gimbal.inner_rate_hz={self.inner_rate_hz:g} must be >= {slowest:g} Hz: each axis "
                             "plant's delay_s includes the zero-order hold's half step (gimbal_lab.control.GimbalAxis)")
        self._number("gyro_noise_rad_s_rthz", low=0.0, high=1.0)
        self._number("max_joint_rate_rad_s", low=0.0, high=1000.0, low_open=True)

    def _encode(self, name, value):
        if name == "kinematics":
            return {"centre_drop_m": value.centre_drop_m, "camera_offset_m": value.camera_offset_m,
                    "joint_limits_rad": [list(pair) for pair in value.joint_limits_rad],
                    "T_body_base": np.asarray(value.T_body_base).tolist()}
        return _plain(value)

    @property
    def axis_plants(self) -> tuple:
        """The (yaw, roll, pitch) :class:`gimbal_lab.control.AxisPlant` the run steps."""
        from .control import AxisPlant

        if self.plants is not None:
            return self.plants
        return tuple(AxisPlant.storm32(axis) for axis in ("yaw", "roll", "pitch"))

    @property
    def joint_limits_rad(self) -> tuple:
        """The joints' (lo, hi) ranges, rad: the kinematics'."""
        return self.kinematics.joint_limits_rad

    @property
    def dt_s(self) -> float:
        """The inner step, s."""
        return 1.0 / self.inner_rate_hz

    @functools.cached_property
    def home_camera_offset_m(self) -> np.ndarray:
        """The optical centre at the home pose, body frame, m (computed once per gimbal)."""
        offset = self.kinematics.T_body_cam(np.zeros(3))[:3, 3]
        offset.setflags(write=False)
        return offset

    def mount(self, body: BodyMotion, mount: str, n_steps: int, seed: int):
        """The :class:`gimbal_lab.mount.GimbalMount` of a run: these axes on ``body`` in ``mount``
        mode for ``n_steps`` inner steps; the gyro noise drawn from ``seed``'s "gyro" stream
        (:func:`seed_stream`)."""
        from .mount import GimbalMount

        gyro_rng = np.random.default_rng(seed_stream(seed, "gyro"))
        return GimbalMount(self.kinematics, body, mount, 1.0 / self.inner_rate_hz, n_steps,
                           self.gyro_noise_rad_s_rthz, gyro_rng, plants=self.plants, rate_gains=self.rate_gains)


# ----------------------------------------------------------------------------------------------
# platform
# ----------------------------------------------------------------------------------------------
#: Each motion and the parameter objects of :class:`Platform` it uses.
_MOTIONS = {"static": (), "hover": ("sway",), "vibration": ("sway", "vibration"), "flight": ("sway", "flight")}


@dataclass(frozen=True)
class Platform(_Part):
    """The drone body's motion (:mod:`gimbal_lab.platform`).

    Parameters
    ----------
    motion : {"static", "hover", "vibration", "flight"}
        Still (the paper), hover sway, hover sway with blade-pass vibration, or the waypoint pass
        with sway; drawn from the run's seed.
    altitude_m : float
        Height of the body above the ground, m (2). A flight's path fixes it: it must be the
        height ``flight`` flies at.
    motion_phase_s : float
        Time offset into the motion, s (>= 0): replicates of the flight start at different points
        of the pass.
    sway, vibration, flight : HoverSway, Vibration, WaypointFlight
        The motion's parameters (defaults: docs/design.md, "Moving drone"); a motion uses those
        it names (hover: sway; vibration: sway and vibration; flight: sway and flight).
    """

    motion: str = "static"
    altitude_m: float = BODY_POSITION_M[2]
    motion_phase_s: float = 0.0
    sway: HoverSway = field(default_factory=HoverSway)
    vibration: Vibration = field(default_factory=Vibration)
    flight: WaypointFlight = field(default_factory=WaypointFlight)

    _NAME = "platform"

    def __post_init__(self):
        self._choice("motion", tuple(_MOTIONS))
        self._number("altitude_m", low=0.0, high=1000.0, low_open=True)
        self._number("motion_phase_s", low=0.0, high=1e6)
        self._table("sway", HoverSway)
        self._table("vibration", Vibration)
        self._table("flight", WaypointFlight)
        if self.motion == "flight":
            heights = {self.flight.start_m[2], self.flight.end_m[2]}
            if heights != {self.altitude_m}:
                raise ValueError(f"platform.altitude_m={self.altitude_m:g} differs from the height platform.flight "
                                 f"flies at (start_m and end_m at z = {', '.join(f'{h:g}' for h in sorted(heights))} m):"
                                 " a flight's path fixes the body's height")

    @property
    def moving(self) -> bool:
        """Whether the body moves at all."""
        return self.motion != "static"

    @property
    def position_m(self) -> tuple[float, float, float]:
        """Where the body rests (a flight's path replaces it), world frame, m."""
        return BODY_POSITION_M[:2] + (self.altitude_m,)

    def body(self, seed: int) -> BodyMotion:
        """The body's motion (:class:`gimbal_lab.platform.BodyMotion`) of a run with ``seed`` (its
        "body" stream, :func:`seed_stream`, draws the sway and vibration)."""
        if not self.moving:
            return BodyMotion.static(self.position_m)
        parts = {name: getattr(self, name) for name in _MOTIONS[self.motion]}
        return BodyMotion(position_m=self.position_m, seed=seed_stream(seed, "body"), time_offset_s=self.motion_phase_s,
                          **parts)


# ----------------------------------------------------------------------------------------------
# target
# ----------------------------------------------------------------------------------------------
_TARGET_KINDS = ("sphere", "aruco")
_TRAJECTORIES = ("circular", "diagonal", "stationary", "cone", "manoeuvring")


@functools.lru_cache(maxsize=8)
def _manoeuvring_path(seed: int, duration_s: float):
    """The manoeuvring target of a run (its plan drawn once per seed and length, from the seed's
    "plan" stream, :func:`seed_stream`)."""
    from .trajectories import ManoeuvringTarget

    return ManoeuvringTarget(seed=seed_stream(seed, "plan"), duration_s=duration_s)


@dataclass(frozen=True)
class Target(_Part):
    """The target, its motion and what stands in its way.

    Parameters
    ----------
    kind : {"sphere", "aruco"}
    trajectory : {"circular", "diagonal", "stationary", "cone", "manoeuvring"}
        The paper's two motions (:class:`gimbal_lab.trajectories.Trajectory`); the target held
        still at the circle's centre, on the home optical axis (the moving drone's static-target
        arm); the lens sweep's
        cone: a circle about the home optical axis at :data:`CONE_RANGE_M` from the home camera,
        :data:`CONE_FIELD_FRACTION` of the camera's half horizontal field off the axis (or
        ``cone_half_angle_rad``); or the
        occlusion study's manoeuvring target (:class:`gimbal_lab.trajectories.ManoeuvringTarget`,
        its plan drawn from the run's seed).
    period_s : float
        Period of the motion, s (2).
    start_phase_s : float
        Time offset of the motion, s, in [0, period_s): replicates draw it from their seed.
    sphere_radius_m, marker_length_m : float
        Sizes (0.10 m sphere; 0.30 m marker on a plate :data:`PLATE_TO_MARKER` as wide).
    occluders : tuple of gimbal_lab.scene.Occluder
        Boxes in the world that can hide the target (none by default).
    cone_half_angle_rad : float or None
        ``trajectory="cone"`` only: the cone's half-angle about the home axis, rad, in (0, π/2).
        None (the default): :data:`CONE_FIELD_FRACTION` of the camera's half horizontal field
        (:meth:`cone_half_angle`). The lens sweep's in-limit cones set 40° (docs/design.md, "When
        does a gimbal pay off?", Repairs).
    cone_range_m : float or None
        ``trajectory="cone"`` only: the distance from the home camera to every point of the cone's
        circle, m, in (0, 100]. None (the default): :data:`CONE_RANGE_M`. The payoff map varies
        it (docs/design.md, "The payoff map").
    """

    kind: str = "sphere"
    trajectory: str = "circular"
    period_s: float = 2.0
    start_phase_s: float = 0.0
    sphere_radius_m: float = 0.10
    marker_length_m: float = 0.30
    occluders: tuple = ()
    cone_half_angle_rad: float | None = None
    cone_range_m: float | None = None

    _NAME = "target"

    def __post_init__(self):
        self._choice("kind", _TARGET_KINDS)
        self._choice("trajectory", _TRAJECTORIES)
        self._number("period_s", low=0.0, low_open=True)
        self._number("start_phase_s", low=0.0)
        if self.start_phase_s >= self.period_s:
            raise ValueError(f"target.start_phase_s must be in [0, target.period_s = {self.period_s:g}), "
                             f"got {self.start_phase_s!r}")
        for name in ("sphere_radius_m", "marker_length_m"):
            self._number(name, low=0.0, high=10.0, low_open=True)
        from .scene import Occluder

        if isinstance(self.occluders, (Occluder, str, bytes, dict)) or not hasattr(self.occluders, "__iter__"):
            raise TypeError("target.occluders must be a sequence of Occluder objects")
        occluders = tuple(_from_table(Occluder, o, "target.occluders[]") if isinstance(o, dict) else o
                          for o in self.occluders)
        for occluder in occluders:
            if not isinstance(occluder, Occluder):
                raise TypeError(f"target.occluders must be Occluder objects, got {type(occluder).__name__}")
        self._set("occluders", occluders)
        if self.cone_half_angle_rad is not None:
            if self.trajectory != "cone":
                raise ValueError(f"target.cone_half_angle_rad={self.cone_half_angle_rad!r} applies to target.trajectory "
                                 f"'cone' only, got {self.trajectory!r}")
            self._number("cone_half_angle_rad", low=0.0, high=0.5 * math.pi, low_open=True)
            if self.cone_half_angle_rad >= 0.5 * math.pi:
                raise ValueError(f"target.cone_half_angle_rad must be < π/2 (the cone lies ahead of the camera), got "
                                 f"{self.cone_half_angle_rad!r}")
        if self.cone_range_m is not None:
            if self.trajectory != "cone":
                raise ValueError(f"target.cone_range_m={self.cone_range_m!r} applies to target.trajectory 'cone' only, "
                                 f"got {self.trajectory!r}")
            self._number("cone_range_m", low=0.0, high=100.0, low_open=True)

    def cone_half_angle(self, field_rad: float) -> float:
        """The cone's half-angle about the home axis, rad: ``cone_half_angle_rad``, or
        :data:`CONE_FIELD_FRACTION` of half the camera's horizontal field ``field_rad`` (rad)."""
        if self.cone_half_angle_rad is not None:
            return self.cone_half_angle_rad
        return CONE_FIELD_FRACTION * 0.5 * field_rad

    def path(self, *, seed: int, duration_s: float, home_camera_m, field_rad: float):
        """The motion of a run: the trajectory, built for the run's ``seed`` and ``duration_s``
        (the manoeuvring plan) and, for the cone, the home camera ``home_camera_m`` (m) and the
        camera's horizontal field ``field_rad`` (rad)."""
        if self.trajectory == "manoeuvring":
            return _manoeuvring_path(seed, duration_s)
        if self.trajectory != "cone":
            return Trajectory(self.trajectory, period_s=self.period_s)
        half_angle = self.cone_half_angle(field_rad)
        range_m = CONE_RANGE_M if self.cone_range_m is None else self.cone_range_m
        centre = home_camera_m + np.array([range_m * math.cos(half_angle), 0.0, 0.0])
        return Trajectory("circular", period_s=self.period_s, centre_m=centre, radius_m=range_m * math.sin(half_angle))

    def scene_kwargs(self) -> dict:
        """What a renderer takes from the target: its kind, sizes and the occluders."""
        return dict(target=self.kind, sphere_radius_m=self.sphere_radius_m, marker_length_m=self.marker_length_m,
                    plate_size_m=PLATE_TO_MARKER * self.marker_length_m, occluders=self.occluders)

    @property
    def renderer_key(self) -> tuple:
        return (self.kind, self.sphere_radius_m, self.marker_length_m, self.occluders)

    def visibility(self, camera_m, T_world_target) -> tuple[bool, float]:
        """Whether the occluders hide the target's centre from ``camera_m``, and the fraction of
        its outline seen past them: 32 points of the sphere's silhouette circle
        (:func:`gimbal_lab.scene.sphere_rim_points`) or the marker's 4 corners. (False, 1.0)
        without occluders."""
        if not self.occluders:
            return False, 1.0
        from .scene import marker_corners, points_visible, sphere_rim_points

        centre = T_world_target[:3, 3]
        if self.kind == "sphere":
            outline = sphere_rim_points(camera_m, centre, self.sphere_radius_m)
        else:
            outline = marker_corners(T_world_target, self.marker_length_m)
        visible = points_visible(self.occluders, camera_m, np.vstack([centre, outline]))
        return not visible[0], float(np.mean(visible[1:]))


# ----------------------------------------------------------------------------------------------
# pointing: the outer loop and the mount mode
# ----------------------------------------------------------------------------------------------
_TARGET_FILTERS = ("cv", "ca", "imm")


class Measurement(NamedTuple):
    """What the estimator made of one frame, as it reaches the outer loop ``latency_frames`` later."""

    frame: int
    t_s: float  # the frame's truth instant (mid-exposure)
    uv_px: np.ndarray | None  # detected centre, px (None: not detected)
    q_rad: np.ndarray  # joint angles at that instant
    range_m: float | None  # the estimator's distance to the target
    p_cam_m: np.ndarray | None  # the estimated target centre, camera optical frame
    T_world_cam: np.ndarray  # the camera's pose at that instant


class _OuterLoopPart:
    """What every outer-loop part offers: ``observe(measurement, q0)``, ``command(t_s, q0)`` and
    ``prediction(t_s)``, the target estimate it logs (None: it keeps none). This one is the
    passive mounts': it observes nothing and asks for no joint rate (a stabilised mount computes
    its own references, a fixed one has none)."""

    def observe(self, m: Measurement, q0) -> None:
        return None

    def command(self, t_s: float, q0) -> np.ndarray:
        return np.zeros(3)

    def prediction(self, t_s: float):
        return None


class _PaperLoop(_OuterLoopPart):
    """The paper's image loop as an outer-loop part: a new rate reference per measurement, held
    between measurements; while the target is not detected, the last one for ``pointing.coast_s``
    (none by default), then zero rate (hold)."""

    def __init__(self, image_loop, kin, fps: float):
        self.image_loop, self.kin, self.dt_s = image_loop, kin, 1.0 / fps
        self.rate = np.zeros(3)

    def observe(self, m: Measurement, q0) -> None:
        J_cam = self.kin.angular_jacobian(q0, frame="camera", check_limits=False)
        self.rate = np.asarray(self.image_loop.update(m.uv_px, self.dt_s, J_cam, q0), float)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.rate


class _PredictiveLoop(_OuterLoopPart):
    """The line-of-sight predictive loop as an outer-loop part."""

    def __init__(self, loop):
        self.loop = loop

    def observe(self, m: Measurement, q0) -> None:
        self.loop.observe(m.t_s, m.uv_px, m.q_rad, range_m=m.range_m)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.loop.command(t_s, q0)


class _FilterLoop(_OuterLoopPart):
    """Pointing driven by a filter on the target's world position, as an outer-loop part."""

    def __init__(self, pointing):
        self.pointing = pointing

    def observe(self, m: Measurement, q0) -> None:
        self.pointing.observe(m.t_s, m.p_cam_m, m.T_world_cam)

    def command(self, t_s: float, q0) -> np.ndarray:
        return self.pointing.command(t_s, q0)

    def prediction(self, t_s: float):
        return self.pointing.prediction(t_s)


def make_target_filter(name: str):
    """The target filter ``name`` ("cv", "ca" or "imm") with its default parameters."""
    from . import filters

    _choice("pointing.filter", name, _TARGET_FILTERS)
    return {"cv": filters.ConstantVelocity, "ca": filters.ConstantAcceleration, "imm": filters.IMM}[name]()


def world_T_base(kinematics, altitude_m: float = BODY_POSITION_M[2]) -> np.ndarray:
    """4 × 4 ``T_world_base`` of the study: the body still at :data:`BODY_POSITION_M` (at ``altitude_m``
    above the ground), axes = world's."""
    T_world_body = np.eye(4)
    T_world_body[:3, 3] = BODY_POSITION_M[:2] + (altitude_m,)
    return T_world_body @ kinematics.T_body_base


def _passive(config, kin, pixel_lens) -> _OuterLoopPart:
    return _OuterLoopPart()


def _paper(config, kin, pixel_lens) -> _OuterLoopPart:
    from .control import ImageLoop

    camera = config.camera
    image_loop = ImageLoop.ziegler_nichols(camera.intrinsics, camera.fps, camera.latency_frames, distortion=pixel_lens,
                                           max_rate_rad_s=config.gimbal.max_joint_rate_rad_s,
                                           coast_s=config.pointing.coast_s or 0.0)
    return _PaperLoop(image_loop, kin, camera.fps)


def _predictive(config, kin, pixel_lens) -> _OuterLoopPart:
    from .tracking import PredictiveLoop

    return _PredictiveLoop(PredictiveLoop(config.camera.intrinsics, kin, distortion=pixel_lens))


def _filter(config, kin, pixel_lens) -> _OuterLoopPart:
    from .tracking import FilterPointing

    pointing = FilterPointing(kin, world_T_base(kin, config.platform.altitude_m),
                              make_target_filter(config.pointing.filter), focal_px=config.camera.intrinsics.fx,
                              radius_m=config.target.sphere_radius_m,
                              max_rate_rad_s=config.gimbal.max_joint_rate_rad_s)
    return _FilterLoop(pointing)


class _Law(NamedTuple):
    mount: str  # the GimbalMount mode: "fixed", "stabilised" or "active"
    build: object  # (config, kinematics, pixel_lens) -> outer-loop part
    still_platform: bool  # whether the law assumes a still body


#: The pointing kinds: how the mount runs, what outer loop they build, whether they need a still body.
_LAWS = {
    "fixed": _Law("fixed", _passive, False),
    "stabilised": _Law("stabilised", _passive, False),
    "paper": _Law("active", _paper, False),
    "predictive": _Law("active", _predictive, True),
    "filter": _Law("active", _filter, True),
}


#: What a link reports and how fast: the device's own limits (gimbal_lab.mavlink.device).
_MAX_STATUS_RATE_HZ = 1000.0


#: How the loop uses a gimbal's latest status (:class:`GimbalLink`).
_LINK_ATTITUDES = ("as-is", "propagated")


@dataclass(frozen=True)
class GimbalLink(_Part):
    """The gimbal behind a MAVLink link (docs/design.md, "The link"): what the loop learns of the
    joints, and when its commands take effect.

    The active loop then talks to the lab's gimbal as a MAVLink Gimbal Protocol v2 device
    (:class:`gimbal_lab.mavlink.device.SimulatedGimbalDevice`, lock-step, on a thread of the run's
    process over loopback UDP) through the driver (:class:`gimbal_lab.mavlink.driver.MavlinkGimbal`):
    it sends joint rates as GIMBAL_DEVICE_SET_ATTITUDE rates and knows the joints only from the
    latest GIMBAL_DEVICE_ATTITUDE_STATUS received, stale between statuses.

    Parameters
    ----------
    status_rate_hz : float
        Attitude statuses per second of simulated time, in (0, 1000] (1000: one every inner step).
    latency_s : float
        One-way delay of statuses and commands, s, in [0, 1] (whole inner steps).
    quantum_rad : float
        Resolution of the reported Z-Y-X angles, rad, in [0, 0.1] (0: float32 only).
    loss : float
        Probability that a status is lost, in [0, 0.9].
    commanded_only : bool
        The gimbal reports the commanded attitude (the integral of the rates sent) instead of
        the measured one: a gimbal without angle feedback.
    attitude : {"as-is", "propagated"}
        How the loop uses the latest status: "as-is" (the default), its joints as reported;
        "propagated", its joints carried forward to the instant they are used by the status's own
        angular velocity times its age, q + A(q)⁻¹·ω·(t − t_status), or by the rates last commanded
        when the status reports none (:meth:`gimbal_lab.mavlink.loop.LinkedGimbal.joints`).

    Notes
    -----
    The losses are drawn from stream 4 of the run's seed (:meth:`effects_seed`).
    """

    status_rate_hz: float = 50.0
    latency_s: float = 0.0
    quantum_rad: float = 0.0
    loss: float = 0.0
    commanded_only: bool = False
    attitude: str = "as-is"

    _NAME = "pointing.link"

    def _encode(self, name, value):
        if name == "attitude" and value == "as-is":
            return None  # the default, left out so that the links of before the field keep their keys
        return _plain(value)

    def __post_init__(self):
        self._number("status_rate_hz", low=0.0, high=_MAX_STATUS_RATE_HZ, low_open=True)
        self._number("latency_s", low=0.0, high=1.0)
        self._number("quantum_rad", low=0.0, high=0.1)
        self._number("loss", low=0.0, high=0.9)
        if not isinstance(self.commanded_only, (bool, np.bool_)):
            raise TypeError(f"pointing.link.commanded_only must be True or False, got {self.commanded_only!r}")
        self._set("commanded_only", bool(self.commanded_only))
        self._choice("attitude", _LINK_ATTITUDES)

    @staticmethod
    def effects_seed(seed: int) -> int:
        """The seed of a run's status losses: stream 4 of the run's ``seed``."""
        return int(np.random.SeedSequence([seed, 4]).generate_state(1)[0])

    @property
    def label(self) -> str:
        """A short name: "50 Hz, 20 ms, 0.1°, 5 % loss" (and "commanded only")."""
        parts = [f"{self.status_rate_hz:g} Hz", f"{1000 * self.latency_s:g} ms", f"{math.degrees(self.quantum_rad):g}°",
                 f"{100 * self.loss:g} % loss"]
        return (", ".join(parts) + (", commanded only" if self.commanded_only else "")
                + (", propagated" if self.attitude == "propagated" else ""))


@dataclass(frozen=True)
class Pointing(_Part):
    """What turns the camera.

    Parameters
    ----------
    kind : {"fixed", "stabilised", "paper", "predictive", "filter"}
        Passive: "fixed" (the camera rigid on the body) or "stabilised" (the gimbal holds its home
        orientation in the world: the paper's passive case; identical to a rigid camera while the
        body is still), see :mod:`gimbal_lab.mount`. Active: "paper", the paper's PI law on the
        pixel error with Ziegler–Nichols gains from the outer loop's own plant
        (:meth:`gimbal_lab.control.ImageLoop.ziegler_nichols`), holding the joints while the
        target is lost (after ``coast_s`` of its last command, if set); "predictive", the line-of-sight filter with feed-forward
        (:class:`gimbal_lab.tracking.PredictiveLoop`, an extension); "filter", pointing where a
        filter on the target's world position predicts it, coasting through misses
        (:class:`gimbal_lab.tracking.FilterPointing`, the occlusion study). "predictive" and
        "filter" assume a still body.
    filter : {"cv", "ca", "imm"} or None
        The filter of ``kind="filter"`` (:mod:`gimbal_lab.filters`, default parameters; None
        there means "imm"); None for every other kind.
    link : GimbalLink or None
        An active loop's gimbal behind a MAVLink link (:class:`GimbalLink`); None: in-process,
        the loop reads the joints and sets the axes' references directly (the paper's
        simulation). A passive camera sends no command and takes none.
    coast_s : float or None
        ``kind="paper"`` only: how long the image loop repeats its last rate command after losing
        the target before it holds the pose, s, >= 0 (:class:`gimbal_lab.control.ImageLoop`
        ``coast_s``). None (the default) or 0: it holds at once. The occlusion study's blind
        fallback uses 1.5 s (docs/design.md, "When does a gimbal pay off?", Repairs).
    """

    kind: str = "stabilised"
    filter: str | None = None
    link: GimbalLink | None = None
    coast_s: float | None = None

    _NAME = "pointing"

    def __post_init__(self):
        self._choice("kind", tuple(_LAWS))
        if self.kind == "filter":
            if self.filter is None:
                self._set("filter", "imm")
            self._choice("filter", _TARGET_FILTERS)
        elif self.filter is not None:
            raise ValueError(f"pointing.filter={self.filter!r} applies to pointing.kind 'filter' only, got kind "
                             f"{self.kind!r}")
        self._table("link", GimbalLink, optional=True)
        if self.link is not None and not self.active:
            raise ValueError(f"pointing.link applies to the active kinds (paper, predictive, filter), got kind "
                             f"{self.kind!r}: a passive camera sends no command")
        if self.coast_s is not None:
            if self.kind != "paper":
                raise ValueError(f"pointing.coast_s={self.coast_s!r} applies to pointing.kind 'paper' only, got kind "
                                 f"{self.kind!r}")
            self._number("coast_s", low=0.0, high=1e6)

    @property
    def mount(self) -> str:
        """The :class:`gimbal_lab.mount.GimbalMount` mode: "fixed", "stabilised" or "active"."""
        return _LAWS[self.kind].mount

    @property
    def active(self) -> bool:
        """Whether an outer loop turns the camera towards the target."""
        return self.mount == "active"

    @property
    def mode(self) -> str:
        """"active" or "passive"."""
        return "active" if self.active else "passive"

    @property
    def assumes_still_platform(self) -> bool:
        return _LAWS[self.kind].still_platform

    def build(self, config: "TrackingConfig", kinematics, pixel_lens):
        """The outer-loop part of a run: ``observe(measurement, q0)``, ``command(t_s, q0)`` (joint-
        rate references, rad/s) and ``prediction(t_s)``; ``pixel_lens`` is the lens the loop
        knows (None: it takes the image for a pinhole's)."""
        return _LAWS[self.kind].build(config, kinematics, pixel_lens)


# ----------------------------------------------------------------------------------------------
# estimator
# ----------------------------------------------------------------------------------------------
_SPHERE_METHODS = ("circle", "ellipse", "streak")
_REFINEMENTS = ("none", "subpix", "contour", "apriltag")
_LENS_STRATEGIES = ("ignore", "undistort", "rectify")
#: The localiser each sphere method records beside its own estimate (``alt_*``).
_ALT_METHOD = {"circle": "ellipse", "ellipse": "circle", "streak": "ellipse"}
#: The columns of a localiser's family in the frame table, after its prefix (``alt_``, ``circle_``, ...).
SPHERE_FAMILY_COLUMNS = ("detected", "est_x_m", "est_y_m", "est_z_m", "est_cam_x_m", "est_cam_y_m", "est_cam_z_m",
                         "d_est_m", "error_m", "abs_error_m")


@dataclass(frozen=True)
class Estimator(_Part):
    """How a frame becomes a target position.

    Parameters
    ----------
    sphere_method : {"circle", "ellipse", "streak"}
        The paper's enclosing-circle estimate, the exact cone (ellipse) method, or the blur-aware
        one (:func:`gimbal_lab.detection.locate_sphere_streak`: range from the solid angle of the
        pixels' coverage, centre at mid-exposure; the cone fit on a sharp frame). Circle and
        ellipse record each other beside them on the same detection (``alt_*`` columns); streak
        records the ellipse, the method it replaces.
    extra_methods : tuple of str
        Sphere methods also run on the same detection and frame, each recorded in a column family of
        its own, ``<method>_*`` (:data:`SPHERE_FAMILY_COLUMNS` after the prefix: ``circle_detected``,
        ``circle_abs_error_m``, ...), after every other column of the frame table. None may be the
        estimator's own method or the one recorded beside it; empty (the default) adds no column and
        is left out of :meth:`to_dict`, so every run without it keeps its key and its frame table. On a
        passive mount, where the estimator steers nothing, one run so records three localisers of the
        same frames (the buying-rule map's passive runs: the streak method, the cone fit beside it
        and the circle method here).
    lens_strategy : {"ignore", "undistort", "rectify"}
        How the estimator treats the lens (docs/design.md, "Lens sweep"). "ignore" (the paper):
        it assumes a pinhole camera whatever the lens. "undistort": it knows the lens and
        undistorts the detected points (the sphere's contour before its circle or cone fit, the
        marker's corners before solvePnP). "rectify": each frame is first resampled to a pinhole
        image (:class:`gimbal_lab.detection.Rectifier`: the same K for a Brown–Conrady lens, a 90°
        pinhole for a fisheye) and detected there. Both known-lens strategies also give the outer
        loop the lens.
    aruco_refinement : {"none", "subpix", "contour", "apriltag"}
        OpenCV's corner refinement. The paper does not say which it used; OpenCV's default is
        none. The study uses sub-pixel refinement, the common choice for pose estimation: on
        static rendered poses it halves the translation error of "none" at 3 m (0.48 % vs
        0.79 % of distance, notebook 05). Notebook 08 also runs "none".
    """

    sphere_method: str = "circle"
    lens_strategy: str = "ignore"
    aruco_refinement: str = "subpix"
    extra_methods: tuple = ()

    _NAME = "estimator"

    def __post_init__(self):
        self._choice("sphere_method", _SPHERE_METHODS)
        self._choice("lens_strategy", _LENS_STRATEGIES)
        self._choice("aruco_refinement", _REFINEMENTS)
        extra = self.extra_methods
        if isinstance(extra, (str, bytes)) or not isinstance(extra, (tuple, list)):
            raise TypeError(f"estimator.extra_methods must be a list of sphere methods, got {extra!r}")
        for method in extra:
            _choice("estimator.extra_methods", method, _SPHERE_METHODS)
        recorded = (self.sphere_method, _ALT_METHOD[self.sphere_method])
        if len(set(extra)) != len(extra) or set(extra) & set(recorded):
            raise ValueError(f"estimator.extra_methods must be distinct methods other than {recorded[0]!r} and "
                             f"{recorded[1]!r} (the estimate and the one beside it), got {list(extra)!r}")
        self._set("extra_methods", tuple(extra))

    def _encode(self, name, value):
        if name == "extra_methods" and not value:
            return None  # the default, left out so that the runs of before the field keep their keys
        return _plain(value)

    @property
    def knows_lens(self) -> bool:
        """Whether the estimator and the outer loop know the lens (any strategy but "ignore")."""
        return self.lens_strategy != "ignore"

    def build(self, camera: Camera, target: Target, alt: bool = True) -> "_Estimator":
        """The detector and localiser of ``camera``'s frames of ``target``: image → (pixel centre,
        centre in the camera frame, the other localiser's centre); its ``partial`` says whether
        the sphere's silhouette was cut. ``alt=False`` skips the other localiser (its centre is
        None): the estimator's own pipeline alone, as the lens sweep times it."""
        return _Estimator(self, camera, target, alt=alt)


class _Estimator:
    """Detector + localiser for one run: image → (pixel centre, centre in camera frame, alt).

    For the sphere both localisers run on the same detection: the estimator's method gives the
    estimate, the other one (circle ↔ ellipse; the ellipse beside the streak method, which also
    reads the frame's pixels) is recorded alongside as ``alt`` so the two can be
    compared on identical frames (the closed loop only uses the pixel centre, which they share).
    The estimator's ``extra_methods`` run on that detection too; after each call ``extra`` holds
    their centres in the camera frame by method (None where a method gives none or nothing was
    detected).

    The lens strategy (:attr:`Estimator.lens_strategy`) decides what the localisers know: nothing
    ("ignore": pinhole with the camera's K), the lens ("undistort": the circle method on the
    undistorted contour, the cone fit on it, solvePnP on undistorted corners), or the rectified
    camera ("rectify": detection and localisation on the pinhole image that
    :class:`gimbal_lab.detection.Rectifier` resamples; the pixel centre is mapped back to the
    camera's own image, where the outer loop measures it).
    """

    def __init__(self, estimator: Estimator, camera: Camera, target: Target, alt: bool = True):
        from . import detection

        self.partial = False
        self._extra = ()
        self.extra = {}
        self.sphere = target.kind == "sphere"
        lens = camera.lens_model
        self.rectifier = detection.Rectifier(camera.intrinsics, lens) if estimator.lens_strategy == "rectify" else None
        self.intrinsics = self.rectifier.out_intrinsics if self.rectifier is not None else camera.intrinsics
        self.lens = lens if estimator.lens_strategy == "undistort" else None
        self.radius_m = target.sphere_radius_m
        K, r, known = self.intrinsics, self.radius_m, self.lens
        if self.sphere:
            self.detector = detection.SphereDetector()
            if known is None:
                circle = lambda det: detection.locate_sphere_circle(det, K, r)  # noqa: E731
            else:
                circle = lambda det: detection.locate_sphere_circle_undistorted(det, K, r, known)  # noqa: E731
            ellipse = lambda det: detection.locate_sphere_ellipse(det, K, r, distortion=known)  # noqa: E731
            # the frame the detection came from (set per frame in __call__): the streak method reads its pixels
            streak = lambda det: detection.locate_sphere_streak(self._image, det, K, r, distortion=known)  # noqa: E731
            by_name = {"circle": circle, "ellipse": ellipse, "streak": streak}
            self._methods = (by_name[estimator.sphere_method], by_name[_ALT_METHOD[estimator.sphere_method]])
            if not alt:
                self._methods = self._methods[:1]
            self._extra = tuple((name, by_name[name]) for name in estimator.extra_methods)
        else:
            if estimator.extra_methods:
                raise ValueError(f"estimator.extra_methods {list(estimator.extra_methods)!r} are sphere localisers; "
                                 f"the target is a {target.kind}")
            self.detector = detection.ArucoTracker(
                K, marker_length_m=target.marker_length_m, refinement=estimator.aruco_refinement, distortion=known
            )

    def _centre(self, uv) -> np.ndarray:
        uv = np.asarray(uv, float)
        return uv if self.rectifier is None else self.rectifier.to_source_px(uv).reshape(2)

    def __call__(self, image):
        """(pixel centre, centre in the camera frame, alt) of one frame; ``partial`` says whether
        the sphere's silhouette was cut."""
        from .camera import UndistortionError

        self.partial = False
        self.extra = {name: None for name, _ in self._extra}
        if self.rectifier is not None:
            image = self.rectifier.rectify(image)
        if self.sphere:
            det = self.detector.detect(image)
            if det is None:
                return None, None, None
            self.partial = det.partial
            self._image = image

            def locate(method):
                try:
                    p = method(det)
                except UndistortionError:  # a contour point beyond the lens's field: no estimate
                    return None
                return None if p is None else np.asarray(p, float)

            p, alt = [locate(m) for m in self._methods] + [None] * (2 - len(self._methods))
            self.extra = {name: locate(m) for name, m in self._extra}
            return self._centre(det.center_px), p, alt
        pose = self.detector.detect(image).get(0)
        if pose is None:
            return None, None, None
        return self._centre(pose.center_px), np.asarray(pose.t_cam_marker_m, float), None


# ----------------------------------------------------------------------------------------------
# the whole run
# ----------------------------------------------------------------------------------------------
_PARTS = {"camera": Camera, "gimbal": Gimbal, "platform": Platform, "target": Target, "pointing": Pointing,
          "estimator": Estimator}


@dataclass(frozen=True)
class TrackingConfig:
    """One run of the closed loop: its parts, length and seed. Defaults are the paper study's
    fixed parameters (docs/design.md): a still body, a passive (stabilised) camera with a
    pinhole lens, the sphere on the circle.

    Parameters
    ----------
    camera : Camera
    gimbal : Gimbal
    platform : Platform
    target : Target
    pointing : Pointing
    estimator : Estimator
        The parts (each may be given as its table, a dict).
    revolutions : float
        Periods of the target's motion simulated (> 0). The study: 2, the first acquisition.
    seed : int
        Seed of the run's draws (>= 0), each from its own named stream (:func:`seed_stream`): the
        sensor noise, the body's sway (:meth:`Platform.body`), the gyro noise (:meth:`Gimbal.mount`)
        and the manoeuvring plan; the studies draw the start phase and the flight's start point
        from the same seed's "phase" and "flight_phase" streams.

    Notes
    -----
    The rules that tie two parts are :func:`check_parts`.

    Examples
    --------
    >>> c = TrackingConfig().with_(camera__fps=60, pointing__kind="paper")
    >>> c.camera.fps, c.pointing.mode, c.n_frames
    (60.0, 'active', 240)
    """

    camera: Camera = field(default_factory=Camera)
    gimbal: Gimbal = field(default_factory=Gimbal)
    platform: Platform = field(default_factory=Platform)
    target: Target = field(default_factory=Target)
    pointing: Pointing = field(default_factory=Pointing)
    estimator: Estimator = field(default_factory=Estimator)
    revolutions: float = 2.0
    seed: int = 0

    def __post_init__(self):
        for name, cls in _PARTS.items():
            value = getattr(self, name)
            if isinstance(value, dict):
                value = cls.from_dict(value)
                object.__setattr__(self, name, value)
            if not isinstance(value, cls):
                raise TypeError(f"{name} must be a {cls.__name__} (or its table, a dict), got {type(value).__name__}")
        object.__setattr__(self, "revolutions", _number("revolutions", self.revolutions, low=0.0, low_open=True))
        object.__setattr__(self, "seed", _number("seed", self.seed, low=0, high=2**63 - 1, integer=True))
        check_parts(self)

    # derived -----------------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(round(self.revolutions * self.target.period_s * self.camera.fps))

    @property
    def frames_per_revolution(self) -> float:
        return self.target.period_s * self.camera.fps

    @property
    def home_camera_m(self) -> np.ndarray:
        """The camera's optical centre at the gimbal's home pose with the body at rest, world frame, m."""
        return np.array(self.platform.position_m) + self.gimbal.home_camera_offset_m

    @property
    def path(self):
        """The target's motion (:meth:`Target.path`: the cone from the camera's field and the home
        camera; the manoeuvring plan from the seed, a period longer than the run)."""
        return self.target.path(seed=self.seed, duration_s=self.revolutions * self.target.period_s + self.target.period_s,
                                home_camera_m=self.home_camera_m, field_rad=self.camera.horizontal_field_rad)

    @property
    def body(self) -> BodyMotion:
        """The drone body's motion, seeded from ``seed``."""
        return self.platform.body(self.seed)

    @property
    def renderer_key(self) -> tuple:
        """What a renderer depends on: two configs with equal keys can share one."""
        return (self.camera.renderer_key, self.target.renderer_key)

    @property
    def label(self) -> str:
        """A short name: target/motion/mount on a moving body, else target/lens/trajectory/mode
        (and the lens strategy when it is not "ignore")."""
        if self.platform.moving:
            return f"{self.target.kind}/{self.platform.motion}/{self.pointing.mount}"
        base = f"{self.target.kind}/{self.camera.lens_label}/{self.target.trajectory}/{self.pointing.mode}"
        strategy = self.estimator.lens_strategy
        base = base if strategy == "ignore" else f"{base}/{strategy}"
        return base if self.pointing.link is None else f"{base} via {self.pointing.link.label}"

    # changes and dicts -------------------------------------------------------------------------
    def replace(self, **changes) -> "TrackingConfig":
        """A copy with some fields (whole parts, ``revolutions``, ``seed``) changed, validated again:
        ``config.replace(camera=config.camera.replace(fps=60))``."""
        return _with(self, changes, "TrackingConfig")

    def with_(self, **changes) -> "TrackingConfig":
        """A copy with fields of the parts changed, ``part__field=value``:
        ``config.with_(camera__fps=60, seed=3)`` is
        ``config.replace(camera=config.camera.replace(fps=60), seed=3)``; a further ``__`` steps
        into a part's parameter objects (``platform__sway__yaw_rms_rad``)."""
        return _with(self, changes, "TrackingConfig")

    def to_dict(self) -> dict:
        """The config as nested plain dicts: one table per part, then ``revolutions`` and ``seed``."""
        out = {name: getattr(self, name).to_dict() for name in _PARTS}
        out.update(revolutions=self.revolutions, seed=self.seed)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "TrackingConfig":
        """The config a :meth:`to_dict` dict (or a TOML file's tables) describes.

        Unknown keys are an error naming them; each part's table is checked by the part, whose
        errors name ``part.key``. A missing part or field takes its default.
        """
        if not isinstance(data, dict):
            raise TypeError(f"a TrackingConfig dict must be a dict, got {type(data).__name__}")
        allowed = [*_PARTS, "revolutions", "seed"]
        unknown = sorted(set(data) - set(allowed))
        if unknown:
            raise ValueError(f"unknown TrackingConfig key(s): {', '.join(unknown)} (allowed: {', '.join(allowed)}; "
                             "each part is a table of its own fields)")
        parts = {name: _PARTS[name].from_dict(data[name]) if isinstance(data[name], dict) else data[name]
                 for name in _PARTS if name in data}
        return cls(**parts, **{k: data[k] for k in ("revolutions", "seed") if k in data})

    @property
    def key(self) -> str:
        """A short stable hash of the schema and every field (the results store adds the source hash)."""
        text = json.dumps({"schema": SCHEMA, "config": self.to_dict()}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_parts(config: TrackingConfig) -> None:
    """The rules that tie two parts of a config; each message names both.

    * the run's length: revolutions × target.period_s × camera.fps frames, at least one and at
      most :data:`_MAX_FRAMES`; camera.latency_frames fewer than that;
    * gimbal.inner_rate_hz >= camera.fps (the axes step at least once per frame);
    * an estimator.lens_strategy other than "ignore" needs a camera lens;
    * target.occluders need camera.blur "subframes" or "auto" when the camera exposes (the fast
      blur cannot put the target behind them), and a global shutter;
    * pointing "predictive" and "filter" assume a still platform;
    * a pointing.link assumes a still platform, and reports at most once per gimbal inner step.

    Raises
    ------
    ValueError

    Notes
    -----
    Where the flat config's cross-field rules went: those among one part's fields stay in that
    part (a rolling shutter needs the fast blur, an exposure fits in a frame and needs a frame of
    latency, a fisheye refuses the fast blur and bounds the field of view: :class:`Camera`; a
    flight fixes the height: :class:`Platform`; the start phase lies within the period:
    :class:`Target`); "a fixed passive mount cannot be active" is gone, as a :class:`Pointing` is
    one kind; the rest are the rules above. The cone's size (camera field, platform height,
    gimbal geometry) is derived, not checked (:attr:`TrackingConfig.path`).
    """
    camera, target = config.camera, config.target
    frames = config.revolutions * target.period_s * camera.fps
    if frames > _MAX_FRAMES:
        raise ValueError(f"revolutions × target.period_s × camera.fps must be <= {_MAX_FRAMES} frames, got {frames:g}")
    if config.n_frames < 1:
        raise ValueError(f"the run must hold at least one frame: revolutions × target.period_s × camera.fps = "
                         f"{frames:g}")
    if camera.latency_frames > config.n_frames - 1:
        raise ValueError(f"camera.latency_frames={camera.latency_frames} must be fewer than the run's frames "
                         f"(revolutions × target.period_s × camera.fps = {config.n_frames})")
    if config.gimbal.inner_rate_hz < camera.fps:
        raise ValueError(f"gimbal.inner_rate_hz={config.gimbal.inner_rate_hz:g} must be >= camera.fps={camera.fps:g}: "
                         "the axes step at least once per frame")
    if config.estimator.knows_lens and camera.lens_model is None:
        raise ValueError(f"estimator.lens_strategy {config.estimator.lens_strategy!r} needs a lens; camera.lens is "
                         f"{camera.lens!r} (an ideal pinhole: use 'ignore')")
    if target.occluders and camera.exposure_s > 0 and camera.blur == "fast":
        raise ValueError("target.occluders need camera.blur 'subframes' (or 'auto'): camera.blur 'fast' cannot put "
                         "the target behind them")
    if target.occluders and camera.readout_s > 0:
        raise ValueError("target.occluders and a rolling shutter (camera.readout_s > 0): only the fast blur renders a "
                         "rolling shutter, and it cannot put the target behind occluders")
    if config.pointing.link is not None and config.platform.moving:
        raise ValueError(f"pointing.link assumes a still platform (the driver maps joint rates to the protocol's "
                         f"vehicle frame on a level body); platform.motion is {config.platform.motion!r}")
    if config.pointing.link is not None and config.pointing.link.status_rate_hz > config.gimbal.inner_rate_hz:
        raise ValueError(f"pointing.link.status_rate_hz={config.pointing.link.status_rate_hz:g} exceeds "
                         f"gimbal.inner_rate_hz={config.gimbal.inner_rate_hz:g}: the device samples its state at "
                         "inner steps")
    if config.pointing.assumes_still_platform and config.platform.moving:
        raise ValueError(f"pointing {config.pointing.kind!r} assumes a still platform; platform.motion is "
                         f"{config.platform.motion!r} (use platform.motion 'static' or pointing 'paper')")
