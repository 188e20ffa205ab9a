"""Command line: ``gimbal-lab reproduce`` runs the paper's study and writes tables and figures."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def _reproduce(args) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from . import plotting
    from .experiments import check_claims, claims_markdown, paper_grid, run_grid, summarize

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    configs = paper_grid(revolutions=args.revolutions)
    print(f"Running {len(configs)} closed-loop runs ({args.revolutions:g} revolutions each) on {args.jobs or os.cpu_count()} processes")
    results = run_grid(configs, jobs=args.jobs, cache_dir=out / "cache" if args.cache else None)

    summary = summarize(results)
    claims = check_claims(summary)
    written = []
    path = out / "summary.csv"
    summary.to_csv(path, index=False)
    written.append(path)
    frames = []
    for r in results:
        f = r.frames.copy()
        for k, v in (("target", r.config.target), ("distortion", r.config.distortion_label),
                     ("trajectory", r.config.trajectory), ("mode", r.config.mode),
                     ("method", r.config.sphere_method if r.config.target == "sphere" else "aruco")):
            f.insert(0, k, v)
        frames.append(f)
    import pandas as pd

    path = out / "frames.csv.gz"
    pd.concat(frames, ignore_index=True).to_csv(path, index=False, compression="gzip")
    written.append(path)
    path = out / "claims.md"
    path.write_text("# Claims of paper §4.1, measured\n\n" + claims_markdown(claims) + "\n")
    written.append(path)

    figures = out / "figures"
    ax = plotting.study.plot_trajectories()
    written.append(plotting.save_figure(ax.figure, "fig10_trajectories", figures))
    for target, name in (("sphere", "fig11_sphere_error"), ("aruco", "fig13_aruco_error")):
        ax = plotting.study.plot_error_bars(summary, target)
        written.append(plotting.save_figure(ax.figure, name, figures))
    for (target, dist, traj), name in (
        (("sphere", "undistorted", "circular"), "fig12_sphere_xyz"),
        (("aruco", "distorted", "diagonal"), "fig14_aruco_xyz"),
    ):
        for r in results:
            c = r.config
            if (c.target, c.distortion_label, c.trajectory) == (target, dist, traj):
                fig = plotting.study.plot_xyz(r, revolution=min(1, int(c.revolutions) - 1) if c.revolutions >= 1 else 0)
                written.append(plotting.save_figure(fig, f"{name}_{c.mode}", figures))
    plt.close("all")

    print(claims_markdown(claims))
    print("\nWrote:")
    for p in written:
        print(f"  {p}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="gimbal-lab", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("reproduce", help="run the paper's 16-run study and write tables and figures")
    rep.add_argument("--out", default="results", help="output folder (default: results)")
    rep.add_argument("--jobs", type=int, default=None, help="worker processes (default: all CPUs)")
    rep.add_argument("--revolutions", type=float, default=10.0, help="revolutions per run (paper: 10)")
    rep.add_argument("--no-cache", dest="cache", action="store_false", help="do not reuse cached runs")
    args = parser.parse_args(argv)
    if args.command == "reproduce":
        if args.revolutions <= 0:
            parser.error("--revolutions must be > 0")
        if args.jobs is not None and args.jobs < 1:
            parser.error("--jobs must be >= 1")
        return _reproduce(args)
    return 1


if __name__ == "__main__":
    sys.exit(main())
