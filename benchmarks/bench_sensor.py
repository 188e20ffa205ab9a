"""Cost of the EMVA 1288 sensor model against today's constant noise, on one rendered study frame.

Renders the sphere 3 m ahead of a camera looking level over the textured ground (640 × 480 RGB,
ground and sky behind it), then times, in one run and taking turns so that load changes affect
them alike: :func:`gimbal_lab.scene.add_sensor_noise` at 2 grey levels (the study's camera) and
:meth:`gimbal_lab.sensor.SensorModel.record` for the IMX273 behind an f/2.8 lens at several light
levels and exposures, with the normal shortcut and with the full model (``exact=True``). Prints
ms/frame (median of ``--frames`` repeats), the ratio to the constant noise, and the share of
pixels that drew the full model.

Usage::

    python benchmarks/bench_sensor.py [--frames 30]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import argparse
import time

import numpy as np

from gimbal_lab.camera import Intrinsics
from gimbal_lab.scene import SceneRenderer, add_sensor_noise
from gimbal_lab.sensor import NORMAL_ABOVE_E, SensorModel

#: OpenCV camera frame at 2 m height looking along world +x (world Z-up).
T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]])
CASES = [(10.0, 0.001), (300.0, 0.001), (300.0, 1.0 / 60.0), (10_000.0, 0.001)]  # (lux, exposure s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=30, help="repeats per case (median taken)")
    args = parser.parse_args()
    with SceneRenderer(Intrinsics.default(), target="sphere") as renderer:
        T_world_target = np.eye(4)
        T_world_target[:3, 3] = T_WORLD_CAM[:3, :3] @ (0.0, 0.0, 3.0) + T_WORLD_CAM[:3, 3]
        image = renderer.render(T_WORLD_CAM, T_world_target)
    rng = np.random.default_rng(0)
    jobs = {"fixed noise_std=2": lambda: add_sensor_noise(image, 2.0, rng)}
    for lux, exposure_s in CASES:
        model = SensorModel("IMX273", light_lux=lux, f_number=2.8)
        for exact in (False, True):
            name = f"sensor {lux:g} lx {exposure_s * 1e3:.1f} ms{' exact' if exact else ''}"
            jobs[name] = (lambda m=model, e=exposure_s, x=exact: m.record(image, e, rng, exact=x))
    times = {name: [] for name in jobs}
    for _ in range(args.frames):
        for name, job in jobs.items():
            t0 = time.perf_counter()
            job()
            times[name].append(time.perf_counter() - t0)
    base = float(np.median(times["fixed noise_std=2"]))
    print(f"frame {image.shape}, mean grey {image.mean():.1f}; {args.frames} repeats, medians")
    for name, ts in times.items():
        med = float(np.median(ts))
        line = f"{name:32s} {med * 1e3:7.2f} ms  x{med / base:5.1f}"
        if name.startswith("sensor") and not name.endswith("exact"):
            lux, ms = float(name.split()[1]), float(name.split()[3]) * 1e-3
            per_level = SensorModel("IMX273", light_lux=lux, f_number=2.8).electrons_at_full_reflectance(ms)
            share = np.mean(per_level * image / 255.0 < NORMAL_ABOVE_E)
            line += f"  full model on {share:.0%} of samples"
        print(line)


if __name__ == "__main__":
    main()
