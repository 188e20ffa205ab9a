"""MP4 clips a browser plays: H.264 video in 4:2:0 (``yuv420p``), encoded by PyAV's libx264.

OpenCV's own ``mp4v`` writer makes MPEG-4 Part 2 video, which browsers refuse (Chromium: "no
supported streams"). Every clip the lab writes to be watched (``gimbal-lab show``, the paper
study's clips, ``gimbal-lab track``) goes through :class:`VideoWriter` (the camera-recording
stand-in :func:`gimbal_lab.realworld.write_video` stays MPEG-4 Part 2, as test input): H.264 High profile, constant quality (``crf``), 4:2:0 chroma, the index at the front of the file
(``+faststart``, so a browser starts playing before it has the whole file). H.264 in 4:2:0 needs
an even width and height: a frame with an odd side is padded by repeating its last row or column.

:func:`probe_video` reads back a file's codec, pixel format, size, frame count and duration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

__all__ = ["VideoWriter", "write_video", "probe_video", "VideoInfo", "CODEC", "PIXEL_FORMAT"]

#: The codec and pixel format of every MP4 the lab writes (what browsers play).
CODEC, PIXEL_FORMAT = "h264", "yuv420p"


def _rate(fps: float) -> Fraction:
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) or not (
            math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a number > 0, got {fps!r}")
    return Fraction(float(fps)).limit_denominator(1001)


class VideoWriter:
    """Write RGB frames (uint8, shape (H, W, 3), all one size) to an H.264 MP4 at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The file (``.mp4``); written as frames come, finished by :meth:`close`.
    fps : float
        Frames per second, > 0.
    crf : int
        x264's constant quality, 0–51 (lower: better and larger; 18 is close to visually
        lossless, x264's default is 23).

    Notes
    -----
    A file is playable only after :meth:`close` (it writes the index); write to a temporary
    name and rename it when closed (:func:`gimbal_lab.outputs.atomic_path`). Use as a context
    manager: leaving the block closes the file, also on Ctrl-C, and :attr:`frames` counts the
    frames it holds.
    """

    def __init__(self, path, fps: float, crf: int = 20):
        import av

        if isinstance(crf, bool) or not isinstance(crf, int) or not 0 <= crf <= 51:
            raise ValueError(f"crf must be an integer in 0..51, got {crf!r}")
        self.path, self.rate, self.crf = Path(path), _rate(fps), crf
        self.frames = 0
        self.size: tuple[int, int] | None = None
        self._av = av
        self._container = av.open(str(self.path), mode="w", format="mp4", options={"movflags": "+faststart"})
        self._stream = None

    def write(self, rgb: np.ndarray) -> None:
        """Append one RGB frame."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"a frame must be uint8 RGB of shape (H, W, 3), got {rgb.dtype} {rgb.shape}")
        h, w = rgb.shape[:2]
        if self.size is None:
            self.size = (w, h)
            stream = self._container.add_stream("libx264", rate=self.rate)
            stream.width, stream.height = w + w % 2, h + h % 2
            stream.pix_fmt = PIXEL_FORMAT
            stream.options = {"crf": str(self.crf)}
            self._stream = stream
        elif (w, h) != self.size:
            raise ValueError(f"frame {self.frames} is {w}x{h} px, the first was {self.size[0]}x{self.size[1]}")
        if w % 2 or h % 2:
            rgb = np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        self._container.mux(self._stream.encode(frame))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and write the index (idempotent)."""
        if self._container is None:
            return
        try:
            if self._stream is not None:
                self._container.mux(self._stream.encode(None))
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_video(path, frames, fps: float = 30.0, crf: int = 20) -> Path:
    """Write RGB ``frames`` to an H.264 MP4 at ``path`` through a temporary name; returns the path.

    Nothing is left at ``path`` (an older file keeps its content) if writing fails, is
    interrupted, or ``frames`` is empty (ValueError).
    """
    from .outputs import atomic_path

    path = Path(path)
    _rate(fps)
    with atomic_path(path) as tmp:
        with VideoWriter(tmp, fps, crf) as writer:
            for rgb in frames:
                writer.write(rgb)
        if writer.frames == 0:
            raise ValueError(f"no frames to write to {path}")
    return path


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`probe_video` reads: codec name, pixel format, size (px), frame count, duration (s)."""

    codec: str
    pixel_format: str
    width: int
    height: int
    frames: int
    duration_s: float
    fps: float


def probe_video(path) -> VideoInfo:
    """The first video stream's codec, pixel format, size, frame count and duration (PyAV)."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        ctx = stream.codec_context
        frames = stream.frames or sum(1 for _ in container.decode(stream))
        if stream.duration is not None and stream.time_base is not None:
            duration = float(stream.duration * stream.time_base)
        else:
            duration = float(container.duration or 0) / av.time_base
        return VideoInfo(ctx.name, ctx.format.name if ctx.format is not None else str(ctx.pix_fmt), ctx.width,
                         ctx.height, int(frames), duration, float(stream.average_rate or 0))
