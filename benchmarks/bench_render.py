"""Rendering speed of :class:`gimbal_lab.scene.SceneRenderer` at 640 × 480.

Prints ms/frame (median over ``--frames`` frames, after warm-up) for: pinhole render, render
with lens distortion (larger canvas + remap; for the still camera also with the whole canvas
remapped, as before only the target's window was), the distorted render multisampled everywhere
(``antialias="full"``, against the default multisampling in the target's window only), each with
a still camera (whose background is reused) and a turning one (drawn every frame), and an
8-sub-frame motion-blurred exposure, with and without distortion; then the ratios between them,
all measured in this one run.

Usage::

    python benchmarks/bench_render.py [--frames 100] [--target sphere|aruco]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import numpy as np

from gimbal_lab.camera import BrownConrady, Intrinsics
from gimbal_lab.scene import SceneRenderer
from gimbal_lab.trajectories import R_WORLD_MARKER, Trajectory

T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]])
FRAME_DT_S = 1.0 / 30.0


def _pose_fn(trajectory: Trajectory):
    def pose_fn(t_s):
        T = np.eye(4)
        T[:3, :3] = R_WORLD_MARKER
        T[:3, 3] = trajectory.position(t_s)
        return T_WORLD_CAM, T

    return pose_fn


def _turning(pose_fn):
    """``pose_fn`` with the camera yawing 0.5°/frame: every frame needs its background drawn."""
    def turning(t_s):
        T_world_cam, T_world_target = pose_fn(t_s)
        a = np.radians(0.5) * t_s / FRAME_DT_S
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        T = T_world_cam.copy()
        T[:3, :3] = R @ T[:3, :3]
        return T, T_world_target

    return turning


def _interleaved_medians_ms(steps: dict, n_frames: int, n_warmup: int = 3) -> dict[str, float]:
    """Median ms per call of each step, the steps taking turns so that load changes on a shared
    machine affect every case alike (their ratios stay meaningful)."""
    for i in range(n_warmup):
        for step in steps.values():
            step(i)
    times = {name: np.empty(n_frames) for name in steps}
    for i in range(n_frames):
        for name, step in steps.items():
            t0 = time.perf_counter()
            step(i)
            times[name][i] = time.perf_counter() - t0
    return {name: 1e3 * float(np.median(t)) for name, t in times.items()}


def main(argv=None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100, help="frames per case (>= 100 for the report)")
    parser.add_argument("--target", choices=("sphere", "aruco"), default="sphere")
    args = parser.parse_args(argv)

    camera = Intrinsics.default()
    pose_fn = _pose_fn(Trajectory.circular())
    exposure_s, n_sub = 0.5 * FRAME_DT_S, 8
    renderers = {}
    cases = (("pinhole", None, "window"), ("distorted", BrownConrady.default(), "window"),
             ("distorted, full anti-aliasing", BrownConrady.default(), "full"))
    for label, lens, antialias in cases:
        t0 = time.perf_counter()
        renderers[label] = SceneRenderer(camera, lens, target=args.target, antialias=antialias)
        renderers[label].render(*pose_fn(0.0))  # shader compilation
        canvas = renderers[label].canvas_intrinsics
        print(f"{label}: canvas {canvas.width}x{canvas.height}, create + first frame {time.perf_counter() - t0:.2f} s")
    steps = {}
    turning = _turning(pose_fn)
    # a still and a turning camera each on their own renderer, so that neither redraws the other's background
    movers = {label: SceneRenderer(camera, lens, target=args.target, antialias=antialias)
              for label, lens, antialias in cases}
    for label, r in renderers.items():
        steps[f"render ({label})"] = lambda i, r=r: r.render(*pose_fn(i * FRAME_DT_S))
        steps[f"render ({label}, turning camera)"] = lambda i, r=movers[label]: r.render(*turning(i * FRAME_DT_S))
    # the still camera's frame as it was before only the target's window was remapped through the lens
    whole = SceneRenderer(camera, BrownConrady.default(), target=args.target)
    steps["render (distorted, whole canvas remapped)"] = lambda i: whole._finish(
        whole._render_sharp_canvas(*pose_fn(i * FRAME_DT_S)))
    for label, r in list(renderers.items())[:2]:
        steps[f"{n_sub}-sub-frame exposure ({label})"] = lambda i, r=r: r.render_exposure(
            pose_fn, i * FRAME_DT_S, exposure_s, n_sub
        )
    results = _interleaved_medians_ms(steps, args.frames)
    for r in [*renderers.values(), *movers.values(), whole]:
        r.close()

    base = results["render (pinhole)"]
    print(f"\n{args.target}, {camera.width}x{camera.height}, median of {args.frames} frames")
    print(f"{'case':60s} {'ms/frame':>9s} {'x render':>9s} {'frames/s':>9s}")
    for name, ms in results.items():
        print(f"{name:60s} {ms:9.1f} {ms / base:9.2f} {1e3 / ms:9.1f}")
    blur = results[f"{n_sub}-sub-frame exposure (pinhole)"]
    print(f"\nexposure / ({n_sub} x render): {blur / (n_sub * base):.2f}")
    print(f"distortion overhead: {results['render (distorted)'] / base - 1:+.0%}")
    print(f"anti-aliasing in the target's window / everywhere, still camera: "
          f"{results['render (distorted)'] / results['render (distorted, full anti-aliasing)']:.2f}; turning camera: "
          f"{results['render (distorted, turning camera)'] / results['render (distorted, full anti-aliasing, turning camera)']:.2f}")
    print(f"still camera, lens remap of the target's window / of the whole canvas: "
          f"{results['render (distorted)'] / results['render (distorted, whole canvas remapped)']:.2f}")
    runs_s = 16 * 600 * base / 1e3
    # llvmpipe already spreads one renderer over every core (LP_NUM_THREADS), so parallel
    # workers do not divide this; measure the study itself for its wall time.
    print(f"16 runs x 600 frames at the pinhole rate: {runs_s:.0f} s of rendering on one renderer")
    return results


if __name__ == "__main__":
    main()
