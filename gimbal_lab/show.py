"""Watch a run: the camera's frames of a finished run, re-rendered, with what the tracker saw.

A run's frame table keeps, per frame, the joint angles and rates, the instants and the detection;
the config keeps the seed. That is enough to render every frame again exactly as the run saw it
(same poses, same sensor noise drawn from the same seed in the same order) and draw on it:

- the image centre (grey cross): where the active loop wants the target;
- the true target centre projected through the lens (green ring), and its recent path (the
  offset trace, yellow);
- the detected centre (magenta x) and the frame's distance error.

:func:`side_by_side` puts the passive and active runs of one cell next to each other at the same
instants; :func:`write_clip` writes MP4 (H.264, which browsers play, through PyAV's bundled
encoder) or GIF (Pillow, already installed with matplotlib), so no system ffmpeg is needed.
``gimbal-lab show`` (:mod:`gimbal_lab.show_cli`) does all of it.

Notes
-----
Paper §4.1 (Fig. 5, the camera's view of the scene during tracking).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from .config import seed_stream
from .mount import exposure_pose_fn
from .simulation import TrackingConfig, TrackingResult, make_renderer, render_frame

__all__ = ["replay", "annotate", "side_by_side", "write_clip", "default_clip_path"]

_GREY, _GREEN, _YELLOW, _MAGENTA = (170, 170, 170), (40, 220, 60), (255, 220, 0), (255, 0, 255)
#: Frames of true-centre history drawn as the offset trace.
TRACE_FRAMES = 30


def _check_result(result) -> TrackingResult:
    if not isinstance(result, TrackingResult):
        raise TypeError(f"result must be a TrackingResult (from gimbal_lab.runner.run or simulate), "
                        f"got {type(result).__name__}")
    if len(result.frames) == 0:
        raise ValueError(f"{result.config.label}: the run has no frames to show")
    return result


def replay(result: TrackingResult, renderer=None, every: int = 1, start: int = 0, stop: int | None = None):
    """Yield ``(row, image)`` for the run's frames, rendered as the run rendered them.

    Parameters
    ----------
    result : TrackingResult
    renderer : gimbal_lab.scene.SceneRenderer, optional
        One built for the run's camera, lens and target (built and closed here when omitted).
    every : int
        Yield every ``every``-th frame (the noise of the skipped ones is still drawn, so the
        frames shown are the run's own).
    start, stop : int
        Frames ``start, start + every, …`` before ``stop`` (default: to the end), as in ``range``.

    Notes
    -----
    Frames are bit-identical to the run's. A sharp frame (``camera.exposure_s == 0``) is rendered by
    :func:`gimbal_lab.simulation.render_frame` from the joint angles and rates the run recorded at
    its start (``q0_*``, ``w_*``) and the config's body motion. A blurred frame integrates the
    camera's motion through the exposure, which the table does not hold: the closed loop
    (:func:`gimbal_lab.simulation.closed_loop`) runs again up to ``stop``, and each frame is
    checked against the table (a run stored by another version of the package raises).
    """
    result = _check_result(result)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every must be an integer >= 1, got {every!r}")
    n = len(result.frames)
    stop = n if stop is None else stop
    for name, value in (("start", start), ("stop", stop)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= n:
            raise ValueError(f"{name} must be an integer in [0, {n}] (the run's frames), got {value!r}")
    config = result.config
    own = renderer is None
    if own:
        renderer = make_renderer(config)
    try:
        camera = config.camera
        if camera.exposure_s > 0:
            yield from _rerun(result, renderer, every, start, stop)
            return
        kin = config.gimbal.kinematics
        body = config.body
        rng = np.random.default_rng(seed_stream(config.seed, "noise"))  # the run's noise stream
        q0_cols = ["q0_yaw_rad", "q0_roll_rad", "q0_pitch_rad"]
        w_cols = ["w_yaw_rad_s", "w_roll_rad_s", "w_pitch_rad_s"]
        blank = np.zeros((camera.height, camera.width, 3), np.uint8)
        for i, row in enumerate(result.frames.itertuples(index=False)):
            if i >= stop:
                break
            if i < start or (i - start) % every:
                camera.add_noise(blank, rng)  # keeps the noise stream in step with the run
                continue
            q0 = np.array([getattr(row, c) for c in q0_cols])
            w = np.array([getattr(row, c) for c in w_cols])
            camera_fn = exposure_pose_fn(kin, body, config.pointing.mount, q0, w, row.t_s, row.t_s + camera.window_s)
            image = render_frame(config, renderer, camera_fn, row.t_s)[0]
            yield row, camera.add_noise(image, rng)
    finally:
        if own:
            renderer.close()


def _rerun(result, renderer, every, start, stop):
    """Frames ``start:stop:every`` of a blurred run, by running its closed loop again."""
    from .simulation import _COLUMNS, closed_loop

    i_t, i_detected = _COLUMNS.index("t_mid_s"), _COLUMNS.index("detected")
    loop = closed_loop(result.config, renderer)
    for i, ((values, image), row) in enumerate(zip(loop, result.frames.itertuples(index=False))):
        if i >= stop:
            break
        if values[i_t] != row.t_mid_s or values[i_detected] != row.detected:
            raise RuntimeError(f"{result.config.label}: frame {i} of the run differs from the frame computed again "
                               "(a run stored by another version of gimbal_lab?); run it again to show it")
        if i >= start and (i - start) % every == 0:
            yield row, image


def _point(u, v):
    return None if not (math.isfinite(u) and math.isfinite(v)) else (int(round(u)), int(round(v)))


def annotate(image: np.ndarray, row, config: TrackingConfig, trace=(), title: str | None = None) -> np.ndarray:
    """A copy of ``image`` with the image centre, true centre, its trace, the detection and a caption.

    ``row`` is the frame's row of the run's table (a namedtuple or a pandas Series); ``trace`` the
    true centre's recent pixel positions, oldest first.
    """
    out = np.ascontiguousarray(image.copy())
    K = config.camera.intrinsics
    h, w = out.shape[:2]
    cv2.drawMarker(out, (int(round(K.cx)), int(round(K.cy))), _GREY, cv2.MARKER_CROSS, 24, 1, cv2.LINE_AA)
    pts = [p for p in (_point(u, v) for u, v in trace) if p is not None]
    if len(pts) > 1:
        cv2.polylines(out, [np.array(pts, np.int32)], False, _YELLOW, 1, cv2.LINE_AA)
    true = _point(row.true_u_px, row.true_v_px)
    if true is not None:
        cv2.circle(out, true, 7, _GREEN, 2, cv2.LINE_AA)
    found = _point(row.u_px, row.v_px)
    if found is not None:
        cv2.drawMarker(out, found, _MAGENTA, cv2.MARKER_TILTED_CROSS, 14, 2, cv2.LINE_AA)
    error = f"|error| {1000 * row.abs_error_m:5.1f} mm" if row.detected else "not detected"
    lines = [title or f"{config.pointing.mode} {config.target.kind}",
             f"t {row.t_mid_s:5.2f} s  offset {row.true_offset_px:5.1f} px  {error}"]
    scale = max(0.4, h / 960)
    y = int(22 * scale / 0.5)
    for text in lines:
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.rectangle(out, (4, y - th - 4), (10 + tw, y + 5), (0, 0, 0), -1)
        cv2.putText(out, text, (7, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
        y += th + 12
    return out


def _annotated(result, renderer, every, title):
    trace = []
    for row, image in replay(result, renderer=renderer, every=every):
        trace = (trace + [(row.true_u_px, row.true_v_px)])[-max(1, TRACE_FRAMES // every):]
        yield annotate(image, row, result.config, trace, title)


def side_by_side(passive: TrackingResult, active: TrackingResult, every: int = 1):
    """Yield frames with the passive run on the left and the active run on the right, same instants.

    Both runs must share the target, camera, lens, frame rate and run length (they are the two
    pointings of one cell); one renderer serves both.
    """
    for r in (passive, active):
        _check_result(r)
    a, b = passive.config, active.config
    same = {"target.kind": lambda c: c.target.kind, "target.trajectory": lambda c: c.target.trajectory,
            "target.period_s": lambda c: c.target.period_s, "camera.width": lambda c: c.camera.width,
            "camera.height": lambda c: c.camera.height, "camera.fps": lambda c: c.camera.fps,
            "camera.lens": lambda c: c.camera.lens, "n_frames": lambda c: c.n_frames}
    differ = [name for name, get in same.items() if get(a) != get(b)]
    if differ:
        raise ValueError(f"the two runs must differ only in pointing; they differ in {', '.join(differ)}")
    renderer = make_renderer(a)
    try:
        name = lambda c: (f"{c.pointing.mode.upper()}  {c.target.kind}, {c.camera.lens_label}, {c.target.trajectory}, "
                          f"seed {c.seed}")
        left = _annotated(passive, renderer, every, name(a))
        right = _annotated(active, renderer, every, name(b))
        for l_img, r_img in zip(left, right):
            gap = np.full((l_img.shape[0], 4, 3), 255, np.uint8)
            yield np.hstack([l_img, gap, r_img])
    finally:
        renderer.close()


def gif_frame_ms(fps: float) -> int:
    """A GIF frame's duration for ``fps``: GIF counts in hundredths of a second (15 fps → 70 ms)."""
    return 10 * max(2, int(round(100.0 / fps)))  # players stretch frames under 20 ms to 100 ms


def write_clip(path, frames, fps: float, gif_scale: float = 0.5) -> Path:
    """Write RGB ``frames`` to ``path`` (.mp4 or .gif) through a temporary file beside it (nothing
    half-written is left on an error or Ctrl-C, and an older file keeps its content).

    MP4 is H.264 in 4:2:0, which browsers play (:mod:`gimbal_lab.video`). GIF frames are scaled by
    ``gif_scale`` to keep the file small and last :func:`gif_frame_ms` each.
    """
    from .outputs import atomic_path

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise ValueError(f"the clip must be a .mp4 or .gif file, got {str(path)!r}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a number > 0, got {fps!r}")
    if not (isinstance(gif_scale, (int, float)) and 0 < gif_scale <= 1):
        raise ValueError(f"gif_scale must be in (0, 1], got {gif_scale!r}")
    if suffix == ".mp4":
        from .video import write_video

        return write_video(path, frames, fps=fps)
    from PIL import Image

    with atomic_path(path) as tmp:
        images = []
        for rgb in frames:
            small = cv2.resize(rgb, None, fx=gif_scale, fy=gif_scale, interpolation=cv2.INTER_AREA)
            # 64 colours without dithering: sensor noise falls into flat colour bins, which
            # keeps the LZW-coded file several times smaller than a dithered palette
            images.append(Image.fromarray(small).quantize(colors=64, dither=Image.Dither.NONE))
        if not images:
            raise ValueError(f"no frames to write to {path}")
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=gif_frame_ms(fps), loop=0)
    return path


def default_clip_path(target: str = "sphere", distortion: str = "default", trajectory: str = "circular",
                      seed: int = 0) -> Path:
    """Where ``gimbal-lab show`` writes a cell's clip when not told: ``results/show/TARGET_LENS_PATH_seedN.mp4``."""
    return Path("results") / "show" / f"{target}_{distortion}_{trajectory}_seed{seed}.mp4"
