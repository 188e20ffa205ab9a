"""Cost of the closed-loop study.

Prints, measured in one run:
1. the cost of a closed-loop frame (render + sensor noise + detect + localise + control + 1 kHz
   inner loop) against a render-only frame of the same poses, per target and mode (target ratio
   ≤ 1.15), with the noise's and the detector's share measured alone on the same frames;
2. the wall time of the replicate grid (16 cells × 10 replicates × 2 revolutions, 19,200 frames)
   on all cores, no store (target ≤ 100 s on 2 cores at low load); skip it with --no-grid.

Usage: python benchmarks/bench_study.py [--frames 150] [--no-grid] [--jobs N]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


from gimbal_lab.runner import run
from gimbal_lab.studies.paper import PaperStudy, grid
from gimbal_lab.config import Camera, Pointing, Target, TrackingConfig
from gimbal_lab.scene import add_sensor_noise
from gimbal_lab.simulation import make_renderer, simulate, world_T_base
from gimbal_lab.trajectories import target_pose


def frame_costs(target: str, mode: str, n_frames: int) -> dict[str, float]:
    """Seconds per frame of a distorted circular run: the closed loop ("closed"), and on the
    same poses and frames a render alone ("render"), sensor noise alone ("noise") and the
    detector with its localisers alone ("detect"). What the closed loop spends beyond the three
    ("loop": the 1 kHz inner loop, kinematics, truth and the table row) is the rest."""
    config = TrackingConfig(camera=Camera(lens="default", noise_std=2.0), target=Target(kind=target),
                            pointing=Pointing("paper" if mode == "active" else "stabilised"), revolutions=n_frames / 60)
    renderer = make_renderer(config)
    try:
        simulate(config.replace(revolutions=0.1), renderer=renderer)  # warm-up: shaders, caches
        t0 = time.perf_counter()
        result = simulate(config, renderer=renderer)
        n = len(result.frames)
        closed = (time.perf_counter() - t0) / n
        kin = config.gimbal.kinematics
        T_world_base = world_T_base(kin)
        f = result.frames
        poses = [
            (T_world_base @ kin.forward(q, check_limits=False), target_pose(config.path, t))
            for q, t in zip(f[["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]].to_numpy(), f["t_s"])
        ]
        t0 = time.perf_counter()
        images = [renderer.render(T_world_cam, T_world_target) for T_world_cam, T_world_target in poses]
        render_only = (time.perf_counter() - t0) / n
    finally:
        renderer.close()
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    noisy = [add_sensor_noise(image, config.camera.noise_std, rng) for image in images]
    noise = (time.perf_counter() - t0) / n
    estimate = config.estimator.build(config.camera, config.target)
    t0 = time.perf_counter()
    for image in noisy:
        estimate(image)
    detect = (time.perf_counter() - t0) / n
    return {"closed": closed, "render": render_only, "noise": noise, "detect": detect,
            "loop": closed - render_only - noise - detect}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--no-grid", dest="grid", action="store_false")
    parser.add_argument("--jobs", type=int, default=None)
    args = parser.parse_args()

    print(f"closed-loop frame vs render-only frame ({args.frames} frames, 640x480, distorted), ms per frame;")
    print("the closed loop is the render, sensor noise, detection + localisation, and the loop's own work")
    print(f"{'target':8s} {'mode':8s} {'closed':>7s} {'render':>7s} {'noise':>7s} {'detect':>7s} {'loop':>7s} "
          f"{'ratio':>7s}")
    for target in ("sphere", "aruco"):
        for mode in ("passive", "active"):
            c = frame_costs(target, mode, args.frames)
            ms = " ".join(f"{1000 * c[k]:7.2f}" for k in ("closed", "render", "noise", "detect", "loop"))
            print(f"{target:8s} {mode:8s} {ms} {c['closed'] / c['render']:7.2f}")
    print("(target ratio 1.15)")

    if args.grid:
        jobs = args.jobs or os.cpu_count()
        configs = grid(PaperStudy())
        t0 = time.perf_counter()
        run(configs, jobs=jobs, progress=False)
        wall = time.perf_counter() - t0
        frames = sum(c.n_frames for c in configs)
        print(f"\nfull grid: {len(configs)} runs, {frames} frames, {jobs} processes: {wall:.1f} s wall "
              f"({1000 * wall / frames:.1f} ms per frame overall; target 100 s)")


if __name__ == "__main__":
    main()
