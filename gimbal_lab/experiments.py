"""The paper's study: the 16-run grid, parallel runs, summary tables and claim checks (§4.1).

Parallel runs use worker processes started with ``spawn`` (never ``fork``): a process that
created an OpenGL context must not fork. Each worker keeps one scene renderer per camera, lens
and target and reuses it across runs.
"""

from __future__ import annotations

import math
import os
import pickle
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pandas as pd

from . import __version__
from .simulation import TrackingConfig, TrackingResult, make_renderer, simulate

__all__ = ["paper_grid", "run_grid", "summarize", "check_claims", "Claim", "EQUIVALENCE_MARGIN"]

#: Two mean errors count as "about equal" when they differ by less than this fraction of their
#: mean (the paper's "no difference" for ArUco without distortion has no stated threshold).
EQUIVALENCE_MARGIN = 0.20


def paper_grid(revolutions: float = 10.0, **overrides) -> list[TrackingConfig]:
    """The 16 configs of §4.1: {sphere, aruco} × {undistorted, distorted} × {circular, diagonal}
    × {passive, active}, with DESIGN.md's defaults (``overrides`` change any other field)."""
    return [
        TrackingConfig(target=target, distortion=dist, trajectory=traj, mode=mode, revolutions=revolutions, **overrides)
        for target in ("sphere", "aruco")
        for dist in ("none", "default")
        for traj in ("circular", "diagonal")
        for mode in ("passive", "active")
    ]


# --- running --------------------------------------------------------------------------------

_RENDERERS: dict = {}


def _renderer_for(config: TrackingConfig):
    key = (config.target, config.lens, config.width, config.height, config.hfov_rad)
    if key not in _RENDERERS:
        _RENDERERS[key] = make_renderer(config)
    return _RENDERERS[key]


def _run_one(config: TrackingConfig) -> TrackingResult:
    return simulate(config, renderer=_renderer_for(config))


def _worker_init():
    # llvmpipe starts one thread per core by default; with one process per core that oversubscribes.
    os.environ.setdefault("LP_NUM_THREADS", "1")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import cv2

    cv2.setNumThreads(1)


def _cache_path(cache_dir: Path, config: TrackingConfig) -> Path:
    return Path(cache_dir) / f"v{__version__}" / f"{config.key}.pkl"


def run_grid(configs, jobs: int | None = None, cache_dir=None, progress: bool = True) -> list[TrackingResult]:
    """Run configs, in parallel on spawned worker processes, and return results in input order.

    Parameters
    ----------
    configs : sequence of TrackingConfig
    jobs : int, optional
        Worker processes (default: the number of CPUs, at most the number of runs). ``jobs=1``
        runs in this process (which then holds a GL context and must not fork afterwards).
    cache_dir : path, optional
        Folder of cached results keyed by the config's hash and the package version; runs found
        there are loaded instead of simulated, new runs are stored.
    progress : bool
        Show a progress bar over runs.
    """
    configs = list(configs)
    for c in configs:
        if not isinstance(c, TrackingConfig):
            raise TypeError(f"configs must hold TrackingConfig objects, got {type(c).__name__}")
    if jobs is None:
        jobs = os.cpu_count() or 1
    if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
        raise ValueError(f"jobs must be a positive integer, got {jobs!r}")
    results: list[TrackingResult | None] = [None] * len(configs)
    todo = []
    for i, c in enumerate(configs):
        path = _cache_path(cache_dir, c) if cache_dir is not None else None
        if path is not None and path.exists():
            with open(path, "rb") as fh:
                results[i] = pickle.load(fh)
        else:
            todo.append(i)

    bar = None
    if progress and todo:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(todo), desc="runs", unit="run")

    def store(i, result):
        results[i] = result
        if cache_dir is not None:
            path = _cache_path(cache_dir, configs[i])
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "wb") as fh:
                pickle.dump(result, fh)
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(configs[i].label)

    jobs = min(int(jobs), max(len(todo), 1))
    if jobs == 1:
        for i in todo:
            store(i, _run_one(configs[i]))
    elif todo:
        # Longest-first keeps both workers busy to the end (ArUco frames cost more than sphere ones).
        order = sorted(todo, key=lambda i: configs[i].target != "aruco")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_worker_init) as pool:
            futures = {pool.submit(_run_one, configs[i]): i for i in order}
            for fut in as_completed(futures):
                store(futures[fut], fut.result())
    if bar is not None:
        bar.close()
    return results


# --- summarising ----------------------------------------------------------------------------


def _stats(f: pd.DataFrame, prefix: str = "") -> dict:
    """Error statistics of one estimator's columns (``prefix`` "" or "alt_") in a frame table."""
    detected = f[f[f"{prefix}detected"]]
    err = detected[f"{prefix}abs_error_m"]
    row = {
        "frames": len(f),
        "detection_rate": float(f[f"{prefix}detected"].mean()) if len(f) else math.nan,
        "mean_error_m": float(err.mean()) if len(err) else math.nan,
        "std_error_m": float(err.std(ddof=1)) if len(err) > 1 else math.nan,
        "median_error_m": float(err.median()) if len(err) else math.nan,
        "mean_offset_px": float(detected["offset_px"].mean()) if len(detected) else math.nan,
    }
    for axis in "xyz":
        diff = detected[f"{prefix}est_{axis}_m"] - detected[f"true_{axis}_m"]
        row[f"mean_abs_err_{axis}_m"] = float(diff.abs().mean())
    for axis in "xyz":
        diff = detected[f"{prefix}est_cam_{axis}_m"] - detected[f"true_cam_{axis}_m"]
        row[f"mean_abs_err_cam_{axis}_m"] = float(diff.abs().mean())
    return row


def summarize(results, alternatives: bool = True) -> pd.DataFrame:
    """One row per run and estimator: detection rate, distance-error statistics, pixel offset,
    per-axis errors.

    Columns: target, distortion, trajectory, mode, method, frames, detection_rate,
    mean_error_m, std_error_m, median_error_m, mean_offset_px, mean_abs_err_{x,y,z}_m (world)
    and mean_abs_err_cam_{x,y,z}_m (camera frame; z is depth), key.

    With ``alternatives`` a sphere run contributes a second row for the localiser it recorded
    alongside its own (circle ↔ ellipse) on the same frames.
    """
    rows = []
    for r in results:
        c = r.config
        ident = {"target": c.target, "distortion": c.distortion_label, "trajectory": c.trajectory, "mode": c.mode}
        if c.target == "sphere":
            other = "ellipse" if c.sphere_method == "circle" else "circle"
            variants = [(c.sphere_method, "")] + ([(other, "alt_")] if alternatives else [])
        else:
            variants = [(f"aruco-{c.aruco_refinement}", "")]
        for method, prefix in variants:
            rows.append({**ident, "method": method, **_stats(r.frames, prefix), "key": c.key})
    return pd.DataFrame(rows)


# --- claims ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Claim:
    """One claim of the paper checked against measured numbers."""

    id: str
    section: str
    statement: str
    condition: str
    measured: str
    holds: bool


def _mean(summary: pd.DataFrame, target, distortion, trajectory, mode, column="mean_error_m") -> float:
    sel = summary[
        (summary["target"] == target)
        & (summary["distortion"] == distortion)
        & (summary["trajectory"] == trajectory)
        & (summary["mode"] == mode)
    ]
    if len(sel) != 1:
        raise ValueError(f"summary must hold exactly one run for {target}/{distortion}/{trajectory}/{mode}, found {len(sel)}")
    return float(sel[column].iloc[0])


def _mm(x: float) -> str:
    return f"{1000 * x:.2f} mm"


def check_claims(summary: pd.DataFrame, sphere_method: str = "circle") -> pd.DataFrame:
    """Every claim of paper §4.1.1–4.1.2 listed in DESIGN.md, with its numbers and a verdict.

    The verdicts are computed from ``summary`` (the output of :func:`summarize` for the 16-run
    grid, or the half of it for one target: the claims of a target that has no rows are
    skipped, and A1, which compares the two targets, needs both); nothing is assumed. Sphere
    rows of other localisers than ``sphere_method`` (the paper's: circle) are ignored.
    "About equal" means a difference below :data:`EQUIVALENCE_MARGIN` of the two errors' mean.

    Returns
    -------
    pandas.DataFrame
        Columns id, section, statement, condition, measured, holds (bool).
    """
    dists = ("undistorted", "distorted")
    trajs = ("circular", "diagonal")
    modes = ("passive", "active")
    if "method" in summary.columns:
        summary = summary[(summary["target"] != "sphere") | (summary["method"] == sphere_method)]
    claims: list[Claim] = []

    def m(target, dist, traj, mode, column="mean_error_m"):
        return _mean(summary, target, dist, traj, mode, column)

    def add(cid, section, statement, condition, measured, holds):
        claims.append(Claim(cid, section, statement, condition, measured, bool(holds)))

    targets = set(summary["target"])
    if not targets & {"sphere", "aruco"}:
        raise ValueError("summary holds no sphere or aruco runs")

    if "sphere" in targets:  # §4.1.1
        _sphere_claims(m, add, dists, trajs, modes)
    if "aruco" in targets:  # §4.1.2
        _aruco_claims(m, add, dists, trajs, modes, with_sphere="sphere" in targets)
    return pd.DataFrame([c.__dict__ for c in claims])


def _sphere_claims(m, add, dists, trajs, modes):
    for dist in dists:
        for traj in trajs:
            p, a = m("sphere", dist, traj, "passive"), m("sphere", dist, traj, "active")
            add("S1", "4.1.1", "sphere: active error < passive error", f"{dist}, {traj}",
                f"active {_mm(a)} vs passive {_mm(p)}", a < p)
    for dist in dists:
        gap = {t: m("sphere", dist, t, "passive") - m("sphere", dist, t, "active") for t in trajs}
        add("S2", "4.1.1", "sphere: the passive−active gap is smaller on the diagonal", dist,
            f"gap diagonal {_mm(gap['diagonal'])} vs circular {_mm(gap['circular'])}",
            abs(gap["diagonal"]) < abs(gap["circular"]))
    for traj in trajs:
        for mode in modes:
            u, d = m("sphere", "undistorted", traj, mode), m("sphere", "distorted", traj, mode)
            add("S3", "4.1.1", "sphere: distortion raises the error", f"{traj}, {mode}",
                f"distorted {_mm(d)} vs undistorted {_mm(u)}", d > u)
    for mode in modes:
        c, g = m("sphere", "distorted", "circular", mode), m("sphere", "distorted", "diagonal", mode)
        add("S4", "4.1.1", "sphere: distorted diagonal error < distorted circular error", mode,
            f"diagonal {_mm(g)} vs circular {_mm(c)}", g < c)
    for mode in modes:
        ex, ey, ez = (m("sphere", "undistorted", "circular", mode, f"mean_abs_err_cam_{a}_m") for a in "xyz")
        add("S5", "4.1.1", "sphere: the error lies mostly in depth (camera z)", f"undistorted, circular, {mode}",
            f"|err| x {_mm(ex)}, y {_mm(ey)}, depth {_mm(ez)}", ez > max(ex, ey))



def _aruco_claims(m, add, dists, trajs, modes, with_sphere):
    if with_sphere:
        und = [m("aruco", "undistorted", t, md) for t in trajs for md in modes]
        others = [
            m(tg, d, t, md) for tg in ("sphere", "aruco") for d in dists for t in trajs for md in modes
            if not (tg == "aruco" and d == "undistorted")
        ]
        add("A1", "4.1.2", "ArUco undistorted is the most accurate of all runs", "all 16 runs",
            f"worst ArUco undistorted {_mm(max(und))} vs best other {_mm(min(others))}", max(und) < min(others))
    for traj in trajs:
        p, a = m("aruco", "undistorted", traj, "passive"), m("aruco", "undistorted", traj, "active")
        rel = abs(a - p) / (0.5 * (a + p)) if a + p > 0 else 0.0
        add("A2", "4.1.2", "ArUco undistorted: active ≈ passive", traj,
            f"active {_mm(a)} vs passive {_mm(p)} (difference {100 * rel:.0f} % of mean; margin "
            f"{100 * EQUIVALENCE_MARGIN:.0f} %)", rel < EQUIVALENCE_MARGIN)
    for traj in trajs:
        for mode in modes:
            u, d = m("aruco", "undistorted", traj, mode), m("aruco", "distorted", traj, mode)
            add("A3", "4.1.2", "ArUco: distortion raises the error", f"{traj}, {mode}",
                f"distorted {_mm(d)} vs undistorted {_mm(u)}", d > u)
    for traj in trajs:
        p, a = m("aruco", "distorted", traj, "passive"), m("aruco", "distorted", traj, "active")
        add("A4", "4.1.2", "ArUco distorted: active error < passive error", traj,
            f"active {_mm(a)} vs passive {_mm(p)}", a < p)
    for mode in modes:
        c, g = m("aruco", "distorted", "circular", mode), m("aruco", "distorted", "diagonal", mode)
        add("A5", "4.1.2", "ArUco: distorted diagonal error < distorted circular error", mode,
            f"diagonal {_mm(g)} vs circular {_mm(c)}", g < c)
    # The paper's Fig. 14 "x and y" are the coordinates across the line of sight; in this lab's
    # world the home optical axis is +x, so the lateral coordinates are world y and z.
    for axis in "yz":
        p = m("aruco", "distorted", "diagonal", "passive", f"mean_abs_err_{axis}_m")
        a = m("aruco", "distorted", "diagonal", "active", f"mean_abs_err_{axis}_m")
        add("A6", "4.1.2", f"ArUco: active tracking adds lateral error (world {axis})", "distorted, diagonal",
            f"active {_mm(a)} vs passive {_mm(p)}", a > p)


def claims_markdown(claims: pd.DataFrame) -> str:
    """The claims table as Markdown, one line per checked condition."""
    lines = [
        "| id | § | claim | condition | measured | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for c in claims.itertuples():
        verdict = "holds" if c.holds else "does not hold"
        lines.append(f"| {c.id} | {c.section} | {c.statement} | {c.condition} | {c.measured} | {verdict} |")
    held = int(claims["holds"].sum())
    lines.append("")
    lines.append(f"{held} of {len(claims)} checked conditions hold.")
    return "\n".join(lines)
