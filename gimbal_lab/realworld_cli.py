"""``gimbal-lab calibrate`` and ``gimbal-lab track``: the command line of :mod:`gimbal_lab.realworld`.

Registered in :mod:`gimbal_lab.cli` through :func:`add_parsers`. Nothing heavy (OpenCV, numpy,
pandas) is imported until a command runs. Arguments and output paths are checked before any
frame is read; outputs are written through temporary names (:mod:`gimbal_lab.outputs`).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

from .argtypes import length_m, positive_int

#: The calibration file formats OpenCV's FileStorage writes, picked by suffix.
CALIBRATION_SUFFIXES = (".yaml", ".yml", ".xml", ".json")


def add_parsers(subparsers) -> None:
    """Register ``gimbal-lab calibrate`` and ``gimbal-lab track`` on an argparse sub-parser set."""
    cal = subparsers.add_parser(
        "calibrate", help="calibrate a camera from chessboard/ChArUco images or a video",
        description="Find a calibration board in every frame and write the camera's intrinsics, lens "
                    "distortion and RMS reprojection error as OpenCV FileStorage YAML. Frames of more than "
                    "40 megapixels are refused from their header, before they are decoded.")
    cal.add_argument("source", help="image folder, image, video file or camera index")
    cal.add_argument("--board", choices=("chessboard", "charuco"), default="chessboard")
    cal.add_argument("--pattern", default="9x6",
                     help="chessboard: inner corners COLSxROWS; charuco: squares COLSxROWS (default 9x6)")
    cal.add_argument("--square", type=length_m, default=0.025, metavar="METRES", help="side of a square (default 0.025)")
    cal.add_argument("--marker", type=length_m, default=None, metavar="METRES", help="ChArUco: side of a marker")
    cal.add_argument("--dictionary", default="DICT_5X5_100", help="ChArUco marker dictionary (default DICT_5X5_100)")
    cal.add_argument("--model", choices=("brown_conrady", "rational"), default="brown_conrady",
                     help="lens model: brown_conrady (k1, k2, p1, p2; k3 held at 0) or rational (OpenCV's "
                          "CALIB_RATIONAL_MODEL, k1..k6 with p1, p2: wide phone and action-camera lenses; needs "
                          "many views reaching the corners) (default brown_conrady)")
    cal.add_argument("--step", type=positive_int, default=1, help="use every STEP-th frame (default 1)")
    cal.add_argument("--max-frames", type=positive_int, default=None, metavar="N", help="read at most N frames")
    cal.add_argument("--out", default="calibration.yaml", metavar="FILE",
                     help="output file, .yaml/.yml/.xml/.json (default calibration.yaml); replaced whole at the end")
    cal.add_argument("--no-progress", action="store_true", help="no progress bar")
    cal.set_defaults(func=_calibrate_command, _parser=cal)

    trk = subparsers.add_parser(
        "track", help="track a sphere or ArUco markers in a video, an image folder or a camera",
        description="Detect the target in every frame, estimate its 3-D position in the camera frame, and "
                    "write DIR/track.mp4 (annotated, H.264) and DIR/track.csv (one row per detection). Both are "
                    "written under temporary names and renamed at the end: Ctrl-C keeps the frames done so "
                    "far as a matching pair; an error keeps an earlier run's files; nothing else in DIR is touched.")
    trk.add_argument("source", help="video file, image folder or camera index (e.g. 0)")
    trk.add_argument("--target", choices=("sphere", "aruco"), required=True)
    trk.add_argument("--calibration", required=True, metavar="FILE",
                     help="calibration YAML (gimbal-lab calibrate, OpenCV FileStorage or ROS camera_info)")
    trk.add_argument("--out", required=True, metavar="DIR", help="output folder")
    trk.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary (default DICT_4X4_50)")
    trk.add_argument("--marker-length", type=length_m, default=0.30, metavar="METRES",
                     help="ArUco: side of the black square (default 0.30)")
    trk.add_argument("--radius", type=length_m, default=0.10, metavar="METRES", help="sphere radius (default 0.10)")
    trk.add_argument("--max-frames", type=positive_int, default=None, metavar="N", help="stop after N frames")
    trk.add_argument("--no-video", action="store_true", help="write the CSV only")
    trk.add_argument("--no-progress", action="store_true", help="no progress bar")
    trk.add_argument("--gimbal", metavar="ADDRESS", default=None,
                     help="steer a MAVLink gimbal device on the detections (the paper's image loop): udpout:HOST:PORT, "
                          "udpin:HOST:PORT or a serial port; logs DIR/gimbal.csv (needs the [mavlink] extra)")
    trk.add_argument("--gimbal-timeout", type=float, default=0.5, metavar="SECONDS",
                     help="stop when the gimbal is silent this long (default 0.5)")
    trk.add_argument("--gimbal-wait", type=float, default=5.0, metavar="SECONDS",
                     help="how long to wait for the gimbal's first HEARTBEAT, then for its first attitude status "
                          "(default 5)")
    trk.add_argument("--gimbal-max-age", type=float, default=0.25, metavar="SECONDS",
                     help="stop (zero rates, exit 1) when the gimbal's latest attitude status is older than this, "
                          "or its quaternion is not finite or not of unit norm (default 0.25)")
    trk.add_argument("--via-manager", action="store_true",
                     help="with --gimbal: steer through a gimbal manager (the device's own or an autopilot's, found by "
                          "its GIMBAL_MANAGER_STATUS): take its primary control, send GIMBAL_MANAGER_SET_PITCHYAW rates, "
                          "release control at the end")
    trk.add_argument("--signing-key-file", default=None, metavar="FILE",
                     help="with --gimbal: MAVLink 2 signing key (32 raw bytes or 64 hex characters); sign the commands "
                          "and refuse packets not signed with it (default: no signing)")
    trk.set_defaults(func=_track_command, _parser=trk)


def _quiet_native_logs(args) -> None:
    """Keep OpenCV's and FFmpeg's own log lines (a damaged file's "moov atom not found", a missing
    camera's warnings) out of the terminal, where the command's one-line error says what went
    wrong; ``gimbal-lab --debug`` leaves them as the libraries print them, and so does a level the
    user set in OPENCV_LOG_LEVEL or OPENCV_FFMPEG_LOGLEVEL."""
    if getattr(args, "debug", False):
        return
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET; read at OpenCV's first FFmpeg open
    if os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT") == "SILENT":  # read when cv2 is imported
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # in case it was imported before


def _limited(frames, max_frames):
    for k, frame in enumerate(frames):
        if max_frames is not None and k >= max_frames:
            return
        yield frame


def _calibrate_command(args, parser) -> int:
    from .outputs import OutputError, atomic_path, check_new_file

    _quiet_native_logs(args)
    if args.board == "charuco" and args.marker is None:
        parser.error("--board charuco needs --marker METRES (the side of a marker)")
    if args.marker is not None and not args.marker < args.square:
        parser.error(f"--marker ({args.marker:g} m) must be smaller than --square ({args.square:g} m)")
    try:
        check_new_file(args.out, "--out", suffixes=CALIBRATION_SUFFIXES)
    except OutputError as exc:
        parser.error(str(exc))
    from . import realworld as rw

    try:
        rw._parse_pattern(args.pattern)
        if args.board == "charuco":
            rw._dictionary_id(args.dictionary)
        frames = rw.open_frames(args.source)
        result = rw.calibrate(_limited(frames, args.max_frames), args.board, args.pattern, args.square, args.marker,
                              args.dictionary, args.step, progress=not args.no_progress, model=args.model)
    except (FileNotFoundError, ValueError) as exc:
        parser.error(str(exc))
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"interrupted: no calibration written ({args.out} is as it was)") from None
    with atomic_path(args.out) as tmp:
        rw.save_calibration(tmp, result)
    cam = result.intrinsics
    print(f"{args.out}: {cam.width}x{cam.height} px, fx={cam.fx:.2f} fy={cam.fy:.2f} cx={cam.cx:.2f} cy={cam.cy:.2f}, "
          f"{args.model} lens k1={result.distortion.k1:.4f} k2={result.distortion.k2:.4f}; RMS reprojection error "
          f"{result.rms_px:.3f} px over {result.views} views")
    return 0


def _track_command(args, parser) -> int:
    from .outputs import OutputError, check_writable_folder

    _quiet_native_logs(args)
    out = Path(args.out)
    if args.signing_key_file is not None and args.gimbal is None:
        parser.error("--signing-key-file needs --gimbal ADDRESS (it signs the gimbal link)")
    if args.via_manager and args.gimbal is None:
        parser.error("--via-manager needs --gimbal ADDRESS (the link to the gimbal and its manager)")
    try:
        check_writable_folder(out, "--out")
        for name in ("track.csv", "track.mp4") + (("gimbal.csv",) if args.gimbal is not None else ()):
            if (out / name).is_dir():
                raise OutputError(f"--out {out}: {name} is a folder; move it away or give another folder")
    except OutputError as exc:
        parser.error(str(exc))
    from . import realworld as rw

    steer, df = None, None
    try:
        calibration = rw.load_calibration(args.calibration)
        if args.gimbal is not None:
            steer = _open_gimbal(args, out, calibration, parser)
        df = rw.track(args.source, out, args.target, calibration, args.dictionary, args.marker_length, args.radius,
                      args.max_frames, progress=not args.no_progress, video=not args.no_video, gimbal=steer,
                      keep_rows=False)
    except (FileNotFoundError, ValueError, TypeError) as exc:
        parser.error(str(exc))
    finally:
        if steer is not None:  # zero rates first, while the link works; gimbal.csv kept with track's files
            steer.close(keep=df is not None or sys.exc_info()[0] is KeyboardInterrupt)
    a = df.attrs
    if steer is not None:
        state = "stopped (zero rates sent)" if steer.stopped else "not stopped: the link is lost"
        print(f"gimbal {args.gimbal}: {steer.rows} frames steered, {state}; wrote {steer.path}")
        if steer.failure is not None:
            print(f"gimbal-lab track: error: steering stopped after frame {a['frames'] - 1}: {steer.failure}",
                  file=sys.stderr)
            return 1
    detected = a["detected"]
    written = " and ".join(str(p) for p in a["written"])
    stale = "" if not args.no_video or not (out / "track.mp4").exists() else \
        f"; {os.path.join(args.out, 'track.mp4')} is an earlier run's, left in place"
    print(f"{a['frames']} frames in {a['seconds']:.1f} s ({a['fps']:.0f} frames/s), target in {detected}; "
          f"wrote {written}{stale}" + ("  (interrupted: kept the frames done so far)" if a["interrupted"] else ""))
    return 130 if a["interrupted"] else 0


def _open_gimbal(args, out, calibration, parser):
    """The :class:`gimbal_lab.mavlink.steer.GimbalSteer` of ``--gimbal`` (one-line errors)."""
    try:
        from .mavlink.driver import GimbalLinkError
        from .mavlink.steer import GimbalSteer
    except ImportError as exc:
        parser.error(f"--gimbal needs the [mavlink] extra (pip install 'gimbal-lab[mavlink]'): {exc}")
    for name in ("gimbal_timeout", "gimbal_wait", "gimbal_max_age"):
        if not (getattr(args, name) > 0 and math.isfinite(getattr(args, name))):
            parser.error(f"--{name.replace('_', '-')} must be a time > 0 s, got {getattr(args, name)!r}")
    out.mkdir(parents=True, exist_ok=True)
    try:
        return GimbalSteer(args.gimbal, calibration.intrinsics, calibration.distortion, out,
                           timeout_s=args.gimbal_timeout, discover_timeout_s=args.gimbal_wait,
                           max_age_s=args.gimbal_max_age, say=lambda line: print(line, flush=True),
                           signing_key_file=args.signing_key_file, via_manager=args.via_manager)
    except (GimbalLinkError, OSError) as exc:
        parser.error(f"--gimbal {args.gimbal}: {exc}")
