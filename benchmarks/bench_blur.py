"""Cost and accuracy of motion-blurred frames: :meth:`SceneRenderer.render_motion` against sharp frames.

The sphere on the study's circle seen by a camera rigidly fixed to a hovering, vibrating drone
(docs/design.md, "Moving drone"): exposure 1/60 s, global shutter and a 20 ms rolling readout.
Prints ms/frame (median over ``--frames`` frames, the cases taking turns so that load changes
affect them alike), the ratio to a sharp :meth:`render`, the part spent in ``pose_fn`` (the
caller's motion model, sampled at the knots through its ``many``), and the error against the
brute-force reference with 64 sub-frames (:meth:`render_motion_reference`): mean absolute
grey-level difference and the differences of :class:`gimbal_lab.detection.SphereDetector`'s
centre and radius.

Usage::

    python benchmarks/bench_blur.py [--frames 60] [--accuracy-frames 8] [--save /tmp/blur_check.png]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import cv2
import numpy as np

from gimbal_lab.camera import Intrinsics
from gimbal_lab.detection import SphereDetector
from gimbal_lab.platform import BodyMotion
from gimbal_lab.scene import SceneRenderer
from gimbal_lab.trajectories import Trajectory, target_pose

# The camera's optical axes in the body frame (body x forward, y left, z up): looking along +x.
T_BODY_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
FRAME_DT_S = 1.0 / 30.0
EXPOSURE_S = 1.0 / 60.0
READOUT_S = 0.020


class _CountingPoseFn:
    """pose_fn of a camera fixed to the body and the target on the circle, with ``many`` for an
    array of times (the body evaluated once, as :class:`gimbal_lab.mount.ExposurePose` does); counts
    its time."""

    def __init__(self, body: BodyMotion, trajectory: Trajectory):
        self.body, self.trajectory = body, trajectory
        self.seconds = 0.0

    def __call__(self, t_s):
        t0 = time.perf_counter()
        poses = self.body.T_world_body(t_s) @ T_BODY_CAM, target_pose(self.trajectory, t_s)
        self.seconds += time.perf_counter() - t0
        return poses

    def many(self, times_s):
        t0 = time.perf_counter()
        poses = (self.body.T_world_body(times_s) @ T_BODY_CAM,
                 np.array([target_pose(self.trajectory, t) for t in times_s]))
        self.seconds += time.perf_counter() - t0
        return poses


def _timed_medians_ms(steps: dict, pose_fn: _CountingPoseFn, n_frames: int, n_warmup: int = 3):
    """Median ms per call and median ms inside pose_fn, the steps taking turns."""
    for i in range(n_warmup):
        for step in steps.values():
            step(i)
    total = {name: np.empty(n_frames) for name in steps}
    inside = {name: np.empty(n_frames) for name in steps}
    for i in range(n_frames):
        for name, step in steps.items():
            pose_fn.seconds = 0.0
            t0 = time.perf_counter()
            step(i)
            total[name][i] = time.perf_counter() - t0
            inside[name][i] = pose_fn.seconds
    return ({n: 1e3 * float(np.median(t)) for n, t in total.items()},
            {n: 1e3 * float(np.median(t)) for n, t in inside.items()})


def _sphere(detector, image):
    d = detector.detect(image)
    return None if d is None else np.r_[d.center_px, d.radius_px]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="timed frames per case")
    parser.add_argument("--accuracy-frames", type=int, default=8, help="frames compared with the reference")
    parser.add_argument("--seed", type=int, default=0, help="seed of the drone's motion")
    parser.add_argument("--save", default="/tmp/blur_check.png", help="side-by-side PNG (sharp | fast | reference)")
    args = parser.parse_args(argv)

    camera = Intrinsics.default()
    pose_fn = _CountingPoseFn(BodyMotion.hover(args.seed, vibration=True), Trajectory.circular())
    renderer = SceneRenderer(camera, target="sphere")
    renderer.render(*pose_fn(0.0))  # shader compilation
    start = lambda i: 0.5 + i * FRAME_DT_S  # noqa: E731

    steps = {
        "sharp render": lambda i: renderer.render(*pose_fn(start(i) + EXPOSURE_S / 2)),
        "render_motion, global shutter": lambda i: renderer.render_motion(pose_fn, start(i), EXPOSURE_S),
        "render_motion, rolling 20 ms": lambda i: renderer.render_motion(pose_fn, start(i), EXPOSURE_S, READOUT_S),
        "render_exposure, 8 sub-frames": lambda i: renderer.render_exposure(pose_fn, start(i), EXPOSURE_S, 8),
    }
    ms, pose_ms = _timed_medians_ms(steps, pose_fn, args.frames)
    stats = {}
    for name, readout in (("global", 0.0), ("rolling", READOUT_S)):
        renderer.render_motion(pose_fn, start(0), EXPOSURE_S, readout)
        stats[name] = renderer._motion_stats

    detector = SphereDetector()
    errors = {name: ([], []) for name in ("render_motion, global shutter", "render_motion, rolling 20 ms",
                                          "render_exposure, 8 sub-frames")}
    for i in range(args.accuracy_frames):
        t0 = start(7 * i)
        for name, readout in (("render_motion, global shutter", 0.0), ("render_motion, rolling 20 ms", READOUT_S),
                              ("render_exposure, 8 sub-frames", 0.0)):
            reference = renderer.render_motion_reference(pose_fn, t0, EXPOSURE_S, readout)
            if name.startswith("render_exposure"):
                image = renderer.render_exposure(pose_fn, t0, EXPOSURE_S, 8)
            else:
                image = renderer.render_motion(pose_fn, t0, EXPOSURE_S, readout)
            errors[name][0].append(np.abs(image.astype(float) - reference).mean())
            a, b = _sphere(detector, image), _sphere(detector, reference)
            if a is not None and b is not None:
                errors[name][1].append(a - b)
            if i == 0 and name == "render_motion, global shutter" and args.save:
                sharp = renderer.render(*pose_fn(t0 + EXPOSURE_S / 2))
                cv2.imwrite(args.save, cv2.cvtColor(np.hstack((sharp, image, reference)), cv2.COLOR_RGB2BGR))
    renderer.close()

    base = ms["sharp render"]
    print(f"sphere, hover with vibration (seed {args.seed}), camera fixed to the body, {camera.width}x{camera.height}; "
          f"exposure {EXPOSURE_S * 1e3:.1f} ms; median of {args.frames} frames")
    print(f"{'case':32s} {'ms/frame':>9s} {'x sharp':>8s} {'pose_fn ms':>11s} {'x sharp w/o pose_fn':>20s}")
    for name, value in ms.items():
        rest = (value - pose_ms[name]) / (base - pose_ms["sharp render"])
        print(f"{name:32s} {value:9.1f} {value / base:8.2f} {pose_ms[name]:11.1f} {rest:20.2f}")
    for name, s in stats.items():
        print(f"render_motion {name}: {s['pose_instants']} pose_fn instants in {s['pose_calls']} calls (knots every "
              f"{s['knot_spacing_s'] * 1e3:.2f} "
              f"ms), {s['slices']} slices, {s['background_warps']} background warps "
              f"(spread {s['background_spread_px']:.1f} px)")
    print(f"\nagainst the 64-sub-frame reference, {args.accuracy_frames} frames:")
    print(f"{'case':32s} {'mean |grey|':>12s} {'max':>6s} {'centre px: mean':>16s} {'max |.|':>8s} "
          f"{'radius px: mean':>16s} {'max |.|':>8s}")
    for name, (grey, det) in errors.items():
        det = np.array(det).reshape(-1, 3)
        centre = det[:, :2]
        print(f"{name:32s} {np.mean(grey):12.2f} {np.max(grey):6.2f} "
              f"{np.array2string(centre.mean(axis=0), precision=2):>16s} {np.abs(centre).max():8.2f} "
              f"{det[:, 2].mean():16.2f} {np.abs(det[:, 2]).max():8.2f}")
    if args.save:
        print(f"\nsharp | render_motion | reference written to {args.save}")
    return {"ms": ms, "pose_ms": pose_ms, "errors": errors}


if __name__ == "__main__":
    main()
