"""Where a light-map frame's time goes: the runs of notebook 16's test size under cProfile.

Runs the first ``--runs`` calibration runs of the light map at notebook 16's size under pytest (12
points, calibration seed 100, E = {1, 16.7} ms, a quarter revolution per run: the full map's code
and camera, shorter runs) in this process, one renderer per ``renderer_key`` made before the
clock starts, as a map's worker keeps them. The frame's cost is split into parts that do not
overlap, each the cumulative time of the functions named (cProfile's wall clock, so llvmpipe's
rasteriser thread counts where the main thread waits for it):

* GL passes: ``SceneRenderer._render_canvas`` (a blurred frame makes three: the background, its
  4× multisampled window behind the target, the target's layer; draw, resolve, read back);
* exposure motion model: ``_ExposureMotion.__init__`` (pose splines through the exposure);
* blur composite: the rest of ``SceneRenderer._motion_canvas`` (warps, decode, weighted sums);
* rest of the render: ``render_frame`` beyond ``_motion_canvas`` (the lens remap, poses);
* sensor: ``SensorModel.record`` (the EMVA 1288 model);
* estimation: the estimator's ``__call__`` (detection, localisation, every pipeline of the run);
* streak column: ``simulation.image_motion`` (the frame table's streak and turn);
* loop and bookkeeping: the rest of ``simulation._frames`` (mount, inner loop, outer loop, row).

Printed: the runs and frames, the CPU time per frame (``time.process_time``: every thread of the
process) and the wall time per frame under the profiler, each part's ms per frame and share, the
load average before and after, the machine and the date. The profiler's own overhead inflates
many small calls more than a few large ones; the shares, not the absolute figures, are the
result (``bench_maps.py`` measures the cost).

Usage::

    python benchmarks/profile_light_frame.py [--runs 48]
"""

from __future__ import annotations

import os

# One BLAS thread and one llvmpipe thread, as the study's workers run; set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "1")

import argparse
import cProfile
import datetime
import pstats
import sys
import time

from _common import cpu_model, machine


def _key(fn) -> tuple:
    code = fn.__code__
    return code.co_filename, code.co_firstlineno, code.co_name


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=48, help="calibration runs to profile, from the first (48)")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")

    from gimbal_lab import config as cfg, scene, sensor, simulation
    from gimbal_lab.studies import light

    study = light.LightStudy(points=12, calibration_seeds=(100,), replicates=2, exposures_ms=(1.0, 16.7),
                             revolutions=0.25)
    configs = light.all_configs(study)[: args.runs]
    renderers = {}
    for c in configs:
        key = simulation.renderer_key(c)
        if key not in renderers:
            renderers[key] = simulation.make_renderer(c)
    load_before = os.getloadavg()
    profile = cProfile.Profile()
    frames, cpu0, wall0 = 0, time.process_time(), time.perf_counter()
    profile.enable()
    for c in configs:
        frames += len(simulation.simulate(c, renderer=renderers[simulation.renderer_key(c)]).frames)
    profile.disable()
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    load_after = os.getloadavg()
    for r in renderers.values():
        r.close()

    stats = pstats.Stats(profile).stats
    cumulative = {key: value[3] for key, value in stats.items()}

    def cum(fn) -> float:
        if _key(fn) not in cumulative:  # renamed or never called: a part would silently read 0
            raise SystemExit(f"{fn.__qualname__} was not called in the profiled runs: update the parts")
        return cumulative[_key(fn)]

    renderer_class = type(next(iter(renderers.values())))
    gl = cum(renderer_class._render_canvas)
    motion = cum(scene._ExposureMotion.__init__)
    canvas = cum(renderer_class._motion_canvas)
    render = cum(simulation.render_frame)
    record = cum(sensor.SensorModel.record)
    estimate = cum(cfg._Estimator.__call__)
    streak = cum(simulation.image_motion)
    loop = cum(simulation._frames)
    parts = [("GL passes", gl), ("exposure motion model", motion), ("blur composite", canvas - gl - motion),
             ("rest of the render", render - canvas), ("sensor", record), ("estimation", estimate),
             ("streak column", streak),
             ("loop and bookkeeping", loop - render - record - estimate - streak)]
    print(f"{len(configs)} runs of notebook 16's test size, {frames} frames: {1000 * cpu / frames:.1f} ms CPU and "
          f"{1000 * wall / frames:.1f} ms wall per frame under the profiler")
    for name, seconds in parts:
        print(f"  {name:24s} {1000 * seconds / frames:6.1f} ms/frame  {100 * seconds / loop:5.1f} %")
    print(f"load average before / after: {load_before[0]:.2f} / {load_after[0]:.2f}; {machine()}; {cpu_model()}; "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC")
    return 0


if __name__ == "__main__":
    sys.exit(main())
