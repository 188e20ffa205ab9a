"""``gimbal-lab run STUDY`` and ``gimbal-lab reproduce`` (= ``run paper``)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

from .. import interrupts
from ..argtypes import int_at_least, positive_int
from . import STUDIES, load


# The payoff map's smallest Latin hypercube, the same number as studies.payoff.MIN_POINTS (a test
# checks); written here so that building the parser does not import the study and its numerics.
PAYOFF_MIN_POINTS = 12


def _add_run_options(p) -> None:
    p.add_argument("--out", default="results", metavar="DIR",
                   help="output folder (default: results): the report goes to DIR/STUDY, the log to DIR/run.log; "
                        "finished runs go to the store, whatever DIR is")
    p.add_argument("--store", metavar="DIR",
                   help="results store: finished runs are kept in and reused from DIR (default: $GIMBAL_LAB_STORE "
                        "when set, else results/store at the repository's root when run inside its checkout, else "
                        "the user's cache folder, ~/.cache/gimbal-lab/store on Linux)")
    p.add_argument("--config", metavar="TOML", help="study parameters (e.g. data/studies/paper.toml, data/studies/moving-drone.toml)")
    p.add_argument("--replicates", type=positive_int, metavar="N", help="replicates per cell (overrides --config)")
    p.add_argument("--points", type=int_at_least(PAYOFF_MIN_POINTS), metavar="N",
                   help=f"points of a map's Latin hypercube, >= {PAYOFF_MIN_POINTS} (the payoff and light maps only; "
                        "overrides --config)")
    p.add_argument("--jobs", type=positive_int, metavar="N", help="local worker processes (default: every CPU)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://HOST:8786 (needs the [dask] extra)")
    p.add_argument("--no-cache", dest="cache", action="store_false",
                   help="recompute every run (the store is still written)")
    p.add_argument("--no-clips", dest="clips", action="store_false",
                   help="do not write the passive | active clips (DIR/STUDY/clips/*.mp4)")
    p.add_argument("--overwrite-edited", action="store_true",
                   help="replace files of OUT/STUDY that were edited since the lab wrote them (by default a run "
                        "refuses such a folder before any work, naming the file)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_parsers(sub) -> None:
    run = sub.add_parser("run", help="run a study and write its tables, claims and figures",
                         description="Run a study: its closed-loop runs (reusing finished ones), then tables, "
                                     "verdicts and figures written to OUT/STUDY.",
                         epilog="OUT/STUDY is the lab's own folder: a run replaces the files it writes there and "
                                "deletes nothing; it refuses a folder holding files it did not write (its list is "
                                "OUT/STUDY/.gimbal-lab-manifest.json). Files of an earlier run that this one does not "
                                "write again (the clips after --no-clips) are kept, and the last line names them. A "
                                "file edited since the lab wrote it is refused unless --overwrite-edited; the report "
                                "is committed whole or, on any failure, the folder is left as it was.")
    run.add_argument("study", nargs="?", help=f"the study: {', '.join(STUDIES)}; or a scenario file, FILE.toml")
    run.add_argument("--list", action="store_true", help="list the studies and the example scenarios and exit")
    _add_run_options(run)
    run.set_defaults(func=_run, _parser=run)
    rep = sub.add_parser("reproduce", help="the paper's study (= run paper)",
                         description="The paper's study (§4.1): the same as `gimbal-lab run paper`.")
    _add_run_options(rep)
    rep.set_defaults(func=_run, study="paper", list=False, _parser=rep)


def _run(args, parser) -> int:
    if args.list:
        for name in STUDIES:
            print(f"{name:12s} {load(name).DESCRIPTION}")
        from .scenario import shipped_scenarios

        for path, description in shipped_scenarios():
            shown = os.path.relpath(path) if not os.path.relpath(path).startswith("..") else str(path)
            print(f"{shown}  {description}")
        return 0
    if not args.study:
        parser.error("name a study (gimbal-lab run --list shows them)")
    scenario = args.study.endswith(".toml")
    if not scenario and args.study not in STUDIES:
        parser.error(f"unknown study {args.study!r}; known studies: {', '.join(sorted(STUDIES))}; "
                     "or a scenario file, FILE.toml")
    if not args.out or not args.out.strip():
        parser.error("--out must name a folder, got an empty string")
    from ..outputs import OutputError, ReportFolder, check_writable_folder, overwriting_edited

    out = Path(args.out)
    module = load(args.study)
    try:
        if scenario:  # a scenario file is its own config
            if args.config:
                raise ValueError("--config sets a built-in study's parameters; a scenario file holds its own")
            params = module.Study.from_toml(args.study)
        else:
            params = module.Study.from_toml(args.config) if args.config else module.Study()
        if args.replicates is not None:
            params = module.Study(**{**params.to_dict(), "replicates": args.replicates})
        if getattr(args, "points", None) is not None:
            if "points" not in params.to_dict():
                raise ValueError(f"--points sets a map's points (payoff, light); {args.study} has none")
            params = module.Study(**{**params.to_dict(), "points": args.points})
    except (ValueError, TypeError, FileNotFoundError) as exc:
        parser.error(str(exc))
    name = params.name if scenario else args.study
    try:  # before anything is computed: a bad --out fails in one line, at once
        check_writable_folder(out, "--out")
        ReportFolder(out / name, "the report folder", overwrite_edited=args.overwrite_edited).check()
    except OutputError as exc:
        parser.error(str(exc))

    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from ..runner import ResultsStore, dask_executor, default_jobs, default_store_root

    # the study's and the runner's imports are done: a Ctrl-C one of them swallowed (trimesh's
    # optional imports catch every exception) stops the command here, before anything runs
    interrupts.stop_if_interrupted()

    if args.store is not None:
        if not args.store.strip():
            parser.error("--store must name a folder, got an empty string")
        store_root = Path(args.store).expanduser()
    else:  # one store whatever --out is (docs/design.md, "Results store and scale")
        store_root = default_store_root()
    store = ResultsStore(store_root, read=args.cache)  # a StoreError is one line (gimbal_lab.cli.main)
    try:  # the store may lie elsewhere (--store, $GIMBAL_LAB_STORE): OUT is not made with it
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"--out {out} cannot be made: {exc.strerror or exc}", out) from None
    log_path = out / "run.log"
    try:
        handler = logging.FileHandler(log_path)
    except OSError as exc:
        raise OutputError(f"cannot write the run log {log_path}: {exc.strerror or exc}", log_path) from None
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
    logger = logging.getLogger("gimbal_lab")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    executor = None
    try:
        if args.scheduler:
            try:
                executor = dask_executor(args.scheduler)
            except (ImportError, ValueError, OSError) as exc:
                parser.error(f"--scheduler: {exc}")
        # every run the study makes: its grid and what it adds beside it (the paper's known-lens
        # pipelines, the moving drone's arms), when it says so
        configs = set(getattr(module, "all_configs", module.grid)(params))
        stored = sum(c in store for c in configs) if store.read else 0
        where = f"the Dask cluster at {args.scheduler}" if executor else f"{args.jobs or default_jobs()} local processes"
        print(f"{args.study}: {len(configs)} runs ({params.replicates} replicates per "
              f"{'point' if hasattr(params, 'points') else 'cell'}, {params.revolutions:g} revolutions each): "
              f"{stored} stored, {len(configs) - stored} to compute on {where}; the store is {store_root}", flush=True)
        try:
            with overwriting_edited(args.overwrite_edited):  # the study's ReportFolder takes it from here
                report = module.run_study(params, out, store=store, executor=executor, jobs=args.jobs,
                                          progress=not args.quiet, clips=args.clips)
        except KeyboardInterrupt as exc:
            from ..outputs import ReportInterrupted

            if isinstance(exc, ReportInterrupted):  # the runs were finished: say so
                raise ReportInterrupted(f"{exc}; every run is kept in {store_root}: run the same command again "
                                        "to write the report in seconds") from None
            raise  # RunInterrupted says what is kept and what a rerun reuses (gimbal_lab.cli.main prints it)
    finally:
        logger.removeHandler(handler)
        handler.close()
        if executor is not None:
            executor.shutdown(wait=False)
    from .report import summary_lines

    print("\n".join(summary_lines(report["verdicts"], report["folder"] / "claims.md")))
    kept = report.get("kept", [])
    note = ""
    if kept:
        names = ", ".join(p.relative_to(report["folder"]).as_posix() for p in kept[:4])
        note = (f"; kept {len(kept)} file(s) of an earlier run that this one did not write again: {names}"
                + (", ..." if len(kept) > 4 else ""))
    print(f"Wrote {len(report['written'])} files to {report['folder']}{note}; the per-run log is {log_path}.")
    return 0
