"""Watching a run: the replayed frames are the run's own (the run's detector finds exactly the
pixel centres the run recorded), overlays land where they should, clips are readable MP4/GIF with
the right frame count, nothing half-written survives an interruption, and bad input is named.
"""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gimbal_lab.show import annotate, replay, side_by_side, write_clip
from gimbal_lab.simulation import TrackingConfig, TrackingResult, closed_loop, make_renderer, simulate

_BASE = TrackingConfig().with_(pointing__kind="paper", camera__lens="default", camera__width=320, camera__height=240,
                               target__start_phase_s=0.4, revolutions=0.25, seed=3)
_POINTING = {"passive": "stabilised", "active": "paper"}
from gimbal_lab.video import probe_video


def cfg(**changes) -> TrackingConfig:
    """The test's run with ``changes`` (``part__field=value``, as :meth:`TrackingConfig.with_`)."""
    return _BASE.with_(**changes)


def estimator_of(config):
    return config.estimator.build(config.camera, config.target)


@pytest.fixture(scope="module")
def runs():
    return {mode: simulate(cfg(pointing__kind=_POINTING[mode])) for mode in ("passive", "active")}


@pytest.mark.parametrize("changes", [{}, {"target__kind": "aruco", "camera__lens": "none", "camera__noise_std": 3.0}],
                         ids=["sphere-distorted", "aruco"])
def test_replayed_frames_are_the_runs_own(changes):
    """Same poses, same noise stream: the run's detector gives bit-identical pixel centres."""
    config = cfg(**changes)
    result = simulate(config)
    estimate = estimator_of(config)
    rows = 0
    for row, image in replay(result):
        uv, _, _ = estimate(image)
        if row.detected:
            assert uv is not None and np.array_equal(uv, [row.u_px, row.v_px])
        else:
            assert uv is None
        rows += 1
    assert rows == len(result.frames) == config.n_frames


def test_skipping_frames_keeps_the_noise_in_step(runs):
    result = runs["active"]
    every_frame = [img for _, img in replay(result)]
    every_third = [(row.frame, img) for row, img in replay(result, every=3)]
    assert [k for k, _ in every_third] == list(range(0, len(every_frame), 3))
    for k, img in every_third:
        assert np.array_equal(img, every_frame[k])


def test_one_frame_from_the_middle_is_the_runs_own(runs):
    result = runs["passive"]
    every_frame = [img for _, img in replay(result)]
    for k in (0, 5, len(every_frame) - 1):
        [(row, img)] = list(replay(result, start=k, stop=k + 1))
        assert row.frame == k and np.array_equal(img, every_frame[k])
    assert list(replay(result, start=4, stop=4)) == []


def test_blurred_frames_replay_exactly():
    config = cfg(camera__exposure_s=1 / 60, camera__blur="subframes", camera__n_subframes=4, revolutions=0.15)
    result = simulate(config)
    estimate = estimator_of(config)
    assert result.frames.detected.sum() >= 5
    for row, image in replay(result):
        uv, _, _ = estimate(image)
        if row.detected:
            assert uv is not None and np.array_equal(uv, [row.u_px, row.v_px])
        else:
            assert uv is None


def test_a_moving_drones_blurred_frames_are_the_closed_loops_own():
    """Vibrating body, active mount, fast blur, rolling shutter: replay runs the loop again."""
    config = cfg(platform__motion="vibration", camera__exposure_s=1 / 60, camera__blur="fast", camera__readout_s=0.01,
                 revolutions=0.2)
    renderer = make_renderer(config)
    try:
        images = [image for _, image in closed_loop(config, renderer)]
        result = simulate(config, renderer=renderer)
        shown = list(replay(result, renderer=renderer, start=1, every=2))
        assert [row.frame for row, _ in shown] == list(range(1, config.n_frames, 2))
        for row, image in shown:
            assert np.array_equal(image, images[row.frame])
        foreign = TrackingResult(config, result.frames.assign(t_mid_s=result.frames["t_mid_s"] + 1e-3))
        with pytest.raises(RuntimeError, match="differs from the frame computed again"):
            list(replay(foreign, renderer=renderer))
    finally:
        renderer.close()


def test_overlays_land_on_the_true_centre_and_the_image_centre(runs):
    result = runs["passive"]
    config = result.config
    row, image = next(replay(result))
    out = annotate(image, row, config, trace=[(row.true_u_px - 20, row.true_v_px), (row.true_u_px, row.true_v_px)])
    assert out.shape == image.shape and out is not image
    u, v = round(row.true_u_px), round(row.true_v_px)
    ring = out[v - 7, u]  # the green ring's top
    assert ring[1] > 150 and ring[0] < 120 and ring[2] < 120
    cx, cy = round(config.camera.intrinsics.cx), round(config.camera.intrinsics.cy)
    assert np.all(np.abs(out[cy, cx + 8].astype(int) - 170) < 40)  # grey cross arm
    # far from every overlay the frame is untouched
    assert np.array_equal(out[-5:, -5:], image[-5:, -5:])


def test_side_by_side_puts_passive_left_at_the_same_instants(runs):
    frames = list(side_by_side(runs["passive"], runs["active"], every=2))
    w, h = runs["passive"].config.camera.width, runs["passive"].config.camera.height
    assert len(frames) == len(range(0, runs["passive"].config.n_frames, 2))
    assert frames[0].shape == (h, 2 * w + 4, 3)
    assert np.all(frames[0][:, w:w + 4] == 255)


def test_side_by_side_refuses_runs_of_different_cells(runs):
    other = simulate(cfg(pointing__kind="stabilised", target__kind="aruco", revolutions=0.1))
    with pytest.raises(ValueError, match="differ only in pointing; they differ in target.kind, n_frames"):
        next(side_by_side(other, runs["active"]))


def test_clips_are_readable_with_every_frame(runs, tmp_path):
    """MP4 clips are H.264 in 4:2:0 (what browsers play; PyAV reads the stream back), with every
    frame, the frame rate asked and the same picture (OpenCV decodes them independently)."""
    frames = list(side_by_side(runs["passive"], runs["active"]))
    mp4 = write_clip(tmp_path / "a" / "clip.mp4", iter(frames), fps=30)
    info = probe_video(mp4)
    assert (info.codec, info.pixel_format) == ("h264", "yuv420p")
    assert (info.width, info.height, info.frames) == (frames[0].shape[1], frames[0].shape[0], len(frames))
    assert info.fps == 30 and info.duration_s == pytest.approx(len(frames) / 30, abs=1 / 30)
    cap = cv2.VideoCapture(str(mp4))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(frames)
    assert (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))) == frames[0].shape[1::-1]
    ok, first = cap.read()
    cap.release()
    assert ok and np.abs(first[..., ::-1].astype(int) - frames[0]).mean() < 8  # lossy, but the same picture

    from PIL import Image

    gif = write_clip(tmp_path / "clip.gif", iter(frames), fps=15, gif_scale=0.5)
    with Image.open(gif) as im:
        assert im.n_frames == len(frames) and im.size == (frames[0].shape[1] // 2, frames[0].shape[0] // 2)
        assert im.info["duration"] == 70  # GIF counts hundredths of a second
    assert not list(tmp_path.rglob(".*partial*"))


def test_an_interrupted_clip_leaves_nothing(runs, tmp_path):
    def frames():
        yield from side_by_side(runs["passive"], runs["active"], every=4)
        raise KeyboardInterrupt

    old = tmp_path / "clip.mp4"
    old.write_bytes(b"the previous clip")
    for name in ("clip.mp4", "clip.gif"):
        with pytest.raises(KeyboardInterrupt):
            write_clip(tmp_path / name, frames(), fps=30)
    assert old.read_bytes() == b"the previous clip"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]


@pytest.mark.parametrize("call, error, message", [
    (lambda r: write_clip("x.avi", [], fps=30), ValueError, r"\.mp4 or \.gif"),
    (lambda r: write_clip("x.mp4", [], fps=0), ValueError, "fps must be a number > 0"),
    (lambda r: write_clip("x.gif", [], fps=10, gif_scale=2), ValueError, "gif_scale must be in"),
    (lambda r: next(replay(r, every=0)), ValueError, "every must be an integer >= 1"),
    (lambda r: next(replay(r.frames)), TypeError, "result must be a TrackingResult"),
    (lambda r: next(replay(r, start=-1)), ValueError, r"start must be an integer in \[0, 15\]"),
    (lambda r: next(replay(r, stop=16)), ValueError, r"stop must be an integer in \[0, 15\]"),
])
def test_bad_input_is_named(runs, call, error, message):
    with pytest.raises(error, match=message):
        call(runs["active"])


def test_show_command_writes_a_clip_and_names_bad_arguments(tmp_path, capsys):
    toml = tmp_path / "tiny.toml"
    toml.write_text("[paper]\nreplicates = 2\nperiod_s = 0.3\n")  # 2 revolutions of 9 frames
    cmd = [sys.executable, "-m", "gimbal_lab.cli", "show"]
    # the cell's two runs in the command's own process: a pool of workers would start (import the
    # lab, open a renderer) for two runs of 18 frames; pools are tested in test_runner.py
    one_process = {**os.environ, "GIMBAL_LAB_JOBS": "1"}
    # without --out: an H.264 MP4 under results/show/, named after the cell, and the last line says where
    ok = subprocess.run(cmd + ["--config", str(toml), "--seed", "1", "--store", "store"], cwd=tmp_path,
                        capture_output=True, text=True, timeout=300, env=one_process)
    assert ok.returncode == 0, ok.stderr
    clip = tmp_path / "results" / "show" / "sphere_default_circular_seed1.mp4"
    assert ok.stdout.strip().splitlines()[-1] == (f"wrote results/show/sphere_default_circular_seed1.mp4 "
                                                  f"({clip.stat().st_size / 1e6:.1f} MB, H.264 MP4, plays in a browser)")
    info = probe_video(clip)
    assert (info.codec, info.pixel_format, info.frames) == ("h264", "yuv420p", 18)
    ok = subprocess.run(cmd + ["--config", str(toml), "--seed", "1", "--store", str(tmp_path / "store"), "--out",
                               str(tmp_path / "c.gif")], capture_output=True, text=True, timeout=300, env=one_process)
    assert ok.returncode == 0, ok.stderr
    assert "wrote" in ok.stdout and (tmp_path / "c.gif").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.gif", "results", "store", "tiny.toml"]
    # bad arguments, in this process (the command's entry point ran twice above): exit 2, one line
    from gimbal_lab import cli

    for args, message in ((["--out", "c.avi"], "--out c.avi must end in .mp4 or .gif"),
                          (["--every", "0"], "argument --every: must be an integer >= 1, got '0'"),
                          (["--config", str(toml), "--seed", "5"], "seed must be one of the study's replicates"),
                          (["--config", str(tmp_path / "missing.toml")], "does not exist")):
        capsys.readouterr()
        try:
            status = cli.main(["show"] + args + (["--out", str(tmp_path / "x.mp4")] if "--out" not in args else []))
        except SystemExit as exc:
            status = exc.code
        err = capsys.readouterr().err
        assert status == 2 and message in err, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "x.mp4").exists()
