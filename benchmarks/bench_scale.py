"""The same sweep on the local worker pool and on a Dask cluster.

Runs the paper study's 16 cells (``--replicates`` each, no store) twice, measured in one run:
on the runner's local pool of ``--jobs`` spawned processes, and on a ``dask.distributed``
``LocalCluster`` of as many single-threaded worker processes on this machine (or on the cluster at
``--scheduler``). Prints both wall times, their ratio, and whether every frame table is equal.
Needs the ``[dask]`` extra.

Usage: python benchmarks/bench_scale.py [--replicates 2] [--jobs 2] [--scheduler tcp://HOST:8786]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import argparse
import contextlib
import logging
import time

import pandas as pd

from gimbal_lab.runner import dask_executor, run
from gimbal_lab.studies.paper import PaperStudy, grid


@contextlib.contextmanager
def _cluster(address: str | None, n_workers: int):
    if address is not None:
        yield address
        return
    from distributed import LocalCluster

    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as cluster:
        yield cluster.scheduler_address


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--replicates", type=int, default=2)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument("--scheduler", default=None, help="a running Dask scheduler (default: a LocalCluster)")
    args = parser.parse_args()

    configs = grid(PaperStudy(replicates=args.replicates))
    frames = sum(c.n_frames for c in configs)
    t0 = time.perf_counter()
    local = run(configs, jobs=args.jobs, progress=False)
    local_s = time.perf_counter() - t0

    with _cluster(args.scheduler, args.jobs) as address:
        with dask_executor(address) as executor:
            t0 = time.perf_counter()
            remote = run(configs, executor=executor, progress=False)
            dask_s = time.perf_counter() - t0

    equal = all(a.frames.equals(b.frames) for a, b in zip(local, remote))
    where = args.scheduler or f"LocalCluster, {args.jobs} worker processes"
    print(f"{len(configs)} runs, {frames} frames")
    print(f"local pool ({args.jobs} processes): {local_s:6.1f} s  ({frames / local_s:5.0f} frames/s)")
    print(f"Dask ({where}): {dask_s:6.1f} s  ({frames / dask_s:5.0f} frames/s)")
    print(f"Dask / local: {dask_s / local_s:.2f}; frame tables equal: {equal}")
    in_run = [sum(r.timing["total_s"] for r in results) for results in (local, remote)]
    print(f"seconds inside the runs (simulate, summed over runs): local {in_run[0]:.1f}, Dask {in_run[1]:.1f}")
    if not equal:
        raise SystemExit("the Dask runs' frame tables differ from the local pool's")


if __name__ == "__main__":
    pd.set_option("display.width", 120)
    main()
