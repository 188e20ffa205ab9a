"""Compare the frame tables of two git revisions on short runs of every study's cells.

Each revision is checked out into a temporary worktree (``git worktree add --detach``) and runs,
with that revision's own gimbal_lab, one replicate (the first seed) of every cell of

* the paper's grid (``studies.paper``), with the notebooks' two extensions beside it: the
  predictive loop as "active" and the ArUco runs without corner refinement;
* the moving-drone grid, the lens sweep and the occlusion study,

each cut to ``--seconds`` of simulated time (0.3 s by default: a few minutes for both revisions on
two cores). The cells come from each revision's study modules,
``grid(Study(replicates=2, revolutions=2))``, shortened through the revision's own
``config.replace(revolutions=...)``; a small adapter per configuration API (the flat config of
before the parts, or the nested parts) reads a config's period and whether it is active.

For every cell the script reports whether the two frame tables are bit-equal: the same columns,
``pandas.DataFrame.equals``, and every float column byte-equal (NaN where the other has NaN, every
other value the same bits). A differing cell lists its columns with the largest absolute change
and the number of frames that changed. Columns only one revision has are listed apart and left
out of the comparison.

Usage::

    python scripts/compare_frame_tables.py 3b6ce23 HEAD
    python scripts/compare_frame_tables.py 3b6ce23 HEAD --seconds 1.0 --study lens-sweep --match fisheye

Exit status 0 when every cell is bit-equal, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

STUDIES = ("paper", "paper-predictive", "paper-aruco-none", "moving-drone", "lens-sweep", "occlusion")


# ----------------------------------------------------------------------------------------------
# the worker: runs inside one revision's worktree (PYTHONPATH points at it)
# ----------------------------------------------------------------------------------------------
def _cells(studies, seconds: float, match: str | None):
    """(study, config) of every cell's first replicate, shortened to ``seconds``, in grid order."""
    import dataclasses

    from gimbal_lab.simulation import TrackingConfig
    from gimbal_lab.studies import lens_sweep, moving_drone, occlusion, paper

    # the config's layout, from the revision's own TrackingConfig (a module's presence is no sign:
    # an editable install may answer for modules the revision lacks)
    parts_api = "camera" in {f.name for f in dataclasses.fields(TrackingConfig)}

    def period_s(c):
        return c.target.period_s if parts_api else c.period_s

    def active(c):
        return c.pointing.active if parts_api else c.mode == "active"

    grids = {
        "paper": lambda: paper.grid(paper.Study(replicates=2, revolutions=2)),
        "paper-predictive": lambda: [c for c in paper.grid(paper.Study(replicates=2, revolutions=2),
                                                            outer_loop="predictive") if active(c)],
        "paper-aruco-none": lambda: paper.grid(paper.Study(replicates=2, revolutions=2), targets=("aruco",),
                                               aruco_refinement="none"),
        "moving-drone": lambda: moving_drone.grid(moving_drone.Study(replicates=2, revolutions=2)),
        "lens-sweep": lambda: lens_sweep.grid(lens_sweep.Study(replicates=2, revolutions=2)),
        "occlusion": lambda: occlusion.grid(occlusion.Study(replicates=2, revolutions=2)),
    }
    cells = []
    for name in studies:
        configs = grids[name]()
        first = min(c.seed for c in configs)
        for c in configs:
            if c.seed != first or (match and match not in c.label):
                continue
            cells.append((name, c.replace(revolutions=seconds / period_s(c))))
    return cells


def _worker(args) -> None:
    import gimbal_lab
    from gimbal_lab.runner import run

    root = Path(args.tree).resolve()
    if not Path(gimbal_lab.__file__).resolve().is_relative_to(root):
        raise SystemExit(f"imported {gimbal_lab.__file__}, not the revision's package under {root}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cells = _cells(args.study or STUDIES, args.seconds, args.match)
    results = run([c for _, c in cells], jobs=args.jobs, progress=False)
    index = []
    for i, ((study, config), result) in enumerate(zip(cells, results)):
        result.frames.to_parquet(out / f"{i:04d}.parquet", index=False)
        index.append({"study": study, "label": config.label, "seed": config.seed, "frames": len(result.frames)})
    (out / "index.json").write_text(json.dumps(index, indent=1))


# ----------------------------------------------------------------------------------------------
# comparison
# ----------------------------------------------------------------------------------------------
def compare_tables(a, b) -> dict:
    """How two frame tables differ: ``equal`` (bool), ``only_a`` and ``only_b`` (columns one lacks),
    ``columns`` (per differing column: ``max_abs`` change and ``frames`` changed)."""
    import numpy as np

    common = [c for c in a.columns if c in b.columns]
    report = {"only_a": [c for c in a.columns if c not in b.columns],
              "only_b": [c for c in b.columns if c not in a.columns], "columns": {}}
    if len(a) != len(b):
        report["equal"] = False
        report["columns"]["<rows>"] = {"max_abs": math.nan, "frames": abs(len(a) - len(b))}
        return report
    for c in common:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        if x.dtype != y.dtype:
            report["columns"][c] = {"max_abs": math.nan, "frames": len(x), "dtype": f"{x.dtype} vs {y.dtype}"}
            continue
        if x.dtype.kind == "f":
            nx, ny = np.isnan(x), np.isnan(y)
            differs = (nx != ny) | (~nx & ~ny & (x.view(np.uint64) != y.view(np.uint64)))  # bits, NaN-aware
            if differs.any():
                both = differs & ~nx & ~ny
                max_abs = float(np.max(np.abs(x[both] - y[both]))) if both.any() else math.inf
                report["columns"][c] = {"max_abs": max_abs, "frames": int(differs.sum())}
        else:
            differs = x != y
            if differs.any():
                report["columns"][c] = {"max_abs": math.nan, "frames": int(differs.sum())}
    report["equal"] = not report["columns"] and a[common].equals(b[common])
    return report


def _run_revision(repo: Path, rev: str, tmp: Path, name: str, args) -> Path:
    tree = tmp / f"tree-{name}"
    subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", "--quiet", str(tree), rev], check=True)
    try:
        commit = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], check=True,
                                capture_output=True, text=True).stdout.strip()
        print(f"{name}: {rev} ({commit}) in {tree}", flush=True)
        out = tmp / f"tables-{name}"
        env = {**os.environ, "PYTHONPATH": str(tree), "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl"),
               "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS", "1")}
        command = [sys.executable, str(Path(__file__).resolve()), "--worker", "--tree", str(tree), "--out", str(out),
                   "--seconds", repr(args.seconds), "--jobs", str(args.jobs)]
        for s in args.study or ():
            command += ["--study", s]
        if args.match:
            command += ["--match", args.match]
        subprocess.run(command, check=True, env=env, cwd=str(tree))
        return out
    finally:
        subprocess.run(["git", "-C", str(repo), "worktree", "remove", "--force", str(tree)], check=False)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rev_a", nargs="?", help="first git revision (e.g. 3b6ce23)")
    parser.add_argument("rev_b", nargs="?", help="second git revision (e.g. HEAD)")
    parser.add_argument("--seconds", type=float, default=0.3, help="simulated time per run, s (0.3)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes per revision (2)")
    parser.add_argument("--study", action="append", choices=STUDIES, help="only these grids (repeatable)")
    parser.add_argument("--match", help="only cells whose label contains this text")
    parser.add_argument("--json", help="write the per-cell report to this file")
    parser.add_argument("--keep", help="copy both revisions' frame tables (and their index.json) into this folder")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tree", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if not (args.seconds > 0 and math.isfinite(args.seconds)):
        parser.error(f"--seconds must be > 0, got {args.seconds}")
    if args.worker:
        _worker(args)
        return 0
    if not (args.rev_a and args.rev_b):
        parser.error("give two git revisions")

    import pandas as pd

    repo = Path(subprocess.run(["git", "rev-parse", "--show-toplevel"], check=True, capture_output=True,
                               text=True, cwd=Path(__file__).resolve().parent).stdout.strip())
    with tempfile.TemporaryDirectory(prefix="compare-frame-tables-") as tmp:
        tmp = Path(tmp)
        out_a = _run_revision(repo, args.rev_a, tmp, "a", args)
        out_b = _run_revision(repo, args.rev_b, tmp, "b", args)
        index_a = json.loads((out_a / "index.json").read_text())
        index_b = json.loads((out_b / "index.json").read_text())
        if len(index_a) != len(index_b):
            print(f"the revisions' grids differ in length: {len(index_a)} vs {len(index_b)} cells")
            return 1
        cells, n_equal = [], 0
        for i, (ca, cb) in enumerate(zip(index_a, index_b)):
            a = pd.read_parquet(out_a / f"{i:04d}.parquet")
            b = pd.read_parquet(out_b / f"{i:04d}.parquet")
            report = compare_tables(a, b)
            report.update(study=ca["study"], label=ca["label"], label_b=cb["label"], seed=ca["seed"], frames=len(a))
            n_equal += report["equal"]
            cells.append(report)
            status = "equal " if report["equal"] else "DIFFER"
            renamed = "" if ca["label"] == cb["label"] else f"  (b: {cb['label']})"
            print(f"{status} {ca['study']:17s} {ca['label']}{renamed}  [{len(a)} frames]")
            for column, d in report["columns"].items():
                print(f"         {column}: max |Δ| {d['max_abs']:.3g}, {d['frames']} frame(s)"
                      + (f", dtype {d['dtype']}" if "dtype" in d else ""))
        extra = sorted({c for r in cells for c in r["only_b"]}), sorted({c for r in cells for c in r["only_a"]})
        print(f"\n{n_equal} of {len(cells)} cells bit-equal ({args.seconds:g} s per run)")
        if extra[0] or extra[1]:
            print(f"columns only in b (not compared): {', '.join(extra[0]) or '-'}; only in a: {', '.join(extra[1]) or '-'}")
        if args.keep:
            import shutil

            for name, out in (("a", out_a), ("b", out_b)):
                shutil.copytree(out, Path(args.keep) / name, dirs_exist_ok=True)
        if args.json:
            Path(args.json).write_text(json.dumps({"rev_a": args.rev_a, "rev_b": args.rev_b, "seconds": args.seconds,
                                                   "cells": cells}, indent=1))
        return 0 if n_equal == len(cells) else 1


if __name__ == "__main__":
    sys.exit(main())
