"""Cost of the sensor models on one rendered study frame: a baseline commit's code against the working tree's.

Renders the sphere 3 m ahead of a camera looking level over the textured ground (640 × 480 RGB,
ground and sky behind it), then times, in one run and taking turns (baseline, working tree,
working tree, baseline, ... so that changes of the machine's load hit both sides alike):
:func:`gimbal_lab.scene.add_sensor_noise` at 2 grey levels (the studies' fixed camera) and
:meth:`gimbal_lab.sensor.SensorModel.record` for the IMX273 behind an f/2.8 lens at 15, 300 and
30,000 lx, each at 1 and 16.7 ms (with ``--exact``, also the full model everywhere). The
baseline's code is imported from a checkout of it (``git worktree add DIR REF``) under another
package name. A case's cost is the CPU time (``time.process_time``, one OpenCV and one BLAS thread,
as the study's workers run) of one call, the median over ``--frames`` repeats.

Printed: per case the baseline's and the working tree's ms/frame, their ratio baseline / working
tree, the share of samples on the full model (Poisson shot noise), and whether the two sides'
frames agree bit for bit on the samples of the normal shortcut (same generator state); the load
average before and after, the CPU and the date.

Usage::

    git worktree add /tmp/sensor-base b52bb98
    python benchmarks/bench_sensor.py --baseline /tmp/sensor-base [--frames 30] [--exact]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import argparse
import datetime
import importlib
import importlib.util
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from _common import cpu_model

from gimbal_lab import scene, sensor
from gimbal_lab.camera import Intrinsics

#: OpenCV camera frame at 2 m height looking along world +x (world Z-up).
T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]])
LIGHTS_LUX = (15.0, 300.0, 30_000.0)
EXPOSURES_S = (0.001, 1.0 / 60.0)
BASELINE_PACKAGE = "gimbal_lab_baseline"


def load_baseline(root: Path):
    """The baseline checkout's ``sensor`` and ``scene`` modules, imported as package ``gimbal_lab_baseline``."""
    package_dir = root / "gimbal_lab"
    if not (package_dir / "sensor.py").is_file():
        sys.exit(f"--baseline: no gimbal_lab/sensor.py under {root}")
    spec = importlib.util.spec_from_file_location(BASELINE_PACKAGE, package_dir / "__init__.py",
                                                  submodule_search_locations=[str(package_dir)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[BASELINE_PACKAGE] = package
    spec.loader.exec_module(package)
    return importlib.import_module(f"{BASELINE_PACKAGE}.sensor"), importlib.import_module(f"{BASELINE_PACKAGE}.scene")


def render_frame() -> np.ndarray:
    with scene.SceneRenderer(Intrinsics.default(), target="sphere") as renderer:
        T_world_target = np.eye(4)
        T_world_target[:3, 3] = T_WORLD_CAM[:3, :3] @ (0.0, 0.0, 3.0) + T_WORLD_CAM[:3, 3]
        return renderer.render(T_WORLD_CAM, T_world_target)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the baseline commit")
    parser.add_argument("--frames", type=int, default=30, help="repeats per case (median taken)")
    parser.add_argument("--exact", action="store_true", help="also time the full model everywhere (exact=True)")
    args = parser.parse_args()
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    cv2.setNumThreads(1)
    old_sensor, old_scene = load_baseline(args.baseline.resolve())
    image = render_frame()
    load_before = os.getloadavg()

    cases = {"fixed noise_std=2": ((old_scene.add_sensor_noise, scene.add_sensor_noise), (image, 2.0), {}, None)}
    for lux in LIGHTS_LUX:
        models = (old_sensor.SensorModel("IMX273", light_lux=lux, f_number=2.8),
                  sensor.SensorModel("IMX273", light_lux=lux, f_number=2.8))
        for exposure_s in EXPOSURES_S:
            for exact in (False, True) if args.exact else (False,):
                name = f"sensor {lux:g} lx {exposure_s * 1e3:.1f} ms{' exact' if exact else ''}"
                normal = models[1].electrons_at_full_reflectance(exposure_s) * image / 255.0 >= sensor.NORMAL_ABOVE_E
                cases[name] = ((models[0].record, models[1].record), (image, exposure_s), {"exact": exact},
                               None if exact else normal)

    # the normal shortcut's samples (every sample of the fixed noise): bit-identical for the same generator state
    same = {}
    for name, (calls, call_args, kwargs, normal) in cases.items():
        if kwargs.get("exact"):
            same[name] = "n/a"
            continue
        frames = [call(*call_args, np.random.default_rng(7), **kwargs) for call in calls]
        mask = np.ones(image.shape, bool) if normal is None else normal
        same[name] = "yes" if np.array_equal(frames[0][mask], frames[1][mask]) else "NO"

    times = {name: ([], []) for name in cases}
    rng = np.random.default_rng(0)
    for repeat in range(args.frames):
        for name, (calls, call_args, kwargs, _) in cases.items():
            for side in ((0, 1) if repeat % 2 == 0 else (1, 0)):
                t0 = time.process_time()
                calls[side](*call_args, rng, **kwargs)
                times[name][side].append(time.process_time() - t0)

    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}; {cpu_model()}, {os.cpu_count()} cores; "
          f"load average {load_before[0]:.1f} before, {os.getloadavg()[0]:.1f} after")
    print(f"baseline {args.baseline}; frame {image.shape}, mean grey {image.mean():.1f}; "
          f"CPU ms per call, median of {args.frames}")
    print(f"{'case':30s} {'baseline':>9s} {'now':>7s} {'ratio':>6s}  {'full model':>10s}  normal path same")
    for name, (old_ts, new_ts) in times.items():
        old_ms, new_ms = 1e3 * float(np.median(old_ts)), 1e3 * float(np.median(new_ts))
        normal = cases[name][3]
        share = "100%" if cases[name][2].get("exact") else "" if normal is None else f"{1.0 - normal.mean():.1%}"
        print(f"{name:30s} {old_ms:9.2f} {new_ms:7.2f} {old_ms / new_ms:6.2f}  {share:>10s}  {same[name]}")


if __name__ == "__main__":
    main()
