"""CPU cost of the maps' frames: the light map and the payoff map, a baseline commit against the working tree.

Times a fixed sample of runs of the two maps, in one run, for the code at ``--baseline REF`` (a
``git worktree`` made under /tmp and removed at the end) and for the working tree. Each side is a
fresh interpreter (``sys.executable``, no fork) that imports ``gimbal_lab`` from its own folder
through ``PYTHONPATH`` and keeps its renderers open across its runs, as the map's workers do
(``gimbal_lab.runner``); a renderer is warmed by a short untimed run of the same config before its
first timed run. The sides take turns run by run (baseline, working tree, baseline, ...), so that
changes of the machine's load hit both alike. A run's cost is ``time.process_time`` around
``simulate`` in the worker (every thread of the process, llvmpipe's included) over the frames the
run made. Only the frame count of a run is read: never its errors (this is cost, not results).

The sample (the same parameters sent to both sides; each builds its configs with its own
``point_config``):

* light map (``gimbal_lab.studies.light``, the EMVA sensor, the body's vibration): four points of
  the full-size design, the dimmest and the brightest of the points below the median vibration and
  of those above it, each at exposures of 1 and 16.7 ms, each run kind of that side's ``RUNS``. Each
  side names its own run kinds; a light run is known by the pipeline it is built from (the
  ``pipeline`` argument of ``point_config``), which pairs the sides' runs where their run kinds are
  named or cut differently; a run only one side has is timed on that side alone;
* payoff map (``gimbal_lab.studies.payoff``): the full-size design's points with the shortest,
  the median and the longest exposure, each of its three pipelines.

A point's runs use seed 990 + its index in the sample (outside both maps' seeds). ``--runs N``
takes the first N runs of the sample in a stated order (two light runs for every payoff run while
both last; the light runs' order spreads points, exposures and run kinds over any prefix);
``--frames F`` shortens every run to its first F frames (default: as long as the map runs it).

Printed: each run's s/frame (CPU) on both sides and their ratio baseline / working tree; the ratio's
median and range, per map and overall; per light point and exposure, the CPU seconds of all of a
side's run kinds (the light map's cost per point, exposure and seed, which changes when the run
kinds do); the load average before and after, the machine (CPU model, cores), the date and the
commits measured; and an estimate of the full light map's wall time on two idle cores: the working
tree's CPU per frame over the sample's light runs × the map's frames at full size (its calibration
runs, ``light.all_configs()``, and two test runs per point and test seed) / 2.

Usage::

    python benchmarks/bench_maps.py --baseline REF [--runs N] [--frames F]
"""

from __future__ import annotations

import os

# One BLAS thread, as the study's workers run (gimbal_lab.runner); set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "1")

import argparse
import datetime
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import machine

REPO = Path(__file__).resolve().parents[1]
#: What a worker's reply line starts with (anything else a library prints on stdout is ignored).
REPLY = "BENCH_MAPS "
#: The light runs' exposures, s: the short end of the map's set and its longest.
LIGHT_EXPOSURES_S = (0.001, 0.0167)
#: Frames of the untimed run that warms a new renderer.
WARMUP_FRAMES = 3
FIRST_SEED = 990
#: The sides, in the order they take turns.
SIDES = ("baseline", "current")


# ----------------------------------------------------------------------------------------------
# the worker: one side's code, imported from PYTHONPATH
# ----------------------------------------------------------------------------------------------
def _light_runs(light) -> list:
    """This side's light run kinds as (run, pipeline it is built from): ``light.RUNS`` entries are
    (run, pointing kind, sphere method, ((pipeline, column prefix), ...))."""
    runs = []
    for entry in light.RUNS:
        if isinstance(entry, str):
            runs.append((entry, entry))
            continue
        pipes = next((e for e in entry[1:] if isinstance(e, tuple) and e and isinstance(e[0], tuple)), None)
        runs.append((str(entry[0]), str(pipes[0][0]) if pipes else str(entry[0])))
    return runs


def _light_map_size() -> dict:
    """The full-size light map's runs and frames: the calibration runs (``all_configs``) and the
    test runs, two per point and test seed at the point's frame count."""
    from gimbal_lab.studies import light

    study = light.LightStudy()
    configs = light.all_configs(study)
    index = light.calibration_index(study)
    frames_of_point = {}
    for point, config in zip(index["point"], configs):
        frames_of_point.setdefault(int(point), config.n_frames)
    test_runs = 2 * study.replicates * len(frames_of_point)
    test_frames = 2 * study.replicates * sum(frames_of_point.values())
    return {"calibration_runs": len(configs), "calibration_frames": sum(c.n_frames for c in configs),
            "test_runs": test_runs, "test_frames": test_frames, "points": study.points,
            "replicates": study.replicates}


def _sample_points() -> dict:
    """The sample's design points (factor values), from this side's full-size designs."""
    from gimbal_lab.studies import light, payoff

    table = light.design(light.LightStudy())
    median = table["vibration_deg"].median()
    chosen = []
    for half in (table[table["vibration_deg"] <= median], table[table["vibration_deg"] > median]):
        chosen += [half.loc[half["light_lux"].idxmin()], half.loc[half["light_lux"].idxmax()]]
    light_points = [{"point": int(row["point"]), **{n: float(row[n]) for n in light.FACTOR_NAMES}}
                    for row in chosen]
    table = payoff.design(payoff.PayoffStudy()).sort_values("exposure_ms", kind="stable").reset_index(drop=True)
    rows = [table.iloc[0], table.iloc[(len(table) - 1) // 2], table.iloc[-1]]
    payoff_points = [{"point": int(row["point"]), **{n: float(row[n]) for n in payoff.FACTOR_NAMES}} for row in rows]
    return {"light": light_points, "payoff": payoff_points}


def _config(case: dict, run_of: dict):
    """The case's config; ``run_of``: this side's light run of each pipeline a run is built from."""
    from gimbal_lab.studies import light, payoff

    values = case["values"]
    if case["map"] == "light":
        try:
            config = light.point_config(values, case["pipeline"], case["exposure_s"], case["seed"])
        except ValueError:  # a side whose point_config names its runs, not their pipelines
            config = light.point_config(values, run_of[case["pipeline"]], case["exposure_s"], case["seed"])
    else:
        config = payoff.point_config(values, case["pipeline"], case["seed"])
    if case["frames"] is not None:
        config = config.replace(revolutions=case["frames"] / config.frames_per_revolution)
    return config


def _worker() -> None:
    """Answer the parent's requests, one JSON line each, on stdout lines starting with :data:`REPLY`."""
    import gc

    import gimbal_lab
    from gimbal_lab.simulation import make_renderer, simulate
    from gimbal_lab.studies import light, payoff

    try:
        from gimbal_lab.runner import _prepare_process  # the map's own worker set-up
    except ImportError:
        _prepare_process = None
    if _prepare_process is not None:
        _prepare_process()
    else:
        import cv2

        cv2.setNumThreads(1)

    def reply(obj):
        sys.stdout.write(REPLY + json.dumps(obj) + "\n")
        sys.stdout.flush()

    run_of = {pipeline: run for run, pipeline in _light_runs(light)}
    renderers = {}
    for line in sys.stdin:
        request = json.loads(line)
        if request["op"] == "info":
            reply({"file": gimbal_lab.__file__, "light_runs": _light_runs(light),
                   "payoff_pipelines": list(payoff.PIPELINES), "points": _sample_points(),
                   "light_map": _light_map_size() if request.get("size") else None})
        elif request["op"] == "run":
            config = _config(request["case"], run_of)
            key = config.renderer_key
            if key not in renderers:
                renderers[key] = make_renderer(config)
                simulate(config.replace(revolutions=WARMUP_FRAMES / config.frames_per_revolution),
                         renderer=renderers[key])
            gc.collect()
            wall0, cpu0 = time.perf_counter(), time.process_time()
            result = simulate(config, renderer=renderers[key])
            cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
            reply({"cpu_s": cpu_s, "wall_s": wall_s, "frames": len(result.frames), "config": config.key})
        elif request["op"] == "quit":
            break
    for renderer in renderers.values():
        renderer.close()


# ----------------------------------------------------------------------------------------------
# the parent
# ----------------------------------------------------------------------------------------------
class Side:
    """One side's worker process, its code imported from ``root``."""

    def __init__(self, name: str, root: Path, log_dir: Path):
        self.name, self.root = name, root
        env = dict(os.environ, PYTHONPATH=str(root), PYOPENGL_PLATFORM="egl", LP_NUM_THREADS="1",
                   OPENBLAS_NUM_THREADS="1")
        self.log = open(log_dir / f"{name}.stderr", "w+")
        self.process = subprocess.Popen([sys.executable, "-u", str(Path(__file__).resolve()), "--worker"],
                                        env=env, cwd=log_dir, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=self.log, text=True)

    def ask(self, request: dict) -> dict:
        self.process.stdin.write(json.dumps(request) + "\n")
        self.process.stdin.flush()
        for line in self.process.stdout:
            if line.startswith(REPLY):
                return json.loads(line[len(REPLY):])
        self.log.seek(0)
        tail = " | ".join(self.log.read().strip().splitlines()[-3:])
        raise RuntimeError(f"the {self.name} worker (code from {self.root}) stopped: {tail}")

    def close(self) -> None:
        if self.process.poll() is None:
            try:
                self.process.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self.process.stdin.close()
                self.process.wait(timeout=60)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()
        self.log.close()


def _diagonal(n_points: int, runs: list, exposures: tuple) -> list:
    """Every (point, run, exposure) once, ordered so that any prefix spreads all three: pass e
    (per exposure), diagonal d, point p -> run (p + d) mod R, exposure (p + d + e) mod E."""
    order = []
    for e in range(len(exposures)):
        for d in range(len(runs)):
            for p in range(n_points):
                order.append((p, runs[(p + d) % len(runs)], exposures[(p + d + e) % len(exposures)]))
    return order


def _run_of(info: dict) -> dict:
    """Each side's light run of each pipeline a run is built from: {side: {pipeline: run}}."""
    return {side: {pipeline: run for run, pipeline in info[side]["light_runs"]} for side in SIDES}


def sample(info: dict, frames: int | None) -> list:
    """The sample's runs in their order. A light run is named by the pipeline it is built from
    (``point_config``'s argument), so the sides' runs pair even where their run kinds are named or
    cut differently; a run names the sides that have it. Light runs come two for every payoff run
    while both last."""
    run_of = _run_of(info)
    keys = list(dict.fromkeys([*run_of["current"], *run_of["baseline"]]))
    points = info["current"]["points"]
    light = [{"map": "light", "index": p, "values": points["light"][p], "pipeline": key, "exposure_s": e,
              "seed": FIRST_SEED + p, "frames": frames, "sides": [s for s in SIDES if key in run_of[s]]}
             for p, key, e in _diagonal(len(points["light"]), keys, LIGHT_EXPOSURES_S)]
    pipelines = info["current"]["payoff_pipelines"]
    payoff = [{"map": "payoff", "index": p, "values": points["payoff"][p], "pipeline": pipe, "exposure_s": None,
               "seed": FIRST_SEED + p, "frames": frames,
               "sides": [s for s in SIDES if pipe in info[s]["payoff_pipelines"]]}
              for p, pipe, _ in _diagonal(len(points["payoff"]), pipelines, (None,))]
    out = []
    while light or payoff:
        take_payoff = (len(out) % 3 == 1 and payoff) or not light
        out.append((payoff if take_payoff else light).pop(0))
    return out


def _git(*args) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], check=True, capture_output=True, text=True).stdout.strip()


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _spread(ratios: list) -> str:
    if not ratios:
        return "no run on both sides"
    return f"median {statistics.median(ratios):.2f}, range {min(ratios):.2f}–{max(ratios):.2f} ({len(ratios)} run{'s' * (len(ratios) != 1)})"


def _case_name(case: dict) -> str:
    if case["map"] == "light":
        return f"light L{case['index']} {case['exposure_s'] * 1e3:4.1f} ms  {case['pipeline']}"
    return f"payoff P{case['index']}          {case['pipeline']}"


def measure(args, baseline_root: Path, log_dir: Path) -> None:
    sides = {}
    try:
        sides = {name: Side(name, root, log_dir) for name, root in (("baseline", baseline_root), ("current", REPO))}
        info = {name: side.ask({"op": "info", "size": name == "current"}) for name, side in sides.items()}
        for name, side in sides.items():
            if not Path(info[name]["file"]).resolve().is_relative_to(side.root.resolve()):
                raise RuntimeError(f"the {name} worker imported gimbal_lab from {info[name]['file']}, "
                                   f"not from {side.root}")
        cases = sample(info, args.frames)
        if args.runs > len(cases):
            print(f"note: the sample has {len(cases)} runs; --runs {args.runs} takes them all")
        cases = cases[:args.runs]
        load_before, started = _load(), time.perf_counter()
        measured = []
        print(f"\n{'run':48s} {'baseline s/frame':>16s} {'current s/frame':>16s} {'frames':>7s} {'ratio':>6s}")
        fields = ("map", "values", "pipeline", "exposure_s", "seed", "frames")
        for case in cases:
            row = {name: sides[name].ask({"op": "run", "case": {k: case[k] for k in fields}})
                   for name in case["sides"]}
            measured.append((case, row))
            per_frame = {s: row[s]["cpu_s"] / row[s]["frames"] for s in row}
            cells = [f"{per_frame[s]:16.3f}" if s in row else f"{'(no such run)':>16s}" for s in SIDES]
            frames = "/".join(str(row[s]["frames"]) for s in SIDES if s in row)
            ratio = ""
            if len(row) == 2:
                ratio = f"{per_frame['baseline'] / per_frame['current']:6.2f}"
                if row["baseline"]["config"] != row["current"]["config"]:
                    ratio += "  (configs differ)"
            print(f"{_case_name(case):48s} {cells[0]} {cells[1]} {frames:>7s} {ratio}", flush=True)
        elapsed, load_after = time.perf_counter() - started, _load()
    finally:
        for side in sides.values():
            side.close()
    report(args, info, measured, load_before, load_after, elapsed)


def report(args, info: dict, measured: list, load_before: str, load_after: str, elapsed_s: float) -> None:
    per_frame = lambda r: r["cpu_s"] / r["frames"]  # noqa: E731
    print("\nratio baseline / current of CPU s per frame (> 1: the working tree is cheaper)")
    for part in ("light", "payoff", None):
        ratios = [per_frame(row["baseline"]) / per_frame(row["current"]) for case, row in measured
                  if len(row) == 2 and part in (None, case["map"])]
        print(f"  {part or 'both maps':10s} {_spread(ratios)}")
    differ = sum(1 for _, row in measured if len(row) == 2 and row["baseline"]["config"] != row["current"]["config"])
    if differ:
        print(f"  {differ} run(s) have different configs on the two sides (the sides' point_config differ)")

    run_of = _run_of(info)
    print("\nlight run kinds (each side's own RUNS; a run is named in the table by the pipeline it is built from):")
    for s in SIDES:
        print(f"  {s:8s} {len(run_of[s])}: " + "; ".join(f"{run!r} from {pipe!r}" for pipe, run in run_of[s].items()))
    groups = {}
    for case, row in measured:
        if case["map"] == "light":
            groups.setdefault((case["index"], case["exposure_s"]), []).append((case["pipeline"], row))
    print("light map, CPU s per point, exposure and seed (every run kind of the side, runs of the measured "
          "length):")
    group_ratios = []
    for (p, e), runs in sorted(groups.items()):
        totals = {}
        for s in SIDES:
            have = {key: row[s] for key, row in runs if s in row}
            if set(have) == set(run_of[s]):
                totals[s] = sum(r["cpu_s"] for r in have.values())
        if len(totals) == 2:
            group_ratios.append(totals["baseline"] / totals["current"])
            print(f"  L{p} {e * 1e3:4.1f} ms: baseline {totals['baseline']:7.1f} s, current {totals['current']:7.1f} s,"
                  f" ratio {group_ratios[-1]:.2f}")
    if group_ratios:
        print(f"  ratio of the totals: {_spread(group_ratios)}")
    else:
        print("  (no point and exposure with every run kind of both sides in this sample)")

    size = info["current"]["light_map"]
    light_rows = [row["current"] for case, row in measured if case["map"] == "light" and "current" in row]
    frames_total = size["calibration_frames"] + size["test_frames"]
    print(f"\nfull light map (working tree): {size['calibration_runs']} calibration + {size['test_runs']} test runs, "
          f"{frames_total:,} frames ({size['points']} points, {size['replicates']} test replicates)")
    if light_rows:
        cpu_per_frame = sum(r["cpu_s"] for r in light_rows) / sum(r["frames"] for r in light_rows)
        hours = cpu_per_frame * frames_total / 2 / 3600
        print(f"  measured {cpu_per_frame:.3f} CPU s per frame over the sample's {len(light_rows)} light runs -> "
              f"{cpu_per_frame * frames_total / 3600:.1f} CPU hours, some {hours:.1f} h ({60 * hours:.0f} min) on "
              "2 idle cores")
        print("  assuming the mean CPU per frame of the sample's light runs is the map's (the sample spans the "
              "design's light and vibration at 1 and 16.7 ms, not its rate, range, size or other exposures), and "
              "two workers each with an idle core doing nothing but the runs (no start-up, store or report)"
              + (f"; measured on each run's first {args.frames} frames" if args.frames is not None else ""))

    points = info["current"]["points"]
    print("\nsample: light " + ", ".join(_point_text(f"L{i}", p, ("light_lux", "vibration_deg"))
                                       for i, p in enumerate(points["light"])))
    print("        payoff " + ", ".join(_point_text(f"P{i}", p, ("exposure_ms",))
                                       for i, p in enumerate(points["payoff"])))
    rows = [r for _, row in measured for r in row.values()]
    share = sum(r["cpu_s"] for r in rows) / max(sum(r["wall_s"] for r in rows), 1e-9)
    print(f"load average (1, 5, 15 min) before {load_before}, after {load_after}; {elapsed_s / 60:.1f} min of runs, "
          f"the timed runs' CPU / wall {share:.2f}")
    print(f"machine: {machine()}")
    print(f"date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC")
    dirty = _git("status", "--porcelain", "--", "gimbal_lab").splitlines()
    print(f"baseline {args.baseline} = {args.baseline_commit[:10]}; current {_git('rev-parse', 'HEAD')[:10]}"
          + (f" with uncommitted changes to {len(dirty)} file(s) of gimbal_lab" if dirty else ""))


def _point_text(label: str, values: dict, keys: tuple) -> str:
    return f"{label} = design point {values['point']} (" + ", ".join(f"{k} {values[k]:.3g}" for k in keys) + ")"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="the commit to compare with (any git revision)")
    parser.add_argument("--runs", type=int, default=1000, help="runs of the sample to time per side (default all)")
    parser.add_argument("--frames", type=int, default=None, help="frames per run (default: the map's own)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        _worker()
        return 0
    if args.baseline is None:
        parser.error("--baseline is required (the commit to compare with)")
    if args.runs < 1:
        parser.error(f"--runs must be >= 1, got {args.runs}")
    if args.frames is not None and args.frames < 1:
        parser.error(f"--frames must be >= 1, got {args.frames}")
    try:
        args.baseline_commit = _git("rev-parse", "--verify", "--quiet", f"{args.baseline}^{{commit}}")
    except subprocess.CalledProcessError:
        parser.error(f"--baseline: {args.baseline!r} is not a commit of {REPO}")
    print(f"cost of the maps' frames: baseline {args.baseline} ({args.baseline_commit[:10]}) against the working "
          f"tree {REPO}; load average {_load()}", flush=True)
    log_dir = Path(tempfile.mkdtemp(prefix="bench-maps-"))
    tree = log_dir / "baseline"
    try:
        _git("worktree", "add", "--detach", str(tree), args.baseline_commit)
        measure(args, tree, log_dir)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except RuntimeError as error:
        print(f"bench_maps: {error}", file=sys.stderr)
        return 1
    except subprocess.CalledProcessError as error:
        print(f"bench_maps: {' '.join(error.cmd)} failed: {error.stderr.strip()}", file=sys.stderr)
        return 1
    finally:
        if tree.exists():
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], capture_output=True)
        shutil.rmtree(log_dir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
