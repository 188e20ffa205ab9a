"""Cost of a run through the MAVLink link against the same run in-process.

A run whose ``pointing.link`` is set talks to the simulated gimbal device (a thread of the run's
process, lock-step over loopback UDP) through the driver: per frame one GIMBAL_DEVICE_SET_ATTITUDE,
one step command and its acknowledgement, and the statuses of the step. This prints, measured in
one run, for the paper's distorted circular cell (sphere and marker, active, two revolutions):

* wall and CPU seconds per run (CPU: ``time.process_time``, every thread of the process), the
  median of ``--repeats`` interleaved repeats, in-process and through links at 1000, 50 and 5 Hz;
* the overhead per run and per frame, and its ratio to the in-process run.

The in-process run and a link run share one renderer, as the runner's workers share theirs.

Usage: python benchmarks/bench_link.py [--repeats 5] [--revolutions 2]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import argparse
import statistics
import time

from gimbal_lab.config import GimbalLink
from gimbal_lab.simulation import make_renderer, simulate
from gimbal_lab.studies.paper import PaperStudy

LINKS = {"in-process": None, "1000 Hz": GimbalLink(status_rate_hz=1000.0), "50 Hz": GimbalLink(status_rate_hz=50.0),
         "5 Hz, 60 ms, 0.1°, 5 %": GimbalLink(status_rate_hz=5.0, latency_s=0.06, quantum_rad=0.0017453292519943296,
                                             loss=0.05)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--revolutions", type=float, default=2.0)
    args = parser.parse_args()
    study = PaperStudy(revolutions=max(2.0, args.revolutions))
    for target in ("sphere", "aruco"):
        base = study.config(target, "distorted", "circular", "active", 0).replace(revolutions=args.revolutions)
        renderer = make_renderer(base)
        wall = {name: [] for name in LINKS}
        cpu = {name: [] for name in LINKS}
        try:
            simulate(base.replace(revolutions=0.2), renderer=renderer)  # warm-up: shaders, caches
            for _ in range(args.repeats):
                for name, link in LINKS.items():
                    config = base.with_(pointing__link=link)
                    w0, c0 = time.perf_counter(), time.process_time()
                    simulate(config, renderer=renderer)
                    wall[name].append(time.perf_counter() - w0)
                    cpu[name].append(time.process_time() - c0)
        finally:
            renderer.close()
        n = base.n_frames
        ref_wall, ref_cpu = statistics.median(wall["in-process"]), statistics.median(cpu["in-process"])
        print(f"{target}: {n} frames per run, median of {args.repeats} (load average {os.getloadavg()[0]:.1f})")
        print(f"  {'link':24s} {'wall s':>8s} {'CPU s':>8s} {'CPU +ms/run':>12s} {'CPU +ms/frame':>14s} {'CPU ratio':>10s}")
        for name in LINKS:
            w, c = statistics.median(wall[name]), statistics.median(cpu[name])
            print(f"  {name:24s} {w:8.3f} {c:8.3f} {1000 * (c - ref_cpu):12.1f} {1000 * (c - ref_cpu) / n:14.2f} "
                  f"{c / ref_cpu:10.3f}")
        del ref_wall


if __name__ == "__main__":
    main()
