"""``gimbal-lab run STUDY`` and ``gimbal-lab reproduce`` (= ``run paper``)."""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from . import STUDIES, load


def _positive_int(text: str) -> int:
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def _add_run_options(p) -> None:
    p.add_argument("--out", default="results", metavar="DIR",
                   help="output folder (default: results): the report goes to DIR/STUDY, finished runs to DIR/store")
    p.add_argument("--config", metavar="TOML", help="study parameters (e.g. data/studies/paper.toml, data/studies/moving-drone.toml)")
    p.add_argument("--replicates", type=_positive_int, metavar="N", help="replicates per cell (overrides --config)")
    p.add_argument("--jobs", type=_positive_int, metavar="N", help="local worker processes (default: every CPU)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://HOST:8786 (needs the [dask] extra)")
    p.add_argument("--no-cache", dest="cache", action="store_false",
                   help="recompute every run (the store is still written)")
    p.add_argument("--no-clips", dest="clips", action="store_false",
                   help="do not write the passive | active clips (DIR/STUDY/clips/*.mp4)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_parsers(sub) -> None:
    run = sub.add_parser("run", help="run a study and write its tables, claims and figures",
                         description="Run a study: its closed-loop runs (reusing finished ones), then tables, "
                                     "verdicts and figures written to OUT/STUDY.")
    run.add_argument("study", nargs="?", help=f"the study: {', '.join(STUDIES)}; or a scenario file, FILE.toml")
    run.add_argument("--list", action="store_true", help="list the studies and the example scenarios and exit")
    _add_run_options(run)
    run.set_defaults(func=_run)
    rep = sub.add_parser("reproduce", help="the paper's study (= run paper)",
                         description="The paper's study (§4.1): the same as `gimbal-lab run paper`.")
    _add_run_options(rep)
    rep.set_defaults(func=_run, study="paper", list=False)


def _run(args, parser) -> int:
    if args.list:
        for name, module in STUDIES.items():
            print(f"{name:12s} {load(name).DESCRIPTION}")
        from .scenario import shipped_scenarios

        for path, description in shipped_scenarios():
            shown = os.path.relpath(path) if not os.path.relpath(path).startswith("..") else str(path)
            print(f"{shown}  {description}")
        return 0
    if not args.study:
        parser.error("name a study (gimbal-lab run --list shows them)")
    try:
        module = load(args.study)
    except ValueError as exc:
        parser.error(str(exc))
    if not args.out or not args.out.strip():
        parser.error("--out must name a folder, got an empty string")
    try:
        if args.study.endswith(".toml"):  # a scenario file is its own config
            if args.config:
                raise ValueError("--config sets a built-in study's parameters; a scenario file holds its own")
            params = module.Study.from_toml(args.study)
        else:
            params = module.Study.from_toml(args.config) if args.config else module.Study()
        if args.replicates is not None:
            params = module.Study(**{**params.to_dict(), "replicates": args.replicates})
    except (ValueError, TypeError, FileNotFoundError) as exc:
        parser.error(str(exc))

    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from ..runner import ResultsStore, RunInterrupted, dask_executor

    out = Path(args.out)
    store_root = out / "store"
    store = ResultsStore(store_root, read=args.cache)
    log_path = out / "run.log"
    handler = logging.FileHandler(log_path)
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
    logger = logging.getLogger("gimbal_lab")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    executor = None
    if args.scheduler:
        try:
            executor = dask_executor(args.scheduler)
        except (ImportError, ValueError, OSError) as exc:
            parser.error(f"--scheduler: {exc}")
    n_runs = len(module.grid(params))
    where = f"the Dask cluster at {args.scheduler}" if executor else f"{args.jobs or os.cpu_count()} local processes"
    print(f"{args.study}: {n_runs} runs ({params.replicates} replicates per cell, {params.revolutions:g} "
          f"revolutions each) on {where}; finished runs are kept in {store_root}")
    try:
        report = module.run_study(params, out, store=store, executor=executor, jobs=args.jobs,
                                  progress=not args.quiet, clips=args.clips)
    except RunInterrupted as exc:
        print(f"\nInterrupted: {exc.kept} of {exc.total} runs are finished and kept in {store_root}; "
              f"run the same command again to resume.", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"\nInterrupted while writing the report; {out / getattr(params, 'name', args.study)} is unchanged. Run the same command "
              "again (every run is kept in the store).", file=sys.stderr)
        return 130
    finally:
        logger.removeHandler(handler)
        handler.close()
        if executor is not None:
            executor.shutdown(wait=False)
    claims = (report["folder"] / "claims.md").read_text()
    print(claims)
    print(f"Wrote {len(report['written'])} files to {report['folder']}; the per-run log is {log_path}.")
    return 0

