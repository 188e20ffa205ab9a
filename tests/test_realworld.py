"""Real-camera tools: calibration, calibration files, tracking on recordings, the CLI front ends.

The oracle is the photo-like renderer of planar targets (``PlanarTargetCamera``), whose truth is
``cv2.projectPoints`` of the target's own 3-D points: a calibration must give back the camera the
frames were made with, and tracking must give back the poses they were made at.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from gimbal_lab import cli
from gimbal_lab import realworld as rw
from gimbal_lab.camera import BrownConrady, Intrinsics, Rational, project

CAM = Intrinsics.default()
LENS = BrownConrady.default()
CLEAN = rw.PhotoEffects(uneven_light=0.0, vignetting=0.0, defocus_px=0.0, noise_std=0.0, jpeg_quality=0)
SQUARE_M = 0.025
CHESSBOARD = (10, 7, SQUARE_M)  # squares; 9 x 6 inner corners
BOARD_SIZE_M = (12 * SQUARE_M, 9 * SQUARE_M)  # with the one-square white margin
PX_PER_M = 4000.0
MARKER_M = 0.15


@pytest.fixture(scope="module")
def planar_camera():
    return rw.PlanarTargetCamera(CAM, LENS, supersample=2)


def board_frames(camera, n, seed, effects):
    texture = rw.board_texture(CHESSBOARD, px_per_m=PX_PER_M)
    return rw.board_views(camera, texture, PX_PER_M, BOARD_SIZE_M, n, np.random.default_rng(seed), effects=effects)


@pytest.fixture(scope="module")
def marker_recording(planar_camera):
    """20 photo-like frames of a printed 15-cm marker (id 7) at 0.6–1.2 m, and the true centres."""
    texture, marker_px = rw.printed_marker_texture("DICT_4X4_50", 7, cell_px=20)
    px_per_m = marker_px / MARKER_M
    margin = (texture.shape[0] - marker_px) / 2
    centre = np.array([(margin + marker_px / 2) / px_per_m] * 2 + [0.0])
    rng = np.random.default_rng(0)
    frames, truth = [], []
    for k in range(20):
        distance, angle = 0.6 + 0.6 * k / 19, 2 * math.pi * k / 20
        eye = centre + np.array([0.2 * math.cos(angle), 0.15 * math.sin(angle), -distance])
        aim = centre + np.array([0.1 * math.sin(angle), 0.1 * math.cos(angle), 0.0])
        T = rw.look_at_pose(eye, aim)
        frames.append(rw.PhotoEffects().apply(planar_camera.render(texture, px_per_m, T), rng))
        truth.append((T @ np.append(centre, 1.0))[:3])
    return frames, np.array(truth)


# --------------------------------------------------------------------------------------------
# calibration
# --------------------------------------------------------------------------------------------


def test_calibration_recovers_the_camera_the_board_was_rendered_with(planar_camera):
    # Clean prints, 25 views: the estimate must be close to the truth, not merely fit well.
    # Bounds from 8 draws of views (seeds 1–8): rms 0.064–0.095 px, fx −0.20 … +0.59 %,
    # cx −1.10 … +0.58 px, cy −0.95 … +0.66 px, k1 −0.2518 … −0.2447, k2 0.096 … 0.127
    # (k2 reads low on average, traded against k3). Seed 1 here: fx −0.14 %, cx −1.10 px.
    result = rw.calibrate(board_frames(planar_camera, 25, 1, CLEAN), "chessboard", (9, 6), SQUARE_M)
    cam = result.intrinsics
    assert result.views == 25 and cam.size == CAM.size
    assert result.rms_px < 0.12
    assert cam.fx == pytest.approx(CAM.fx, rel=0.01) and cam.fy == pytest.approx(CAM.fy, rel=0.01)
    assert abs(cam.cx - CAM.cx) < 2.0 and abs(cam.cy - CAM.cy) < 2.0
    assert result.distortion.k1 == pytest.approx(LENS.k1, abs=0.01)
    assert result.distortion.k2 == pytest.approx(LENS.k2, abs=0.03)


def test_calibration_on_photo_like_views_stays_within_a_percent(planar_camera):
    # uneven light, vignetting, defocus, noise and JPEG at quality 50
    result = rw.calibrate(board_frames(planar_camera, 12, 0, rw.PhotoEffects()), "chessboard", (9, 6), SQUARE_M)
    assert result.rms_px < 0.2  # measured 0.09 px
    assert result.intrinsics.fx == pytest.approx(CAM.fx, rel=0.015)  # measured 0.6 %
    assert result.distortion.k1 == pytest.approx(LENS.k1, abs=0.02)


def test_a_rational_calibration_fits_the_views_as_closely(planar_camera):
    """calibrate(model="rational") fits OpenCV's CALIB_RATIONAL_MODEL: the same camera as the
    Brown–Conrady fit to the same bounds (test above), its lens a Rational with k4..k6 fitted.
    Measured on seeds 1-3: rms 0.064-0.074 px, fx -0.14 ... +0.33 %, cx -1.09 ... +0.09 px,
    cy -0.16 ... +0.32 px."""
    result = rw.calibrate(board_frames(planar_camera, 25, 1, CLEAN), "chessboard", (9, 6), SQUARE_M, model="rational")
    cam = result.intrinsics
    assert isinstance(result.distortion, Rational) and np.any(result.distortion.coefficients[5:] != 0)
    assert result.views == 25 and result.rms_px < 0.12
    assert cam.fx == pytest.approx(CAM.fx, rel=0.01) and cam.fy == pytest.approx(CAM.fy, rel=0.01)
    assert abs(cam.cx - CAM.cx) < 2.0 and abs(cam.cy - CAM.cy) < 2.0
    with pytest.raises(ValueError, match=r"model must be one of \('brown_conrady', 'rational'\), got 'fisheye'"):
        rw.calibrate([], "chessboard", (9, 6), SQUARE_M, model="fisheye")


def test_calibration_refuses_too_few_views_and_mixed_sizes(planar_camera):
    frames = board_frames(planar_camera, 2, 0, CLEAN)
    with pytest.raises(ValueError, match="found in 2 frame"):
        rw.calibrate(frames, "chessboard", (9, 6), SQUARE_M)
    blank = np.full((480, 640, 3), 128, np.uint8)
    with pytest.raises(ValueError, match="found in 0 frame"):
        rw.calibrate([blank] * 4, "chessboard", (9, 6), SQUARE_M)
    with pytest.raises(ValueError, match="one camera, one size"):
        rw.calibrate([blank, np.zeros((240, 320, 3), np.uint8)], "chessboard", (9, 6), SQUARE_M)
    with pytest.raises(ValueError, match="pattern"):
        rw.calibrate([blank], "chessboard", "9by6", SQUARE_M)
    with pytest.raises(ValueError, match="step"):
        rw.calibrate([blank], "chessboard", (9, 6), SQUARE_M, step=0)
    with pytest.raises(ValueError, match="board"):
        rw.calibrate([blank], "circles", (9, 6), SQUARE_M)


def test_charuco_board_is_found_with_its_own_corner_ids(planar_camera):
    board = rw.charuco_board((7, 5), 0.04, 0.03)
    texture = rw.board_texture(board, px_per_m=PX_PER_M)
    T = rw.look_at_pose((0.16, 0.12, -0.45), (0.14, 0.10, 0.0))
    gray = cv2.cvtColor(CLEAN.apply(planar_camera.render(texture, PX_PER_M, T), np.random.default_rng(0)), cv2.COLOR_RGB2GRAY)
    objects, image = rw.find_board(gray, "charuco", (7, 5), 0.04, 0.03)
    assert len(objects) == 24  # every inner corner of a 7 x 5 board
    # each corner where projectPoints puts its own 3-D point
    assert np.abs(image - planar_camera.corners_px(objects, T)).max() < 0.3
    with pytest.raises(ValueError, match="marker_m"):
        rw.find_board(gray, "charuco", (7, 5), 0.04)


# --------------------------------------------------------------------------------------------
# tracking on recordings
# --------------------------------------------------------------------------------------------


def test_track_recovers_the_marker_positions_from_a_jpeg_video(tmp_path, marker_recording):
    frames, truth = marker_recording
    video = rw.write_video(tmp_path / "in.mp4", frames)
    df = rw.track(video, tmp_path / "out", "aruco", rw.Calibration(CAM, LENS), marker_length_m=MARKER_M, progress=False)
    assert list(df.columns) == list(rw.TRACK_COLUMNS)
    assert df.attrs["frames"] == 20 and not df.attrs["interrupted"]
    assert (df["target"] == "7").all() and list(df["frame"]) == list(range(20))
    estimate = df[["x_m", "y_m", "z_m"]].to_numpy()
    relative = np.linalg.norm(estimate - truth, axis=1) / np.linalg.norm(truth, axis=1)
    # JPEG at quality 50, then MPEG-4: measured 0.8–1.4 % of the distance (markers 70–140 px)
    assert relative.max() < 0.02
    # the CSV is the returned table; the video has every frame at the calibration's size
    written = pd.read_csv(tmp_path / "out" / "track.csv", dtype={"target": str})
    np.testing.assert_allclose(written[["x_m", "y_m", "z_m"]].to_numpy(), estimate, rtol=1e-9)
    capture = cv2.VideoCapture(str(tmp_path / "out" / "track.mp4"))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 20
    assert (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))) == CAM.size
    capture.release()


def test_track_without_the_lens_is_worse(tmp_path, marker_recording):
    frames, truth = marker_recording
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, rgb in enumerate(frames):
        cv2.imwrite(str(folder / f"{k:03d}.png"), rgb[..., ::-1])
    errors = {}
    for name, lens in (("lens", LENS), ("pinhole", BrownConrady())):
        df = rw.track(folder, tmp_path / name, "aruco", rw.Calibration(CAM, lens), marker_length_m=MARKER_M,
                      progress=False, video=False)
        estimate = df[["x_m", "y_m", "z_m"]].to_numpy()
        errors[name] = np.linalg.norm(estimate - truth, axis=1).mean()
    # the marker stays within ~15° of the axis: measured 10.2 mm with the lens, 18.8 mm without
    assert errors["pinhole"] > 1.5 * errors["lens"]


def test_track_takes_an_ideal_lens_as_none(tmp_path, marker_recording):
    """A calibration file with an ideal lens is read as distortion=None; tracking (and drawing the
    annotated video) then runs as with an all-zero Brown–Conrady lens."""
    frames, _ = marker_recording
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, rgb in enumerate(frames[:3]):
        cv2.imwrite(str(folder / f"{k:03d}.png"), rgb[..., ::-1])
    runs = [rw.track(folder, tmp_path / name, "aruco", rw.Calibration(CAM, lens), marker_length_m=MARKER_M,
                     progress=False) for name, lens in (("none", None), ("zeros", BrownConrady()))]
    pd.testing.assert_frame_equal(runs[0].drop(columns="detect_ms"), runs[1].drop(columns="detect_ms"))
    assert (tmp_path / "none" / "track.mp4").is_file()


@pytest.mark.parametrize("lens", [None, LENS], ids=["pinhole", "brown-conrady"])
def test_pose_axes_drawn_through_a_lens_match_opencv(lens):
    """_draw_axes (used for fisheye lenses, which cv2.drawFrameAxes cannot draw) puts the same
    pixels as cv2.drawFrameAxes where both apply: the oracle for its frame and colours."""
    rvec, tvec = np.array([0.3, -0.2, 0.1]), np.array([0.05, -0.02, 0.8])
    theirs, ours = np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640, 3), np.uint8)
    cv2.drawFrameAxes(theirs, CAM.K, None if lens is None else lens.coefficients, rvec, tvec, 0.1, 2)
    rw._draw_axes(ours, CAM, lens, rvec, tvec, 0.1)
    assert np.count_nonzero(theirs.any(axis=2)) > 150  # three axes some 60 px long, 2 px wide
    np.testing.assert_array_equal(ours, theirs)


def test_frames_without_a_target_get_an_empty_row(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k}.png"), np.full((480, 640, 3), 90 + k, np.uint8))
    df = rw.track(folder, tmp_path / "out", "sphere", rw.Calibration(CAM, LENS), progress=False)
    assert list(df["frame"]) == [0, 1, 2] and (df["target"] == "").all() and df["x_m"].isna().all()


def _pair(folder):
    """(frames in track.csv, frames in track.mp4) of a track output folder."""
    from gimbal_lab.video import probe_video

    return pd.read_csv(folder / "track.csv")["frame"].nunique(), probe_video(folder / "track.mp4").frames


def test_track_keeps_what_it_wrote_when_interrupted(tmp_path, monkeypatch, marker_recording):
    frames, _ = marker_recording

    def three_then_ctrl_c():
        yield from frames[:3]
        raise KeyboardInterrupt

    monkeypatch.setattr(rw, "open_frames", lambda source: rw.FrameSource("test", 30.0, 20, three_then_ctrl_c()))
    df = rw.track("ignored", tmp_path, "aruco", rw.Calibration(CAM, LENS), marker_length_m=MARKER_M, progress=False)
    assert df.attrs["interrupted"] and df.attrs["frames"] == 3
    assert len(pd.read_csv(tmp_path / "track.csv")) == 3
    capture = cv2.VideoCapture(str(tmp_path / "track.mp4"))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    capture.release()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["track.csv", "track.mp4"]  # no temporary file left


def test_ctrl_c_while_a_frame_is_written_keeps_a_matching_pair(tmp_path, monkeypatch, marker_recording):
    """SIGINT arrives while frame 3 goes into the video: it is held back until the frame's CSV rows
    are written too, so the CSV and the MP4 hold the same 4 frames."""
    import os
    import signal

    from gimbal_lab import video

    frames, _ = marker_recording
    monkeypatch.setattr(rw, "open_frames", lambda source: rw.FrameSource("test", 30.0, 20, iter(frames)))
    real_write = video.VideoWriter.write

    def write(self, rgb):
        real_write(self, rgb)
        if self.frames == 4:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(video.VideoWriter, "write", write)
    df = rw.track("ignored", tmp_path, "aruco", rw.Calibration(CAM, LENS), marker_length_m=MARKER_M, progress=False)
    assert df.attrs["interrupted"] and df.attrs["frames"] == 4
    assert _pair(tmp_path) == (4, 4)


def test_a_failed_rerun_keeps_the_earlier_pair(tmp_path, monkeypatch, marker_recording):
    frames, _ = marker_recording
    calibration = rw.Calibration(CAM, LENS)
    monkeypatch.setattr(rw, "open_frames", lambda source: rw.FrameSource("test", 30.0, 5, iter(frames[:5])))
    rw.track("ignored", tmp_path, "aruco", calibration, marker_length_m=MARKER_M, progress=False)
    before = {name: (tmp_path / name).read_bytes() for name in ("track.csv", "track.mp4")}
    bad = frames[:3] + [np.zeros((240, 320, 3), np.uint8)]  # frame 3 is of another camera
    monkeypatch.setattr(rw, "open_frames", lambda source: rw.FrameSource("test", 30.0, 4, iter(bad)))
    with pytest.raises(ValueError, match="frame 3 of test is 320x240 px"):
        rw.track("ignored", tmp_path, "aruco", calibration, marker_length_m=MARKER_M, progress=False)
    assert {name: (tmp_path / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["track.csv", "track.mp4"]


_KILLED_TRACK = """
import sys, time
from pathlib import Path
import numpy as np
from gimbal_lab import realworld as rw
from gimbal_lab.camera import BrownConrady, Intrinsics

out = Path(sys.argv[1])
def frames():
    rng = np.random.default_rng(0)
    for k in range(5):
        yield rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    (out / "ready").write_text("5 frames written")
    time.sleep(120)
rw.open_frames = lambda source: rw.FrameSource("test", 30.0, None, frames())
rw.track("ignored", out / "tracked", "sphere", rw.Calibration(Intrinsics.default(), BrownConrady.default()),
         progress=False)
"""


def test_a_killed_track_leaves_no_file_under_its_final_name(tmp_path, marker_recording):
    """SIGKILL mid-run: no torn track.mp4 or track.csv; the next run removes the temporary files."""
    import signal
    import subprocess
    import sys
    import time

    child = subprocess.Popen([sys.executable, "-c", _KILLED_TRACK, str(tmp_path)])
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "ready").exists():
            assert child.poll() is None and time.monotonic() < deadline, "the tracking process did not start"
            time.sleep(0.1)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    out = tmp_path / "tracked"
    left = sorted(p.name for p in out.iterdir())
    assert "track.mp4" not in left and "track.csv" not in left
    assert left and all(name.startswith(".track.partial-") for name in left), left
    frames, _ = marker_recording
    rw.track(frames_folder(tmp_path, frames[:2]), out, "aruco", rw.Calibration(CAM, LENS), marker_length_m=MARKER_M,
             progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["track.csv", "track.mp4"]
    assert _pair(out) == (2, 2)


def frames_folder(tmp_path, frames):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, rgb in enumerate(frames):
        cv2.imwrite(str(folder / f"{k:03d}.png"), rgb[..., ::-1])
    return folder


def test_a_huge_image_is_refused_from_its_header(tmp_path):
    from test_cli import huge_png

    image = huge_png(tmp_path / "big.png", 8000, 6000)  # 48 megapixels; never decoded here
    with pytest.raises(ValueError, match=r"image '.*big.png' is 8000x6000 px \(48 megapixels\), more than the 40"):
        next(iter(rw.open_frames(image)))
    folder = tmp_path / "folder"
    folder.mkdir()
    image.rename(folder / "a.png")
    source = rw.open_frames(folder)
    with pytest.raises(ValueError, match="8000x6000 px"):
        next(iter(source))


def test_bad_sources_and_mismatched_calibrations_are_named(tmp_path):
    calibration = rw.Calibration(CAM, LENS)
    with pytest.raises(FileNotFoundError, match="missing.mp4"):
        rw.track(tmp_path / "missing.mp4", tmp_path / "out", "aruco", calibration, progress=False)
    damaged = tmp_path / "damaged.mp4"
    damaged.write_bytes(b"\x00\x01 not a video" * 100)
    with pytest.raises(ValueError, match="damaged.mp4"):
        rw.track(damaged, tmp_path / "out", "aruco", calibration, progress=False)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="holds no image"):
        rw.track(empty, tmp_path / "out", "aruco", calibration, progress=False)
    small = tmp_path / "small"
    small.mkdir()
    cv2.imwrite(str(small / "0.png"), np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(ValueError, match="320x240 px but the calibration is for 640x480"):
        rw.track(small, tmp_path / "out", "aruco", calibration, progress=False)
    with pytest.raises(ValueError, match="target"):
        rw.track(small, tmp_path / "out", "box", calibration, progress=False)
    with pytest.raises(ValueError, match="marker_length_m"):
        rw.track(small, tmp_path / "out", "aruco", calibration, marker_length_m=-1, progress=False)
    with pytest.raises(TypeError, match="Calibration"):
        rw.track(small, tmp_path / "out", "aruco", CAM, progress=False)


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------


def test_calibrate_then_track_from_the_command_line(tmp_path, planar_camera, marker_recording, capsys):
    boards = tmp_path / "boards"
    boards.mkdir()
    for k, rgb in enumerate(board_frames(planar_camera, 12, 0, rw.PhotoEffects())):
        cv2.imwrite(str(boards / f"{k:02d}.jpg"), rgb[..., ::-1])
    yaml = tmp_path / "cam.yaml"
    assert cli.main(["calibrate", str(boards), "--pattern", "9x6", "--square", str(SQUARE_M), "--out", str(yaml),
                     "--no-progress"]) == 0
    assert "RMS reprojection error" in capsys.readouterr().out
    calibration = rw.load_calibration(yaml)
    assert calibration.intrinsics.fx == pytest.approx(CAM.fx, rel=0.015) and calibration.views == 12

    frames, truth = marker_recording
    video = rw.write_video(tmp_path / "in.mp4", frames)
    out = tmp_path / "tracked"
    assert cli.main(["track", str(video), "--target", "aruco", "--calibration", str(yaml), "--out", str(out),
                     "--marker-length", str(MARKER_M), "--no-progress"]) == 0
    assert "20 frames" in capsys.readouterr().out
    df = pd.read_csv(out / "track.csv")
    relative = np.linalg.norm(df[["x_m", "y_m", "z_m"]].to_numpy() - truth, axis=1) / np.linalg.norm(truth, axis=1)
    assert relative.max() < 0.03  # with the calibrated (not the true) camera


@pytest.mark.parametrize(
    "argv, message",
    [
        (["track", "missing.mp4", "--target", "aruco", "--calibration", "missing.yaml", "--out", "o"], "missing.yaml"),
        (["track", "x.mp4", "--target", "box", "--calibration", "c.yaml", "--out", "o"], "invalid choice"),
        (["track", "x.mp4", "--calibration", "c.yaml", "--out", "o"], "--target"),
        (["calibrate", "no_such_folder"], "no_such_folder"),
    ],
)
def test_command_line_errors_are_clear(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_look_at_pose_puts_up_up_and_right_right():
    """The plane direction ``up`` appears straight up in the image and the camera frame is
    right-handed, so a print is seen as printed (not turned by 180°)."""
    K = Intrinsics.default()
    for up in ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.6, 0.8, 0.0)):
        T = rw.look_at_pose((0.2, 0.1, -1.0), (0.2, 0.1, 0.0), up=up)
        R = T[:3, :3]
        assert np.linalg.det(R) == pytest.approx(1.0)
        centre = T @ [0.2, 0.1, 0.0, 1.0]
        above = T @ np.append(np.array([0.2, 0.1, 0.0]) + 0.1 * np.asarray(up), 1.0)
        uv = project(np.array([centre[:3], above[:3]]), K)
        assert uv[1, 1] < uv[0, 1] - 10 and abs(uv[1, 0] - uv[0, 0]) < 1e-9  # straight up in the image
    # default: plane +x (texture columns) runs to the right, plane +y (texture rows) down
    T = rw.look_at_pose((0.0, 0.0, -1.0), (0.0, 0.0, 0.0))
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-15)


# --------------------------------------------------------------------------------------------
# a real camera's rational calibration (photos kept outside the repository)
# --------------------------------------------------------------------------------------------

#: The shared real photographs: ../shared beside the clone, or the machine's /work/shared.
REAL = next((path for path in (Path(__file__).resolve().parents[2] / "shared" / "data" / "real-aruco",
                               Path("/work/shared/data/real-aruco")) if path.is_dir()), None)
#: OpenCV's ChArUco tutorial photographs (SOURCES.md): a 5 x 7 board, 4 cm squares, 2 cm markers.
CHARUCO_PHOTOS = ("img_00.jpg", "img_01.jpg", "img_02.jpg", "img_03.jpg", "chocclusion_original.jpg")


@pytest.mark.skipif(REAL is None, reason="the shared real photographs (not in the repository) are absent")
def test_a_rational_calibration_of_a_real_camera_drives_track(tmp_path, capsys):
    """gimbal-lab calibrate --model rational on five real photographs of a ChArUco board; the file
    it writes is read as a Rational lens that projects as cv2.projectPoints does with the file's
    raw numbers (Brown–Conrady's tolerance, 1e-6 px), builds a Camera, and drives gimbal-lab track.
    The markers' positions are checked against OpenCV's own pose of the whole board (solvePnP of
    its ChArUco corners with the 8 coefficients): single 2-cm markers at 0.42-0.47 m give a
    median distance of 9 mm and a largest of 32 mm from it (measured); bounds 15 and 50 mm."""
    import shutil

    from gimbal_lab.calibration import load_calibration
    from gimbal_lab.config import Camera

    photos = tmp_path / "photos"
    photos.mkdir()
    for name in CHARUCO_PHOTOS:
        shutil.copy(REAL / name, photos / name)
    path = tmp_path / "phone.yml"
    assert cli.main(["calibrate", str(photos), "--board", "charuco", "--pattern", "5x7", "--square", "0.04",
                     "--marker", "0.02", "--dictionary", "DICT_6X6_250", "--model", "rational", "--out", str(path),
                     "--no-progress"]) == 0
    assert "rational lens" in capsys.readouterr().out
    raw = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K_raw, D_raw = raw.getNode("camera_matrix").mat(), raw.getNode("distortion_coefficients").mat().reshape(-1)
    model = raw.getNode("distortion_model").string()
    raw.release()
    assert model == "rational_polynomial" and D_raw.size == 8 and np.all(D_raw[5:] != 0)
    calibration = load_calibration(path)
    assert isinstance(calibration.distortion, Rational)
    np.testing.assert_array_equal(calibration.distortion.coefficients, D_raw)
    rng = np.random.default_rng(0)
    u, v, z = rng.uniform(0, 639, 1000), rng.uniform(0, 479, 1000), rng.uniform(0.3, 5.0, 1000)
    points = np.column_stack(((u - K_raw[0, 2]) / K_raw[0, 0] * z, (v - K_raw[1, 2]) / K_raw[1, 1] * z, z))
    theirs = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K_raw, D_raw)[0].reshape(-1, 2)
    assert np.abs(project(points, calibration.intrinsics, calibration.lens) - theirs).max() < 1e-6

    camera = Camera.from_calibration(path)
    assert camera.lens_model == calibration.distortion and camera.intrinsics == calibration.intrinsics

    out = tmp_path / "tracked"
    assert cli.main(["track", str(photos), "--target", "aruco", "--dictionary", "DICT_6X6_250", "--marker-length",
                     "0.02", "--calibration", str(path), "--out", str(out), "--no-progress", "--no-video"]) == 0
    rows = pd.read_csv(out / "track.csv", dtype={"target": str})
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    centres = {int(i): corners.mean(axis=0) for i, corners in zip(board.getIds().ravel(), board.getObjPoints())}
    misses = []
    for frame, name in enumerate(sorted(CHARUCO_PHOTOS)):
        gray = cv2.imread(str(photos / name), cv2.IMREAD_GRAYSCALE)
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
        ok, rvec, tvec = cv2.solvePnP(board.getChessboardCorners()[ids.ravel()], corners, K_raw, D_raw)
        R = cv2.Rodrigues(rvec)[0]
        found = rows[(rows["frame"] == frame) & rows["target"].notna()]
        assert ok and len(found) >= 10
        for _, row in found.iterrows():
            expected = R @ centres[int(row["target"])] + tvec.reshape(3)
            misses.append(np.linalg.norm(expected - row[["x_m", "y_m", "z_m"]].to_numpy(float)))
    assert np.median(misses) < 0.015 and max(misses) < 0.05


def test_a_rational_calibration_drives_the_simulated_camera(tmp_path):
    """A phone calibration with a rational lens (written by save_calibration, read back by
    Camera.from_calibration) renders the sphere where project() puts its centre through that lens:
    the scene's lens remap takes the camera module's undistortion. The lens moves the centre by
    28 px there; the blob's centre sits 0.24 px from the projection (measured; the image of a
    sphere is not centred on its centre's image by a fraction of a pixel): bound 1 px."""
    import os

    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from gimbal_lab.calibration import save_calibration
    from gimbal_lab.config import Camera
    from gimbal_lab.detection import SphereDetector
    from gimbal_lab.scene import SceneRenderer

    lens = Rational(k1=2.2, k2=0.8, p1=0.0005, p2=-0.0003, k3=0.02, k4=2.6, k5=1.5, k6=0.12)
    path = save_calibration(tmp_path / "phone.yml", rw.Calibration(CAM, lens))
    camera = Camera.from_calibration(path)
    assert camera.lens_model == lens
    centre_cam = np.array([0.45, 0.30, 1.0]) * 3.0  # 3 m ahead, normalised (0.45, 0.30)
    T_world_cam, T_world_target = np.eye(4), np.eye(4)
    T_world_target[:3, 3] = centre_cam
    with SceneRenderer(camera.intrinsics, distortion=camera.lens_model, target="sphere") as scene:
        image = scene.render(T_world_cam, T_world_target)
    found = SphereDetector().detect(image).center_px
    through_lens = project(centre_cam, camera.intrinsics, lens)[0]
    assert np.hypot(*(through_lens - project(centre_cam, camera.intrinsics)[0])) > 20.0
    assert np.hypot(*(found - through_lens)) < 1.0


# --------------------------------------------------------------------------------------------
# named pipes, native log lines, long sources
# --------------------------------------------------------------------------------------------


def tiny_video(path, n=20):
    """An H.264 MP4 of n 64 x 48 frames, each a flat grey of its own level (10 k)."""
    from gimbal_lab.video import VideoWriter

    writer = VideoWriter(path, 30.0)
    for k in range(n):
        writer.write(np.full((48, 64, 3), 10 * k, np.uint8))
    writer.close()
    return path


def test_a_named_pipe_is_read_like_the_video_written_to_it(tmp_path):
    """A writer that starts after the open: the pipe's frames are the file's."""
    import os
    import threading
    import time

    video = tiny_video(tmp_path / "tiny.mp4")
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)

    def writer():
        time.sleep(0.3)
        with open(pipe, "wb") as handle:
            handle.write(video.read_bytes())

    thread = threading.Thread(target=writer)
    thread.start()
    source = rw.open_frames(pipe, pipe_timeout_s=30.0)
    from_pipe = list(source)
    thread.join()
    from_file = list(rw.open_frames(video))
    assert source.fps == 30.0 and len(from_pipe) == len(from_file) == 20
    assert all(np.array_equal(a, b) for a, b in zip(from_pipe, from_file))


_PIPE_WITHOUT_WRITER = """
import sys, threading
from gimbal_lab import realworld as rw
try:
    rw.open_frames(sys.argv[1], pipe_timeout_s=0.5)
except ValueError as exc:
    print(exc)
print("reader threads left:", sum(t.name.startswith("gimbal-lab pipe reader") for t in threading.enumerate()))
"""


def test_a_named_pipe_without_a_writer_times_out_and_frees_its_reader(tmp_path):
    """In a child process (an open blocked in FFmpeg would hang the test run, not fail it)."""
    import os
    import subprocess
    import sys

    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    done = subprocess.run([sys.executable, "-c", _PIPE_WITHOUT_WRITER, str(pipe)], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "OPENCV_LOG_LEVEL": "SILENT"})
    assert done.stdout.splitlines() == [f"named pipe {str(pipe)!r}: no video arrived within 0.5 s (start the program "
                                        "that writes it first)", "reader threads left: 0"], done.stderr


def test_sigterm_stops_track_on_a_silent_named_pipe(tmp_path):
    """A writer that opens the pipe and sends nothing: FFmpeg's read blocks in native code, where no
    Python signal handler runs; the pipe's reader thread keeps the command's own thread waiting in
    Python, so SIGTERM stops it (exit 143, one line) instead of being held until the writer speaks."""
    import os
    import signal
    import subprocess
    import sys
    import time

    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    calibration = rw.save_calibration(tmp_path / "cam.yml", rw.Calibration(Intrinsics.from_fov(64, 48, 1.0), None))
    child = subprocess.Popen([sys.executable, "-m", "gimbal_lab.cli", "track", str(pipe), "--target", "sphere",
                              "--calibration", str(calibration), "--out", str(tmp_path / "out"), "--no-progress"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    writer = None
    try:
        deadline = time.monotonic() + 60
        while writer is None:  # a non-blocking open for writing succeeds once the command reads the pipe
            assert child.poll() is None and time.monotonic() < deadline, "track did not open the pipe"
            try:
                writer = os.open(pipe, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:
                time.sleep(0.05)
        time.sleep(0.5)  # FFmpeg now waits in its read
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=20)
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
        if writer is not None:
            os.close(writer)
    assert child.returncode == 143
    assert err.strip().splitlines() == ["gimbal-lab track: SIGTERM: interrupted"]


@pytest.mark.parametrize("command", ["track", "calibrate"])
def test_native_log_lines_stay_out_of_the_terminal_unless_debug(tmp_path, command):
    """A damaged video: FFmpeg itself prints "moov atom not found" (seen with --debug); without it the
    command's one-line error is the only line on stderr."""
    import os
    import subprocess
    import sys

    damaged = tmp_path / "damaged.mp4"
    damaged.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    calibration = rw.save_calibration(tmp_path / "cam.yml", rw.Calibration(CAM, None))
    extra = (["--target", "aruco", "--calibration", str(calibration), "--out", str(tmp_path / "out")]
             if command == "track" else ["--out", str(tmp_path / "cam_out.yml")])

    # the user's environment without the levels (an in-process command of another test may have set them)
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_LOG_LEVEL", "OPENCV_FFMPEG_LOGLEVEL")}

    def stderr_of(*first):
        done = subprocess.run([sys.executable, "-m", "gimbal_lab.cli", *first, command, str(damaged), *extra,
                               "--no-progress"], capture_output=True, text=True, timeout=120, env=env)
        assert done.returncode == 2
        return done.stderr.strip().splitlines()

    assert stderr_of() == [f"gimbal-lab {command}: error: cannot read {str(damaged)!r} as a video or an image "
                           "(unknown format or damaged file)"]
    assert any("moov atom not found" in line for line in stderr_of("--debug"))


def test_track_streams_its_rows_to_disk(tmp_path, monkeypatch):
    """keep_rows=False (the command line's): memory does not grow with the source. Python's
    allocations (tracemalloc) at their peak over 2,000 and 20,000 frames of a synthetic source (a
    detection in every other frame, one row a frame): kept rows add about 0.48 KB a frame (8.6 MB for the 18,000 more; measured),
    streamed ones nothing (the peak moved by under 0.01 MB; measured). Bound: 1 MB."""
    import itertools
    import tracemalloc

    frame = np.zeros((48, 64, 3), np.uint8)
    calibration = rw.Calibration(Intrinsics.from_fov(64, 48, 1.0), None)
    one = [("7", np.array([31.5, 23.5]), np.array([0.01, 0.02, 1.5]), None)]
    calls = itertools.count()  # a detection in every other frame; the others get their empty row
    monkeypatch.setattr(rw, "_make_localiser", lambda *args: (lambda rgb: [] if next(calls) % 2 else one,
                                                               lambda bgr, found: None))

    def peak_bytes(n, keep_rows):
        monkeypatch.setattr(rw, "open_frames", lambda source: rw.FrameSource("synthetic", 30.0, n,
                                                                             (frame for _ in range(n))))
        tracemalloc.start()
        try:
            df = rw.track("ignored", tmp_path / f"{n}-{keep_rows}", "aruco", calibration, progress=False, video=False,
                          keep_rows=keep_rows)
            return tracemalloc.get_traced_memory()[1], df
        finally:
            tracemalloc.stop()

    peak_bytes(10, False)  # the first run's imports are not the rows'
    small, df = peak_bytes(2_000, False)
    large, df = peak_bytes(20_000, False)
    assert df.empty and df.attrs["frames"] == 20_000 and df.attrs["detected"] == 10_000
    assert sum(1 for _ in open(tmp_path / "20000-False" / "track.csv")) == 20_001  # every row, on disk
    assert large - small < 1_000_000
    kept_small, _ = peak_bytes(2_000, True)
    kept_large, df = peak_bytes(20_000, True)
    assert len(df) == 20_000 and kept_large - kept_small > 4_000_000  # what the bound would catch
