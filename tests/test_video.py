"""MP4 clips a browser plays: H.264 in 4:2:0, every frame, the frame rate asked, the picture kept
(OpenCV decodes independently of the PyAV encoder), odd sizes padded, nothing torn left behind."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gimbal_lab.video import VideoWriter, probe_video, write_video


def frames(n: int, width: int, height: int):
    """Smooth moving gradients (what H.264 keeps well), one per frame."""
    yy, xx = np.mgrid[0:height, 0:width]
    for k in range(n):
        rgb = np.stack([xx * 200 // max(width - 1, 1) + 2 * k, yy * 200 // max(height - 1, 1) + 20,
                        np.full_like(xx, 60 + k)], axis=-1)
        yield rgb.astype(np.uint8)


@pytest.mark.parametrize("width, height, fps", [(320, 240, 30.0), (321, 239, 7.5), (64, 48, 29.97)])
def test_clips_are_h264_with_every_frame_and_the_picture_kept(tmp_path, width, height, fps):
    shown = list(frames(12, width, height))
    path = write_video(tmp_path / "clip.mp4", iter(shown), fps=fps)
    info = probe_video(path)
    # 4:2:0 needs even sides: an odd side gets one more row or column, a copy of the last one
    assert (info.codec, info.pixel_format) == ("h264", "yuv420p")
    assert (info.width, info.height, info.frames) == (width + width % 2, height + height % 2, 12)
    assert info.fps == pytest.approx(fps, rel=1e-3)  # a Fraction within 1/1001 of fps
    assert info.duration_s == pytest.approx(12 / fps, abs=1 / fps)
    capture = cv2.VideoCapture(str(path))
    decoded = []
    while True:
        ok, bgr = capture.read()
        if not ok:
            break
        decoded.append(bgr[..., ::-1])
    capture.release()
    assert len(decoded) == 12
    for got, sent in zip(decoded, shown):
        # crf 20 is meant to be close to visually lossless: on smooth gradients the mean error stays
        # under 4 grey levels (1.6 %; 4:2:0 halves the colour resolution); a wrong picture is off by tens
        assert np.abs(got[:height, :width].astype(int) - sent).mean() < 4
        if width % 2:
            np.testing.assert_allclose(got[:height, -1].astype(int), got[:height, -2].astype(int), atol=12)


def test_bad_frames_and_rates_are_named(tmp_path):
    with pytest.raises(ValueError, match="fps must be a number > 0"):
        write_video(tmp_path / "a.mp4", frames(2, 32, 32), fps=0)
    with pytest.raises(ValueError, match="no frames to write"):
        write_video(tmp_path / "a.mp4", [], fps=30)
    with pytest.raises(ValueError, match="frame 1 is 16x16 px, the first was 32x32"):
        write_video(tmp_path / "a.mp4", [next(frames(1, 32, 32)), next(frames(1, 16, 16))], fps=30)
    with pytest.raises(ValueError, match=r"uint8 RGB of shape \(H, W, 3\)"):
        write_video(tmp_path / "a.mp4", [np.zeros((8, 8), np.uint8)], fps=30)
    assert list(tmp_path.iterdir()) == []  # nothing half-written left


def test_an_interrupted_clip_keeps_the_old_file(tmp_path):
    old = tmp_path / "clip.mp4"
    write_video(old, frames(3, 32, 32), fps=30)
    before = old.read_bytes()

    def then_ctrl_c():
        yield from frames(3, 32, 32)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_video(old, then_ctrl_c(), fps=30)
    assert old.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_a_closed_writer_counts_its_frames(tmp_path):
    with VideoWriter(tmp_path / "c.mp4", 10) as writer:
        for rgb in frames(5, 16, 16):
            writer.write(rgb)
    writer.close()  # idempotent
    assert writer.frames == 5 and probe_video(tmp_path / "c.mp4").frames == 5
