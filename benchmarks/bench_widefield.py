"""Rendering speed of :class:`gimbal_lab.widefield.WideFieldRenderer` against the pinhole path.

Prints ms/frame and frames/s (median over ``--frames`` frames, after warm-up, the cases taking
turns) for: the study's 640 × 480 pinhole ``SceneRenderer.render``, and the 120°, 150° and 185°
fisheyes of the lens sweep; for the 185° lens also its two stages, the faces (render and linear
decode) and the resampling (remap and encode). Ratios to the pinhole path are taken in this run.

Usage::

    python benchmarks/bench_widefield.py [--frames 50] [--target sphere|aruco]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import time


from gimbal_lab.camera import Intrinsics, KannalaBrandt
from gimbal_lab.scene import SceneRenderer
from gimbal_lab.trajectories import Trajectory
from gimbal_lab.widefield import WideFieldRenderer

from bench_render import FRAME_DT_S, _interleaved_medians_ms, _pose_fn  # noqa: E402 (same folder)

FISHEYE_HFOV_DEG = (120.0, 150.0, 185.0)


def main(argv=None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50, help="frames per case")
    parser.add_argument("--target", choices=("sphere", "aruco"), default="sphere")
    args = parser.parse_args(argv)

    pose_fn = _pose_fn(Trajectory.circular())
    renderers = {"pinhole 60°": SceneRenderer(Intrinsics.default(), target=args.target)}
    for hfov_deg in FISHEYE_HFOV_DEG:
        lens, f = KannalaBrandt.equidistant_for_fov(640, math.radians(hfov_deg))
        t0 = time.perf_counter()
        wide = WideFieldRenderer(Intrinsics(f, f, 319.5, 239.5, 640, 480), lens, target=args.target)
        wide.render(*pose_fn(0.0))  # shader compilation
        faces = ", ".join(f"{x.name} {x.intrinsics.width}x{x.intrinsics.height}" for x in wide.faces)
        n_px = sum(x.intrinsics.width * x.intrinsics.height for x in wide.faces)
        print(f"fisheye {hfov_deg:g}°: faces {faces}; {n_px / (640 * 480):.2f}x the output's pixels; "
              f"create + first frame {time.perf_counter() - t0:.2f} s")
        renderers[f"fisheye {hfov_deg:g}°"] = wide
    steps = {f"render ({name})": (lambda i, r=r: r.render(*pose_fn(i * FRAME_DT_S))) for name, r in renderers.items()}
    widest = renderers[f"fisheye {FISHEYE_HFOV_DEG[-1]:g}°"]
    atlas = widest._render_faces(*pose_fn(0.0)).copy()
    steps["185° stage: faces + decode"] = lambda i: widest._render_faces(*pose_fn(i * FRAME_DT_S))
    steps["185° stage: remap + encode"] = lambda i: widest._resample(atlas)
    try:
        results = _interleaved_medians_ms(steps, args.frames)
    finally:
        for r in renderers.values():
            r.close()

    base = results["render (pinhole 60°)"]
    print(f"\n{args.target}, 640x480, median of {args.frames} frames")
    print(f"{'case':32s} {'ms/frame':>9s} {'x pinhole':>10s} {'frames/s':>9s}")
    for name, ms in results.items():
        print(f"{name:32s} {ms:9.1f} {ms / base:10.2f} {1e3 / ms:9.1f}")
    ratio = results[f"render (fisheye {FISHEYE_HFOV_DEG[-1]:g}°)"] / base
    print(f"\n185° wide-field frame / pinhole frame: {ratio:.2f} "
          f"({1e3 / results['render (fisheye 185°)']:.1f} vs {1e3 / base:.1f} frames/s)")
    return results


if __name__ == "__main__":
    main()
